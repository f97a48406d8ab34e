"""Zero offsets from straight runs: GNSS antenna-baseline mounting offset and optical-sensor slip zero.

On a straight road at steady speed the true sideslip is (very nearly) zero, so

- the azimuth of the antenna baseline minus the course over ground is the angle between the
  baseline and the vehicle x axis (the *mounting offset*), and
- the slip angle an optical sensor reports (moved to the CG; with r ≈ 0 the lever arm hardly
  matters) minus the GNSS sideslip (≈ 0) is the sensor's *zero offset*.

Uncertainty (see :mod:`calibration.stats`): each straight run is located with a Huber estimate;
its standard error comes from an AR(1) model of the within-run noise whose lag-1 coefficient is
pooled over all runs (samples 50 ms apart are far from independent: with τ ≈ 1 s a 5 s run at
20 Hz holds about three independent samples, not a hundred). Runs in the same direction are
combined by inverse-variance weighting, inflated by the Birge ratio when they scatter more than
their own uncertainties. When runs exist in both directions the estimate is the plain mean of the
two direction means: a cross wind (or anything else whose sideslip flips sign with the driving
direction) cancels, and a disagreement between the directions is reported as a warning.
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
    Ar1BiasTable,
    CombinedEstimate,
    LocationEstimate,
    average_of_two,
    block_residuals,
    combine,
    correlated_location,
    pooled_ar1,
    pooled_lag1,
    studentized_quantiles,
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
    """k of the interval offset ± k·σ (simulated quantile of |error|/σ, see :mod:`calibration.stats`)."""
    dof: float
    ar1_phi: float
    """Pooled lag-1 autocorrelation of the within-run noise (per sample, median-unbiased)."""
    ar1_phi_upper: float
    """Its one-sided 84 % upper bound, at which the interval's coverage factor is simulated."""
    method: str
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
            "ar1_phi": self.ar1_phi,
            "ar1_phi_upper": self.ar1_phi_upper,
            "method": self.method,
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
) -> OffsetEstimate:
    """Robust offset with an honest confidence interval from per-sample offsets on straight runs.

    ``offset_samples_rad`` is any angle whose true value is the constant offset on a straight run
    (e.g. baseline azimuth − course). Samples are selected by time (``Segment.mask``), so the
    arrays may come from another device than the one the segments were found on. NaNs are skipped.
    ``quantity`` names the thing in messages.

    Raises:
        CalibrationError: no segment, or no segment with at least 5 finite samples.
    """
    t, _ = check_time(t_s)
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
    resid = [block_residuals(b) for b in blocks]
    table = Ar1BiasTable([b.size for b in blocks])
    phi = pooled_ar1(resid, table=table)
    phi_upper = max(phi, float(table.upper(pooled_lag1(resid))))
    # One continuous scale for all runs: about the circular mean of the run means.
    run_means = np.array([wrap_pi(r + float(np.median(b))) for r, b in zip(refs, blocks, strict=True)])
    centre = _circular_mean(run_means)
    estimates: list[LocationEstimate] = []
    for ref, b in zip(refs, blocks, strict=True):
        est = correlated_location(b, phi)
        shift = float(wrap_pi(ref - centre))
        estimates.append(
            LocationEstimate(est.value + shift, est.std_error, est.dof, est.n_samples, est.n_effective)
        )

    # Direction groups: within ±90° of the longest run's course, and the rest.
    ref_course = max(used, key=lambda s: s.duration_s).course_rad
    same = [abs(float(wrap_pi(s.course_rad - ref_course))) <= math.pi / 2.0 for s in used]
    group_members = [m for m in ([i for i, f in enumerate(same) if f], [i for i, f in enumerate(same) if not f]) if m]
    # Interval half widths: quantiles of |error|/σ of this very estimator, simulated (bootstrap-t).
    # Simulated at the 84 % upper bound of φ, since a few runs pin φ down poorly and larger φ widens them.
    sq = studentized_quantiles([b.size for b in blocks], group_members, phi_upper, confidence, table=table)

    seg_results: list[SegmentOffset] = []
    for seg, est, k_blk in zip(used, estimates, sq.blocks, strict=True):
        h = k_blk * est.std_error
        offset = float(wrap_pi(centre + est.value))
        seg_results.append(
            SegmentOffset(
                t_start_s=seg.t_start_s,
                duration_s=seg.duration_s,
                mean_speed_mps=seg.mean_speed_mps,
                course_rad=seg.course_rad,
                offset_rad=offset,
                std_error_rad=est.std_error,
                ci_low_rad=offset - h,
                ci_high_rad=offset + h,
                n_samples=est.n_samples,
                n_effective=est.n_effective,
            )
        )

    groups: list[tuple[CombinedEstimate, DirectionGroup]] = []
    for members, k_grp in zip(group_members, sq.groups, strict=True):
        comb = combine([estimates[i] for i in members])
        h = k_grp * comb.std_error
        offset = float(wrap_pi(centre + comb.value))
        courses = np.array([used[i].course_rad for i in members])
        groups.append(
            (
                comb,
                DirectionGroup(
                    course_rad=float(wrap_2pi(_circular_mean(courses))),
                    offset_rad=offset,
                    std_error_rad=comb.std_error,
                    ci_low_rad=offset - h,
                    ci_high_rad=offset + h,
                    n_segments=len(members),
                    birge_ratio=comb.birge_ratio,
                ),
            )
        )
        if len(members) > 1 and comb.chi2_p_value < 0.01:
            warnings.append(
                f"the {len(members)} runs at course {math.degrees(groups[-1][1].course_rad):.0f}° scatter more than "
                f"their noise explains (Birge ratio {comb.birge_ratio:.2f}); uncertainty inflated accordingly"
            )

    if len(groups) == 2:
        (ca, ga), (cb, gb) = groups
        total = average_of_two(ca, cb)
        method = (
            f"direction-balanced mean of {ga.n_segments} run(s) at {math.degrees(ga.course_rad):.0f}° and "
            f"{gb.n_segments} run(s) at {math.degrees(gb.course_rad):.0f}°"
        )
        diff = ca.value - cb.value
        se_diff = math.hypot(ca.std_error, cb.std_error)
        h = sq.difference * se_diff
        if abs(diff) > h:
            warnings.append(
                f"runs in opposite directions disagree: {quantity} {math.degrees(ga.offset_rad):.3f}° at course "
                f"{math.degrees(ga.course_rad):.0f}° vs {math.degrees(gb.offset_rad):.3f}° at "
                f"{math.degrees(gb.course_rad):.0f}° (difference {math.degrees(diff):.3f}° ± "
                f"{math.degrees(h):.3f}°, {100 * confidence:.0f} %): cross wind or road crown? The balanced mean "
                "cancels a bias that flips sign with the direction, not one that does not"
            )
    else:
        total = groups[0][0]
        method = f"inverse-variance mean of {total.n_blocks} run(s) in one direction"
        warnings.append(
            f"all straight runs in one direction (course {math.degrees(groups[0][1].course_rad):.0f}°): a cross wind "
            "or road crown would bias the result undetected; drive the straight both ways"
        )
    value = float(wrap_pi(centre + total.value))
    h = sq.total * total.std_error
    if abs(value) > LARGE_OFFSET_RAD:
        warnings.append(
            f"{quantity} {math.degrees(value):.1f}° is implausibly large: antennas or channels swapped, "
            "reversing on a 'straight', or wrong sign convention?"
        )
    return OffsetEstimate(
        offset_rad=value,
        std_error_rad=total.std_error,
        ci_low_rad=value - h,
        ci_high_rad=value + h,
        confidence=confidence,
        coverage_factor=sq.total,
        dof=total.dof,
        ar1_phi=phi,
        ar1_phi_upper=phi_upper,
        method=method,
        segments=tuple(seg_results),
        groups=tuple(g for _, g in groups),
        warnings=tuple(warnings),
    )


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
) -> MountOffsetResult:
    """Antenna-baseline mounting offset from straight runs (see :class:`MountOffsetResult` for the sign).

    ``heading_rad`` is the azimuth of the baseline B → A (dual-antenna heading), ``course_rad`` the
    course over ground, ``baseline_length_m`` the measured antenna separation, all on ``t_s`` (s).
    On a straight run the true sideslip is ≈ 0, so heading − course is the offset.

    Raises:
        CalibrationError: no usable run, mismatched arrays, or a non-positive nominal length.
    """
    t, _ = check_time(t_s)
    heading = _array("heading_rad", heading_rad, t.size)
    course = _array("course_rad", course_rad, t.size)
    samples = sideslip_from_azimuths(heading, course)
    est = estimate_offset_from_straights(segments, t, samples, confidence=confidence, quantity="mounting offset")
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
    est = estimate_offset_from_straights(segments, t, beta, confidence=confidence, quantity="optical slip zero")
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
    )
