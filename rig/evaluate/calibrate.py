"""The ``rig calibrate-*`` computations: inputs from :mod:`rig.data.inputs`, math from :mod:`calibration`.

- :func:`calibrate_baseline` — antenna mounting offset (and the optical sensors' slip zero) from
  the straight runs of a session, with the baseline-length check;
- :func:`calibrate_steering_ratio` — steering ratio per steering-wheel angle, forward and reverse,
  from constant-SWA circles (rear-axle-centre track moved from antenna A with the dual-antenna
  heading);
- :func:`read_accel_csv` / :func:`read_gyro_csv` / :func:`calibrate_imu` — accelerometer and
  gyroscope triads from static positions and turntable runs (CSV formats documented there);
- :func:`write_profile_calibration` — put results into a vehicle-profile TOML file in place,
  keeping everything else (comments, order, formatting) with tomlkit;
- plots (matplotlib, Agg backend, PNG).

Results are also recorded next to the session (:func:`rig.data.sidefiles.update_calibration_file`),
where :func:`rig.data.inputs.load_inputs` picks them up for later commands.
"""

from __future__ import annotations

import csv
import datetime as dt
import math
import os
import tempfile
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from calibration.imu import (
    STANDARD_GRAVITY,
    StaticPosition,
    TriadCalibration,
    TurntableRun,
    calibrate_accelerometer,
    calibrate_gyroscope,
)
from calibration.mount import MountOffsetResult, OpticalZeroResult, estimate_mount_offset, estimate_optical_zero
from calibration.segments import (
    DEFAULT_MAX_COURSE_STD_RAD,
    DEFAULT_MAX_YAW_RATE_RPS,
    Direction,
    Segment,
    SwaSegment,
    diagnose_straight_segments,
    find_constant_swa_segments,
    find_straight_segments,
)
from calibration.steering import (
    SasZeroEstimate,
    SteeringRatioRow,
    SteeringRatioTable,
    antenna_to_rear_axle,
    apply_sas_zero,
    combine_sas_zero,
    sas_zero_from_circle_pairs,
    sas_zero_from_straights,
    steering_ratio_from_circles,
)
from rig.core.config import ImuCalibrationConfig, SessionConfig, load_profile
from rig.data.inputs import DualGnss, SessionInputs
from rig.data.verdicts import check_inputs
from vsccore.angles import unwrap, wrap_2pi, wrap_pi
from vsccore.errors import CalibrationError, ConfigError

__all__ = [
    "BaselineCalibration",
    "BaselineOptions",
    "ImuResult",
    "SteeringCalibration",
    "SteeringOptions",
    "calibrate_baseline",
    "calibrate_imu",
    "calibrate_steering_ratio",
    "plot_baseline",
    "plot_steering",
    "read_accel_csv",
    "read_gyro_csv",
    "write_profile_calibration",
]

FloatArray = npt.NDArray[np.float64]

_YAW_FROM_HEADING_WINDOW_S = 1.0
_YAW_RATE_AGREEMENT_RPS = math.radians(1.0)
"""CAN and GNSS-heading yaw rates further apart than this (90th percentile) → the CAN one is not trusted."""


def _today() -> str:
    return dt.date.today().isoformat()


def _window_bounds(t: FloatArray) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], FloatArray]:
    half = 0.5 * _YAW_FROM_HEADING_WINDOW_S
    lo = np.searchsorted(t, t - half)
    hi = np.clip(np.searchsorted(t, t + half, side="right") - 1, 0, t.size - 1)
    return lo, hi, t[hi] - t[lo]


def _yaw_rate_from_heading(g: DualGnss) -> FloatArray:
    """Yaw rate (rad/s) from the baseline heading: differences over ±0.5 s (noise σ_ψ·√2 / 1 s, not ·20 Hz)."""
    az = np.where(g.valid & g.rtk_fixed_both, g.baseline_azimuth_rad, np.nan)
    ok = np.isfinite(az)
    r = np.full(len(g), np.nan)
    if ok.sum() > 2:
        t = g.t_s[ok]
        psi = unwrap(-az[ok])  # yaw angle increases counter-clockwise; azimuth clockwise
        lo, hi, span = _window_bounds(t)
        with np.errstate(invalid="ignore", divide="ignore"):
            rr = np.where(span > 0.25 * _YAW_FROM_HEADING_WINDOW_S, (psi[hi] - psi[lo]) / span, np.nan)
        r[ok] = rr
    return r


def _window_mean(t: FloatArray, r: FloatArray) -> FloatArray:
    """``r`` averaged over the same ±0.5 s windows as :func:`_yaw_rate_from_heading` (trapezoidal integral)."""
    out = np.full(t.size, np.nan)
    ok = np.isfinite(r)
    if ok.sum() > 2:
        tt, rr = t[ok], r[ok]
        integral = np.concatenate(([0.0], np.cumsum(0.5 * (rr[1:] + rr[:-1]) * np.diff(tt))))
        lo, hi, span = _window_bounds(tt)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[ok] = np.where(span > 0.25 * _YAW_FROM_HEADING_WINDOW_S, (integral[hi] - integral[lo]) / span, np.nan)
    return out


@dataclass(frozen=True, slots=True)
class YawRate:
    """Yaw rate at the GNSS epochs with where it came from and the sensor zero removed from it."""

    values: FloatArray
    source: str
    bias_rps: float
    """Zero offset of the CAN yaw-rate sensor against the GNSS heading rate (removed from ``values``); 0 without CAN."""


