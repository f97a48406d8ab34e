"""Manoeuvre segmentation of a drive (automatic and from operator marks) and scoring per manoeuvre.

Automatic segmentation works on the vehicle's own signals on one time base (speed, steering-wheel
angle, yaw rate, lateral acceleration) and labels every sample:

- LOW_SPEED (low-speed manoeuvring): speed below ``low_speed_mps`` (default 15 km/h; parking,
  steering-ratio circles). The GNSS sideslip reference is not needed (nor meaningful) there, so the
  overall score and the reference's valid fraction leave it out (docs/manoeuvres.md).
- STRAIGHT: at least ``min_straight_s`` of |a_y| < 0.5 m/s², |r| < 1 °/s, |SWA| < 10°.
- Otherwise samples are *active*; active stretches closer than ``merge_gap_s`` are one event,
  padded by ``pad_s``. Each event is classified from its steering *lobes* (stretches where the
  SWA has one sign and exceeds 30 % of the event's peak), the steering rate at their onsets and
  the speed change:

  ============================ ==========================================================
  STEADY_STATE_CORNERING       one lobe lasting ≥ ``steady_min_s`` (ISO 4138)
  STEP_STEER                   one lobe, fast onset (> ``fast_steer_dps``), speed held (ISO 7401)
  J_TURN                       one lobe, fast onset, speed falls by > 5 % (throttle released)
  FISHHOOK                     two lobes of opposite sign, the second held ≥ 2 s (NHTSA)
  SINE_WITH_DWELL              two lobes, fast onset, the second shorter (FMVSS 126)
  LANE_CHANGE                  two lobes, slow onset, the second shorter than 2 s (ISO 3888-2)
  SLALOM                       five or more alternating lobes, evenly spaced (their onsets'
                               spacing varies by ≤ 20 %)
  DOUBLE_LANE_CHANGE           three or more alternating lobes within 15 s (ISO 3888-1)
  OTHER                        anything else (curves, transitions)
  ============================ ==========================================================

Operator marks (``rig mark`` during a session) override the automatic labels where they lie.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rig.analysis.arrays import as_1d, check_time, runs
from rig.analysis.metrics import Tolerances, ValidationMetrics, compare
from vsccore.angles import FloatArray
from vsccore.errors import AnalysisError

__all__ = [
    "Manoeuvre",
    "ManoeuvreKind",
    "ManoeuvreScore",
    "SegmentationParams",
    "apply_marks",
    "score_manoeuvres",
    "segment_manoeuvres",
]


class ManoeuvreKind(enum.StrEnum):
    """What the vehicle was doing."""

    STRAIGHT = "straight"
    STEADY_STATE_CORNERING = "steady_state_cornering"
    DOUBLE_LANE_CHANGE = "double_lane_change"
    LANE_CHANGE = "lane_change"
    SLALOM = "slalom"
    STEP_STEER = "step_steer"
    J_TURN = "j_turn"
    FISHHOOK = "fishhook"
    SINE_WITH_DWELL = "sine_with_dwell"
    LOW_SPEED = "low_speed"
    OTHER = "other"


class Source(enum.StrEnum):
    """Where a manoeuvre's label came from."""

    AUTO = "auto"
    MARK = "mark"


@dataclass(frozen=True, slots=True)
class Manoeuvre:
    """Samples [start_index, stop_index) of the time base, with a kind and a label."""

    kind: ManoeuvreKind
    start_index: int
    stop_index: int
    t_start_s: float
    t_stop_s: float
    """Time of the last sample."""
    source: Source = Source.AUTO
    label: str = ""
    """Free text: the operator's mark, or the automatic classification's reason."""

    @property
    def duration_s(self) -> float:
        return self.t_stop_s - self.t_start_s

    def mask(self, n: int) -> npt.NDArray[np.bool_]:
        m = np.zeros(n, dtype=bool)
        m[self.start_index : self.stop_index] = True
        return m

    def to_dict(self) -> dict[str, object]:
        """JSON-able view."""
        return {
            "kind": self.kind.value,
            "t_start_s": self.t_start_s,
            "t_stop_s": self.t_stop_s,
            "duration_s": self.duration_s,
            "source": self.source.value,
            "label": self.label,
        }


