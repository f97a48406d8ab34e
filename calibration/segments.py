"""Find the parts of a drive that a calibration can use: straight runs and constant-steering circles.

Both searches work on arrays sampled on one time base (s); the caller interpolates signals from
other devices onto it. A run is broken wherever a sample fails a criterion or the time stamps
have a gap. Durations count whole sample periods: n samples at period dt last n·dt.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vsccore.angles import FloatArray, unwrap, wrap_2pi
from vsccore.errors import CalibrationError

BoolArray = npt.NDArray[np.bool_]

DEFAULT_MIN_SPEED_MPS = 25.0 / 3.6
DEFAULT_MAX_YAW_RATE_RPS = math.radians(0.5)
DEFAULT_MAX_COURSE_STD_RAD = math.radians(0.5)
DEFAULT_MIN_STRAIGHT_S = 5.0


class Direction(enum.Enum):
    """Direction of travel along the vehicle x axis."""

    FORWARD = "forward"
    REVERSE = "reverse"


class StraightCriterion(enum.Enum):
    """The conditions a straight-run sample or segment must meet."""

    SPEED = "speed"
    YAW_RATE = "yaw rate"
    RTK_FIXED = "RTK fixed"
    COURSE = "course stability"
    DURATION = "duration"


@dataclass(frozen=True, slots=True)
class Segment:
    """A straight run: samples [start_index, stop_index) of the arrays it was found in."""

    start_index: int
    stop_index: int
    t_start_s: float
    t_stop_s: float
    """Time of the last sample."""
    duration_s: float
    mean_speed_mps: float
    course_rad: float
    """Circular mean course azimuth, clockwise from north in [0, 2π)."""
    course_std_rad: float
    n_samples: int

    def mask(self, t_s: FloatArray) -> BoolArray:
        """Samples of another time base (s) that fall inside this segment."""
        t = np.asarray(t_s, dtype=float)
        return np.asarray((t >= self.t_start_s) & (t <= self.t_stop_s), dtype=np.bool_)

    def to_dict(self) -> dict[str, float | int]:
        """JSON-able view (units in the key names)."""
        return {
            "t_start_s": self.t_start_s,
            "duration_s": self.duration_s,
            "mean_speed_kmh": self.mean_speed_mps * 3.6,
            "course_deg": math.degrees(self.course_rad),
            "course_std_deg": math.degrees(self.course_std_rad),
            "n_samples": self.n_samples,
        }


@dataclass(frozen=True, slots=True)
class StraightDiagnosis:
    """Why a drive has (or lacks) usable straight runs."""

    n_samples: int
    n_segments: int
    longest_duration_s: float
    """Longest run meeting every criterion but the duration."""
    longest_mean_speed_mps: float
    longest_t_start_s: float
    failing_fraction: tuple[tuple[StraightCriterion, float], ...]
    """Fraction of samples failing each per-sample criterion."""
    longest_without: tuple[tuple[StraightCriterion, float], ...]
    """Longest run (s) if that criterion alone were dropped."""
    limiting: StraightCriterion
    """The criterion whose removal alone gives the longest run, if that run is long enough; else DURATION."""
    requirement: str

    @property
    def message(self) -> str:
        """One paragraph for the user: what is there, what is needed, what stops it."""
        if self.n_samples == 0:
            return "no samples to search for straight runs"
        fails = ", ".join(f"{c.value} {100.0 * f:.0f} %" for c, f in self.failing_fraction)
        if self.longest_duration_s > 0.0:
            head = (
                f"longest straight segment {self.longest_duration_s:.1f} s at "
                f"{3.6 * self.longest_mean_speed_mps:.0f} km/h; need {self.requirement}. "
                f"It starts at t = {self.longest_t_start_s:.1f} s."
            )
        else:
            head = f"no sample meets all straight-run criteria; need {self.requirement}."
        if self.limiting is StraightCriterion.DURATION:
            why = "No single criterion stops it: the straight runs are too short; drive longer ones."
        else:
            without = dict(self.longest_without).get(self.limiting, 0.0)
            why = f"Most limiting: {self.limiting.value} (dropping it alone would give {without:.1f} s)."
        return f"{head} {why} Samples failing: {fails}."

    def to_dict(self) -> dict[str, object]:
        """JSON-able view."""
        return {
            "n_samples": self.n_samples,
            "n_segments": self.n_segments,
            "longest_duration_s": self.longest_duration_s,
            "longest_mean_speed_kmh": 3.6 * self.longest_mean_speed_mps,
            "longest_t_start_s": self.longest_t_start_s,
            "failing_fraction": {c.value: f for c, f in self.failing_fraction},
            "longest_without_s": {c.value: d for c, d in self.longest_without},
            "limiting": self.limiting.value,
            "message": self.message,
        }


@dataclass(frozen=True, slots=True)
class SwaSegment:
    """A constant steering-wheel-angle run at low speed in one direction: samples [start, stop)."""

    start_index: int
    stop_index: int
    t_start_s: float
    t_stop_s: float
    duration_s: float
    swa_rad: float
    """Median steering-wheel angle, positive to the left."""
    swa_spread_rad: float
    """Peak-to-peak steering-wheel angle in the run."""
    direction: Direction
    mean_speed_mps: float
    """Mean |speed|."""
    turn_rad: float | None
    """Heading change |∫ r dt| when a yaw rate was given."""
    n_samples: int

    def mask(self, t_s: FloatArray) -> BoolArray:
        """Samples of another time base (s) that fall inside this segment."""
        t = np.asarray(t_s, dtype=float)
        return np.asarray((t >= self.t_start_s) & (t <= self.t_stop_s), dtype=np.bool_)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        return {
            "t_start_s": self.t_start_s,
            "duration_s": self.duration_s,
            "swa_deg": math.degrees(self.swa_rad),
            "swa_spread_deg": math.degrees(self.swa_spread_rad),
            "direction": self.direction.value,
            "mean_speed_kmh": 3.6 * self.mean_speed_mps,
            "turn_deg": None if self.turn_rad is None else math.degrees(self.turn_rad),
            "n_samples": self.n_samples,
        }


# --------------------------------------------------------------------------------------------
# helpers


def _as_1d(name: str, x: npt.ArrayLike, n: int | None = None) -> FloatArray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise CalibrationError(f"{name}: expected a 1-D array, got shape {a.shape}")
    if n is not None and a.shape[0] != n:
        raise CalibrationError(f"{name}: length {a.shape[0]} differs from t_s length {n}")
    return a


def check_time(t_s: npt.ArrayLike) -> tuple[FloatArray, float]:
    """Validate a time vector (1-D, finite, strictly increasing); return it and its median period."""
    t = _as_1d("t_s", t_s)
    if t.size and not np.all(np.isfinite(t)):
        raise CalibrationError("t_s: contains NaN or infinite times")
    if t.size > 1 and np.any(np.diff(t) <= 0.0):
        i = int(np.argmax(np.diff(t) <= 0.0))
        raise CalibrationError(f"t_s: not strictly increasing at sample {i + 1} (t = {t[i + 1]:.6f} s)")
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return t, dt


def _runs(ok: BoolArray, t: FloatArray, max_gap_s: float) -> list[tuple[int, int]]:
    """Maximal runs [i, j) of True samples without a time gap larger than max_gap_s."""
    ok = np.asarray(ok, dtype=bool).copy()
    n = ok.size
    if n == 0:
        return []
    breaks = np.zeros(n, dtype=bool)
    if n > 1:
        breaks[1:] = np.diff(t) > max_gap_s
    runs: list[tuple[int, int]] = []
    i = 0
    while i < n:
        if not ok[i]:
            i += 1
            continue
        j = i + 1
        while j < n and ok[j] and not breaks[j]:
            j += 1
        runs.append((i, j))
        i = j
    return runs


def _split_by_spread(values: FloatArray, i: int, j: int, max_std: float) -> list[tuple[int, int]]:
    """Greedy split of [i, j) into pieces whose standard deviation stays within max_std.

    ``values`` must be continuous (unwrapped); running sums about the piece's first sample keep it O(n).
    """
    pieces: list[tuple[int, int]] = []
    start = i
    ref = values[i]
    s1 = 0.0
    s2 = 0.0
    m = 0
    for k in range(i, j):
        d = values[k] - ref
        s1n, s2n, mn = s1 + d, s2 + d * d, m + 1
        var = s2n / mn - (s1n / mn) ** 2
        if mn > 1 and math.sqrt(max(var, 0.0)) > max_std:
            pieces.append((start, k))
            start, ref = k, values[k]
            s1, s2, m = 0.0, 0.0, 1
        else:
            s1, s2, m = s1n, s2n, mn
    pieces.append((start, j))
    return pieces


def _split_by_range(values: FloatArray, i: int, j: int, max_range: float) -> list[tuple[int, int]]:
    """Greedy split of [i, j) into pieces whose peak-to-peak stays within max_range."""
    pieces: list[tuple[int, int]] = []
    start = i
    lo = hi = values[i]
    for k in range(i, j):
        v = values[k]
        nlo, nhi = min(lo, v), max(hi, v)
        if nhi - nlo > max_range:
            pieces.append((start, k))
            start, lo, hi = k, v, v
        else:
            lo, hi = nlo, nhi
    pieces.append((start, j))
    return pieces


def _circular_mean_std(angle: FloatArray) -> tuple[float, float]:
    """Circular mean (in [0, 2π)) and standard deviation about it (small-spread approximation)."""
    c = float(np.mean(np.cos(angle)))
    s = float(np.mean(np.sin(angle)))
    mean = float(wrap_2pi(math.atan2(s, c)))
    dev = unwrap(angle) - float(np.mean(unwrap(angle)))
    return mean, float(np.std(dev))


# --------------------------------------------------------------------------------------------
# straight runs


def _straight_pieces(
    t: FloatArray,
    course: FloatArray,
    per_sample: dict[StraightCriterion, BoolArray],
    use_course: bool,
    max_course_std_rad: float,
    max_gap_s: float,
) -> list[tuple[int, int]]:
    ok = np.ones(t.size, dtype=bool)
    for mask in per_sample.values():
        ok &= mask
    pieces: list[tuple[int, int]] = []
    for i, j in _runs(ok, t, max_gap_s):
        if use_course:
            u = unwrap(course[i:j])
            pieces.extend((i + a, i + b) for a, b in _split_by_spread(u, 0, j - i, max_course_std_rad))
        else:
            pieces.append((i, j))
    return pieces


def _duration(t: FloatArray, dt: float, i: int, j: int) -> float:
    return float(t[j - 1] - t[i] + dt)


def _longest(t: FloatArray, dt: float, pieces: list[tuple[int, int]]) -> tuple[float, tuple[int, int] | None]:
    best = 0.0
    best_piece: tuple[int, int] | None = None
    for i, j in pieces:
        d = _duration(t, dt, i, j)
        if d > best:
            best, best_piece = d, (i, j)
    return best, best_piece


def _make_segment(t: FloatArray, dt: float, speed: FloatArray, course: FloatArray, i: int, j: int) -> Segment:
    mean, std = _circular_mean_std(course[i:j])
    return Segment(
        start_index=i,
        stop_index=j,
        t_start_s=float(t[i]),
        t_stop_s=float(t[j - 1]),
        duration_s=_duration(t, dt, i, j),
        mean_speed_mps=float(np.mean(speed[i:j])),
        course_rad=mean,
        course_std_rad=std,
        n_samples=j - i,
    )


def _straight_search(
    t_s: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    course_rad: npt.ArrayLike,
    rtk_fixed_mask: npt.ArrayLike,
    *,
    min_speed_mps: float,
    max_yaw_rate_rps: float,
    max_course_std_rad: float,
    min_duration_s: float,
    max_gap_s: float | None,
) -> tuple[list[Segment], StraightDiagnosis]:
    t, dt = check_time(t_s)
    n = t.size
    speed = _as_1d("speed_mps", speed_mps, n)
    r = _as_1d("yaw_rate_rps", yaw_rate_rps, n)
    course = _as_1d("course_rad", course_rad, n)
    rtk = np.asarray(rtk_fixed_mask)
    if rtk.shape != (n,):
        raise CalibrationError(f"rtk_fixed_mask: shape {rtk.shape} differs from t_s shape ({n},)")
    for name, value in (
        ("min_speed_mps", min_speed_mps),
        ("max_yaw_rate_rps", max_yaw_rate_rps),
        ("max_course_std_rad", max_course_std_rad),
        ("min_duration_s", min_duration_s),
    ):
        if not value > 0.0:
            raise CalibrationError(f"{name} must be positive, got {value}")
    gap = max_gap_s if max_gap_s is not None else 2.5 * dt
    requirement = (
        f"{min_duration_s:.1f} s at > {3.6 * min_speed_mps:.0f} km/h with |yaw rate| < "
        f"{math.degrees(max_yaw_rate_rps):.2f}°/s, course std < {math.degrees(max_course_std_rad):.2f}° "
        "and RTK fixed on both rovers"
    )
    with np.errstate(invalid="ignore"):
        per_sample: dict[StraightCriterion, BoolArray] = {
            StraightCriterion.SPEED: np.asarray(speed > min_speed_mps, dtype=bool),
            StraightCriterion.YAW_RATE: np.asarray(np.abs(r) < max_yaw_rate_rps, dtype=bool),
            StraightCriterion.RTK_FIXED: rtk.astype(bool),
            StraightCriterion.COURSE: np.asarray(np.isfinite(course), dtype=bool),
        }
    if n == 0:
        diag = StraightDiagnosis(0, 0, 0.0, 0.0, 0.0, (), (), StraightCriterion.DURATION, requirement)
        return [], diag

    pieces = _straight_pieces(t, course, per_sample, True, max_course_std_rad, gap)
    segments = [
        _make_segment(t, dt, speed, course, i, j) for i, j in pieces if _duration(t, dt, i, j) >= min_duration_s - 1e-9
    ]
    longest, piece = _longest(t, dt, pieces)
    if piece is not None:
        l_speed = float(np.mean(speed[piece[0] : piece[1]]))
        l_t0 = float(t[piece[0]])
    else:
        l_speed, l_t0 = 0.0, 0.0

    # What one criterion, dropped alone, would give: the largest is the binding one.
    without: list[tuple[StraightCriterion, float]] = []
    for crit in per_sample:
        reduced = {c: m for c, m in per_sample.items() if c is not crit}
        use_course = crit is not StraightCriterion.COURSE
        d, _ = _longest(t, dt, _straight_pieces(t, course, reduced, use_course, max_course_std_rad, gap))
        without.append((crit, d))
    # A criterion limits when dropping it alone would give a long enough run; else the runs are just short.
    limiting, best = max(without, key=lambda cd: cd[1])
    if best < min_duration_s - 1e-9 or best <= longest + 1e-9:
        limiting = StraightCriterion.DURATION
    failing = tuple(
        (c, float(np.mean(~m))) for c, m in per_sample.items() if c is not StraightCriterion.COURSE
    )
    diag = StraightDiagnosis(
        n_samples=n,
        n_segments=len(segments),
        longest_duration_s=longest,
        longest_mean_speed_mps=l_speed,
        longest_t_start_s=l_t0,
        failing_fraction=failing,
        longest_without=tuple(without),
        limiting=limiting,
        requirement=requirement,
    )
    return segments, diag


def find_straight_segments(
    t_s: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    course_rad: npt.ArrayLike,
    rtk_fixed_mask: npt.ArrayLike,
    *,
    min_speed_mps: float = DEFAULT_MIN_SPEED_MPS,
    max_yaw_rate_rps: float = DEFAULT_MAX_YAW_RATE_RPS,
    max_course_std_rad: float = DEFAULT_MAX_COURSE_STD_RAD,
    min_duration_s: float = DEFAULT_MIN_STRAIGHT_S,
    max_gap_s: float | None = None,
) -> list[Segment]:
    """Straight runs: fast enough, not turning, steady course, RTK fixed, long enough.

    A sample qualifies when speed > ``min_speed_mps`` (default 25 km/h: GNSS course noise grows
    as 1/speed), |yaw rate| < ``max_yaw_rate_rps`` (default 0.5 °/s), the course is finite and
    ``rtk_fixed_mask`` (True where both rovers have an RTK fixed solution) is set. Runs of such
    samples are cut wherever the time stamps jump by more than ``max_gap_s`` (default 2.5 median
    sample periods) and split greedily so that the course standard deviation within each piece
    stays below ``max_course_std_rad`` (default 0.5°: catches slow curves the yaw-rate sensor
    misses). Pieces lasting at least ``min_duration_s`` (default 5 s) are returned.

    Arguments are sampled on ``t_s`` (s); ``course_rad`` is the course-over-ground azimuth.

    Raises:
        CalibrationError: inputs malformed, or no segment qualifies; the message then says what
            the longest candidate was and which criterion limits it most (see
            :func:`diagnose_straight_segments`).
    """
    segments, diag = _straight_search(
        t_s,
        speed_mps,
        yaw_rate_rps,
        course_rad,
        rtk_fixed_mask,
        min_speed_mps=min_speed_mps,
        max_yaw_rate_rps=max_yaw_rate_rps,
        max_course_std_rad=max_course_std_rad,
        min_duration_s=min_duration_s,
        max_gap_s=max_gap_s,
    )
    if not segments:
        raise CalibrationError(f"no usable straight segment: {diag.message}")
    return segments


def diagnose_straight_segments(
    t_s: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    course_rad: npt.ArrayLike,
    rtk_fixed_mask: npt.ArrayLike,
    *,
    min_speed_mps: float = DEFAULT_MIN_SPEED_MPS,
    max_yaw_rate_rps: float = DEFAULT_MAX_YAW_RATE_RPS,
    max_course_std_rad: float = DEFAULT_MAX_COURSE_STD_RAD,
    min_duration_s: float = DEFAULT_MIN_STRAIGHT_S,
    max_gap_s: float | None = None,
) -> StraightDiagnosis:
    """The same search as :func:`find_straight_segments`, returning the diagnosis instead of raising."""
    _, diag = _straight_search(
        t_s,
        speed_mps,
        yaw_rate_rps,
        course_rad,
        rtk_fixed_mask,
        min_speed_mps=min_speed_mps,
        max_yaw_rate_rps=max_yaw_rate_rps,
        max_course_std_rad=max_course_std_rad,
        min_duration_s=min_duration_s,
        max_gap_s=max_gap_s,
    )
    return diag


# --------------------------------------------------------------------------------------------
# constant steering-wheel angle (steering-ratio circles)


def find_constant_swa_segments(
    t_s: npt.ArrayLike,
    swa_rad: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    *,
    yaw_rate_rps: npt.ArrayLike | None = None,
    min_speed_mps: float = 0.5,
    max_speed_mps: float = 15.0 / 3.6,
    max_swa_spread_rad: float = math.radians(2.0),
    min_duration_s: float = 10.0,
    min_turn_rad: float = math.radians(270.0),
    max_gap_s: float | None = None,
) -> list[SwaSegment]:
    """Runs at constant steering-wheel angle, low speed, one direction: for steering-ratio circles.

    ``speed_mps`` is the signed longitudinal speed (negative when reversing). A sample qualifies
    when ``min_speed_mps`` ≤ |speed| ≤ ``max_speed_mps`` (default 15 km/h: low enough that tyre
    slip angles are negligible and the kinematic relation δ = atan(L/R) holds). Runs are split at
    direction changes and time gaps and then greedily so the steering-wheel angle stays within a
    peak-to-peak ``max_swa_spread_rad`` (default 2°). A run is kept when it lasts
    ``min_duration_s`` or — when ``yaw_rate_rps`` is given — the vehicle turned through
    ``min_turn_rad`` (default 270°, most of a circle).

    Raises:
        CalibrationError: malformed inputs or thresholds.
    """
    t, dt = check_time(t_s)
    n = t.size
    swa = _as_1d("swa_rad", swa_rad, n)
    v = _as_1d("speed_mps", speed_mps, n)
    r = _as_1d("yaw_rate_rps", yaw_rate_rps, n) if yaw_rate_rps is not None else None
    if not 0.0 <= min_speed_mps < max_speed_mps:
        raise CalibrationError(
            f"speed band must satisfy 0 ≤ min_speed_mps < max_speed_mps, got {min_speed_mps}, {max_speed_mps}"
        )
    if not max_swa_spread_rad > 0.0:
        raise CalibrationError(f"max_swa_spread_rad must be positive, got {max_swa_spread_rad}")
    gap = max_gap_s if max_gap_s is not None else 2.5 * dt
    with np.errstate(invalid="ignore"):
        band = np.isfinite(swa) & (np.abs(v) >= min_speed_mps) & (np.abs(v) <= max_speed_mps)
        fwd = band & (v > 0.0)
        rev = band & (v < 0.0)
    out: list[SwaSegment] = []
    for direction, ok in ((Direction.FORWARD, fwd), (Direction.REVERSE, rev)):
        for i, j in _runs(np.asarray(ok, dtype=np.bool_), t, gap):
            for a, b in _split_by_range(swa, i, j, max_swa_spread_rad):
                seg = _make_swa_segment(t, dt, swa, v, r, a, b, direction)
                long_enough = seg.duration_s >= min_duration_s - 1e-9
                turned = seg.turn_rad is not None and seg.turn_rad >= min_turn_rad
                if long_enough or turned:
                    out.append(seg)
    out.sort(key=lambda s: s.start_index)
    return out


def _make_swa_segment(
    t: FloatArray,
    dt: float,
    swa: FloatArray,
    v: FloatArray,
    r: FloatArray | None,
    i: int,
    j: int,
    direction: Direction,
) -> SwaSegment:
    turn: float | None = None
    if r is not None:
        # Each sample stands for one period, as in the duration.
        turn = abs(float(np.sum(r[i:j]))) * dt
    return SwaSegment(
        start_index=i,
        stop_index=j,
        t_start_s=float(t[i]),
        t_stop_s=float(t[j - 1]),
        duration_s=_duration(t, dt, i, j),
        swa_rad=float(np.median(swa[i:j])),
        swa_spread_rad=float(np.ptp(swa[i:j])),
        direction=direction,
        mean_speed_mps=float(np.mean(np.abs(v[i:j]))),
        turn_rad=turn,
        n_samples=j - i,
    )

