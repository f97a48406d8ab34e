"""Time-base quality of a stream: the thresholds, the verdict good / degraded / unusable, the gate, and the
verdicts a recorder gives at finalize.

A result computed from a stream whose timing cannot be trusted is not a result. One
:class:`StreamQuality` per stream — ``gnss:<receiver>``, ``can:<bus>``, ``daq:<device>`` — carries the
figures, the thresholds they were judged against and the fix (a recorded session's verdicts:
:mod:`rig.data.verdicts`), and :func:`gate` makes every command that uses a stream check it: degraded → a
warning that the command shows in its headline, unusable →
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

Rationale of the limits: the reference smoother (:mod:`rig.analysis.reference`) propagates the
heading between 20 Hz GNSS epochs (50 ms) with the CAN yaw rate, and its error budget asks for a
yaw-rate timing error ≪ 10 ms: at 1 ms the β reference is indistinguishable from perfect timing
(good), above 5 ms — half the budget — it visibly degrades, so that is unusable. A stream missing
more than 10 % of the session leaves manoeuvres unscored or cut; any gap at all is worth a warning.
The bound checked against the simulator's truth, and the figures behind the limits:
``docs/decisions/0006-timebase-verdicts.md``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from rig.core.timebase import ClockEstimator, causality_bound_ns
from vsccore.errors import AnalysisError

if TYPE_CHECKING:
    pass

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
    "ended_early",
    "find_gaps",
    "gate",
    "judge",
    "live_daq_causality_ns",
    "live_verdicts",
    "stall_threshold_ns",
    "stream_of_topic",
    "timing_fix_text",
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


# ---------------------------------------------------------------------------------------------
# Verdicts of a recorded session
# ---------------------------------------------------------------------------------------------




def timing_fix_text(simulated: bool) -> str:
    return ("record at --speed 2 (or lower): the simulated devices and readers were starved of CPU"
            if simulated else "record on a less loaded host (close other programs, give the recorder a core)")


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
    fix = timing_fix_text(simulated)
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