@dataclass(frozen=True, slots=True)
class SegmentationParams:
    """Thresholds of :func:`segment_manoeuvres` (SI units; the defaults suit a passenger car)."""

    low_speed_mps: float = 15.0 / 3.6
    quiet_ay_mps2: float = 0.5
    quiet_yaw_rate_rps: float = math.radians(1.0)
    quiet_swa_rad: float = math.radians(10.0)
    active_ay_mps2: float = 1.0
    min_straight_s: float = 2.0
    merge_gap_s: float = 1.5
    pad_s: float = 0.5
    lobe_fraction: float = 0.3
    min_lobe_swa_rad: float = math.radians(3.0)
    fast_steer_dps: float = 150.0
    steady_min_s: float = 8.0
    fishhook_hold_s: float = 2.0
    speed_drop_fraction: float = 0.05
    smooth_s: float = 0.1
    slalom_min_lobes: int = 5
    slalom_spacing_cv: float = 0.2


@dataclass(frozen=True, slots=True)
class _Lobe:
    sign: int
    start: int
    stop: int


def _smooth(x: FloatArray, k: int) -> FloatArray:
    if k <= 1:
        return x
    kernel = np.full(k, 1.0 / k)
    return np.asarray(np.convolve(np.pad(x, (k // 2, k - 1 - k // 2), mode="edge"), kernel, mode="valid"), dtype=float)


def _lobes(swa: FloatArray, i: int, j: int, p: SegmentationParams) -> list[_Lobe]:
    seg = swa[i:j]
    peak = float(np.max(np.abs(seg))) if seg.size else 0.0
    thr = max(p.lobe_fraction * peak, p.min_lobe_swa_rad)
    sign = np.where(seg > thr, 1, np.where(seg < -thr, -1, 0))
    out: list[_Lobe] = []
    for s in (1, -1):
        for a, b in runs(sign == s):
            out.append(_Lobe(s, i + a, i + b))
    out.sort(key=lambda lb: lb.start)
    merged: list[_Lobe] = []
    for lb in out:  # neighbouring pieces of one sign (a dip below the threshold) are one lobe
        if merged and merged[-1].sign == lb.sign:
            merged[-1] = _Lobe(lb.sign, merged[-1].start, lb.stop)
        else:
            merged.append(lb)
    return merged


def _classify(
    t: FloatArray, speed: FloatArray, swa: FloatArray, swa_rate_dps: FloatArray, i: int, j: int, p: SegmentationParams
) -> tuple[ManoeuvreKind, str]:
    lobes = _lobes(swa, i, j, p)
    if not lobes:
        return ManoeuvreKind.OTHER, "no steering lobe"

    def dur(lb: _Lobe) -> float:
        return float(t[lb.stop - 1] - t[lb.start])

    def onset_rate(lb: _Lobe) -> float:
        a = max(i, lb.start - int(round(0.5 / max(float(np.median(np.diff(t[i:j]))), 1e-6))))
        return float(np.max(np.abs(swa_rate_dps[a : lb.start + 1])))

    first = lobes[0]
    fast = onset_rate(first) > p.fast_steer_dps
    v0 = float(np.mean(speed[max(i, first.start - 5) : first.start + 1]))
    drop = (v0 - float(np.min(speed[first.start : first.stop]))) / max(v0, 1e-6)
    n = len(lobes)
    if n == 1:
        if dur(first) >= p.steady_min_s:
            return ManoeuvreKind.STEADY_STATE_CORNERING, f"one steering lobe of {dur(first):.1f} s"
        if fast:
            if drop > p.speed_drop_fraction:
                return ManoeuvreKind.J_TURN, f"fast steer and hold, speed −{100 * drop:.0f} %"
            return ManoeuvreKind.STEP_STEER, f"fast steer and hold at constant speed (−{100 * drop:.0f} %)"
        return ManoeuvreKind.OTHER, "one slow steering lobe (a curve?)"
    if n == 2:
        if dur(lobes[1]) >= p.fishhook_hold_s:
            return ManoeuvreKind.FISHHOOK, f"steer, counter-steer held {dur(lobes[1]):.1f} s"
        if fast:
            return ManoeuvreKind.SINE_WITH_DWELL, "fast steer and counter-steer"
        return ManoeuvreKind.LANE_CHANGE, "steer and counter-steer (single lane change)"
    if n >= p.slalom_min_lobes:
        starts = np.asarray([t[lb.start] for lb in lobes], dtype=float)
        spacing = np.diff(starts)
        if float(np.std(spacing)) <= p.slalom_spacing_cv * float(np.mean(spacing)):
            return ManoeuvreKind.SLALOM, f"{n} evenly spaced alternating lobes ({float(np.mean(spacing)):.1f} s apart)"
    if float(t[j - 1] - t[i]) <= 15.0:
        return ManoeuvreKind.DOUBLE_LANE_CHANGE, f"{n} alternating steering lobes"
    return ManoeuvreKind.OTHER, f"{n} steering lobes over {float(t[j - 1] - t[i]):.0f} s"


def segment_manoeuvres(
    t_s: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    swa_rad: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    ay_mps2: npt.ArrayLike,
    *,
    params: SegmentationParams | None = None,
) -> list[Manoeuvre]:
    """Label a drive into manoeuvres (module docstring); every sample belongs to exactly one.

    Raises:
        AnalysisError: malformed arrays.
    """
    p = params or SegmentationParams()
    t = check_time("t_s", t_s, min_samples=2)
    n = t.size
    dt = float(np.median(np.diff(t)))
    k = max(1, int(round(p.smooth_s / dt)))
    speed = _smooth(np.nan_to_num(as_1d("speed_mps", speed_mps, n)), k)
    swa = _smooth(np.nan_to_num(as_1d("swa_rad", swa_rad, n)), k)
    r = _smooth(np.nan_to_num(as_1d("yaw_rate_rps", yaw_rate_rps, n)), k)
    ay = _smooth(np.nan_to_num(as_1d("ay_mps2", ay_mps2, n)), k)
    swa_rate = np.degrees(np.gradient(swa, t))

    low = speed < p.low_speed_mps
    quiet = (np.abs(ay) < p.quiet_ay_mps2) & (np.abs(r) < p.quiet_yaw_rate_rps) & (np.abs(swa) < p.quiet_swa_rad)
    active = ~low & ((np.abs(ay) >= p.active_ay_mps2) | (np.abs(swa) >= p.quiet_swa_rad))

    labels = np.full(n, -1, dtype=np.int64)  # index into `kinds`
    kinds: list[tuple[ManoeuvreKind, str]] = []
    # events: active runs merged across short gaps, padded, never into low-speed samples
    pad = int(round(p.pad_s / dt))
    gap = int(round(p.merge_gap_s / dt))
    events: list[list[int]] = []
    for a, b in runs(active):
        if events and a - events[-1][1] <= gap:
            events[-1][1] = b
        else:
            events.append([a, b])
    for a, b in events:
        a2, b2 = max(0, a - pad), min(n, b + pad)
        lo = a2 + int(np.argmax(~low[a2:a])) if np.any(low[a2:a]) else a2
        while lo < a and low[lo]:
            lo += 1
        hi = b2
        if np.any(low[b:b2]):
            hi = b + int(np.argmax(low[b:b2]))
        kinds.append(_classify(t, speed, swa, swa_rate, lo, hi, p))
        labels[lo:hi] = len(kinds) - 1
    free = labels < 0
    kinds.append((ManoeuvreKind.LOW_SPEED, "below the low-speed limit"))
    labels[free & low] = len(kinds) - 1
    kinds.append((ManoeuvreKind.STRAIGHT, "no lateral motion"))
    straight_id = len(kinds) - 1
    min_n = int(round(p.min_straight_s / dt))
    for a, b in runs(free & ~low & quiet):
        if b - a >= min_n:
            labels[a:b] = straight_id
    kinds.append((ManoeuvreKind.OTHER, "between manoeuvres"))
    labels[labels < 0] = len(kinds) - 1

    out: list[Manoeuvre] = []
    change = np.flatnonzero(np.diff(labels)) + 1
    edges = [0, *change.tolist(), n]
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        kind, why = kinds[int(labels[a])]
        out.append(Manoeuvre(kind, a, b, float(t[a]), float(t[b - 1]), Source.AUTO, why))
    return out


def apply_marks(
    t_s: npt.ArrayLike,
    manoeuvres: Sequence[Manoeuvre],
    marks: Sequence[tuple[float, float, str]],
) -> list[Manoeuvre]:
    """Overlay operator marks (t_start, t_stop, label) on automatic manoeuvres; marks win where they lie.

    A mark's label names its kind when it matches one (``"fishhook"``, ``"double lane change"``,
    case and spaces ignored); otherwise it becomes OTHER with the label kept. Automatic pieces
    cut by a mark keep their kind.

    Raises:
        AnalysisError: a mark that ends before it starts.
    """
    t = check_time("t_s", t_s)
    n = t.size
    owner = np.full(n, -1, dtype=np.int64)
    items: list[Manoeuvre] = list(manoeuvres)
    for m_i, m in enumerate(items):
        owner[m.start_index : m.stop_index] = m_i
    by_name = {k.value.replace("_", ""): k for k in ManoeuvreKind}
    for t0, t1, label in marks:
        if not t1 >= t0:
            raise AnalysisError(f"mark {label!r}: ends ({t1} s) before it starts ({t0} s)")
        a = int(np.searchsorted(t, t0, side="left"))
        b = int(np.searchsorted(t, t1, side="right"))
        if b <= a:
            continue
        kind = by_name.get(label.lower().replace(" ", "").replace("_", "").replace("-", ""), ManoeuvreKind.OTHER)
        items.append(Manoeuvre(kind, a, b, float(t[a]), float(t[b - 1]), Source.MARK, label))
        owner[a:b] = len(items) - 1
    out: list[Manoeuvre] = []
    change = np.flatnonzero(np.diff(owner)) + 1
    edges = [0, *change.tolist(), n]
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        o = int(owner[a])
        if o < 0:
            continue
        src = items[o]
        out.append(Manoeuvre(src.kind, a, b, float(t[a]), float(t[b - 1]), src.source, src.label))
    return out


@dataclass(frozen=True, slots=True)
class ManoeuvreScore:
    """Metrics of one manoeuvre (or of all of one kind)."""

    manoeuvre: Manoeuvre | None
    """None for a per-kind or overall summary."""
    kind: ManoeuvreKind | None
    metrics: ValidationMetrics | None
    """None when the reference had no valid sample there."""

    def to_dict(self) -> dict[str, object]:
        """JSON-able view."""
        return {
            "manoeuvre": None if self.manoeuvre is None else self.manoeuvre.to_dict(),
            "kind": None if self.kind is None else self.kind.value,
            "metrics": None if self.metrics is None else self.metrics.to_dict(),
        }


def score_manoeuvres(
    t_s: npt.ArrayLike,
    estimate_rad: npt.ArrayLike,
    reference_rad: npt.ArrayLike,
    manoeuvres: Sequence[Manoeuvre],
    *,
    reference_valid: npt.ArrayLike | None = None,
    reference_sigma: npt.ArrayLike | None = None,
    ay_mps2: npt.ArrayLike | None = None,
    tolerances: Tolerances | Mapping[ManoeuvreKind, Tolerances] | None = None,
    skip: Sequence[ManoeuvreKind] = (ManoeuvreKind.LOW_SPEED,),
) -> tuple[list[ManoeuvreScore], list[ManoeuvreScore], ManoeuvreScore]:
    """Score an estimate per manoeuvre, per kind and overall (kinds in ``skip`` left out of the overall).

    ``tolerances`` may differ per kind (a mapping; kinds not in it use the defaults). Returns
    (per manoeuvre, per kind, overall).

    Raises:
        AnalysisError: malformed arrays or no valid sample at all.
    """
    t = check_time("t_s", t_s, min_samples=2)
    n = t.size
    est = as_1d("estimate_rad", estimate_rad, n)
    ref = as_1d("reference_rad", reference_rad, n)
    valid = np.ones(n, dtype=bool) if reference_valid is None else np.asarray(reference_valid, dtype=bool)
    sigma = None if reference_sigma is None else as_1d("reference_sigma", reference_sigma, n)
    ay = None if ay_mps2 is None else as_1d("ay_mps2", ay_mps2, n)

    def tol_for(kind: ManoeuvreKind | None) -> Tolerances:
        if isinstance(tolerances, Mapping):
            return tolerances.get(kind, Tolerances()) if kind is not None else Tolerances()
        return tolerances or Tolerances()

    def score(mask: npt.NDArray[np.bool_], kind: ManoeuvreKind | None) -> ValidationMetrics | None:
        idx = np.flatnonzero(mask)
        if idx.size < 2 or not np.any(valid[idx] & np.isfinite(ref[idx]) & np.isfinite(est[idx])):
            return None
        a, b = int(idx[0]), int(idx[-1]) + 1
        sub = np.zeros(n, dtype=bool)
        sub[idx] = True
        return compare(
            t[a:b], est[a:b], ref[a:b],
            reference_valid=(valid & sub)[a:b],
            scored=sub[a:b],
            reference_sigma=None if sigma is None else sigma[a:b],
            ay=None if ay is None else ay[a:b],
            tolerances=tol_for(kind),
        )

    per: list[ManoeuvreScore] = []
    for m in manoeuvres:
        per.append(ManoeuvreScore(m, m.kind, score(m.mask(n), m.kind)))
    kinds: list[ManoeuvreScore] = []
    for kind in ManoeuvreKind:
        mask = np.zeros(n, dtype=bool)
        for m in manoeuvres:
            if m.kind is kind:
                mask[m.start_index : m.stop_index] = True
        if np.any(mask):
            kinds.append(ManoeuvreScore(None, kind, score(mask, kind)))
    overall_mask = np.ones(n, dtype=bool)
    for m in manoeuvres:
        if m.kind in skip:
            overall_mask[m.start_index : m.stop_index] = False
    overall = score(overall_mask, None)
    if overall is None:
        raise AnalysisError("score_manoeuvres: the reference has no valid sample outside the skipped manoeuvres")
    return per, kinds, ManoeuvreScore(None, None, overall)
