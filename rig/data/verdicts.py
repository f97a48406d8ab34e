"""Time-base verdicts of a recorded session: every stream judged from what the file holds, and the gate of
analysis inputs (the thresholds and the live verdicts: :mod:`rig.core.quality`)."""

from __future__ import annotations

import math
import weakref
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.core.quality import (
    FLOOR_ALLOWANCE_MS,
    Figure,
    Gap,
    IntArray,
    StreamQuality,
    backward_steps,
    find_gaps,
    gate,
    judge,
    stall_threshold_ns,
    timing_fix_text,
    verdict_lines,
)
from rig.core.timebase import ClockEstimator
from rig.data.session import Session
from vsccore.errors import RigError

__all__ = ["check_inputs", "daq_causality_ns", "info_json", "info_lines", "input_streams", "session_verdicts"]

_MS = 1_000_000

_CACHE: weakref.WeakKeyDictionary[Any, dict[str, StreamQuality]] = weakref.WeakKeyDictionary()


def _missing_percent(gaps: Sequence[Gap], span_ns: int) -> float:
    if span_ns <= 0:
        return 0.0
    return 100.0 * sum(g.end_ns - g.start_ns for g in gaps) / span_ns


def _envelope(name: str, device_ns: IntArray, host_ns: IntArray) -> ClockEstimator | None:
    if device_ns.size < 2:
        return None
    order = np.argsort(device_ns, kind="stable")
    est = ClockEstimator(name)
    est.add_many(device_ns[order], host_ns[order])
    return est


def _lag_p95_ns(est: ClockEstimator, device_ns: IntArray, host_ns: IntArray) -> float:
    return float(np.percentile(host_ns - est.mapping()(device_ns), 95)) if device_ns.size else math.nan


@dataclass(slots=True)
class _Stream:
    name: str
    topics: list[str] = field(default_factory=list)
    times: IntArray | None = None
    """The stream's main series on the common time base (for gaps)."""
    main_topic: str = ""


