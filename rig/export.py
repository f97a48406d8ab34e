"""Getting data out of a session: raw GNSS streams for post-processing, decoded tables as CSV.

:func:`export_raw_gnss` writes each receiver's port bytes (``/gnss/<receiver>/raw``, every read as
received) concatenated in recording order into ``<dir>/<receiver>.gps``, and the relayed correction
bytes (``/relay/raw``) into ``<dir>/corrections.rtcm3``. The files are byte-exact copies of what
the ports delivered, across every part of the session:

- ``.gps`` is the extension by which RTKLIB's ``convbin`` recognises NovAtel OEM4/6/7 data (the same
  as ``convbin -r nov``); NovAtel Convert and other NovAtel tools read the binary/ASCII mix as a
  receiver log file. (``.bin`` would be taken for Hemisphere by ``convbin``.)
- ``.rtcm3`` is ``convbin``'s extension for RTCM 3 (another relay format gets ``.rtca``, ``.cmr``).
  RTCM 3 carries no GPS week; ``convbin`` takes it from the file's modification time when no
  ``-tr`` is given, so every exported file's modification time is set to the log time of its
  first bytes.

Parts are read one at a time (memory stays at one part's raw data). A message's sequence number
runs on per topic across parts; a break in the sequence (lost or repeated reads) is reported.

:func:`export_csv` writes decoded tables through :mod:`rig.dataset`: GNSS logs per receiver, CAN
roles per bus (with the DBC and role map attached to the session), optical-sensor topics and the
event list.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

import rig.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.recorder.reader import PartScan, ProblemKind, find_parts, scan_part
from vsccore.errors import AnalysisError, ConfigError, SessionFileError

__all__ = [
    "CORRECTIONS_STEM",
    "NOVATEL_SUFFIX",
    "ExportKind",
    "ExportReport",
    "ExportedFile",
    "correction_suffix",
    "export_csv",
    "export_raw_gnss",
]

log = logging.getLogger(__name__)

NOVATEL_SUFFIX = ".gps"
"""RTKLIB convbin's extension for NovAtel OEM4/6/7 raw data (``-r nov``)."""
CORRECTIONS_STEM = "corrections"
_CORRECTION_SUFFIXES = {"rtcmv3": ".rtcm3", "rtcm3": ".rtcm3", "rtca": ".rtca", "cmr": ".cmr", "novatel": ".gps"}
_SEQ_MOD = 1 << 32


class ExportKind(StrEnum):
    """What an exported file holds."""

    GNSS_RAW = "gnss_raw"
    CORRECTIONS = "corrections"
    TABLE = "table"


@dataclass(frozen=True, slots=True)
class ExportedFile:
    """One file written by an export."""

    path: Path
    kind: ExportKind
    source: str
    """The topic (raw streams) or what the table holds (``gnss rover_a bestpos``)."""
    bytes: int
    records: int
    """Messages concatenated (raw streams) or rows (tables)."""
    first_ns: int | None = None
    last_ns: int | None = None
    parts: int = 0
    """Session parts that contributed (raw streams)."""
    sequence_breaks: int = 0
    """Places where the topic's sequence numbers do not run on by one (lost or repeated reads)."""


@dataclass(frozen=True, slots=True)
class ExportReport:
    """The files an export wrote, and what it noticed."""

    files: tuple[ExportedFile, ...]
    warnings: tuple[str, ...] = ()

    @property
    def total_bytes(self) -> int:
        return sum(f.bytes for f in self.files)


def correction_suffix(relay_format: str | None) -> str:
    """File suffix for the relayed corrections of ``relay_format`` (``rtcmv3`` → ``.rtcm3``; unknown → ``.rtcm3``)."""
    if not relay_format:
        return ".rtcm3"
    return _CORRECTION_SUFFIXES.get(relay_format.lower(), "." + "".join(c for c in relay_format.lower() if c.isalnum()))


def _is_raw_stream(topic: str) -> bool:
    if topic == T.TOPIC_RELAY_RAW:
        return True
    try:
        spec, _params = T.spec_for_topic(topic)
    except ValueError:
        return False
    return spec.pattern == "/gnss/{receiver}/raw"


