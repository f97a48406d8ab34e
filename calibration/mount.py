"""Zero offsets from straight runs: GNSS antenna-baseline mounting offset and optical-sensor slip zero.

On a straight road at steady speed the true sideslip is (very nearly) zero, so

- the azimuth of the antenna baseline minus the course over ground is the angle between the
  baseline and the vehicle x axis (the *mounting offset*), and
- the slip angle an optical sensor reports (moved to the CG; with r ≈ 0 the lever arm hardly
  matters) minus the GNSS sideslip (≈ 0) is the sensor's *zero offset*.

Uncertainty (see :mod:`calibration.stats`): each straight run is located with a Huber estimate.
Its samples (50 ms apart) are far from independent: the noise is modelled as white noise plus a
Gauss–Markov process (ARMA(1,1)) whose white share and correlation time are pooled over all runs by
their restricted likelihood, and the interval integrates over the values the data leave open
(with τ ≈ 1 s a few runs of 5–10 s pin the correlation time down poorly, and the variance of a
run's mean grows with it). Runs in the same direction are combined by inverse-variance weighting,
inflated by the Birge ratio when they scatter more than the model says. When runs exist in both
directions the estimate is the plain mean of the two direction means: a cross wind (or anything
else whose sideslip flips sign with the driving direction) cancels, and a disagreement between the
directions is reported as a warning.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from calibration.segments import (
    DEFAULT_MAX_COURSE_STD_RAD,
    DEFAULT_MAX_YAW_RATE_RPS,
    DEFAULT_MIN_SPEED_MPS,
    DEFAULT_MIN_STRAIGHT_S,
    Segment,
    check_time,
    find_straight_segments,
)
from calibration.stats import (
    DEFAULT_MAX_CORRELATION_S,
    equivalent_dof,
    method_text,
    straight_run_stats,
)
from vsccore.angles import (
    FloatArray,
    sideslip_from_azimuths,
    sideslip_from_velocity,
    transfer_velocity,
    wrap_2pi,
    wrap_pi,
)
from vsccore.errors import CalibrationError

DEFAULT_LENGTH_TOLERANCE_M = 0.03
MIN_SAMPLES_PER_SEGMENT = 5
LARGE_OFFSET_RAD = math.radians(10.0)
GROSS_FACTOR = 3.0
REFERENCE_MAX_SAMPLES = 24_000
"""At most this many baseline-length samples serve as noise reference (20 min at 20 Hz)."""


@dataclass(frozen=True, slots=True)
class SegmentOffset:
    """The offset measured on one straight run."""

    t_start_s: float
    duration_s: float
    mean_speed_mps: float
    course_rad: float
    """Course azimuth of the run (direction of travel), clockwise from north."""
    offset_rad: float
    std_error_rad: float
    ci_low_rad: float
    ci_high_rad: float
    n_samples: int
    n_effective: float

    def to_dict(self) -> dict[str, float | int]:
        """JSON-able view (units in the key names)."""
        return {
            "t_start_s": self.t_start_s,
            "duration_s": self.duration_s,
            "mean_speed_kmh": 3.6 * self.mean_speed_mps,
            "course_deg": math.degrees(self.course_rad),
            "offset_deg": math.degrees(self.offset_rad),
            "std_error_deg": math.degrees(self.std_error_rad),
            "ci_low_deg": math.degrees(self.ci_low_rad),
            "ci_high_deg": math.degrees(self.ci_high_rad),
            "n_samples": self.n_samples,
            "n_effective": self.n_effective,
        }


@dataclass(frozen=True, slots=True)
class DirectionGroup:
    """The runs driven in one direction (within ±90° of each other), combined."""

    course_rad: float
    offset_rad: float
    std_error_rad: float
    ci_low_rad: float
    ci_high_rad: float
    n_segments: int
    birge_ratio: float

    def to_dict(self) -> dict[str, float | int]:
        """JSON-able view (units in the key names)."""
        return {
            "course_deg": math.degrees(self.course_rad),
            "offset_deg": math.degrees(self.offset_rad),
            "std_error_deg": math.degrees(self.std_error_rad),
            "ci_low_deg": math.degrees(self.ci_low_rad),
            "ci_high_deg": math.degrees(self.ci_high_rad),
            "n_segments": self.n_segments,
            "birge_ratio": self.birge_ratio,
        }


@dataclass(frozen=True, slots=True)
class OffsetEstimate:
    """An angle offset estimated from straight runs, with its confidence interval."""

    offset_rad: float
    std_error_rad: float
    ci_low_rad: float
    ci_high_rad: float
    confidence: float
    coverage_factor: float
    """k of the interval offset ± k·σ (quantile of the likelihood-weighted mixture, see :mod:`calibration.stats`)."""
    dof: float
    """Degrees of freedom of the Student-t with the same coverage factor (1000: as good as normal)."""
    noise_sigma_rad: float
    """Per-sample standard deviation of the within-run noise (winsorised)."""
    noise_white_share: float
    """Share of that variance that is white (likelihood-weighted mean); the rest is Gauss–Markov."""
    noise_correlation_time_s: float
    """Correlation time of the Gauss–Markov part (likelihood-weighted median, s)."""
    method: str
    uncertainty_method: str
    """How the interval was found, in words (for reports)."""
    segments: tuple[SegmentOffset, ...]
    groups: tuple[DirectionGroup, ...]
    warnings: tuple[str, ...]

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        return {
            "offset_deg": math.degrees(self.offset_rad),
            "std_error_deg": math.degrees(self.std_error_rad),
            "ci_low_deg": math.degrees(self.ci_low_rad),
            "ci_high_deg": math.degrees(self.ci_high_rad),
            "confidence": self.confidence,
            "coverage_factor": self.coverage_factor,
            "dof": self.dof,
            "noise_sigma_deg": math.degrees(self.noise_sigma_rad),
            "noise_white_share": self.noise_white_share,
            "noise_correlation_time_s": self.noise_correlation_time_s,
            "method": self.method,
            "uncertainty_method": self.uncertainty_method,
            "segments": [s.to_dict() for s in self.segments],
            "direction_groups": [g.to_dict() for g in self.groups],
            "warnings": list(self.warnings),
        }


@dataclass(frozen=True, slots=True)
class BaselineCheck:
    """Measured antenna baseline length against the configured one (on the straight runs)."""

    nominal_m: float
    mean_m: float
    std_m: float
    min_m: float
    max_m: float
    n_samples: int
    n_outside_tolerance: int
    n_gross: int
    """Samples off by more than GROSS_FACTOR × tolerance (a wrong ambiguity fix jumps by decimetres)."""
    tolerance_m: float

    @property
    def ok(self) -> bool:
        """True when the mean length is within tolerance of the configured one."""
        return abs(self.mean_m - self.nominal_m) <= self.tolerance_m

    def to_dict(self) -> dict[str, float | int | bool]:
        """JSON-able view (units in the key names)."""
        return {
            "nominal_m": self.nominal_m,
            "mean_m": self.mean_m,
            "std_m": self.std_m,
            "min_m": self.min_m,
            "max_m": self.max_m,
            "n_samples": self.n_samples,
            "n_outside_tolerance": self.n_outside_tolerance,
            "n_gross": self.n_gross,
            "tolerance_m": self.tolerance_m,
            "ok": self.ok,
        }


@dataclass(frozen=True, slots=True)
class MountOffsetResult:
    """Antenna-baseline mounting offset: baseline azimuth − vehicle x-axis azimuth.

    Positive when the baseline (B → A, pointing forward) points clockwise (to the right, seen
    from above) of the vehicle x axis; the vehicle heading is ``baseline azimuth − offset``
    (:func:`apply_mount_offset`).
    """

    estimate: OffsetEstimate
    baseline: BaselineCheck
    warnings: tuple[str, ...]

    @property
    def offset_rad(self) -> float:
        """The mounting offset (rad)."""
        return self.estimate.offset_rad

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        d = self.estimate.to_dict()
        d["baseline"] = self.baseline.to_dict()
        d["warnings"] = list(self.warnings)
        return d


@dataclass(frozen=True, slots=True)
class OpticalZeroResult:
    """Optical-sensor slip-angle zero: what the sensor reports (at the CG) when the true slip is zero.

    The corrected slip angle is ``measured − zero`` (:func:`apply_optical_zero` for velocities).
    """

    estimate: OffsetEstimate
    sensor_xy_m: tuple[float, float]

    @property
    def zero_rad(self) -> float:
        """The slip-angle zero offset (rad)."""
        return self.estimate.offset_rad

    @property
    def warnings(self) -> tuple[str, ...]:
        """Warnings of the estimate."""
        return self.estimate.warnings

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        d = self.estimate.to_dict()
        d["zero_deg"] = d.pop("offset_deg")
        d["sensor_x_m"], d["sensor_y_m"] = self.sensor_xy_m
        return d


@dataclass(frozen=True, slots=True)
class NoiseReference:
    """Blocks of a series whose noise has the shape of the slow part of the offset samples' noise.

    See :func:`calibration.stats.fit_noise` (``reference``).
    """

    name: str
    blocks: tuple[FloatArray, ...]
    duration_s: float


# --------------------------------------------------------------------------------------------


def _array(name: str, x: npt.ArrayLike, n: int) -> FloatArray:
    a = np.asarray(x, dtype=float)
    if a.shape != (n,):
        raise CalibrationError(f"{name}: shape {a.shape} differs from t_s shape ({n},)")
    return a


def _circular_mean(angle: FloatArray) -> float:
    return float(math.atan2(float(np.mean(np.sin(angle))), float(np.mean(np.cos(angle)))))


def estimate_offset_from_straights(
    segments: Sequence[Segment],
    t_s: npt.ArrayLike,
    offset_samples_rad: npt.ArrayLike,
    *,
    confidence: float = 0.95,
    quantity: str = "offset",
    max_correlation_s: float = DEFAULT_MAX_CORRELATION_S,
    reference: NoiseReference | None = None,
) -> OffsetEstimate:
    """Robust offset with an honest confidence interval from per-sample offsets on straight runs.

    ``offset_samples_rad`` is any angle whose true value is the constant offset on a straight run
    (e.g. baseline azimuth − course). Samples are selected by time (``Segment.mask``), so the
    arrays may come from another device than the one the segments were found on. NaNs are skipped.
    ``quantity`` names the thing in messages. ``max_correlation_s`` bounds the correlation time of
    the noise the interval allows for; ``reference`` is a series whose noise has the shape of the
    slow part of these samples' noise (:func:`calibration.stats.fit_noise`), on the same time base.

    Raises:
        CalibrationError: no segment, or no segment with at least 5 finite samples.
    """
    t, dt = check_time(t_s)
    x = _array(quantity, offset_samples_rad, t.size)
    if not segments:
        raise CalibrationError(f"{quantity}: no straight segments given")
    warnings: list[str] = []
    used: list[Segment] = []
    blocks: list[FloatArray] = []
    refs: list[float] = []
    for seg in segments:
        m = seg.mask(t)
        xs = x[m]
        xs = xs[np.isfinite(xs)]
        if xs.size < MIN_SAMPLES_PER_SEGMENT:
            warnings.append(
                f"straight run at t = {seg.t_start_s:.1f} s skipped: {xs.size} finite {quantity} samples "
                f"(need {MIN_SAMPLES_PER_SEGMENT})"
            )
            continue
        ref = _circular_mean(xs)
        used.append(seg)
        refs.append(ref)
        blocks.append(np.asarray(wrap_pi(xs - ref), dtype=float))  # small deviations about the run's mean
    if not used:
        raise CalibrationError(
            f"{quantity}: none of the {len(segments)} straight runs has {MIN_SAMPLES_PER_SEGMENT} finite samples "
            "in the data given (time bases mismatched?)"
        )
    # One continuous scale for all runs: about the circular mean of the run medians.
    run_means = np.array([wrap_pi(r + float(np.median(b))) for r, b in zip(refs, blocks, strict=True)])
    centre = _circular_mean(run_means)
    shifted = [b + float(wrap_pi(r - centre)) for r, b in zip(refs, blocks, strict=True)]

    # Direction groups: within ±90° of the longest run's course, and the rest.
    ref_course = max(used, key=lambda s: s.duration_s).course_rad
    same = [abs(float(wrap_pi(s.course_rad - ref_course))) <= math.pi / 2.0 for s in used]
    group_members = [m for m in ([i for i, f in enumerate(same) if f], [i for i, f in enumerate(same) if not f]) if m]
    st = straight_run_stats(
        shifted,
        group_members,
        dt_s=dt,
        confidence=confidence,
        max_correlation_s=max_correlation_s,
        reference=list(reference.blocks) if reference is not None and reference.blocks else None,
    )
    ref_used = bool(st.reference_used[0])
    if reference is not None and reference.blocks and not ref_used:
        warnings.append(
            f"the noise of {reference.name} does not match that of the {quantity} samples (Bayes factor "
            f"{math.exp(-float(st.reference_log_bf[0])):.0f} against); interval from the straight runs alone"
        )

    seg_results: list[SegmentOffset] = []
    for j, (seg, b) in enumerate(zip(used, blocks, strict=True)):
        h = float(st.blocks.half_width[j, 0])
        offset = float(wrap_pi(centre + st.blocks.value[j, 0]))
        seg_results.append(
            SegmentOffset(
                t_start_s=seg.t_start_s,
                duration_s=seg.duration_s,
                mean_speed_mps=seg.mean_speed_mps,
                course_rad=seg.course_rad,
                offset_rad=offset,
                std_error_rad=float(st.blocks.std_error[j, 0]),
                ci_low_rad=offset - h,
                ci_high_rad=offset + h,
                n_samples=int(b.size),
                n_effective=float(st.n_effective[j, 0]),
            )
        )

    groups: list[DirectionGroup] = []
    for g, members in enumerate(group_members):
        h = float(st.groups.half_width[g, 0])
        offset = float(wrap_pi(centre + st.groups.value[g, 0]))
        courses = np.array([used[i].course_rad for i in members])
        birge = float(st.birge_ratio[g, 0])
        groups.append(
            DirectionGroup(
                course_rad=float(wrap_2pi(_circular_mean(courses))),
                offset_rad=offset,
                std_error_rad=float(st.groups.std_error[g, 0]),
                ci_low_rad=offset - h,
                ci_high_rad=offset + h,
                n_segments=len(members),
                birge_ratio=birge,
            )
        )
        if len(members) > 1 and float(st.chi2_p_value[g, 0]) < 0.01:
            warnings.append(
                f"the {len(members)} runs at course {math.degrees(groups[-1].course_rad):.0f}° scatter more than "
                f"their noise explains (Birge ratio {birge:.2f}); uncertainty inflated accordingly"
            )

    if len(groups) == 2 and st.difference is not None:
        ga, gb = groups
        method = (
            f"direction-balanced mean of {ga.n_segments} run(s) at {math.degrees(ga.course_rad):.0f}° and "
            f"{gb.n_segments} run(s) at {math.degrees(gb.course_rad):.0f}°"
        )
        diff = float(st.difference.value[0])
        h = float(st.difference.half_width[0])
        if abs(diff) > h:
            warnings.append(
                f"runs in opposite directions disagree: {quantity} {math.degrees(ga.offset_rad):.3f}° at course "
                f"{math.degrees(ga.course_rad):.0f}° vs {math.degrees(gb.offset_rad):.3f}° at "
                f"{math.degrees(gb.course_rad):.0f}° (difference {math.degrees(diff):.3f}° ± "
                f"{math.degrees(h):.3f}°, {100 * confidence:.0f} %): cross wind or road crown? The balanced mean "
                "cancels a bias that flips sign with the direction, not one that does not"
            )
    else:
        method = f"inverse-variance mean of {groups[0].n_segments} run(s) in one direction"
        warnings.append(
            f"all straight runs in one direction (course {math.degrees(groups[0].course_rad):.0f}°): a cross wind "
            "or road crown would bias the result undetected; drive the straight both ways"
        )
    value = float(wrap_pi(centre + st.total.value[0]))
    se = float(st.total.std_error[0])
    h = float(st.total.half_width[0])
    k = h / se if se > 0.0 else 0.0
    if abs(value) > LARGE_OFFSET_RAD:
        warnings.append(
            f"{quantity} {math.degrees(value):.1f}° is implausibly large: antennas or channels swapped, "
            "reversing on a 'straight', or wrong sign convention?"
        )
    return OffsetEstimate(
        offset_rad=value,
        std_error_rad=se,
        ci_low_rad=value - h,
        ci_high_rad=value + h,
        confidence=confidence,
        coverage_factor=k,
        dof=equivalent_dof(k, confidence),
        noise_sigma_rad=float(st.sigma[0]),
        noise_white_share=float(st.white_share[0]),
        noise_correlation_time_s=float(st.correlation_time_s[0]),
        method=method,
        uncertainty_method=method_text(
            confidence,
            dt,
            max_correlation_s,
            reference=reference.name if reference is not None and ref_used else "",
            reference_s=reference.duration_s if reference is not None else 0.0,
        ),
        segments=tuple(seg_results),
        groups=tuple(groups),
        warnings=tuple(warnings),
    )


def length_reference(
    segments: Sequence[Segment],
    t_s: npt.ArrayLike,
    baseline_length_m: npt.ArrayLike,
    *,
    usable_mask: npt.ArrayLike | None = None,
    tolerance_m: float = DEFAULT_LENGTH_TOLERANCE_M,
    max_samples: int = REFERENCE_MAX_SAMPLES,
) -> NoiseReference:
    """The measured antenna separation as noise reference for the baseline heading.

    Its error is the relative position error *along* the baseline, the heading's is the one
    *across* it: with horizontally isotropic errors they share their spectrum, and a whole session
    of it tells the correlation time far better than a few short runs. Samples: ``usable_mask``
    (both rovers RTK fixed; the straight runs when not given) and finite, without gross length
    errors (wrong fix: off the median by more than GROSS_FACTOR × ``tolerance_m``), in gap-free
    stretches of at least 1 s; at most ``max_samples`` of them, the stretches nearest to the
    straight runs first.
    """
    t, dt = check_time(t_s)
    length = _array("baseline_length_m", baseline_length_m, t.size)
    if usable_mask is None:
        ok = np.zeros(t.size, dtype=bool)
        for seg in segments:
            ok |= seg.mask(t)
    else:
        ok = np.asarray(usable_mask, dtype=bool)
        if ok.shape != t.shape:
            raise CalibrationError(f"usable_mask: shape {ok.shape} differs from t_s shape {t.shape}")
    ok &= np.isfinite(length)
    if np.any(ok):  # about the median, not the configured length: a wrong configuration is flagged elsewhere
        ok &= np.abs(length - float(np.median(length[ok]))) <= GROSS_FACTOR * tolerance_m
    if dt <= 0.0 or not np.any(ok):
        return NoiseReference("the antenna baseline length", (), 0.0)
    cut = np.ones(t.size, dtype=bool)
    cut[1:] = (np.diff(t) > 1.5 * dt) | ~ok[:-1]
    starts = [int(i) for i in np.flatnonzero(ok & cut)]
    stretches: list[tuple[int, int]] = []
    for i in starts:
        j = i + 1
        while j < t.size and ok[j] and not cut[j]:
            j += 1
        if (j - i) * dt >= 1.0:
            stretches.append((i, j))
    centres = np.array([0.5 * (s.t_start_s + s.t_stop_s) for s in segments]) if segments else np.zeros(1)
    stretches.sort(key=lambda ij: float(np.min(np.abs(centres - 0.5 * (t[ij[0]] + t[ij[1] - 1])))))
    blocks: list[FloatArray] = []
    total = 0
    for i, j in stretches:
        take = int(min(j - i, max_samples - total))
        if take < 20:
            break
        blocks.append(np.asarray(length[i : i + take], dtype=np.float64))
        total += take
    return NoiseReference("the antenna baseline length", tuple(blocks), total * dt)


def check_baseline_length(
    segments: Sequence[Segment],
    t_s: npt.ArrayLike,
    baseline_length_m: npt.ArrayLike,
    nominal_length_m: float,
    *,
    tolerance_m: float = DEFAULT_LENGTH_TOLERANCE_M,
) -> BaselineCheck:
    """Mean and spread of the measured antenna separation on the straight runs against the configured one.

    Raises:
        CalibrationError: no finite baseline length inside the segments, or a non-positive nominal length.
    """
    t, _ = check_time(t_s)
    length = _array("baseline_length_m", baseline_length_m, t.size)
    if not nominal_length_m > 0.0:
        raise CalibrationError(f"nominal baseline length must be positive, got {nominal_length_m} m")
    m = np.zeros(t.size, dtype=bool)
    for seg in segments:
        m |= seg.mask(t)
    vals = length[m]
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        raise CalibrationError("baseline_length_m: no finite sample inside the straight runs")
    return BaselineCheck(
        nominal_m=float(nominal_length_m),
        mean_m=float(np.mean(vals)),
        std_m=float(np.std(vals)),
        min_m=float(np.min(vals)),
        max_m=float(np.max(vals)),
        n_samples=int(vals.size),
        n_outside_tolerance=int(np.sum(np.abs(vals - nominal_length_m) > tolerance_m)),
        n_gross=int(np.sum(np.abs(vals - nominal_length_m) > GROSS_FACTOR * tolerance_m)),
        tolerance_m=float(tolerance_m),
    )


def estimate_mount_offset(
    segments: Sequence[Segment],
    t_s: npt.ArrayLike,
    heading_rad: npt.ArrayLike,
    course_rad: npt.ArrayLike,
    baseline_length_m: npt.ArrayLike,
    nominal_length_m: float,
    *,
    length_tolerance_m: float = DEFAULT_LENGTH_TOLERANCE_M,
    confidence: float = 0.95,
    max_correlation_s: float = DEFAULT_MAX_CORRELATION_S,
    rtk_fixed_mask: npt.ArrayLike | None = None,
    length_as_noise_reference: bool = True,
) -> MountOffsetResult:
    """Antenna-baseline mounting offset from straight runs (see :class:`MountOffsetResult` for the sign).

    ``heading_rad`` is the azimuth of the baseline B → A (dual-antenna heading), ``course_rad`` the
    course over ground, ``baseline_length_m`` the measured antenna separation, all on ``t_s`` (s).
    On a straight run the true sideslip is ≈ 0, so heading − course is the offset.
    ``rtk_fixed_mask`` (True where both rovers are RTK fixed) lets the whole session's baseline
    length serve as noise reference (:func:`length_reference`; without it, the straight runs' only);
    ``length_as_noise_reference`` False uses the straight runs' heading − course alone.

    Raises:
        CalibrationError: no usable run, mismatched arrays, or a non-positive nominal length.
    """
    t, _ = check_time(t_s)
    heading = _array("heading_rad", heading_rad, t.size)
    course = _array("course_rad", course_rad, t.size)
    samples = sideslip_from_azimuths(heading, course)
    ref = (
        length_reference(segments, t, baseline_length_m, usable_mask=rtk_fixed_mask, tolerance_m=length_tolerance_m)
        if length_as_noise_reference
        else None
    )
    est = estimate_offset_from_straights(
        segments,
        t,
        samples,
        confidence=confidence,
        quantity="mounting offset",
        max_correlation_s=max_correlation_s,
        reference=ref,
    )
    base = check_baseline_length(segments, t, baseline_length_m, nominal_length_m, tolerance_m=length_tolerance_m)
    warnings = list(est.warnings)
    if not base.ok:
        warnings.append(
            f"measured antenna baseline {base.mean_m:.3f} m (spread {base.std_m:.3f} m) differs from the configured "
            f"{base.nominal_m:.3f} m by more than {base.tolerance_m:.3f} m: wrong RTK fix or wrong configuration?"
        )
    elif base.n_gross:
        warnings.append(
            f"{base.n_gross} of {base.n_samples} baseline samples deviate from {base.nominal_m:.3f} m by more than "
            f"{GROSS_FACTOR * base.tolerance_m:.3f} m: intermittent wrong fix?"
        )
    return MountOffsetResult(estimate=est, baseline=base, warnings=tuple(warnings))


def estimate_optical_zero(
    segments: Sequence[Segment],
    t_s: npt.ArrayLike,
    optical_vx_mps: npt.ArrayLike,
    optical_vy_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    sensor_xy_m: tuple[float, float],
    *,
    reference_beta_rad: npt.ArrayLike | None = None,
    confidence: float = 0.95,
    max_correlation_s: float = DEFAULT_MAX_CORRELATION_S,
) -> OpticalZeroResult:
    """Slip-angle zero of an optical sensor from straight runs.

    The sensor's longitudinal and lateral velocities (vehicle axes, at ``sensor_xy_m`` from the
    CG) are moved to the CG with the yaw rate, turned into a slip angle and compared with
    ``reference_beta_rad`` (the GNSS sideslip at the CG on ``t_s``; taken as 0 when omitted, as it
    is on a straight). All arrays are on the sensor's time base ``t_s`` (s); the segments are
    applied by time.

    Raises:
        CalibrationError: no usable run or mismatched arrays.
    """
    t, _ = check_time(t_s)
    vx = _array("optical_vx_mps", optical_vx_mps, t.size)
    vy = _array("optical_vy_mps", optical_vy_mps, t.size)
    r = _array("yaw_rate_rps", yaw_rate_rps, t.size)
    vx_cg, vy_cg = transfer_velocity(vx, vy, r, sensor_xy_m, (0.0, 0.0))
    beta = sideslip_from_velocity(vx_cg, vy_cg)
    if reference_beta_rad is not None:
        beta = np.asarray(wrap_pi(beta - _array("reference_beta_rad", reference_beta_rad, t.size)), dtype=float)
    est = estimate_offset_from_straights(
        segments, t, beta, confidence=confidence, quantity="optical slip zero", max_correlation_s=max_correlation_s
    )
    return OpticalZeroResult(estimate=est, sensor_xy_m=(float(sensor_xy_m[0]), float(sensor_xy_m[1])))


def apply_mount_offset(heading_rad: npt.ArrayLike, offset_rad: float) -> FloatArray:
    """Vehicle x-axis azimuth from the baseline azimuth: wrap_2π(heading − offset)."""
    return np.asarray(wrap_2pi(np.asarray(heading_rad, dtype=float) - offset_rad), dtype=float)


def apply_optical_zero(
    vx_mps: npt.ArrayLike, vy_mps: npt.ArrayLike, zero_rad: float
) -> tuple[FloatArray, FloatArray]:
    """Rotate optical-sensor velocities by −zero so that their slip angle reads (measured − zero)."""
    c, s = math.cos(zero_rad), math.sin(zero_rad)
    vx = np.asarray(vx_mps, dtype=float)
    vy = np.asarray(vy_mps, dtype=float)
    return c * vx + s * vy, -s * vx + c * vy


def calibrate_mount_offset(
    t_s: npt.ArrayLike,
    heading_rad: npt.ArrayLike,
    course_rad: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    baseline_length_m: npt.ArrayLike,
    rtk_fixed_mask: npt.ArrayLike,
    nominal_length_m: float,
    *,
    min_speed_mps: float = DEFAULT_MIN_SPEED_MPS,
    max_yaw_rate_rps: float = DEFAULT_MAX_YAW_RATE_RPS,
    max_course_std_rad: float = DEFAULT_MAX_COURSE_STD_RAD,
    min_duration_s: float = DEFAULT_MIN_STRAIGHT_S,
    length_tolerance_m: float = DEFAULT_LENGTH_TOLERANCE_M,
    confidence: float = 0.95,
    max_correlation_s: float = DEFAULT_MAX_CORRELATION_S,
) -> MountOffsetResult:
    """The whole ``rig calibrate-baseline`` computation on arrays at the GNSS epochs.

    Finds the straight runs (:func:`calibration.segments.find_straight_segments`; the yaw rate
    interpolated onto ``t_s`` by the caller; ``rtk_fixed_mask`` True where both rovers are RTK
    fixed) and estimates the offset from them (:func:`estimate_mount_offset`).

    Raises:
        CalibrationError: no usable straight run (the message says what was missing, e.g.
            "longest straight segment 3.2 s at 31 km/h; need 5.0 s at > 25 km/h …"), or bad arrays.
    """
    segments = find_straight_segments(
        t_s,
        speed_mps,
        yaw_rate_rps,
        course_rad,
        rtk_fixed_mask,
        min_speed_mps=min_speed_mps,
        max_yaw_rate_rps=max_yaw_rate_rps,
        max_course_std_rad=max_course_std_rad,
        min_duration_s=min_duration_s,
    )
    return estimate_mount_offset(
        segments,
        t_s,
        heading_rad,
        course_rad,
        baseline_length_m,
        nominal_length_m,
        length_tolerance_m=length_tolerance_m,
        confidence=confidence,
        max_correlation_s=max_correlation_s,
        rtk_fixed_mask=rtk_fixed_mask,
    )