def session_verdicts(ds: Session) -> dict[str, StreamQuality]:
    """Every stream's time-base verdict, from what the session file holds (cached per session).

    Streams: ``gnss:<receiver>`` (decoded logs), ``can:<bus>`` (frames and roles) and ``daq:<device>``
    (sample blocks and the optical channels). Raises nothing for a stream it cannot judge: such a
    stream gets no figure and a note.
    """
    cached = _CACHE.get(ds)
    if cached is not None:
        return cached
    simulated = bool(ds.config.get("simulation"))
    speed_fix = timing_fix_text(simulated)
    streams: dict[str, _Stream] = {}
    counts = ds.topic_counts
    for rx in ds.receivers():
        s = streams[f"gnss:{rx}"] = _Stream(f"gnss:{rx}")
        s.topics = [t for t in (T.gnss_bestpos(rx), T.gnss_bestvel(rx), T.gnss_time(rx), T.gnss_heading(rx),
                                T.gnss_fix(rx)) if t in counts]
        s.main_topic = T.gnss_bestpos(rx)
        if s.main_topic in counts:
            s.times = np.asarray(ds.gnss(rx).bestpos.time_ns, dtype=np.int64)
    notes: dict[str, str] = {}
    extra: dict[str, list[Figure]] = {}
    # host → GPS map (the reference receiver's envelope): its error goes into every host-timed stream
    host_dev_ms = math.nan
    causal_ms = 0.0
    host_fix = speed_fix
    ref = ds.host_clock
    if ref is not None:
        e = ref.map_error_ns()
        host_dev_ms = e / _MS if e is not None else math.nan
        # the lateness of the map's own pairs that no statistic of them sees, shown by the DAQ's causality
        causal: list[str] = []
        for dev_name in ds.daq_devices():
            b, why = daq_causality_ns(ds, dev_name)
            if b is not None:
                causal_ms = max(causal_ms, b / _MS)
                causal.append(f"DAQ {dev_name} causality {b / _MS:.3g} ms")
            else:
                causal.append(f"DAQ {dev_name} causality not judged: {why}")
        rx = ref.name.removeprefix("gnss:")
        if causal_ms > FLOOR_ALLOWANCE_MS:
            host_fix = (f"{speed_fix}; or receiver {rx}'s logs leave later than its output_latency_s "
                        f"([[receivers]]) states: the DAQ's blocks reach the host {causal_ms:.3g} ms before their "
                        "last sample on its time base")
        if f"gnss:{rx}" in streams:
            extra.setdefault(f"gnss:{rx}", []).append(
                judge("host_map_error_ms", host_dev_ms + FLOOR_ALLOWANCE_MS + causal_ms, host_fix))
            notes[f"gnss:{rx}"] = (f"host map: floor {host_dev_ms:.3g} ms + allowance {FLOOR_ALLOWANCE_MS:g} ms"
                                   + "".join(f"; {c}" for c in causal))
    host_add = (0.0 if math.isnan(host_dev_ms) else host_dev_ms) + FLOOR_ALLOWANCE_MS + causal_ms
    for bus in ds.can_buses():
        name = f"can:{bus}"
        s = streams[name] = _Stream(name)
        s.topics = [t for t in (T.can_frames(bus), T.can_roles(bus)) if t in counts]
        s.main_topic = T.can_frames(bus)
        try:
            frames = ds.can_frames(bus)
        except RigError as exc:  # an unreadable stream is the error of the command that reads it
            notes[name] = f"not judged: {exc}"
            continue
        s.times = np.asarray(frames.time_ns, dtype=np.int64)
        dev = frames.records["device_ts_ns"].astype(np.int64)
        host = frames.records["host_ts_ns"].astype(np.int64)
        if frames.time_source == "interface":
            est = _envelope(name, dev, host)
            env = est.map_error_ns() if est is not None else None
            err = (env / _MS if env is not None else math.nan) + host_add
            notes[name] = "interface stamps"
            if est is not None:
                notes[name] += f", arrival lag p95 {_lag_p95_ns(est, dev, host) / _MS:.3g} ms"
            extra.setdefault(name, []).append(judge("timing_error_ms", err, host_fix))
        else:
            lag = _host_arrival_lag_ms(frames.records)
            notes[name] = "host stamps only (no interface clock)"
            extra.setdefault(name, []).append(
                judge("timing_error_ms", lag + host_add,
                      "a CAN interface with hardware stamps (PCAN, Kvaser, Vector, SocketCAN); " + host_fix))
    tb = ds.timebase_records()
    for dev_name in ds.daq_devices():
        name = f"daq:{dev_name}"
        s = streams[name] = _Stream(name)
        s.main_topic = T.daq_samples(dev_name)
        s.topics = [s.main_topic, *(t for t in counts if t.startswith("/optical/"))]
        s.times = ds.message_times(s.main_topic)[0]
        rms = _last_sync_rms_ns(tb, dev_name)
        if rms is not None:
            notes[name] = "sync-pulse aligned"
            extra.setdefault(name, []).append(judge("timing_error_ms", rms / _MS,
                                                    "check the sync switch wiring to the DAQ and the event input"))
        else:
            notes[name] = "no live sync-pulse record: timed by the analysis' own alignment"
    # gaps: against the session's end, which GNSS (on GPS time) tells best; a late host-stamped stream
    # must not move it (its lag is judged by its timing figure)
    timed = [s for s in streams.values() if s.times is not None and s.times.size]
    ref_streams = [s for s in timed if s.name.startswith("gnss:")] or timed
    ends = [int(s.times.max()) for s in ref_streams if s.times is not None]
    starts = [int(s.times.min()) for s in ref_streams if s.times is not None]
    session_end = max(ends) if ends else None
    span = (max(ends) - min(starts)) if ends else 0
    out: dict[str, StreamQuality] = {}
    for name, s in streams.items():
        figs = list(extra.get(name, []))
        gaps: list[Gap] = []
        if s.times is not None and s.times.size:
            gaps = find_gaps(name, s.main_topic, s.times, session_end)
            figs.append(judge("missing_percent", _missing_percent(gaps, span), speed_fix))
        back = 0.0
        n_back = 0
        for topic in s.topics:
            n, mx = backward_steps(ds.message_times(topic)[0])
            n_back += n
            back = max(back, mx)
        figs.append(judge("backward_max_ms", back, "record with this version: log_time is monotonic per channel"))
        note = notes.get(name, "")
        if n_back:
            note = (note + "; " if note else "") + f"{n_back} backward log_time step(s)"
        out[name] = StreamQuality(name, tuple(figs), tuple(gaps), note)
    _CACHE[ds] = out
    return out


def daq_causality_ns(ds: Session, device: str) -> tuple[float | None, str]:
    """The causality bound of the session's host → GPS map from ``device``'s blocks (ns; None: not judged) and
    why not (:meth:`rig.data.session.Session.daq_causality_ns`)."""
    return ds.daq_causality_ns(device)


