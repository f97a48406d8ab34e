"""Campaign analysis: ``rig validate`` (and optionally ``calibrate-baseline`` and ``rollover``) on every session of a
test campaign, as Dask tasks, into one Parquet metrics table and an HTML report with trend plots.

- Sessions: :func:`find_sessions` turns directories (searched recursively) and glob patterns into session base
  paths (``DIR/NAME`` of the parts ``NAME.NNN.mcap``, or a lone ``FILE.mcap``).
- Work: one task per session (:func:`analyse_session`, a plain function of picklable arguments) reads the session
  once and validates it with every estimator that is not cached yet (``None``: the recorded CAN role
  ``vsc_beta_estimate``; else ``package.module:function`` as ``rig validate --estimator``). With
  ``calibrate`` the antenna mounting offset is estimated from the session's straight runs
  (:func:`~rig.evaluate.calibrate.calibrate_baseline`) and used by that session's validation in place of the
  offset in force (nothing is written beside the session); with ``rollover`` the LTR summary of
  :func:`rig.evaluate.validate.rollover_session` joins the rows.
- Schedulers: ``serial`` runs the tasks in this process; otherwise a ``distributed.LocalCluster`` of
  ``workers`` processes, or the cluster at a ``tcp://`` scheduler address (whose workers must have vsc-rig installed
  and see the session paths and the estimator modules). A failing session (unreadable file, missing stream,
  unusable time base, raising estimator, lost worker) becomes a row with its error; the campaign goes on.
- Cache (``OUT/cache``): one JSON entry per (session content, estimator identity, validation configuration).
  The session content key (:func:`session_content_key`) is, by default (``quick``), each part's name, size,
  mtime (ns) and a BLAKE2b hash of its last :data:`TAIL_BYTES` — the MCAP footer and summary section (chunk
  indexes with every chunk's offset, size and time span; statistics with message counts; the summary CRC), so a
  re-written, recovered, appended or truncated file changes the key, and a re-run over hundreds of sessions reads a
  megabyte per part instead of every byte; plus the hash of the session's calibration file, whose results the
  analysis uses. ``full`` hashes every byte of every part (use it when files may be edited in place with their
  mtime restored). The estimator identity is its spec and the BLAKE2b of its module's source; the configuration
  is the reference method, the calibrate flag and the vsc-rig version. Deterministic failures
  (:class:`~vsccore.errors.RigError`: bad file, missing stream) are cached with the key; unexpected ones are not.
- Output: ``OUT/metrics.parquet`` (:data:`SCHEMA`; one row per session × estimator × manoeuvre (plus ``overall``)
  × a_y bin (``all`` and the bins of :class:`rig.analysis.metrics.AyBin`)); with two or more estimators also
  ``OUT/compare.parquet`` (one row per session × manoeuvre × a_y bin, the metrics of each estimator side by side
  as ``rmse_deg[<estimator>]``, …); ``OUT/report.html`` (trend plots, embedded PNG); ``OUT/campaign.json`` (what
  this run did: sessions computed, taken from the cache, failed).
"""

from __future__ import annotations

import base64
import glob
import hashlib
import html
import importlib.util
import io
import json
import logging
import math
import os
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vsccore import __version__
from vsccore.errors import ConfigError, RigError, SessionFileError

if TYPE_CHECKING:
    import pyarrow as pa

    from rig.data.inputs import SessionInputs
    from rig.evaluate.validate import SessionValidation

__all__ = [
    "CACHE_FORMAT",
    "RECORDED_ESTIMATE",
    "SCHEMA_FIELDS",
    "TAIL_BYTES",
    "CampaignOptions",
    "CampaignResult",
    "KeyMode",
    "SessionTask",
    "analyse_session",
    "estimator_identity",
    "find_sessions",
    "run_campaign",
    "session_content_key",
]

log = logging.getLogger(__name__)

CACHE_FORMAT = "vsc-rig-campaign-cache/1"
TAIL_BYTES = 1 << 20
"""How much of each part's end the quick content key hashes (the MCAP footer and summary section)."""
RECORDED_ESTIMATE = "vsc_beta_estimate"
"""The ``estimator`` column of the rows that score the recorded CAN role ``vsc_beta_estimate``."""
SERIAL = "serial"

