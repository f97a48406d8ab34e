"""Time-base quality of every stream of a session: a verdict good / degraded / unusable, and the gates.

A result computed from a stream whose timing cannot be trusted is not a result. This module turns
what a session file holds (the message times, the raw CAN stamps, ``/rig/timebase``) into one
:class:`StreamQuality` per stream — ``gnss:<receiver>``, ``can:<bus>``, ``daq:<device>`` — with the
figures, the thresholds they were judged against and the fix, and :func:`gate` makes every command
that uses a stream check it: degraded → a warning that the command shows in its headline, unusable →
:class:`TimingQualityError` (exit status 2) naming the stream, the figure and the fix.

The figures (each judged by :data:`THRESHOLDS`, the one place the limits live):

- ``timing_error_ms`` (CAN, DAQ): how far a sample's time on the common base can be off. For a
  stream with device stamps it is the map error bound of the device clock
  (:meth:`rig.core.timebase.ClockEstimator.map_error_ns`) plus that of the host → GPS map it is composed
  with (which includes :data:`FLOOR_ALLOWANCE_MS` and the causality bound); for a stream stamped only by
  the host it is the host arrival lag itself (p95: there a late stamp *is* a wrong time) plus the host
  map's figure; for a DAQ aligned by sync pulses it is the alignment's RMS residual.
- ``host_map_error_ms`` (GNSS reference receiver): the host → GPS map's floor bound plus
  :data:`FLOOR_ALLOWANCE_MS` plus the DAQ's causality bound of the map (:func:`daq_causality_ns`;
  0 when causality holds). GNSS data carry their own GPS time, so this figure only degrades the
  receiver's verdict; it is added into the host-timed streams' timing error, where it does harm.
- ``missing_percent``: stalls (a silence longer than :data:`STALL_FACTOR` × the stream's own median
  period, and at least :data:`MIN_STALL_S`) and an early end (the stream stops more than
  :data:`END_TOLERANCE_S` before the last stream of the session) as a share of the session span.
  Each is a :class:`Gap` with its span.
- ``backward_max_ms``: the largest step back of ``log_time`` between consecutive messages of one
  channel in file order (the dataset sorts by time, so results do not suffer; a player does).

Why the timing bound is what it is, and how it relates to the truth. A frame's time is its device
stamp through the maps (device → host → GPS); how late the frame reached the host does not enter it,
so its error is the *maps'* error at its time, not its latency. Let ``T(x)`` be the true clock
relation plus the constant part of the latency that the configuration does not state; every pair
lies on or above it (latency ≥ 0), and the fitted lower envelope ``M(x)`` lies under every pair.
Over a window ``W`` (5 s) whose lowest pair sits ``h_W`` above the map and ``ε_W`` above ``T``:
``M ≤ lowest pair = T + ε_W`` and ``T ≤ lowest pair = M + h_W``, so ``−h_W ≤ M − T ≤ ε_W`` on ``W``.
``h_W`` is measured (:meth:`~rig.core.timebase.ClockEstimator.floor_heights`; a clock step or slew, or a
floor that rose — the pairs cannot say which, so the map may be off by that much there); ``ε_W``,
how late the most prompt pair of 5 s still was, is seen by no statistic of the pairs and is the
:data:`FLOOR_ALLOWANCE_MS` assumption. Composed, the two maps' floors enter with opposite signs (a
late CAN read moves the frame later, a late GNSS read moves GPS time earlier), so one allowance
covers both: ``|error| ≤ h_CAN + h_host + FLOOR_ALLOWANCE_MS``, and the figure exceeds the truth by
at most the allowance plus the floors' own wander. A frame that was merely late (a descheduled
reader, a burst) is latency: shorter than a window, it moves no figure.

The host map's ``ε`` is not left to the allowance alone where a clock the map does not enter shows
it: causality. A DAQ block's samples are timed by the sync pulse against MARKTIME (GPS time, no host
clock), and the block cannot reach the host before its last sample was taken; mapped through the
host → GPS map, a block that arrives *earlier* than that sample shows the map early by at least the
difference (``ε ≥ c``, ``c`` = :func:`daq_causality_ns`; ``ε = c + d`` with ``d`` the most prompt
block's delivery latency). A constant lateness of every GNSS pair (a wrong
``receivers.N.output_latency_s``, a USB-serial latency timer, receivers writing late on the
free-running simulated clock) shifts the map and its pairs alike and only this shows it. With the
allowance now standing for ``d`` (how late the most prompt DAQ block of 10 s still was, as it stood
for the most prompt GNSS log), ``ε ≤ c + FLOOR_ALLOWANCE_MS`` and the host map's figure is
``h_host + FLOOR_ALLOWANCE_MS + c`` — the old figure where causality holds (``c = 0``), and where it
does not, a figure that exceeds the truth by ``h_host + FLOOR_ALLOWANCE_MS − d`` (it falls short only
by what the DAQ's prompt delivery exceeds the floors and the allowance). ``c`` is robust to wild
stamps: it must be held by three half-seconds within 10 s (:func:`rig.core.timebase.causality_bound_ns`).

Measured against the simulator's truth (``benchmarks/study_timebase_gate.py`` and
``tests/quality/test_map_error.py``; CAN figure / true max error): governed at 1×, 0.20 / 0.11 ms
(host map 0.20 / 0.18 ms); governed at 8×, 0.27–0.61 ms / ≤ 0.14 ms in six runs, where the previous
figure — the 95th percentile per second of the lowest pair's height, which read every second whose
frames were all late as map error — gave 0.50–1.21 ms (degraded in two of the six; 1.03–1.34 ms on
stressed demo runs whose true error was ≤ 42 µs); a starved reader 1623 ms / 2.3 ms, unusable (its
floor rose by seconds: a backlog and a runaway clock look alike, and the stream also ended early).
A constant latency beyond the allowance — the simulated receivers writing late on the free-running
clock under load, 1.1–2.5 ms of constant offset, true CAN error 1.6–2.8 ms — was rated good at
0.51–0.63 ms before the causality bound (H31) and is now seen by it. Free-running at 1× (load
average 11–17 on 2 cores): causality 3.43 ms against a host map 3.62 ms early (median; at most
4.13), CAN figure 4.37 / true 4.06 ms, degraded (the floor bound alone: 0.94 ms, good); starved:
causality 6.20 ms, host map 6.83 ms early. The reference receiver's output latency configured 2 ms
short on the governed clock: causality 1.43 ms at 1× and 1.91–1.93 ms at 8×, CAN figure 1.64 / true
2.02 ms at 1× and 2.41–2.45 / 2.02–2.07 ms at 8× (the recorder's own verdicts the same), degraded,
where the floor bound alone gave 0.21–0.82 ms (good). The shortfall is the DAQ's prompt delivery
latency, which the simulated clock scales with its speed: at 8× under a load average of 15–25 it
reached 1.0 ms of simulated time (causality 0.98 ms for a 2 ms offset, 1.97 ms for 3 ms; CAN
figures 1.47 / 2.01 and 2.35 / 3.03 ms, still degraded). Governed and correctly configured: causality
0 at 1×, 0.05 ms at 8× (that host map is 0.1 ms early: inside the allowance), so those figures
barely move. A session without a synchronised DAQ (no sync channel, no MARKTIME) has no causality
evidence and keeps the allowance alone. The DAQ's sync-pulse RMS (≤ 1 µs) sits beside a true error
of 1–3 µs.

Rationale of the limits: the reference smoother (:mod:`rig.analysis.reference`) propagates the
heading between 20 Hz GNSS epochs (50 ms) with the CAN yaw rate, and its error budget asks for a
yaw-rate timing error ≪ 10 ms: at 1 ms the β reference is indistinguishable from perfect timing
(good), above 5 ms — half the budget — it visibly degrades (issue 15 measured 7.8–30.9° RMS with
seconds of lag), so that is unusable. A stream missing more than 10 % of the session leaves
manoeuvres unscored or cut (the starved recordings of issue 15 lost 30–36 %); any gap at all is worth a
warning — a second lost at the end of a short recording at 8× (the CAN reader's backlog when the
devices stop) is one.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.core.timebase import ClockEstimator, causality_bound_ns
from vsccore.errors import AnalysisError, RigError

if TYPE_CHECKING:
    from rig.data import Session

__all__ = [
    "END_TOLERANCE_S",
    "FLOOR_ALLOWANCE_MS",
    "MIN_STALL_S",
    "STALL_FACTOR",
    "THRESHOLDS",
    "Figure",
    "Gap",
    "StreamQuality",
    "Threshold",
    "TimingQualityError",
    "Verdict",
    "backward_steps",
    "check_inputs",
    "daq_causality_ns",
    "ended_early",
    "find_gaps",
    "gate",
    "info_json",
    "info_lines",
    "input_streams",
    "judge",
    "live_daq_causality_ns",
    "live_verdicts",
    "session_verdicts",
    "stall_threshold_ns",
    "stream_of_topic",
    "verdict_lines",
]

IntArray = npt.NDArray[np.int64]

STALL_FACTOR = 10.0
"""A silence longer than this many of the stream's own median periods is a stall: periodic sources
(20 Hz GNSS, 100 Hz CAN, DAQ blocks) do not miss ten periods in a row through scheduling jitter."""
MIN_STALL_S = 0.25
"""…and at least this long (a burst-mode topic's median interval can be a fraction of a ms)."""
FLOOR_ALLOWANCE_MS = 0.2
"""How late the most prompt pair of 5 s of a clock may still be, beyond the latency the configuration
states (output latency, serial transmission time): a read on a host that is not starved. No statistic
of the pairs can see it (module docstring); the governed simulator measures 0.01–0.11 ms. Where the
DAQ's causality shows the host map early, it stands for the most prompt DAQ block's delivery latency
on top of that bound instead."""
END_TOLERANCE_S = 1.0
"""A stream that stops more than this before the session's last stream is a gap (the devices are
stopped one after another, which takes well under a second)."""

_NS = 1_000_000_000
_MS = 1_000_000


class Verdict(StrEnum):
    """How far a stream's timing can be trusted (ordered: good < degraded < unusable)."""

    GOOD = "good"
    DEGRADED = "degraded"
    UNUSABLE = "unusable"

    @property
    def rank(self) -> int:
        return _RANK[self]


_RANK = {Verdict.GOOD: 0, Verdict.DEGRADED: 1, Verdict.UNUSABLE: 2}


class TimingQualityError(AnalysisError):
    """A command refused a stream whose time-base verdict is unusable (exit status 2)."""


@dataclass(frozen=True, slots=True)
class Threshold:
    """The limits of one figure: above ``degraded_above`` degraded, above ``unusable_above`` unusable."""

    figure: str
    unit: str
    degraded_above: float
    unusable_above: float | None
    why: str

    def judge(self, value: float) -> Verdict:
        if not math.isfinite(value):
            return Verdict.GOOD
        if self.unusable_above is not None and value > self.unusable_above:
            return Verdict.UNUSABLE
        if value > self.degraded_above:
            return Verdict.DEGRADED
        return Verdict.GOOD


THRESHOLDS: Mapping[str, Threshold] = {
    "timing_error_ms": Threshold(
        "timing_error_ms", "ms", 1.0, 5.0,
        "the reference smoother needs CAN yaw-rate timing ≪ 10 ms (module docstring)"),
    "host_map_error_ms": Threshold(
        "host_map_error_ms", "ms", 5.0, None,
        "GNSS data carry GPS time; the host map only matters to host-timed streams, where it is added"),
    "missing_percent": Threshold(
        "missing_percent", "%", 0.0, 10.0,
        "beyond 10 % of the session missing, manoeuvres go unscored or are cut"),
    "backward_max_ms": Threshold(
        "backward_max_ms", "ms", 0.0, None,
        "results sort by time; a player of the file sees time run back"),
}
"""Every limit of the verdicts, in one place (see the module docstring for the rationale)."""


@dataclass(frozen=True, slots=True)
class Figure:
    """One judged figure of a stream."""

    name: str
    value: float
    verdict: Verdict
    fix: str

    @property
    def threshold(self) -> Threshold:
        return THRESHOLDS[self.name]

    def text(self) -> str:
        th = self.threshold
        lim = f"degraded > {th.degraded_above:g}"
        if th.unusable_above is not None:
            lim += f", unusable > {th.unusable_above:g}"
        label = self.name.removesuffix("_ms").removesuffix("_percent").replace("_", " ")
        return f"{label} {self.value:.3g} {th.unit} ({lim} {th.unit})"

    def to_json(self) -> dict[str, Any]:
        th = self.threshold
        return {"value": self.value if math.isfinite(self.value) else None, "unit": th.unit,
                "verdict": self.verdict.value, "degraded_above": th.degraded_above,
                "unusable_above": th.unusable_above, "fix": self.fix}


def judge(name: str, value: float, fix: str) -> Figure:
    """The :class:`Figure` of ``value`` against :data:`THRESHOLDS` [``name``]."""
    return Figure(name, float(value), THRESHOLDS[name].judge(float(value)), fix)


@dataclass(frozen=True, slots=True)
class Gap:
    """A stretch where a stream was silent: a stall inside it, or its early end before the session's."""

    stream: str
    topic: str
    kind: str
    """``stall`` or ``ended_early``."""
    start_ns: int
    end_ns: int

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / _NS

    def text(self) -> str:
        what = "stalled" if self.kind == "stall" else "ended early"
        return f"{self.stream} {what}: no {self.topic} for {self.duration_s:.3f} s"

    def to_json(self) -> dict[str, Any]:
        return {"stream": self.stream, "topic": self.topic, "kind": self.kind, "start_ns": self.start_ns,
                "end_ns": self.end_ns, "duration_s": self.duration_s}


@dataclass(frozen=True, slots=True)
class StreamQuality:
    """The verdict of one stream, with its figures and gaps."""

    stream: str
    figures: tuple[Figure, ...]
    gaps: tuple[Gap, ...] = ()
    note: str = ""

    @property
    def verdict(self) -> Verdict:
        return max((f.verdict for f in self.figures), key=lambda v: v.rank, default=Verdict.GOOD)

    def bad(self) -> tuple[Figure, ...]:
        """The figures that made the verdict (worst first)."""
        worst = self.verdict
        return tuple(f for f in self.figures if f.verdict is worst) if worst is not Verdict.GOOD else ()

    def message(self) -> str:
        """One line: ``can:vsc unusable: timing error 240 ms (…); fix: …``."""
        bad = self.bad()
        if not bad:
            return f"{self.stream} {self.verdict.value}"
        fixes = list(dict.fromkeys(f.fix for f in bad))
        return f"{self.stream} {self.verdict.value}: {'; '.join(f.text() for f in bad)}; fix: {'; '.join(fixes)}"

    def to_json(self) -> dict[str, Any]:
        return {"stream": self.stream, "verdict": self.verdict.value, "note": self.note,
                "figures": {f.name: f.to_json() for f in self.figures},
                "gaps": [g.to_json() for g in self.gaps]}


# ---------------------------------------------------------------------------------------------
# Figures from times
# ---------------------------------------------------------------------------------------------


def backward_steps(log_ns: npt.ArrayLike) -> tuple[int, float]:
    """(count, largest step in ms) of ``log_time`` running back between consecutive messages (file order)."""
    t = np.asarray(log_ns, dtype=np.int64)
    if t.size < 2:
        return 0, 0.0
    d = np.diff(t)
    back = d < 0
    return int(np.count_nonzero(back)), float(-d[back].min() / _MS) if back.any() else 0.0


def stall_threshold_ns(period_ns: float) -> float:
    """A silence longer than this is a stall (:data:`STALL_FACTOR`, :data:`MIN_STALL_S`)."""
    return max(STALL_FACTOR * period_ns, MIN_STALL_S * _NS)


def find_gaps(stream: str, topic: str, times_ns: npt.ArrayLike, session_end_ns: int | None) -> list[Gap]:
    """Stalls inside ``times_ns`` (any order) and an early end before ``session_end_ns``."""
    t = np.sort(np.asarray(times_ns, dtype=np.int64))
    if t.size < 2:
        return []
    d = np.diff(t)
    pos = d[d > 0]
    period = float(np.median(pos)) if pos.size else 0.0
    thr = stall_threshold_ns(period)
    out = [Gap(stream, topic, "stall", int(t[i]), int(t[i + 1])) for i in np.flatnonzero(d > thr).tolist()]
    if session_end_ns is not None and session_end_ns - int(t[-1]) > max(thr, END_TOLERANCE_S * _NS):
        out.append(Gap(stream, topic, "ended_early", int(t[-1]), int(session_end_ns)))
    return out


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


# ---------------------------------------------------------------------------------------------
# Verdicts of a recorded session
# ---------------------------------------------------------------------------------------------


_CACHE: weakref.WeakKeyDictionary[Any, dict[str, StreamQuality]] = weakref.WeakKeyDictionary()


def _speed_fix(simulated: bool) -> str:
    return ("record at --speed 2 (or lower): the simulated devices and readers were starved of CPU"
            if simulated else "record on a less loaded host (close other programs, give the recorder a core)")


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
    speed_fix = _speed_fix(simulated)
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
    """The causality bound of the host → GPS map from ``device``'s blocks (ns; None: not judged) and why not.

    Each block's last sample is timed by the sync pulse against MARKTIME (GPS time; the host map does
    not enter), and the block cannot reach the host before that sample was taken: where its host receive
    time, mapped to GPS time, lies earlier, the map is early by at least that much
    (:func:`rig.core.timebase.causality_bound_ns`). Only blocks whose segment is synchronised count.
    """
    daq_cfg = ds.config.get("daq")
    if not isinstance(daq_cfg, Mapping) or not daq_cfg.get("sync_channel"):
        return None, "no sync channel"
    if daq_cfg.get("device") not in (None, device):
        return None, "not the configured DAQ"
    if ds.host_clock is None or ds.leap_seconds is None:
        return None, "no host → GPS map"
    marks = [r for r in ds.receivers() if len(ds.gnss(r).marktime) or len(ds.gnss(r).markpos)]
    if not marks:
        return None, "no MARKTIME/MARKPOS"
    try:
        d = ds.daq(device, sync_channel=str(daq_cfg["sync_channel"]), receiver=marks[0])
        _first, last, host = ds.daq_blocks(device)
    except RigError as exc:
        return None, f"not judged ({exc})"
    if not len(d):
        return None, "no samples"
    pos = np.minimum(np.searchsorted(d.sample_index, last), len(d) - 1)
    ok = (d.sample_index[pos] == last) & d.synced[pos]
    if not ok.any():
        return None, "no block timed by the sync pulse"
    arrival, mapped = ds.host_to_utc(host[ok])
    if not mapped:
        return None, "host map not on GPS time"
    b = causality_bound_ns(d.time_ns[pos[ok]], arrival)
    return b, "" if b is not None else "too few blocks"


def live_daq_causality_ns(
    block_pairs: tuple[npt.ArrayLike, npt.ArrayLike],
    ns_per_sample: float,
    segments: Sequence[tuple[int, Any]],
    host_clock: ClockEstimator,
) -> float | None:
    """:func:`daq_causality_ns` in a recorder at finalize, from what it kept (ns; None: not judged).

    ``block_pairs``: the DAQ clock's :meth:`~rig.core.timebase.ClockEstimator.floor_pairs` — per 0.5 s the most
    prompt block as (its last sample's file index × ``ns_per_sample``, host receive ns); ``segments``:
    (file index of the acquisition's index 0, its :class:`~rig.core.timebase.SyncFit` or None) per acquisition;
    ``host_clock``: the reference receiver's GPS → host estimator (compared on GPS time).
    """
    dev = np.asarray(block_pairs[0], dtype=np.float64)
    host = np.asarray(block_pairs[1], dtype=np.int64)
    segs = sorted(((int(b), f) for b, f in segments), key=lambda bf: bf[0])
    if dev.size == 0 or host_clock.n == 0 or all(f is None for _b, f in segs):
        return None
    idx = np.round(dev / ns_per_sample)
    own = np.searchsorted(np.asarray([b for b, _f in segs], dtype=np.int64), idx, side="right") - 1
    event = np.zeros(idx.size, dtype=np.int64)
    ok = np.zeros(idx.size, dtype=bool)
    for k, (_base, fit) in enumerate(segs):
        m = own == k
        if fit is not None and m.any():  # an acquisition not synchronised has no sync time
            event[m] = fit.gps_ns(idx[m])
            ok |= m
    if not ok.any():
        return None
    return causality_bound_ns(event[ok], host_clock.mapping().inverse_ns(host[ok]))


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


# ---------------------------------------------------------------------------------------------
# Verdicts of a live recording (at finalize)
# ---------------------------------------------------------------------------------------------


def stream_of_topic(topic: str) -> str | None:
    """The stream a topic belongs to (``/can/vsc/roles`` → ``can:vsc``), None for rig/relay/sim topics."""
    parts = topic.strip("/").split("/")
    if len(parts) >= 2 and parts[0] in ("gnss", "can", "daq"):
        return f"{parts[0]}:{parts[1]}"
    if parts[0] == "optical":
        return "daq"
    return None


def ended_early(last_log_ns: int, period_ns: float | None, session_end_ns: int) -> bool:
    """A channel that stopped this long before the session's end is a gap (:data:`END_TOLERANCE_S`)."""
    thr = max(stall_threshold_ns(period_ns or 0.0), END_TOLERANCE_S * _NS)
    return session_end_ns - last_log_ns > thr


def live_verdicts(
    timings: Sequence[Any],
    gaps: Sequence[Gap],
    *,
    span_ns: int,
    timing_error_ms: Mapping[str, float],
    host_map_error_ms: Mapping[str, float],
    simulated: bool,
) -> dict[str, StreamQuality]:
    """Verdicts from what a recorder knows at finalize.

    ``timings``: :class:`rig.store.sources.ChannelTiming` of every channel; ``gaps``: the stalls and
    early ends found; ``timing_error_ms``: per stream (``can:<bus>``), the live clock's envelope error
    plus the host map's; ``host_map_error_ms``: per GNSS stream.
    """
    fix = _speed_fix(simulated)
    streams: dict[str, list[Any]] = {}
    for ct in timings:
        name = stream_of_topic(ct.topic)
        if name is not None and name != "daq":
            streams.setdefault(name, []).append(ct)
    out: dict[str, StreamQuality] = {}
    for name, cts in sorted(streams.items()):
        figs: list[Figure] = []
        if name in timing_error_ms:
            figs.append(judge("timing_error_ms", timing_error_ms[name], fix))
        if name in host_map_error_ms:
            figs.append(judge("host_map_error_ms", host_map_error_ms[name], fix))
        mine = [g for g in gaps if g.stream == name]
        worst = max((100.0 * sum(g.end_ns - g.start_ns for g in mine if g.topic == ct.topic) / span_ns
                     for ct in cts), default=0.0) if span_ns > 0 else 0.0
        figs.append(judge("missing_percent", worst, fix))
        figs.append(judge("backward_max_ms", max(ct.clamp_max_ns for ct in cts) / _MS,
                          "the recorder clamped them: see the timebase events"))
        clamped = sum(ct.clamped for ct in cts)
        note = f"live: {clamped} log_time clamp(s)" if clamped else "live"
        out[name] = StreamQuality(name, tuple(figs), tuple(mine), note)
    return out


# ---------------------------------------------------------------------------------------------
# Gates
# ---------------------------------------------------------------------------------------------


def gate(verdicts: Mapping[str, StreamQuality], streams: Iterable[str], *, what: str) -> tuple[str, ...]:
    """Check the streams a result uses: the warnings of degraded ones; unusable ones raise.

    ``streams``: stream names (``gnss:rover_a``, ``can:vsc``, ``daq:daq1``); names the session has no
    verdict for are skipped (the command itself reports a missing stream).

    Raises:
        TimingQualityError: a stream is unusable; the message names the stream, the figure and the fix.
    """
    wanted = list(dict.fromkeys(streams))
    unusable = [verdicts[s] for s in wanted if s in verdicts and verdicts[s].verdict is Verdict.UNUSABLE]
    if unusable:
        raise TimingQualityError(f"{what}: refused, time base unusable — "
                                 + " | ".join(q.message() for q in unusable))
    return tuple(f"TIMING DEGRADED — {verdicts[s].message()}" for s in wanted
                 if s in verdicts and verdicts[s].verdict is Verdict.DEGRADED)


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


def verdict_lines(verdicts: Mapping[str, StreamQuality]) -> list[str]:
    """Human-readable lines, one per stream (``rig info``)."""
    lines = []
    for name in sorted(verdicts):
        q = verdicts[name]
        figs = ", ".join(f"{f.name} {f.value:.3g}" for f in q.figures if math.isfinite(f.value))
        line = f"{name:<16} {q.verdict.value.upper():<9} {figs}"
        if q.note:
            line += f"  [{q.note}]"
        lines.append(line)
        for g in q.gaps:
            lines.append(f"  gap: {g.text()}")
        if q.verdict is not Verdict.GOOD:
            lines.append(f"  {q.message()}")
    return lines