def _host_arrival_lag_ms(records: npt.NDArray[Any]) -> float:
    """p95 arrival lag of host-stamped frames, from the most frequent identifier's periodicity.

    Frame ``k`` of a periodic message is sent at ``t0 + k·P``; the lower envelope of (k·P, host time)
    is the on-time arrival, and each frame's height above it is how late it was stamped.
    """
    ids = records["can_id"].astype(np.int64)
    host = records["host_ts_ns"].astype(np.int64)
    if ids.size < 4:
        return math.nan
    vals, cnt = np.unique(ids, return_counts=True)
    sel = np.flatnonzero(ids == vals[int(np.argmax(cnt))])
    h = np.sort(host[sel])
    if h.size < 4:
        return math.nan
    d = np.diff(h)
    period = float(np.median(d[d > 0])) if np.any(d > 0) else 0.0
    if period <= 0:
        return math.nan
    # frame index: one period per frame, except across a silence long enough to be a gap (frames lost),
    # which is credited with the periods it spans (a backlog's burst must not count as lost frames)
    steps = np.where(d > stall_threshold_ns(period), np.round(d / period), 1.0)
    k = (h[0] + np.round(np.r_[0.0, np.cumsum(steps)] * period)).astype(np.int64)
    est = _envelope("can:host", k, h)
    return _lag_p95_ns(est, k, h) / _MS if est is not None else math.nan


def _last_sync_rms_ns(tb: Any, device: str) -> float | None:
    if not len(tb) or "clock" not in tb or "method" not in tb or "rms_ns" not in tb:
        return None
    clocks, methods, rms = tb["clock"], tb["method"], tb["rms_ns"]
    for i in range(len(tb) - 1, -1, -1):
        if str(clocks[i]) == device and str(methods[i]) == "sync_pulse":
            v = rms[i]
            try:
                f = float(v)
            except (TypeError, ValueError):
                return None
            return f if math.isfinite(f) else None
    return None


def input_streams(inputs: Any, *, gnss: bool = True, can: Iterable[str] | None = None,
                  optical: bool = True) -> list[str]:
    """The stream names a result computed from :class:`rig.data.inputs.SessionInputs` uses.

    ``gnss``: both rovers; ``can``: the roles used (None: every loaded role); ``optical``: the DAQ
    devices when optical series were loaded from them.
    """
    out: list[str] = []
    g = inputs.gnss
    if gnss and g is not None:
        out += [f"gnss:{g.a.receiver}", f"gnss:{g.b.receiver}"]
    roles = inputs.can if can is None else {r: inputs.can[r] for r in can if r in inputs.can}
    out += [str(sig.source) for sig in roles.values() if str(sig.source).startswith("can:")]
    if optical and inputs.optical:
        out += [f"daq:{d}" for d in inputs.session.daq_devices()]
    return list(dict.fromkeys(out))


def check_inputs(inputs: Any, *, what: str, gnss: bool = True, can: Iterable[str] | None = None,
                 optical: bool = True) -> tuple[tuple[str, ...], dict[str, StreamQuality]]:
    """:func:`gate` the streams of ``inputs`` a result uses: (warnings, the verdicts of those streams)."""
    verdicts = session_verdicts(inputs.session)
    used = input_streams(inputs, gnss=gnss, can=can, optical=optical)
    warnings = gate(verdicts, used, what=what)
    return warnings, {s: verdicts[s] for s in used if s in verdicts}


def _load_verdicts(path: Path | str) -> tuple[dict[str, StreamQuality], str | None]:
    from rig.data import load_session

    try:
        ds = load_session(path)
        return session_verdicts(ds), None
    except (RigError, OSError) as exc:
        return {}, f"not judged: {exc}"


def info_lines(path: Path | str) -> list[str]:
    """The verdict block of ``rig info`` for the session at ``path`` (never raises for a bad session)."""
    verdicts, problem = _load_verdicts(path)
    if problem is not None:
        return [problem]
    return verdict_lines(verdicts) or ["(no GNSS, CAN or DAQ stream to judge)"]


def info_json(path: Path | str) -> dict[str, Any]:
    """The verdicts of the session at ``path`` as JSON (``rig info --json``: ``timebase.verdicts``)."""
    verdicts, problem = _load_verdicts(path)
    return {"problem": problem, "streams": {k: q.to_json() for k, q in sorted(verdicts.items())}}