SCHEMA_FIELDS: tuple[tuple[str, str], ...] = (
    ("session", "string"),
    ("path", "string"),
    ("start_utc", "timestamp"),
    ("estimator", "string"),
    ("manoeuvre", "int32"),
    ("kind", "string"),
    ("label", "string"),
    ("t_start_s", "float64"),
    ("t_stop_s", "float64"),
    ("speed_kmh", "float64"),
    ("ay_peak_mps2", "float64"),
    ("ay_bin", "string"),
    ("ay_lo_mps2", "float64"),
    ("ay_hi_mps2", "float64"),
    ("n", "int64"),
    ("rmse_deg", "float64"),
    ("bias_deg", "float64"),
    ("max_abs_deg", "float64"),
    ("verdict", "string"),
    ("reference_valid_fraction", "float64"),
    ("session_passed", "bool"),
    ("time_base_verdict", "string"),
    ("time_base", "string"),
    ("mount_offset_deg", "float64"),
    ("mount_offset_u95_deg", "float64"),
    ("calibration_note", "string"),
    ("rollover_peak_ltr", "float64"),
    ("rollover_first_warning_s", "float64"),
    ("rollover_ltr_error_rms", "float64"),
    ("error", "string"),
)
"""The columns of ``metrics.parquet`` (name, Arrow type). ``manoeuvre``: index of the manoeuvre in the session,
null on the ``overall`` rows (``kind`` = ``overall``: low-speed driving left out) and on error rows. ``ay_bin``:
``all`` (the whole manoeuvre; ``verdict`` PASS/FAIL against ``[validation]``, NONE when nothing was compared) or
``LO-HI`` m/s² of |a_y| (no verdict). ``verdict`` ERROR: the row carries ``error``. ``time_base_verdict``: the
worst :mod:`rig.core.quality` verdict of the streams the validation used, ``time_base`` each of them."""


class KeyMode(StrEnum):
    """How the session content key is computed (module docstring)."""

    QUICK = "quick"
    FULL = "full"


@dataclass(frozen=True, slots=True)
class CampaignOptions:
    """What the campaign computes for every session."""

    estimators: tuple[str | None, ...] = (None,)
    """``None``: the recorded ``vsc_beta_estimate``; else ``package.module:function``."""
    method: str = "rts"
    calibrate: bool = False
    rollover: bool = False
    key_mode: KeyMode = KeyMode.QUICK

    def check(self) -> None:
        """Raises ConfigError naming the bad option."""
        if not self.estimators:
            raise ConfigError("rig campaign: give at least one estimator (or none for the recorded estimate)")
        if len(set(self.estimators)) != len(self.estimators):
            raise ConfigError(f"rig campaign --estimator: given twice: {list(self.estimators)}")
        for e in self.estimators:
            if e is not None and (":" not in e or e.startswith(":") or e.endswith(":")):
                raise ConfigError(f"rig campaign --estimator {e!r}: expected 'package.module:function'")
        if self.method not in ("raw", "wavelet", "rts"):
            raise ConfigError(f"rig campaign --method: expected raw, wavelet or rts, got {self.method!r}")


@dataclass(frozen=True, slots=True)
class SessionTask:
    """One session's work, as sent to a worker (picklable)."""

    path: str
    estimators: tuple[str | None, ...]
    """The estimators not in the cache."""
    method: str
    calibrate: bool
    rollover: bool


@dataclass(frozen=True, slots=True)
class CampaignResult:
    """What :func:`run_campaign` wrote and did."""

    table: Path
    compare: Path | None
    report: Path | None
    manifest: Path
    sessions: int
    computed: int
    """Session × estimator validations computed in this run."""
    cached: int
    """Session × estimator validations taken from the cache."""
    failed: int
    """Session × estimator rows with an error (computed or cached)."""
    rows: int
    elapsed_s: float
    scheduler: str
    errors: tuple[tuple[str, str, str], ...] = field(default=())
    """(session path, estimator, error) of every failed row."""


# --------------------------------------------------------------------------------------------
# Sessions and keys
# --------------------------------------------------------------------------------------------


def _sessions_in(p: Path) -> list[Path]:
    from rig.store.reader import part_index, session_base

    out: set[Path] = set()
    files = [p] if p.is_file() else sorted(p.rglob("*.mcap"))
    for f in files:
        if f.suffix != ".mcap":
            continue
        out.add(session_base(f) if part_index(f) is not None else f)
    return sorted(out)