def _scan_parts(path: Path | str, want: Callable[[str], bool]) -> Iterable[tuple[int, int, PartScan, list[str]]]:
    """(index, count, scan, warnings) of every part in order; a truncated last part is tolerated."""
    parts = find_parts(path)
    for i, p in enumerate(parts):
        where = f"{p} (part {i + 1} of {len(parts)})"
        try:
            scan = scan_part(p, want=want)
        except SessionFileError as exc:
            raise SessionFileError(f"{where}: {exc}") from exc
        notes: list[str] = []
        if scan.problem is not None:
            if scan.problem_kind is ProblemKind.TRUNCATED and i == len(parts) - 1:
                notes.append(f"{where}: {scan.problem}; exported up to its last complete record")
                log.warning("%s", notes[-1])
            else:
                raise SessionFileError(f"{where}: {scan.problem}")
        yield i, len(parts), scan, notes


@dataclass(slots=True)
class _Stream:
    topic: str
    kind: ExportKind
    path: Path
    file: IO[bytes]
    bytes: int = 0
    records: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    parts: set[int] = field(default_factory=set)
    next_seq: int | None = None
    breaks: int = 0


def _check_new(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise SessionFileError(f"{path} already exists (remove it or pass --overwrite)")


def _partial(path: Path) -> Path:
    return path.with_name(f".{path.name}.partial")


def rtklib_format(path: Path | str, sniff_bytes: int = 1 << 18) -> str:
    """RTKLIB ``convbin -r`` format of an exported raw file, from its content: ``rtcm3`` when RTCM 3
    frames outnumber NovAtel ones (a base receiver's correction output), else ``nov``."""
    from drivers.novatel import FrameKind, Framer

    with open(path, "rb") as f:
        head = f.read(sniff_bytes)
    framer = Framer(decode_logs=False, decode_nmea=False, decode_rtcm=False)
    frames = framer.feed(head)
    rtcm = sum(1 for fr in frames if fr.kind is FrameKind.RTCM3)
    return "rtcm3" if rtcm > len(frames) - rtcm else "nov"


def export_raw_gnss(path: Path | str, out_dir: Path | str, *, overwrite: bool = False) -> ExportReport:
    """Write every receiver's raw byte stream and the relayed corrections of a session into ``out_dir``.

    ``<out_dir>/<receiver>.gps`` per ``/gnss/<receiver>/raw`` topic and
    ``<out_dir>/corrections.rtcm3`` (suffix after the relay's format) for ``/relay/raw``; the
    directory is created if needed. Files are written under temporary names and renamed when the
    whole session has been read, so a failed export leaves no partial file behind. Raises
    :class:`~vsccore.errors.SessionFileError` for a missing or damaged part, a file that exists
    (unless ``overwrite``) or a write error, and :class:`~vsccore.errors.AnalysisError` when the
    session has no raw GNSS or correction stream.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"{out}: cannot create the export directory: {exc}") from exc
    streams: dict[str, _Stream] = {}
    warnings: list[str] = []
    relay_format: str | None = None
    try:
        for i, _n, scan, notes in _scan_parts(path, lambda t: _is_raw_stream(t) or t == T.TOPIC_RELAY_STATS):
            warnings.extend(notes)
            stats = scan.topics.get(T.TOPIC_RELAY_STATS)
            if stats is not None and len(stats):
                try:
                    fmt = json.loads(stats.data[-1]).get("format")
                except (ValueError, AttributeError):
                    fmt = None
                if isinstance(fmt, str) and fmt:
                    relay_format = fmt
            for topic in sorted(scan.topics):
                tm = scan.topics[topic]
                if topic == T.TOPIC_RELAY_STATS or not len(tm):
                    continue
                st = streams.get(topic)
                if st is None:
                    if topic == T.TOPIC_RELAY_RAW:
                        # the suffix follows the relay format, known for sure only at the end
                        final = out / f"{CORRECTIONS_STEM}.rtcm3"
                        kind = ExportKind.CORRECTIONS
                    else:
                        final = out / f"{T.spec_for_topic(topic)[1]['receiver']}{NOVATEL_SUFFIX}"
                        kind = ExportKind.GNSS_RAW
                        _check_new(final, overwrite)
                    tmp = _partial(final)
                    try:
                        fobj = open(tmp, "wb")  # noqa: SIM115 - closed below, also on errors
                    except OSError as exc:
                        raise SessionFileError(f"{tmp}: cannot create the export file: {exc}") from exc
                    st = _Stream(topic, kind, final, fobj)
                    streams[topic] = st
                _append(st, i, tm.log_time, tm.sequence, tm.data)
        for st in streams.values():
            st.file.close()
        if T.TOPIC_RELAY_RAW in streams:
            st = streams[T.TOPIC_RELAY_RAW]
            old = st.path
            st.path = out / f"{CORRECTIONS_STEM}{correction_suffix(relay_format)}"
            os.replace(_partial(old), _partial(st.path))
            _check_new(st.path, overwrite)
        for st in streams.values():
            os.replace(_partial(st.path), st.path)
    except BaseException:
        for st in streams.values():
            st.file.close()
            _partial(st.path).unlink(missing_ok=True)
        _partial(out / f"{CORRECTIONS_STEM}.rtcm3").unlink(missing_ok=True)
        raise
    if not streams:
        raise AnalysisError(f"{path}: the session has no raw GNSS (/gnss/<receiver>/raw) or {T.TOPIC_RELAY_RAW} data")
    files: list[ExportedFile] = []
    for st in sorted(streams.values(), key=lambda s: (s.kind != ExportKind.GNSS_RAW, s.topic)):
        if st.first_ns is not None:
            os.utime(st.path, ns=(st.first_ns, st.first_ns))
        if st.breaks:
            warnings.append(f"{st.topic}: sequence numbers break {st.breaks} times (reads lost or repeated)")
        files.append(ExportedFile(st.path, st.kind, st.topic, st.bytes, st.records, st.first_ns, st.last_ns,
                                  len(st.parts), st.breaks))
    return ExportReport(tuple(files), tuple(warnings))


def _append(st: _Stream, part: int, log_time: Sequence[int], sequence: Sequence[int], data: Sequence[bytes]) -> None:
    try:
        for chunk in data:
            st.file.write(chunk)
    except OSError as exc:
        raise SessionFileError(f"{st.path}: write failed: {exc}") from exc
    st.bytes += sum(len(d) for d in data)
    st.records += len(data)
    st.parts.add(part)
    if log_time:
        lo, hi = min(log_time), max(log_time)
        st.first_ns = lo if st.first_ns is None else min(st.first_ns, lo)
        st.last_ns = hi if st.last_ns is None else max(st.last_ns, hi)
    seq = np.asarray(sequence, dtype=np.int64)
    if seq.size:
        if st.next_seq is not None and int(seq[0]) != st.next_seq:
            st.breaks += 1
        st.breaks += int(np.count_nonzero((np.diff(seq) % _SEQ_MOD) != 1))
        st.next_seq = (int(seq[-1]) + 1) % _SEQ_MOD


# ---------------------------------------------------------------------------------------------
# CSV tables
# ---------------------------------------------------------------------------------------------


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    if isinstance(v, bool | np.bool_):
        return "1" if v else "0"
    if v is None:
        return ""
    if isinstance(v, dict | list):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


def _write_csv(path: Path, header: Sequence[str], columns: Sequence[npt.NDArray[Any] | list[Any]],
               overwrite: bool) -> int:
    _check_new(path, overwrite)
    n = len(columns[0]) if columns else 0
    lists = [c.tolist() if isinstance(c, np.ndarray) else list(c) for c in columns]
    try:
        with open(path, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(header)
            for i in range(n):
                w.writerow([_cell(col[i]) for col in lists])
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot write the CSV file: {exc}") from exc
    return n


def export_csv(path: Path | str, out_dir: Path | str, *, overwrite: bool = False) -> ExportReport:
    """Write the session's decoded tables as CSV files into ``out_dir`` (created if needed).

    - ``gnss_<receiver>_<log>.csv`` for BESTPOS, BESTVEL, HEADING, MARKPOS, MARKTIME and TIME:
      ``time_ns`` (common time base), ``host_ns``, ``valid``, then every field of the log;
    - ``can_<bus>_roles.csv``: ``time_ns, role, value, unit, ok, flags`` (SI, ISO 8855), long
      format in time order, decoded with the session's attached DBC and role map;
    - ``optical_<sensor>.csv`` from the ``/optical/<sensor>`` topics;
    - ``events.csv``: ``time_ns, kind, severity, source, text, start_ns, end_ns, details``.

    A table that cannot be made (e.g. no DBC attached) is skipped with a warning. Raises
    :class:`~vsccore.errors.SessionFileError` for unreadable parts and existing files.
    """
    from rig.dataset import load_session

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"{out}: cannot create the export directory: {exc}") from exc
    session = load_session(path)
    files: list[ExportedFile] = []
    warnings: list[str] = list(session.warnings)

    def table(name: str, source: str, header: Sequence[str], cols: Sequence[npt.NDArray[Any] | list[Any]]) -> None:
        p = out / name
        rows = _write_csv(p, header, cols, overwrite)
        files.append(ExportedFile(p, ExportKind.TABLE, source, p.stat().st_size, rows))

    for rx in session.receivers():
        g = session.gnss(rx)
        for log_name in ("bestpos", "bestvel", "heading", "markpos", "marktime", "time"):
            tbl = getattr(g, log_name)
            if len(tbl) == 0:
                continue
            names = list(tbl.columns)
            table(f"gnss_{rx}_{log_name}.csv", f"gnss {rx} {log_name}", ["time_ns", "host_ns", "valid", *names],
                  [tbl.time_ns, tbl.host_ns, tbl.valid, *(tbl.columns[k] for k in names)])
    for bus in session.can_buses():
        try:
            roles = session.can_roles(bus)
        except (AnalysisError, ConfigError) as exc:
            warnings.append(f"CAN bus {bus}: roles not exported: {exc}")
            continue
        rows_t: list[npt.NDArray[np.int64]] = []
        rows_role: list[npt.NDArray[Any]] = []
        rows_v: list[npt.NDArray[np.float64]] = []
        rows_unit: list[npt.NDArray[Any]] = []
        rows_ok: list[npt.NDArray[np.bool_]] = []
        rows_flags: list[npt.NDArray[Any]] = []
        for role, s in roles.items():
            n = len(s)
            rows_t.append(s.timestamps_ns)
            rows_role.append(np.full(n, role, dtype=object))
            rows_v.append(s.values)
            rows_unit.append(np.full(n, s.unit, dtype=object))
            rows_ok.append(s.ok)
            rows_flags.append(s.flags)
        if not rows_t:
            warnings.append(f"CAN bus {bus}: no role values decoded")
            continue
        t = np.concatenate(rows_t)
        order = np.argsort(t, kind="stable")
        table(f"can_{bus}_roles.csv", f"can {bus} roles", ["time_ns", "role", "value", "unit", "ok", "flags"],
              [t[order], np.concatenate(rows_role)[order], np.concatenate(rows_v)[order],
               np.concatenate(rows_unit)[order], np.concatenate(rows_ok)[order], np.concatenate(rows_flags)[order]])
    for topic in sorted(session.topic_counts):
        spec_params = _optical_sensor(topic)
        if spec_params is None:
            continue
        times, sample = session.optical(spec_params)
        table(f"optical_{spec_params}.csv", f"optical {spec_params}",
              ["time_ns", "vx_mps", "vy_mps", "speed_mps", "slip_angle_rad", "valid"],
              [times, sample.vx, sample.vy, sample.speed, sample.slip_angle, sample.valid])
    evs = session.events
    if evs:
        header = ["time_ns", "kind", "severity", "source", "text", "start_ns", "end_ns", "details"]
        table("events.csv", "events", header,
              [[t for t, _e in evs], [e.kind.value for _t, e in evs], [e.severity.value for _t, e in evs],
               [e.source for _t, e in evs], [e.text for _t, e in evs], [e.start_ns for _t, e in evs],
               [e.end_ns for _t, e in evs], [dict(e.details) for _t, e in evs]])
    if not files:
        raise AnalysisError(f"{path}: nothing to export as CSV (no decoded GNSS, CAN, optical or event data)")
    return ExportReport(tuple(files), tuple(warnings))


def _optical_sensor(topic: str) -> str | None:
    try:
        spec, params = T.spec_for_topic(topic)
    except ValueError:
        return None
    return params["sensor"] if spec.pattern == "/optical/{sensor}" else None