def _yaw_rate_at_epochs(inputs: SessionInputs, g: DualGnss) -> YawRate:
    """CAN ``yaw_rate`` (its zero offset against the GNSS heading rate removed), else the GNSS heading rate."""
    r_gnss = _yaw_rate_from_heading(g)
    why = "no CAN yaw_rate in the session"
    if "yaw_rate" in inputs.can:
        s = inputs.can["yaw_rate"]
        r = s.at(g.t_s, max_gap_s=0.25)
        both = np.isfinite(r) & np.isfinite(r_gnss) & (g.speed_mps > 2.0)
        if both.sum() < 20:
            return YawRate(r, f"CAN yaw_rate ({s.source}; zero offset not checked: too few GNSS epochs)", 0.0)
        # compare like with like: the CAN rate averaged over the same windows as the heading differences
        r_avg = _window_mean(g.t_s, r)
        both &= np.isfinite(r_avg)
        bias = float(np.median(r_avg[both] - r_gnss[both]))
        p90 = float(np.percentile(np.abs(r_avg[both] - bias - r_gnss[both]), 90))
        if p90 <= _YAW_RATE_AGREEMENT_RPS:
            return YawRate(r - bias, f"CAN yaw_rate ({s.source})", bias)
        why = (f"CAN yaw_rate disagrees with the GNSS heading rate (90th percentile of the difference "
               f"{math.degrees(p90):.2f} °/s > {math.degrees(_YAW_RATE_AGREEMENT_RPS):.1f} °/s): wrong time base, "
               "sign or scaling of the CAN yaw rate?")
    return YawRate(r_gnss, f"GNSS baseline heading ({why})", 0.0)


# ---------------------------------------------------------------------------------------------
# calibrate-baseline
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BaselineOptions:
    """Straight-run criteria and the baseline-length tolerance (None: the profile's ``baseline_tolerance_m``)."""

    min_speed_kmh: float = 25.0
    min_duration_s: float = 5.0
    max_yaw_rate_dps: float = math.degrees(DEFAULT_MAX_YAW_RATE_RPS)
    max_course_std_deg: float = math.degrees(DEFAULT_MAX_COURSE_STD_RAD)
    length_tolerance_m: float | None = None
    confidence: float = 0.95

    def check(self) -> None:
        if not (self.min_speed_kmh >= 0 and self.min_duration_s > 0 and self.max_yaw_rate_dps > 0
                and self.max_course_std_deg > 0 and 0.5 < self.confidence < 1.0):
            raise ConfigError(
                f"calibrate-baseline: --min-speed-kmh must be >= 0, --min-duration-s, --max-yaw-rate-dps and "
                f"--max-course-std-deg > 0, confidence in (0.5, 1) (got {self.min_speed_kmh}, {self.min_duration_s}, "
                f"{self.max_yaw_rate_dps}, {self.max_course_std_deg}, {self.confidence})"
            )
        if self.length_tolerance_m is not None and not self.length_tolerance_m > 0:
            raise ConfigError(f"calibrate-baseline: --length-tolerance-m must be > 0, got {self.length_tolerance_m}")


@dataclass(frozen=True, slots=True)
class OpticalZero:
    """An optical sensor's slip zero: the residual measured on the recorded (already corrected) data plus the
    zero that was applied while recording."""

    sensor: str
    result: OpticalZeroResult
    applied_rad: float

    @property
    def zero_rad(self) -> float:
        return self.applied_rad + self.result.zero_rad

    @property
    def u95_rad(self) -> float:
        e = self.result.estimate
        return 0.5 * (e.ci_high_rad - e.ci_low_rad)

    def to_dict(self) -> dict[str, object]:
        d = self.result.to_dict()
        residual = d.pop("zero_deg")
        return {"sensor": self.sensor, "zero_deg": math.degrees(self.zero_rad), "u95_deg": math.degrees(self.u95_rad),
                "applied_when_recorded_deg": math.degrees(self.applied_rad), "residual_deg": residual, **d}


@dataclass(frozen=True, slots=True)
class BaselineCalibration:
    """Result of :func:`calibrate_baseline`."""

    session: str
    session_path: Path
    mount: MountOffsetResult
    segments: tuple[Segment, ...]
    options: BaselineOptions
    nominal_length_m: float
    tolerance_m: float
    in_force_offset_deg: float
    yaw_rate_source: str
    yaw_rate_bias_dps: float
    """Zero offset of the CAN yaw-rate sensor found against the GNSS heading rate (removed before use)."""
    optical: tuple[OpticalZero, ...]
    optical_skipped: Mapping[str, str]
    truth_offset_deg: float | None
    """Simulated sessions: the simulator's true mounting offset (for comparison only)."""
    truth_optical_zero_deg: Mapping[str, float]
    warnings: tuple[str, ...]
    plot_data: Mapping[str, FloatArray] = field(repr=False, compare=False, default_factory=dict)

    @property
    def offset_deg(self) -> float:
        return math.degrees(self.mount.offset_rad)

    @property
    def u95_deg(self) -> float:
        """Half-width of the confidence interval (95 % by default)."""
        e = self.mount.estimate
        return math.degrees(0.5 * (e.ci_high_rad - e.ci_low_rad))

    @property
    def length_ok(self) -> bool:
        return self.mount.baseline.ok and self.mount.baseline.n_gross == 0

    def to_dict(self) -> dict[str, object]:
        """JSON view: ``offset_deg``, ``u95_deg``, ``ci_low_deg``/``ci_high_deg``, ``segments`` (time, duration,
        speed, course, offset), ``direction_groups``, ``baseline`` (length check), ``optical_zero``, ``warnings``,
        ``uncertainty_method`` and, for simulated sessions, ``simulation_truth``."""
        est = self.mount.estimate
        segs: list[dict[str, object]] = []
        for s in est.segments:
            d: dict[str, object] = dict(s.to_dict())
            d["direction"] = _compass(s.course_rad)
            segs.append(d)
        out: dict[str, object] = {
            "session": self.session,
            "offset_deg": self.offset_deg,
            "u95_deg": self.u95_deg,
            "ci_low_deg": math.degrees(est.ci_low_rad),
            "ci_high_deg": math.degrees(est.ci_high_rad),
            "std_error_deg": math.degrees(est.std_error_rad),
            "confidence": est.confidence,
            "coverage_factor": est.coverage_factor,
            "dof": est.dof,
            "noise_sigma_deg": math.degrees(est.noise_sigma_rad),
            "noise_white_share": est.noise_white_share,
            "noise_correlation_time_s": est.noise_correlation_time_s,
            "method": est.method,
            "uncertainty_method": est.uncertainty_method,
            "in_force_offset_deg": self.in_force_offset_deg,
            "segments": segs,
            "direction_groups": [g.to_dict() for g in est.groups],
            "baseline": {**self.mount.baseline.to_dict(), "flagged": not self.length_ok},
            "optical_zero": {o.sensor: o.to_dict() for o in self.optical},
            "optical_skipped": dict(self.optical_skipped),
            "yaw_rate_source": self.yaw_rate_source,
            "yaw_rate_bias_dps": self.yaw_rate_bias_dps,
            "options": {"min_speed_kmh": self.options.min_speed_kmh, "min_duration_s": self.options.min_duration_s,
                        "max_yaw_rate_dps": self.options.max_yaw_rate_dps,
                        "max_course_std_deg": self.options.max_course_std_deg, "length_tolerance_m": self.tolerance_m},
            "warnings": list(self.warnings),
        }
        if self.truth_offset_deg is not None:
            out["simulation_truth"] = {
                "true_mount_offset_deg": self.truth_offset_deg,
                "error_deg": self.offset_deg - self.truth_offset_deg,
                "true_optical_zero_deg": dict(self.truth_optical_zero_deg),
            }
        return out