def find_sessions(specs: Iterable[str | Path]) -> list[Path]:
    """Session base paths (or lone ``.mcap`` files) under directories, part files, session base paths (``DIR/NAME``)
    and glob patterns, sorted.

    Raises:
        SessionFileError: a spec matches nothing, or nothing holds a session (the message names it).
    """
    found: set[Path] = set()
    for spec in specs:
        s = str(spec)
        matches = [Path(m) for m in sorted(glob.glob(s, recursive=True))] if glob.has_magic(s) else [Path(s)]
        if len(matches) == 1 and not matches[0].exists() and any(matches[0].parent.glob(
                f"{glob.escape(matches[0].name)}.*.mcap")):
            found.add(matches[0])  # a session base path DIR/NAME
            continue
        if not matches or not any(m.exists() for m in matches):
            raise SessionFileError(f"rig campaign: {s}: no such file or directory")
        got = [b for m in matches for b in _sessions_in(m)]
        if not got:
            raise SessionFileError(f"rig campaign: {s}: holds no session (no NAME.NNN.mcap)")
        found.update(got)
    return sorted(found)


def _blake(data: Iterable[bytes]) -> str:
    h = hashlib.blake2b(digest_size=20)
    for b in data:
        h.update(b)
    return h.hexdigest()


def _file_chunks(path: Path, start: int = 0, block: int = 1 << 22) -> Iterable[bytes]:
    with path.open("rb") as f:
        f.seek(start)
        while chunk := f.read(block):
            yield chunk


def session_content_key(path: Path | str, mode: KeyMode = KeyMode.QUICK) -> str:
    """The content key of a session (module docstring: which bytes, and why).

    Raises:
        SessionFileError: the session's parts cannot be found or read.
    """
    from rig.data.sidefiles import calibration_file_path
    from rig.store import find_parts

    parts = find_parts(path)
    items: list[bytes] = [mode.value.encode()]
    try:
        for p in parts:
            st = p.stat()
            if mode is KeyMode.QUICK:
                digest = _blake(_file_chunks(p, max(0, st.st_size - TAIL_BYTES)))
                items.append(f"{p.name}|{st.st_size}|{st.st_mtime_ns}|{digest}".encode())
            else:
                items.append(f"{p.name}|{st.st_size}|{_blake(_file_chunks(p))}".encode())
        cal = calibration_file_path(path)
        if cal.exists():
            items.append(b"calibration|" + _blake(_file_chunks(cal)).encode())
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot read for the campaign cache key: {exc}") from exc
    return _blake(items)


def estimator_identity(estimator: str | None) -> str:
    """The estimator's cache identity: its spec and the hash of its module's source (when it can be found)."""
    if estimator is None:
        return RECORDED_ESTIMATE
    mod = estimator.partition(":")[0]
    try:
        spec = importlib.util.find_spec(mod)
    except (ImportError, ValueError):
        spec = None
    origin = None if spec is None else spec.origin
    if origin is None or not Path(origin).is_file():
        return f"{estimator}|source unknown"
    return f"{estimator}|{_blake(_file_chunks(Path(origin)))}"


def _entry_key(content: str, estimator: str | None, opts: CampaignOptions) -> str:
    config = json.dumps({"format": CACHE_FORMAT, "version": __version__, "method": opts.method,
                         "calibrate": opts.calibrate, "rollover": opts.rollover}, sort_keys=True)
    return _blake([content.encode(), b"\0", estimator_identity(estimator).encode(), b"\0", config.encode()])


# --------------------------------------------------------------------------------------------
# One session (runs on a worker)
# --------------------------------------------------------------------------------------------


def _estimator_label(estimator: str | None) -> str:
    return RECORDED_ESTIMATE if estimator is None else estimator


def _err_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {' '.join(str(exc).split()) or '(no message)'}"


def _bin_label(lo: float, hi: float) -> str:
    return f"{lo:g}-{'inf' if math.isinf(hi) else f'{hi:g}'}"


def _f(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _deg(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else math.degrees(x)


def _time_base(sv_time_base: Mapping[str, Any]) -> tuple[str | None, str | None]:
    if not sv_time_base:
        return None, None
    worst = max(sv_time_base.values(), key=lambda q: q.verdict.rank).verdict.value
    return worst, ", ".join(f"{k}={q.verdict.value}" for k, q in sorted(sv_time_base.items()))


def _validation_rows(sv: SessionValidation, base: dict[str, Any]) -> list[dict[str, Any]]:
    import numpy as np

    res = sv.result
    tb_worst, tb_text = _time_base(sv.time_base)
    common = {**base, "session_passed": sv.passed, "time_base_verdict": tb_worst, "time_base": tb_text}
    rows: list[dict[str, Any]] = []
    scores = [(i, s) for i, s in enumerate(s for s in res.per_manoeuvre if s.manoeuvre is not None)]
    for idx, score in [*scores, (None, res.overall)]:
        m = score.manoeuvre
        met = score.metrics
        if m is not None:
            sl = slice(m.start_index, m.stop_index)
            speed = sv.speed_mps[sl]
            ay = np.abs(sv.ay_mps2[sl])
            head = {"manoeuvre": idx, "kind": m.kind.value, "label": m.label, "t_start_s": m.t_start_s,
                    "t_stop_s": m.t_stop_s}
        else:
            speed, ay = sv.speed_mps, np.abs(sv.ay_mps2)
            head = {"manoeuvre": None, "kind": "overall", "label": "", "t_start_s": float(sv.t_s[0]),
                    "t_stop_s": float(sv.t_s[-1])}
        speed_kmh = _f(3.6 * float(np.nanmean(speed))) if np.any(np.isfinite(speed)) else None
        ay_peak = _f(float(np.nanmax(ay))) if np.any(np.isfinite(ay)) else None
        verdict = "NONE" if met is None else ("PASS" if met.passed else "FAIL")
        row = {**common, **head, "speed_kmh": speed_kmh, "ay_peak_mps2": ay_peak, "ay_bin": "all",
               "ay_lo_mps2": None, "ay_hi_mps2": None, "n": 0 if met is None else met.n_compared,
               "rmse_deg": None if met is None else _deg(met.rmse_rad),
               "bias_deg": None if met is None else _deg(met.bias_rad),
               "max_abs_deg": None if met is None else _deg(met.max_abs_rad),
               "verdict": verdict, "reference_valid_fraction": None if met is None else _f(met.valid_fraction)}
        rows.append(row)
        for b in () if met is None else met.bins:
            if b.n == 0:
                continue
            rows.append({**row, "ay_bin": _bin_label(b.lo_mps2, b.hi_mps2), "ay_lo_mps2": b.lo_mps2,
                         "ay_hi_mps2": _f(b.hi_mps2), "n": b.n, "rmse_deg": _deg(b.rmse_rad),
                         "bias_deg": _deg(b.bias_rad), "max_abs_deg": _deg(b.max_abs_rad), "verdict": None})
    return rows


def _error_row(base: dict[str, Any], error: str, time_base: tuple[str | None, str | None] = (None, None)) -> dict[
        str, Any]:
    return {**base, "manoeuvre": None, "kind": None, "verdict": "ERROR", "error": error,
            "time_base_verdict": time_base[0], "time_base": time_base[1]}


def _extras(inp: SessionInputs, task: SessionTask) -> tuple[dict[str, Any], SessionInputs]:
    """Calibration and rollover columns; the inputs with the calibrated mounting offset in force (``calibrate``)."""
    import dataclasses

    out: dict[str, Any] = {}
    if task.calibrate:
        from rig.evaluate.calibrate import calibrate_baseline

        try:
            cal = calibrate_baseline(inp)
            out.update(mount_offset_deg=_f(cal.offset_deg), mount_offset_u95_deg=_f(cal.u95_deg),
                       calibration_note=f"mounting offset {cal.offset_deg:+.3f}° used (was "
                       f"{inp.profile.calibration.mount_offset_deg:+.3f}°)")
            prof = inp.profile
            new_cal = prof.calibration.model_copy(update={"mount_offset_deg": cal.offset_deg})
            inp = dataclasses.replace(inp, profile=prof.model_copy(update={"calibration": new_cal}))
        except RigError as exc:
            out["calibration_note"] = f"not calibrated, offset in force used: {_err_text(exc)}"
    if task.rollover:
        from rig.evaluate.validate import rollover_session

        try:
            rep = rollover_session(inp)
            d = rep.to_dict()
            truth = d.get("truth")
            out.update(rollover_peak_ltr=_f(float(d["peak_abs_ltr"])),  # type: ignore[arg-type]
                       rollover_first_warning_s=_f(rep.prediction.first_warning_s()),
                       rollover_ltr_error_rms=_f(truth.get("ltr_error_rms")) if isinstance(truth, dict) else None)
        except RigError as exc:
            note = out.get("calibration_note")
            out["calibration_note"] = "; ".join(x for x in (note, f"rollover: {_err_text(exc)}") if x)
    return out, inp


def analyse_session(task: SessionTask) -> dict[str, Any]:
    """Validate one session with each estimator of ``task`` (a Dask task: never raises).

    Returns ``{"results": {estimator label: {"rows": [...], "cacheable": bool}}}``; an error becomes one row
    with ``verdict`` ERROR and the error text (cacheable when it is a :class:`RigError`: it follows from the data).
    """
    from rig.analysis.reference import ReferenceMethod
    from rig.data.inputs import load_inputs
    from rig.data.verdicts import session_verdicts
    from rig.evaluate.validate import validate_session

    name = Path(task.path).name
    results: dict[str, dict[str, Any]] = {}

    def base(est: str | None, inp: SessionInputs | None = None) -> dict[str, Any]:
        start = None if inp is None else inp.t0_ns
        return {"session": name if inp is None else inp.name, "path": task.path, "start_utc": start,
                "estimator": _estimator_label(est)}

    try:
        inp = load_inputs(task.path)
        extras, inp = _extras(inp, task)
    except Exception as exc:  # the campaign goes on: the session is a row with its error
        cacheable = isinstance(exc, RigError)
        if not cacheable:
            log.warning("session %s: %s", task.path, traceback.format_exc())
        for est in task.estimators:
            results[_estimator_label(est)] = {"rows": [_error_row(base(est), _err_text(exc))], "cacheable": cacheable}
        return {"results": results}
    for est in task.estimators:
        b = {**base(est, inp), **extras}
        try:
            sv = validate_session(inp, estimator=est, method=ReferenceMethod(task.method))
            results[_estimator_label(est)] = {"rows": _validation_rows(sv, b), "cacheable": True}
        except Exception as exc:
            cacheable = isinstance(exc, RigError)
            if not cacheable:
                log.warning("session %s, estimator %s: %s", task.path, est, traceback.format_exc())
            try:
                tb = _time_base(session_verdicts(inp.session))
            except Exception:  # the verdicts are context for the error row, not a second failure
                tb = (None, None)
            results[_estimator_label(est)] = {"rows": [_error_row(b, _err_text(exc), tb)], "cacheable": cacheable}
    return {"results": results}


# --------------------------------------------------------------------------------------------
# The campaign
# --------------------------------------------------------------------------------------------


def _cache_path(cache_dir: Path, key: str) -> Path:
    return cache_dir / key[:2] / f"{key}.json"


def _read_cache(cache_dir: Path, key: str) -> dict[str, Any] | None:
    p = _cache_path(cache_dir, key)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        log.warning("campaign cache %s unreadable (%s): recomputing", p, exc)
        return None
    if not isinstance(doc, dict) or doc.get("format") != CACHE_FORMAT or doc.get("key") != key:
        return None
    return doc


def _write_cache(cache_dir: Path, key: str, doc: dict[str, Any]) -> None:
    p = _cache_path(cache_dir, key)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(doc), encoding="utf-8")
        tmp.replace(p)
    except OSError as exc:
        raise SessionFileError(f"campaign cache {p}: cannot write: {exc}") from exc


def _arrow_schema() -> pa.Schema:
    import pyarrow as pa

    types = {"string": pa.string(), "float64": pa.float64(), "int32": pa.int32(), "int64": pa.int64(),
             "bool": pa.bool_(), "timestamp": pa.timestamp("ns", tz="UTC")}
    return pa.schema([(n, types[t]) for n, t in SCHEMA_FIELDS])


def _sort_key(row: Mapping[str, Any], order: Mapping[str, int]) -> tuple[Any, ...]:
    m = row.get("manoeuvre")
    lo = row.get("ay_lo_mps2")
    return (row["path"], order.get(row["estimator"], 0), m is None, -1 if m is None else m,
            row.get("ay_bin") != "all", -1.0 if lo is None else lo)


Executor = Callable[[Sequence[SessionTask]], Iterable[tuple[SessionTask, dict[str, Any] | BaseException]]]


def _serial(tasks: Sequence[SessionTask]) -> Iterable[tuple[SessionTask, dict[str, Any] | BaseException]]:
    for t in tasks:
        yield t, analyse_session(t)


def _dask(scheduler: str | None, workers: int) -> Callable[[Sequence[SessionTask]], Iterable[
        tuple[SessionTask, dict[str, Any] | BaseException]]]:
    def run(tasks: Sequence[SessionTask]) -> Iterable[tuple[SessionTask, dict[str, Any] | BaseException]]:
        from distributed import Client, LocalCluster, as_completed

        if not tasks:
            return
        cluster = None
        try:
            if scheduler is None:
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
                client = Client(cluster)
            else:
                client = Client(scheduler, timeout=30)
        except (OSError, TimeoutError) as exc:
            if cluster is not None:
                cluster.close()
            raise SessionFileError(f"rig campaign --scheduler {scheduler or 'local'}: cannot connect: {exc}") from exc
        try:
            futures = client.map(analyse_session, list(tasks), pure=False)
            task_of = {f.key: t for f, t in zip(futures, tasks, strict=True)}
            for fut in as_completed(futures):
                try:
                    yield task_of[fut.key], fut.result()
                except Exception as exc:  # a lost worker, an unpicklable result: that session's row says so
                    yield task_of[fut.key], exc
        finally:
            client.close()
            if cluster is not None:
                cluster.close()

    return run


def run_campaign(
    sessions: Sequence[Path],
    out: Path,
    options: CampaignOptions | None = None,
    *,
    scheduler: str | None = None,
    workers: int = 2,
    report: bool = True,
    progress: Callable[[str], None] | None = None,
) -> CampaignResult:
    """Analyse ``sessions`` (module docstring) and write the table, the comparison, the report and the manifest.

    ``scheduler``: ``None`` a LocalCluster of ``workers`` processes (``workers`` 0: serial), ``"serial"`` this
    process, else a Dask scheduler address (``tcp://host:8786``).

    Raises:
        ConfigError: bad options. SessionFileError: ``out`` cannot be written, the scheduler cannot be reached.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    opts = options or CampaignOptions()
    opts.check()
    if workers < 0:
        raise ConfigError(f"rig campaign --workers: must be ≥ 0, got {workers}")
    say = progress or (lambda _m: None)
    t_start = time.perf_counter()
    cache_dir = out / "cache"
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"rig campaign --out {out}: cannot create: {exc}") from exc
    labels = [_estimator_label(e) for e in opts.estimators]
    order = {lab: i for i, lab in enumerate(labels)}

    rows: list[dict[str, Any]] = []
    tasks: list[SessionTask] = []
    keys: dict[tuple[str, str], str] = {}
    status: dict[str, dict[str, str]] = {}
    cached = computed = 0
    for s in sessions:
        sp = str(s)
        status[sp] = {}
        try:
            content = session_content_key(s, opts.key_mode)
        except RigError as exc:
            for e in opts.estimators:
                rows.append(_error_row({"session": s.name, "path": sp, "start_utc": None,
                                        "estimator": _estimator_label(e)}, _err_text(exc)))
                status[sp][_estimator_label(e)] = "error (unreadable)"
            continue
        todo: list[str | None] = []
        for e in opts.estimators:
            key = _entry_key(content, e, opts)
            keys[(sp, _estimator_label(e))] = key
            doc = _read_cache(cache_dir, key)
            if doc is None:
                todo.append(e)
            else:
                rows.extend(doc["rows"])
                cached += 1
                status[sp][_estimator_label(e)] = "cached"
        if todo:
            tasks.append(SessionTask(sp, tuple(todo), opts.method, opts.calibrate, opts.rollover))
    say(f"{len(sessions)} sessions: {cached} validations cached, {sum(len(t.estimators) for t in tasks)} to compute")

    if scheduler == SERIAL or (scheduler is None and workers == 0):
        executor: Executor = _serial
        sched_text = "serial (in-process)"
    else:
        executor = _dask(scheduler, workers)
        sched_text = scheduler or f"LocalCluster ({workers} worker processes)"
    for done, (task, outcome) in enumerate(executor(tasks), start=1):
        if isinstance(outcome, BaseException):
            outcome = {"results": {_estimator_label(e): {
                "rows": [_error_row({"session": Path(task.path).name, "path": task.path, "start_utc": None,
                                     "estimator": _estimator_label(e)}, _err_text(outcome))],
                "cacheable": False} for e in task.estimators}}
        for lab, r in outcome["results"].items():
            computed += 1
            rows.extend(r["rows"])
            failed = any(x.get("verdict") == "ERROR" for x in r["rows"])
            status[task.path][lab] = "error" if failed else "computed"
            if r["cacheable"]:
                key = keys[(task.path, lab)]
                _write_cache(cache_dir, key, {"format": CACHE_FORMAT, "key": key, "session": task.path,
                                              "estimator": lab, "computed_unix": time.time(), "rows": r["rows"]})
        say(f"{done}/{len(tasks)} {Path(task.path).name}")

    rows.sort(key=lambda r: _sort_key(r, order))
    schema = _arrow_schema()
    table = pa.Table.from_pylist([{n: r.get(n) for n, _t in SCHEMA_FIELDS} for r in rows], schema=schema)
    metrics = out / "metrics.parquet"
    compare = out / "compare.parquet" if len(labels) > 1 else None
    try:
        pq.write_table(table, metrics)
        if compare is not None:
            pq.write_table(_compare_table(rows, labels), compare)
    except OSError as exc:
        raise SessionFileError(f"rig campaign --out {out}: cannot write the tables: {exc}") from exc
    errors = tuple((str(r["path"]), str(r["estimator"]), str(r["error"])) for r in rows if r.get("verdict") == "ERROR")
    report_path = _write_report(out / "report.html", rows, labels, errors) if report else None
    elapsed = time.perf_counter() - t_start
    manifest = out / "campaign.json"
    doc = {"format": CACHE_FORMAT, "version": __version__, "scheduler": sched_text, "sessions": len(sessions),
           "estimators": labels, "method": opts.method, "calibrate": opts.calibrate, "rollover": opts.rollover,
           "cache_key": opts.key_mode.value, "computed": computed, "cached": cached, "failed": len(errors),
           "rows": table.num_rows, "elapsed_s": elapsed, "status": status}
    try:
        manifest.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    except OSError as exc:
        raise SessionFileError(f"rig campaign: cannot write {manifest}: {exc}") from exc
    return CampaignResult(metrics, compare, report_path, manifest, len(sessions), computed, cached, len(errors),
                          table.num_rows, elapsed, sched_text, errors)


_COMPARED = ("n", "rmse_deg", "bias_deg", "max_abs_deg", "verdict", "error")


def _compare_table(rows: Sequence[Mapping[str, Any]], labels: Sequence[str]) -> pa.Table:
    """Session × manoeuvre × a_y bin, each estimator's metrics side by side (``rmse_deg[<estimator>]``)."""
    import pyarrow as pa

    joined: dict[tuple[Any, ...], dict[str, Any]] = {}
    for r in rows:
        k = (r["path"], r.get("manoeuvre"), r.get("kind"), r.get("ay_bin"))
        j = joined.setdefault(k, {"session": r["session"], "path": r["path"], "manoeuvre": r.get("manoeuvre"),
                                  "kind": r.get("kind"), "label": r.get("label"), "speed_kmh": r.get("speed_kmh"),
                                  "ay_bin": r.get("ay_bin")})
        for c in _COMPARED:
            j[f"{c}[{r['estimator']}]"] = r.get(c)
    fields = [pa.field("session", pa.string()), pa.field("path", pa.string()), pa.field("manoeuvre", pa.int32()),
              pa.field("kind", pa.string()), pa.field("label", pa.string()), pa.field("speed_kmh", pa.float64()),
              pa.field("ay_bin", pa.string())]
    types = {"n": pa.int64(), "verdict": pa.string(), "error": pa.string()}
    for lab in labels:
        fields += [pa.field(f"{c}[{lab}]", types.get(c, pa.float64())) for c in _COMPARED]
    schema = pa.schema(fields)
    return pa.Table.from_pylist([{f.name: j.get(f.name) for f in schema} for j in joined.values()], schema=schema)


# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _write_report(path: Path, rows: Sequence[Mapping[str, Any]], labels: Sequence[str],
                  errors: Sequence[tuple[str, str, str]]) -> Path:
    """The campaign HTML report: error against a_y per estimator, overall RMSE across sessions, tables."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots: list[tuple[str, str]] = []
    bins = [r for r in rows if r.get("kind") != "overall" and r.get("ay_bin") not in ("all", None)
            and r.get("rmse_deg") is not None]
    fig, ax = plt.subplots(figsize=(8, 4.2))
    try:
        for i, lab in enumerate(labels):
            sel = [r for r in bins if r["estimator"] == lab]
            if not sel:
                continue
            mids: dict[float, list[float]] = {}
            for r in sel:
                hi = r["ay_hi_mps2"] if r["ay_hi_mps2"] is not None else r["ay_lo_mps2"] + 2.0
                mids.setdefault(0.5 * (r["ay_lo_mps2"] + hi), []).append(r["rmse_deg"])
            x = sorted(mids)
            off = 0.12 * (i - 0.5 * (len(labels) - 1))
            ax.scatter([m + off for m in x for _ in mids[m]], [v for m in x for v in mids[m]], s=10, alpha=0.5,
                       color=f"C{i}")
            ax.plot(x, [sorted(mids[m])[len(mids[m]) // 2] for m in x], "-o", color=f"C{i}", label=f"{lab} (median)")
        ax.set_xlabel("|a_y| bin centre (m/s²)")
        ax.set_ylabel("RMSE of β (°)")
        ax.set_title("Sideslip error against lateral acceleration, every manoeuvre of every session")
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        fig.tight_layout()
        plots.append(("Error against a_y", _png(fig)))
    finally:
        plt.close(fig)
    overall = [r for r in rows if r.get("kind") == "overall" and r.get("ay_bin") == "all"]
    sessions = sorted({(r.get("start_utc") or 0, r["path"]) for r in overall})
    pos = {p: i for i, (_s, p) in enumerate(sessions)}
    fig, ax = plt.subplots(figsize=(8, 4.2))
    try:
        for i, lab in enumerate(labels):
            pts = sorted((pos[r["path"]], r["rmse_deg"]) for r in overall if r["estimator"] == lab
                         and r.get("rmse_deg") is not None)
            if pts:
                ax.plot([a for a, _ in pts], [b for _, b in pts], "-o", ms=4, color=f"C{i}", label=lab)
        ax.set_xlabel("session (in order of recording)")
        ax.set_ylabel("overall RMSE of β (°)")
        ax.set_title("Overall error across the campaign")
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        fig.tight_layout()
        plots.append(("Overall error across sessions", _png(fig)))
    finally:
        plt.close(fig)

    def cell(v: Any) -> str:
        if v is None:
            return "–"
        if isinstance(v, float):
            return f"{v:.3f}"
        return html.escape(str(v))

    head = "".join(f"<th colspan=3>{html.escape(lab)}</th>" for lab in labels)
    sub = "<th>RMSE °</th><th>bias °</th><th>verdict</th>" * len(labels)
    by: dict[str, dict[str, Mapping[str, Any]]] = {}
    for r in overall:
        by.setdefault(r["path"], {})[r["estimator"]] = r
    body = []
    for _s, p in sessions:
        cells = "".join(f"<td>{cell(by[p].get(lab, {}).get('rmse_deg'))}</td><td>"
                        f"{cell(by[p].get(lab, {}).get('bias_deg'))}</td><td>{cell(by[p].get(lab, {}).get('verdict'))}"
                        "</td>" for lab in labels)
        name = next(iter(by[p].values()))["session"]
        tb = next(iter(by[p].values())).get("time_base_verdict")
        body.append(f"<tr><td>{html.escape(name)}</td><td>{cell(tb)}</td>{cells}</tr>")
    errs = "".join(f"<tr><td>{html.escape(p)}</td><td>{html.escape(e)}</td><td>{html.escape(t)}</td></tr>"
                   for p, e, t in errors)
    imgs = "".join(f"<h2>{html.escape(t)}</h2><img alt='{html.escape(t)}' src='data:image/png;base64,{b}'>"
                   for t, b in plots)
    doc = (f"<!doctype html><html><head><meta charset='utf-8'><title>vsc-rig campaign</title><style>"
           "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
           "padding:2px 6px}</style></head><body>"
           f"<h1>Campaign: {len(sessions) + len({p for p, _e, _t in errors} - set(by))} sessions, "
           f"{len(errors)} failed</h1>{imgs}<h2>Overall per session</h2><table><tr><th>session</th>"
           f"<th>time base</th>{head}</tr><tr><th></th><th></th>{sub}</tr>{''.join(body)}</table>"
           f"<h2>Failed</h2><table><tr><th>session</th><th>estimator</th><th>error</th></tr>{errs}</table>"
           f"<p>vsc-rig {html.escape(__version__)}</p></body></html>")
    try:
        path.write_text(doc, encoding="utf-8")
    except OSError as exc:
        raise SessionFileError(f"rig campaign: cannot write {path}: {exc}") from exc
    return path