def _compass(az_rad: float) -> str:
    names = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")
    return names[int((math.degrees(wrap_2pi(az_rad)) + 22.5) // 45.0) % 8]


def calibrate_baseline(inputs: SessionInputs, options: BaselineOptions | None = None) -> BaselineCalibration:
    """Mounting offset (and optical zeros) from the straight runs of ``inputs``.

    Raises:
        AnalysisError: the session has no dual-antenna GNSS.
        CalibrationError: no usable straight run; the message says what was missing (longest
            candidate, which criterion stopped it, share of RTK-fixed epochs).
    """
    opts = options or BaselineOptions()
    opts.check()
    g = inputs.require_gnss()
    timing, _verdicts = check_inputs(inputs, what=f"rig calibrate-baseline {inputs.name}", can=("yaw_rate",))
    ant = inputs.profile.antennas
    nominal = ant.baseline_length_m
    tol = opts.length_tolerance_m if opts.length_tolerance_m is not None else ant.baseline_tolerance_m
    yr = _yaw_rate_at_epochs(inputs, g)
    yaw, yaw_src = yr.values, yr.source
    fixed = g.rtk_fixed_both & g.valid
    kw: dict[str, Any] = {
        "min_speed_mps": opts.min_speed_kmh / 3.6,
        "max_yaw_rate_rps": math.radians(opts.max_yaw_rate_dps),
        "max_course_std_rad": math.radians(opts.max_course_std_deg),
        "min_duration_s": opts.min_duration_s,
    }
    course = np.where(g.valid, g.course_rad, np.nan)
    try:
        segments = find_straight_segments(g.t_s, g.speed_mps, yaw, course, fixed, **kw)
    except CalibrationError as exc:
        diag = diagnose_straight_segments(g.t_s, g.speed_mps, yaw, course, fixed, **kw)
        extra = (f" Session {inputs.name}: {len(g)} GNSS epochs over {g.t_s[-1] - g.t_s[0]:.1f} s, both rovers RTK "
                 f"fixed in {100.0 * float(np.mean(fixed)):.0f} %; yaw rate from {yaw_src}.")
        raise CalibrationError(f"{diag.message if diag.n_samples else exc}{extra}") from None
    mount = estimate_mount_offset(segments, g.t_s, g.baseline_azimuth_rad, course, g.baseline_length_m, nominal,
                                  length_tolerance_m=tol, confidence=opts.confidence, rtk_fixed_mask=fixed)
    warnings = list(mount.warnings)
    if not yaw_src.startswith("CAN"):
        warnings.append(f"yaw rate taken from the {yaw_src}: straight runs found with a noisier criterion")
    # optical zero from the same runs
    optical: list[OpticalZero] = []
    skipped: dict[str, str] = {}
    for name, ser in inputs.optical.items():
        if ser.kind != "body":
            skipped[name] = "wheel-mounted sensor: its zero is not observable on straight runs (toe, wheel axes)"
            continue
        ok = ser.valid & np.isfinite(ser.vx_mps) & np.isfinite(ser.vy_mps)
        if ok.sum() < 5:
            skipped[name] = "no valid samples"
            continue
        t = ser.t_s[ok]
        r_opt = np.interp(t, g.t_s, np.nan_to_num(yaw, nan=0.0))
        try:
            res = estimate_optical_zero(segments, t, ser.vx_mps[ok], ser.vy_mps[ok], r_opt, ser.mount_xy_m,
                                        confidence=opts.confidence)
        except CalibrationError as exc:
            skipped[name] = str(exc)
            continue
        optical.append(OpticalZero(name, res, ser.zero_applied_rad))
        warnings += [f"optical {name}: {w}" for w in res.warnings]
    sim = inputs.simulation or {}
    truth_off = sim.get("true_mount_offset_deg") if inputs.is_simulated else None
    tz = sim.get("true_optical_zero_deg")
    d = np.asarray(wrap_pi(g.baseline_azimuth_rad - course), dtype=float)
    return BaselineCalibration(
        session=inputs.name, session_path=inputs.path, mount=mount, segments=tuple(segments), options=opts,
        nominal_length_m=nominal, tolerance_m=tol, in_force_offset_deg=inputs.profile.calibration.mount_offset_deg,
        yaw_rate_source=yaw_src, yaw_rate_bias_dps=math.degrees(yr.bias_rps), optical=tuple(optical),
        optical_skipped=skipped,
        truth_offset_deg=float(truth_off) if isinstance(truth_off, int | float) else None,
        truth_optical_zero_deg={str(k): float(v) for k, v in tz.items()} if isinstance(tz, Mapping) else {},
        warnings=(*timing, *warnings, *(f"session: {w}" for w in inputs.warnings)),
        plot_data={"t": g.t_s, "speed": g.speed_mps, "diff": d, "length": g.baseline_length_m,
                   "fixed": fixed.astype(float)},
    )


def baseline_record(cal: BaselineCalibration) -> dict[str, Any]:
    """The entry recorded in the session's calibration file (key ``mount_offset``)."""
    d = cal.to_dict()
    return {"offset_deg": cal.offset_deg, "u95_deg": cal.u95_deg, "date": _today(), "session": cal.session,
            "ci_low_deg": d["ci_low_deg"], "ci_high_deg": d["ci_high_deg"], "segments": d["segments"],
            "baseline": d["baseline"], "warnings": d["warnings"]}


def optical_record(cal: BaselineCalibration) -> dict[str, Any]:
    """The entry recorded in the session's calibration file (key ``optical_zero``)."""
    return {o.sensor: {"zero_deg": math.degrees(o.zero_rad), "u95_deg": math.degrees(o.u95_rad), "date": _today(),
                       "session": cal.session} for o in cal.optical}


def format_baseline(cal: BaselineCalibration) -> str:
    """The human-readable report of ``rig calibrate-baseline``."""
    est = cal.mount.estimate
    lines = [(f"session {cal.session}: {len(est.segments)} straight run(s) "
              f"(speed > {cal.options.min_speed_kmh:g} km/h, "
             f"|yaw rate| < {cal.options.max_yaw_rate_dps:g} °/s, course σ < {cal.options.max_course_std_deg:g}°, "
             f"≥ {cal.options.min_duration_s:g} s, both rovers RTK fixed; yaw rate from {cal.yaw_rate_source}"
             + (f", its zero offset {cal.yaw_rate_bias_dps:+.3f} °/s removed)" if cal.yaw_rate_bias_dps else ")")), ""]
    lines.append(f"  {'#':>2} {'t (s)':>8} {'dur (s)':>8} {'km/h':>6} {'dir':>4} {'course °':>9} "
                 f"{'offset °':>9} {'±95 % °':>8} {'n_eff':>6}")
    for i, s in enumerate(est.segments, 1):
        half = 0.5 * math.degrees(s.ci_high_rad - s.ci_low_rad)
        lines.append(f"  {i:>2} {s.t_start_s:8.1f} {s.duration_s:8.1f} {3.6 * s.mean_speed_mps:6.1f} "
                     f"{_compass(s.course_rad):>4} {math.degrees(s.course_rad):9.1f} "
                     f"{math.degrees(s.offset_rad):9.3f} {half:8.3f} {s.n_effective:6.1f}")
    if len(est.groups) > 1:
        lines.append("")
        for gr in est.groups:
            lines.append(f"  direction {_compass(gr.course_rad):>2} ({math.degrees(gr.course_rad):5.1f}°): "
                         f"{math.degrees(gr.offset_rad):.3f}° ± "
                         f"{math.degrees(0.5 * (gr.ci_high_rad - gr.ci_low_rad)):.3f}° from {gr.n_segments} run(s)")
    lines += ["", (f"mounting offset {cal.offset_deg:+.3f}° ± {cal.u95_deg:.3f}° ({100 * est.confidence:.0f} %; "
                  f"in force: {cal.in_force_offset_deg:+.3f}°)")]
    if cal.truth_offset_deg is not None:
        err = cal.offset_deg - cal.truth_offset_deg
        lines.append(f"  simulation truth {cal.truth_offset_deg:+.3f}°: error {err:+.4f}°")
    lines.append(f"  within-run noise: σ {math.degrees(est.noise_sigma_rad):.3f}° per sample, "
                 f"{100 * est.noise_white_share:.0f} % white, the rest correlated over ≈ "
                 f"{est.noise_correlation_time_s:.2g} s")
    lines.append(f"  uncertainty: {est.uncertainty_method}")
    b = cal.mount.baseline
    flag = "OK" if cal.length_ok else "FLAGGED (wrong RTK fix or wrong configuration?)"
    lines += ["", (f"baseline length {b.mean_m:.4f} m (spread σ {1000 * b.std_m:.1f} mm, "
                   f"{b.min_m:.3f} … {b.max_m:.3f} m) vs "
                  f"configured {b.nominal_m:.3f} m ± {b.tolerance_m:.3f} m: {flag}")]
    for o in cal.optical:
        lines.append(f"optical {o.sensor}: slip zero {math.degrees(o.zero_rad):+.3f}° ± {math.degrees(o.u95_rad):.3f}° "
                     f"(residual {math.degrees(o.result.zero_rad):+.3f}° on top of {math.degrees(o.applied_rad):+.3f}° "
                     "applied while recording)")
        t = cal.truth_optical_zero_deg.get(o.sensor)
        if t is not None:
            lines.append(f"  simulation truth {t:+.3f}°: error {math.degrees(o.zero_rad) - t:+.4f}°")
    for name, why in cal.optical_skipped.items():
        lines.append(f"optical {name}: not estimated: {why}")
    for w in cal.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines) + "\n"


def plot_baseline(cal: BaselineCalibration, path: Path) -> Path:
    """Speed, heading − course and baseline length over time with the straight runs and their offsets (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pd = cal.plot_data
    t, d = pd["t"], np.degrees(pd["diff"])
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    try:
        ax = axes[0]
        ax.plot(t, 3.6 * pd["speed"], lw=0.8, color="0.3")
        ax.axhline(cal.options.min_speed_kmh, ls=":", color="tab:red", lw=0.8)
        ax.set_ylabel("speed (km/h)")
        ax = axes[1]
        inside = np.zeros(t.size, dtype=bool)
        for s in cal.segments:
            inside |= s.mask(t)
        ax.plot(t[inside], d[inside], ".", ms=2, color="0.5", label="heading − course (straight runs)")
        est = cal.mount.estimate
        for so in est.segments:
            lo, hi = math.degrees(so.ci_low_rad), math.degrees(so.ci_high_rad)
            ax.fill_between([so.t_start_s, so.t_start_s + so.duration_s], lo, hi, color="tab:blue", alpha=0.3)
            ax.hlines(math.degrees(so.offset_rad), so.t_start_s, so.t_start_s + so.duration_s, color="tab:blue")
        ax.axhline(cal.offset_deg, color="tab:green", label=f"estimate {cal.offset_deg:+.3f}° ± {cal.u95_deg:.3f}°")
        ax.axhspan(cal.offset_deg - cal.u95_deg, cal.offset_deg + cal.u95_deg, color="tab:green", alpha=0.15)
        if cal.truth_offset_deg is not None:
            ax.axhline(cal.truth_offset_deg, color="tab:red", ls="--", lw=0.8, label="simulation truth")
        if inside.any():
            lo, hi = np.nanpercentile(d[inside], [1, 99])
            pad = 0.2 * (hi - lo) + 0.05
            ax.set_ylim(min(lo, cal.offset_deg) - pad, max(hi, cal.offset_deg) + pad)
        ax.set_ylabel("offset (°)")
        ax.legend(loc="upper right", fontsize=8)
        for a in axes:
            for s in cal.segments:
                a.axvspan(s.t_start_s, s.t_stop_s, color="tab:blue", alpha=0.08)
        ax = axes[2]
        ax.plot(t, pd["length"], lw=0.8, color="0.3")
        b = cal.mount.baseline
        ax.axhline(b.nominal_m, color="tab:green", lw=0.8)
        ax.axhspan(b.nominal_m - b.tolerance_m, b.nominal_m + b.tolerance_m, color="tab:green", alpha=0.15)
        ax.set_ylim(b.nominal_m - 5 * b.tolerance_m, b.nominal_m + 5 * b.tolerance_m)
        ax.set_ylabel("baseline (m)")
        ax.set_xlabel("t (s)")
        fig.suptitle(f"{cal.session}: antenna mounting offset from straight runs")
        fig.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------
# calibrate-steering-ratio
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SteeringOptions:
    """Constant-SWA circle criteria.

    A run is a candidate when it lasts ``min_duration_s`` or turns the car through ``min_turn_deg``;
    its circle is used when it sweeps ``min_arc_deg``. The relative radius error is about the
    position error divided by the depth (sagitta) of the driven arc, R·(1 − cos(arc/2)): with 1 cm
    RTK noise a 50° arc of a 5 m circle (sagitta 0.5 m) is off by up to ≈ 1.5 %, 90° and more by a
    few tenths of a percent (benchmarks/study_steering_ratio.py). Small steering angles need long
    holds: the radius grows as 1/δ (≈ 85 m at 30° SWA: 110 s for 90° at 5 km/h).

    The steering-angle sensor's zero offset is estimated from left/right circle pairs and from the
    straight runs at more than ``straight_min_speed_kmh`` (docs/steering.md) and removed; a row whose
    95 % ratio uncertainty exceeds ``max_ratio_u95_percent`` is flagged instead of reported.
    """

    max_speed_kmh: float = 15.0
    min_speed_kmh: float = 1.0
    max_swa_spread_deg: float = 2.0
    min_duration_s: float = 5.0
    min_turn_deg: float = 60.0
    min_arc_deg: float = 60.0
    straight_min_speed_kmh: float = 25.0
    straight_min_duration_s: float = 3.0
    max_ratio_u95_percent: float = 1.0


@dataclass(frozen=True, slots=True)
class SteeringCalibration:
    """Result of :func:`calibrate_steering_ratio`."""

    session: str
    table: SteeringRatioTable
    segments: tuple[SwaSegment, ...]
    mount_offset_deg: float
    truth_ratio: Mapping[int, float]
    """Simulated sessions: the simulator's SWA / road-wheel angle over each row's circle (row index → ratio)."""
    warnings: tuple[str, ...]
    plot_data: Mapping[str, FloatArray] = field(repr=False, compare=False, default_factory=dict)
    flagged_truth_ratio: Mapping[int, float] = field(default_factory=dict)
    """As ``truth_ratio`` for ``table.flagged``."""

    @property
    def sas_zero(self) -> SasZeroEstimate | None:
        """The steering-angle sensor's zero offset removed from the rows (None when it could not be estimated)."""
        return self.table.sas_zero

    def to_dict(self) -> dict[str, object]:
        """JSON view: ``rows`` (swa_deg, direction, radius_m, delta_deg, ratio, ratio_u95_percent, …), ``flagged``
        (rows too uncertain to be results), ``sas_zero`` (offset_deg, u95_deg, sources), ``wheelbase_m``,
        ``warnings``."""
        d = self.table.to_dict()
        for key, truth in (("rows", self.truth_ratio), ("flagged", self.flagged_truth_ratio)):
            rows = d[key]
            assert isinstance(rows, list)
            for i, r in enumerate(rows):
                if i in truth:
                    r["simulation_true_ratio"] = truth[i]
        d["session"] = self.session
        d["mount_offset_deg"] = self.mount_offset_deg
        d["warnings"] = list(self.table.warnings) + list(self.warnings)
        return d


def _signed_speed(g: DualGnss, heading: FloatArray) -> FloatArray:
    """Speed of A with the sign of travel along the x axis (negative when the course is behind the heading)."""
    back = np.abs(np.asarray(wrap_pi(g.course_rad - heading), dtype=float)) > 0.5 * math.pi
    return np.where(back, -g.speed_mps, g.speed_mps)


def calibrate_steering_ratio(inputs: SessionInputs, options: SteeringOptions | None = None) -> SteeringCalibration:
    """Steering ratio per SWA and direction from the constant-SWA circles of ``inputs``.

    Raises:
        AnalysisError: no dual-antenna GNSS or no CAN ``swa``.
        CalibrationError: no usable circle (the message says why each candidate failed).
    """
    o = options or SteeringOptions()
    g = inputs.require_gnss()
    swa_sig = inputs.signal("swa")
    timing, _verdicts = check_inputs(inputs, what=f"rig calibrate-steering-ratio {inputs.name}",
                                     can=("swa", "yaw_rate"), optical=False)
    offset = math.radians(inputs.profile.calibration.mount_offset_deg)
    heading = g.heading_rad(offset)
    ok = g.valid & g.rtk_fixed_both
    swa = np.where(ok, swa_sig.at(g.t_s, max_gap_s=0.25), np.nan)
    v = _signed_speed(g, heading)
    yaw = _yaw_rate_at_epochs(inputs, g).values
    segs = find_constant_swa_segments(
        g.t_s, swa, v, yaw_rate_rps=np.nan_to_num(yaw, nan=0.0), min_speed_mps=o.min_speed_kmh / 3.6,
        max_speed_mps=o.max_speed_kmh / 3.6, max_swa_spread_rad=math.radians(o.max_swa_spread_deg),
        min_duration_s=o.min_duration_s, min_turn_rad=math.radians(o.min_turn_deg),
    )
    if not segs:
        raise CalibrationError(
            f"session {inputs.name}: no constant-SWA circle (|SWA| spread < {o.max_swa_spread_deg:g}°, "
            f"{o.min_speed_kmh:g} … {o.max_speed_kmh:g} km/h, ≥ {o.min_duration_s:g} s or ≥ {o.min_turn_deg:g}° of "
            f"turn, both rovers RTK fixed); RTK fixed in {100.0 * float(np.mean(ok)):.0f} % of "
            f"{len(g)} epochs, speed {3.6 * float(np.nanmin(np.abs(v))):.0f} … {3.6 * float(np.nanmax(np.abs(v))):.0f} "
            "km/h"
        )
    veh = inputs.profile.vehicle
    a = inputs.profile.antennas.a
    e, n = antenna_to_rear_axle(g.a.east_m, g.a.north_m, heading, a.xy, (-veh.cg_to_rear_axle_m, 0.0))
    table = steering_ratio_from_circles(segs, g.t_s, e, n, wheelbase_m=veh.wheelbase_m,
                                        min_arc_rad=math.radians(o.min_arc_deg))
    # the steering-angle sensor's zero: left/right circle pairs and straight runs at speed
    pairs = sas_zero_from_circle_pairs(table.rows)
    straight = None
    try:
        runs = find_straight_segments(
            g.t_s, g.speed_mps, yaw, np.where(g.valid, g.course_rad, np.nan), ok,
            min_speed_mps=o.straight_min_speed_kmh / 3.6, min_duration_s=o.straight_min_duration_s)
    except CalibrationError:
        runs = []
    if runs:
        idx = np.arange(len(g))
        straight = sas_zero_from_straights(g.t_s, swa, yaw, v,
                                           [(idx >= r.start_index) & (idx < r.stop_index) for r in runs])
    extra: list[str] = []
    try:
        zero = combine_sas_zero([pairs, straight], resolution_rad=_resolution(swa_sig.values[swa_sig.valid]))
    except CalibrationError as exc:
        extra.append(f"{exc}: ratios use the SWA as measured")
    else:
        table = apply_sas_zero(table, zero, max_ratio_u95=o.max_ratio_u95_percent / 100.0)
    return SteeringCalibration(
        session=inputs.name, table=table, segments=tuple(segs), mount_offset_deg=math.degrees(offset),
        truth_ratio=_truth_ratios(inputs, table.rows),
        warnings=(*timing, *extra, *(f"session: {w}" for w in inputs.warnings)),
        plot_data={"t": g.t_s, "e": e, "n": n, "swa": swa, "v": v},
        flagged_truth_ratio=_truth_ratios(inputs, table.flagged),
    )


def _resolution(x: FloatArray) -> float:
    """The quantisation step of a signal: the smallest difference between its distinct values (0 if none)."""
    u = np.unique(np.round(x[np.isfinite(x)], 9))
    d = np.diff(u)
    return float(np.min(d)) if d.size else 0.0


def _truth_ratios(inputs: SessionInputs, rows: Sequence[SteeringRatioRow]) -> dict[int, float]:
    """Simulated sessions: the simulator's mean SWA / mean road-wheel angle over each row's circle."""
    out: dict[int, float] = {}
    if inputs.truth is not None:
        tr = inputs.truth
        for i, row in enumerate(rows):
            m = (tr.t_s >= row.t_start_s) & (tr.t_s <= row.t_start_s + row.duration_s)
            rwa = tr.truth.road_wheel_angle[m]
            sw = tr.truth.swa[m]
            if m.sum() > 10 and np.all(np.abs(rwa) > 1e-4):
                out[i] = float(np.mean(sw) / np.mean(rwa))
    return out


def steering_record(cal: SteeringCalibration) -> dict[str, Any]:
    """The entry recorded in the session's calibration file (key ``steering_ratio``): forward rows, mean per SWA."""
    rows = [r for r in cal.table.rows if r.direction is Direction.FORWARD and r.ratio > 0]
    keys = sorted({round(r.swa_deg, 1) for r in rows})
    ratios = [float(np.mean([r.ratio for r in rows if round(r.swa_deg, 1) == k])) for k in keys]
    d = cal.to_dict()
    return {"swa_deg": keys, "ratio": ratios, "date": _today(), "session": cal.session,
            "rows": d["rows"], "flagged": d["flagged"], "sas_zero": d["sas_zero"]}


def format_steering(cal: SteeringCalibration) -> str:
    lines = [(f"session {cal.session}: {len(cal.table.rows)} circle(s), wheelbase {cal.table.wheelbase_m:.3f} m, "
             f"mounting offset in force {cal.mount_offset_deg:+.3f}°")]
    z = cal.sas_zero
    if z is None:
        lines.append("SAS zero offset: not estimated; SWA used as measured")
    else:
        src = ", ".join(f"{x.method} {math.degrees(x.offset_rad):+.3f}° (n = {x.n})" for x in z.sources)
        lines.append(f"SAS zero offset {z.offset_deg:+.3f}° ± {z.u95_deg:.3f}° (95 %), removed; from {src}")
    lines.append("")
    head = (f"  {'direction':<9} {'SWA °':>8} {'R (m)':>8} {'δ °':>8} {'ratio':>8} {'±95 %':>6} {'arc °':>7} "
            f"{'rms mm':>7}")
    if cal.truth_ratio or cal.flagged_truth_ratio:
        head += f" {'sim ratio':>9} {'err %':>6}"
    lines.append(head)

    def row_line(r: SteeringRatioRow, truth: float | None) -> str:
        s = (f"  {r.direction.value:<9} {r.swa_deg:8.1f} {r.radius_m:8.2f} {r.delta_deg:8.3f} {r.ratio:8.3f} "
             f"{100 * r.ratio_u95:5.2f}% {math.degrees(r.arc_rad):7.0f} {1000 * r.rms_residual_m:7.1f}")
        if truth is not None:
            s += f" {truth:9.3f} {100 * (r.ratio / truth - 1):+6.2f}"
        return s

    for i, r in enumerate(cal.table.rows):
        lines.append(row_line(r, cal.truth_ratio.get(i)))
    if cal.table.flagged:
        lines.append("flagged — too uncertain to be results (not recorded):")
        for i, r in enumerate(cal.table.flagged):
            lines.append(row_line(r, cal.flagged_truth_ratio.get(i)))
    for w in (*cal.table.warnings, *cal.warnings):
        lines.append(f"warning: {w}")
    return "\n".join(lines) + "\n"


def plot_steering(cal: SteeringCalibration, path: Path) -> Path:
    """Ratio against SWA (forward and reverse) and the rear-axle tracks of the circles (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 5))
    try:
        for direction, mk in ((Direction.FORWARD, "o-"), (Direction.REVERSE, "s--")):
            rows = [r for r in cal.table.rows if r.direction is direction]
            if rows:
                ax1.plot([r.swa_deg for r in rows], [r.ratio for r in rows], mk, label=direction.value)
        if cal.truth_ratio:
            ax1.plot([cal.table.rows[i].swa_deg for i in cal.truth_ratio], list(cal.truth_ratio.values()), "kx",
                     label="simulation truth")
        ax1.set_xlabel("steering-wheel angle (°)")
        ax1.set_ylabel("steering ratio SWA/δ")
        ax1.grid(True, alpha=0.3)
        ax1.legend()
        pd = cal.plot_data
        for s in cal.segments:
            m = s.mask(pd["t"])
            ax2.plot(pd["e"][m], pd["n"][m], lw=0.8)
        ax2.set_aspect("equal", adjustable="datalim")
        ax2.set_xlabel("east (m)")
        ax2.set_ylabel("north (m)")
        ax2.set_title("rear-axle centre on the circles")
        fig.suptitle(f"{cal.session}: steering ratio")
        fig.tight_layout()
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------
# calibrate-imu
# ---------------------------------------------------------------------------------------------

ACCEL_UNITS = {"mps2": 1.0, "g": STANDARD_GRAVITY}
GYRO_UNITS = {"rps": 1.0, "dps": math.pi / 180.0}


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = [r for r in csv.reader(f) if r and not r[0].lstrip().startswith("#")]
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    if not rows:
        raise ConfigError(f"{path}: empty CSV file")
    return [h.strip().lower() for h in rows[0]], [[c.strip() for c in r] for r in rows[1:]]


def _value_columns(path: Path, header: list[str], prefix: str, units: Mapping[str, float]) -> tuple[list[int], float]:
    for unit, scale in units.items():
        names = [f"{prefix}{a}_{unit}" for a in "xyz"]
        if all(n in header for n in names):
            return [header.index(n) for n in names], scale
    want = " or ".join(",".join(f"{prefix}{a}_{u}" for a in "xyz") for u in units)
    raise ConfigError(f"{path}: header needs the columns {want}; got {header}")


def _num(path: Path, line: int, text: str, col: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{path}:{line}: column {col!r}: {text!r} is not a number") from None


def read_accel_csv(path: Path | str) -> list[StaticPosition]:
    """Accelerometer static positions from CSV.

    Format: a header, then one row per sample::

        position,ax_mps2,ay_mps2,az_mps2      (or ax_g,ay_g,az_g)
        +z,0.012,-0.004,9.809
        ...

    ``position`` names the sensor axis pointing up (``+x``, ``-x``, ``+y``, ``-y``, ``+z``, ``-z``);
    the rows of one position form one static run (six positions at least). Lines starting with
    ``#`` are comments.

    Raises:
        ConfigError: unreadable file, missing columns or a bad value (file and line named).
    """
    p = Path(path)
    header, rows = _read_csv(p)
    if "position" not in header:
        raise ConfigError(f"{p}: header needs a 'position' column (+x, -x, +y, -y, +z, -z: the axis pointing up)")
    ci = header.index("position")
    cols, scale = _value_columns(p, header, "a", ACCEL_UNITS)
    groups: dict[str, list[list[float]]] = {}
    for k, r in enumerate(rows, 2):
        if len(r) < len(header):
            raise ConfigError(f"{p}:{k}: {len(r)} columns, header has {len(header)}")
        label = r[ci].lower()
        if label.lstrip("+-") not in ("x", "y", "z") or len(label) > 2:
            raise ConfigError(f"{p}:{k}: position {r[ci]!r} is not one of +x, -x, +y, -y, +z, -z")
        label = label if label[0] in "+-" else "+" + label
        groups.setdefault(label, []).append([_num(p, k, r[c], header[c]) * scale for c in cols])
    return [StaticPosition(np.asarray(v, dtype=float), up) for up, v in groups.items()]


def read_gyro_csv(path: Path | str) -> list[TurntableRun]:
    """Gyroscope turntable runs from CSV.

    Format: a header, then one row per sample::

        axis,rate_dps,gx_dps,gy_dps,gz_dps      (or gx_rps,gy_rps,gz_rps)
        +z,90,0.31,-0.02,90.4
        ...

    ``axis`` is the sensor axis on the turntable's spin axis (``+x`` … ``-z``), ``rate_dps`` the
    table's known rate (deg/s, right-hand rule about that axis; 0 for a static run); the rows with
    the same axis and rate form one run (e.g. ±80, ±90, ±100 °/s about each axis).

    Raises:
        ConfigError: unreadable file, missing columns or a bad value (file and line named).
    """
    p = Path(path)
    header, rows = _read_csv(p)
    for need in ("axis", "rate_dps"):
        if need not in header:
            raise ConfigError(f"{p}: header needs an {need!r} column; got {header}")
    ca, cr = header.index("axis"), header.index("rate_dps")
    cols, scale = _value_columns(p, header, "g", GYRO_UNITS)
    groups: dict[tuple[str, float], list[list[float]]] = {}
    for k, r in enumerate(rows, 2):
        if len(r) < len(header):
            raise ConfigError(f"{p}:{k}: {len(r)} columns, header has {len(header)}")
        label = r[ca].lower()
        if label.lstrip("+-") not in ("x", "y", "z") or len(label) > 2:
            raise ConfigError(f"{p}:{k}: axis {r[ca]!r} is not one of +x, -x, +y, -y, +z, -z")
        label = label if label[0] in "+-" else "+" + label
        rate = _num(p, k, r[cr], "rate_dps")
        groups.setdefault((label, rate), []).append([_num(p, k, r[c], header[c]) * scale for c in cols])
    return [TurntableRun(np.asarray(v, dtype=float), ax, math.radians(rate)) for (ax, rate), v in groups.items()]


@dataclass(frozen=True, slots=True)
class ImuResult:
    """Accelerometer and/or gyroscope calibration, and the profile's ``[calibration.imu]`` they make."""

    accel: TriadCalibration | None
    gyro: TriadCalibration | None
    config: ImuCalibrationConfig

    def to_dict(self) -> dict[str, object]:
        """JSON view: ``accel`` / ``gyro`` (matrix, bias, scale_factors, misalignment, residuals, …) and
        ``config`` (the ``[calibration.imu]`` table)."""
        return {"accel": None if self.accel is None else self.accel.to_dict(),
                "gyro": None if self.gyro is None else self.gyro.to_dict(),
                "config": self.config.model_dump(mode="json")}


def calibrate_imu(
    accel: Sequence[StaticPosition] | None, gyro: Sequence[TurntableRun] | None, *, base: ImuCalibrationConfig | None
    = None, source: str | None = None
) -> ImuResult:
    """Fit the triads given; the other keeps ``base``'s values (identity and zero bias by default).

    Raises:
        CalibrationError: neither given, or a degenerate set of runs.
    """
    if not accel and not gyro:
        raise CalibrationError("calibrate-imu: give accelerometer positions and/or gyroscope turntable runs")
    b = base or ImuCalibrationConfig()
    a_cal = calibrate_accelerometer(accel) if accel else None
    g_cal = calibrate_gyroscope(gyro) if gyro else None

    def rows(m: FloatArray) -> tuple[tuple[float, float, float], ...]:
        return tuple((float(r[0]), float(r[1]), float(r[2])) for r in m)

    def vec(v: FloatArray) -> tuple[float, float, float]:
        return float(v[0]), float(v[1]), float(v[2])

    cfg = b.model_copy(update={
        **({"accel_matrix": rows(a_cal.matrix), "accel_bias_mps2": vec(a_cal.bias)} if a_cal else {}),
        **({"gyro_matrix": rows(g_cal.matrix), "gyro_bias_rps": vec(g_cal.bias)} if g_cal else {}),
        "date": _today(), "source": source,
    })
    return ImuResult(a_cal, g_cal, ImuCalibrationConfig.model_validate(cfg.model_dump()))


def format_imu(res: ImuResult) -> str:
    lines: list[str] = []
    for name, cal, unit, k in (("accelerometer", res.accel, "m/s²", 1.0), ("gyroscope", res.gyro, "°/s",
                                                                          180.0 / math.pi)):
        if cal is None:
            continue
        lines.append(f"{name} ({cal.n_runs} runs): measured = M · true + b")
        for i, ax in enumerate("xyz"):
            m = cal.matrix[i]
            lines.append(f"  {ax}: M = [{m[0]:+.5f} {m[1]:+.5f} {m[2]:+.5f}]  b = {k * cal.bias[i]:+.5f} {unit} "
                         f"(±{k * cal.bias_std[i]:.5f})  scale {cal.scale_factors[i]:.5f}  "
                         f"residual rms {k * cal.residual_rms[i]:.2e} {unit}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# writing the vehicle profile
# ---------------------------------------------------------------------------------------------


def write_profile_calibration(profile_path: Path | str, values: Mapping[str, Any]) -> Path:
    """Set keys of the profile's ``[calibration]`` table in place (tomlkit: comments and layout kept).

    ``profile_path`` is a vehicle profile, or a session configuration holding the profile inline
    (not one that names its profile with ``vehicle_profile``: that file is the one to write).

    ``values`` maps keys of :class:`rig.core.config.CalibrationConfig` to values; a mapping value
    (``optical_zero_deg``, ``imu``) is merged key by key into the existing (inline or standard)
    table. The result is validated as a vehicle profile before the file is replaced (atomically).

    Raises:
        ConfigError: the file cannot be read/parsed, is not a vehicle profile, or the result does not validate.
    """
    import tomlkit
    from tomlkit.exceptions import TOMLKitError

    p = Path(profile_path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such vehicle profile") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.strerror}") from exc
    try:
        doc = tomlkit.parse(text)
    except TOMLKitError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    if "vehicle_profile" in doc:
        raise ConfigError(f"{p}: this session configuration takes its vehicle from vehicle_profile = "
                          f"{doc['vehicle_profile']!r}; write the calibration into that file")
    is_session = any(k in doc for k in ("receivers", "can", "daq", "relay", "output", "simulation"))
    cal = doc.get("calibration")
    if cal is None:
        cal = tomlkit.table()
        doc["calibration"] = cal
    for key, value in values.items():
        if isinstance(value, Mapping):
            sub = cal.get(key)
            if sub is None:
                sub = tomlkit.inline_table() if key == "optical_zero_deg" else tomlkit.table()
                cal[key] = sub
            for k2, v2 in value.items():
                if v2 is not None:
                    sub[k2] = _toml_value(v2)
        elif value is not None:
            cal[key] = _toml_value(value)
    new = tomlkit.dumps(doc)
    fd, tmp = tempfile.mkstemp(prefix=p.name, suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(new)
        if is_session:  # a session configuration with the profile inline: check the schema (not its device files)
            try:
                SessionConfig.model_validate(tomllib.loads(new))
            except ValidationError as exc:
                raise ConfigError(f"{p}: the updated session configuration does not validate: {exc}") from None
        else:
            load_profile(tmp)  # raises ConfigFileError (a ConfigError) naming the problem
        Path(tmp).replace(p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


def _toml_value(v: Any) -> Any:
    if isinstance(v, float):
        return float(f"{v:.9g}") if math.isfinite(v) else v
    if isinstance(v, tuple | list):
        return [_toml_value(x) for x in v]
    return v
