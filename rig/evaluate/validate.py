"""Session-level analysis: ``rig validate``, ``rig rollover`` and ``rig steering reconstruct`` on a recorded session.

:func:`validate_session` reads a session (:func:`rig.data.inputs.load_inputs`), computes the
references and scores the VSC estimate:

1. GNSS reference sideslip at the CG and at the wheels (:func:`rig.analysis.reference.reference_sideslip`,
   method ``rts`` by default, ``wavelet`` or ``raw``) from the dual-antenna epochs, the CAN yaw rate
   and lateral acceleration, the antenna lever arm, baseline and mounting offset in force; the
   static roll gain of the ``a_y`` correction comes from the vehicle profile (roll stiffness).
2. Optical reference (each body-mounted optical sensor, zero in force): moved to the CG,
   averaged onto the GNSS epochs, cross-checked against the GNSS reference; the cross-check is
   *flagged* when more than ``CROSS_CHECK_MAX_FRACTION`` of the common epochs disagree beyond
   k = 2 combined uncertainty, or any disagreement lasts ≥ 0.5 s.
3. The estimate: the CAN role ``vsc_beta_estimate``, or a user's estimator
   (``--estimator package.module:function``). The estimator is called once with every CAN role
   resampled onto a uniform grid at the rate of the ``yaw_rate`` role (``"t"`` is that grid in s,
   NaN where a role has a gap > 0.25 s) and must return β (rad) on that grid; the result is
   interpolated onto the GNSS epochs.
4. Manoeuvres (automatic, then operator marks: each mark opens a span labelled with its text,
   closed by the next mark, by a mark reading ``end``/``stop``, or after ``MAX_MARK_S``), metrics
   per manoeuvre, per kind and overall (low-speed driving left out) against the tolerances of the
   session configuration's ``[validation]`` (``rmse_deg``, ``max_abs_deg``, ``bias_deg``; the
   reference is invalid below ``min_speed_kmh``).
5. With simulator truth: every reference (GNSS, optical) scored against the true sideslip.

:func:`rollover_session` computes the LTR from the CAN lateral acceleration with the roll angle
from the vehicle's roll model (:class:`rig.analysis.rollover.RollModel`), predicts it 1–3 s
ahead (ARX with the steering demand when the session has ``swa``, else AR) and scores both
against the true LTR of a simulated session.

:func:`steering_session` reconstructs the front road-wheel angle from GNSS speed and CAN lateral
acceleration and compares it with SWA / steering ratio.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from rig.analysis.manoeuvres import SegmentationParams
from rig.analysis.metrics import Tolerances, error_series
from rig.analysis.reference import (
    AntennaGeometry,
    CrossCheck,
    GnssSpec,
    ImuSeries,
    ImuSpec,
    OpticalSideslip,
    ReferenceMethod,
    ReferenceSideslip,
    cross_check,
    optical_sideslip,
    reference_sideslip,
    resample_mean,
    tyre_slip_angles,
    vehicle_points,
)
from rig.analysis.rollover import (
    LtrDemandModel,
    LtrExogenous,
    LtrPrediction,
    PredictionError,
    RollModel,
    VehicleLtrModel,
    horizontal_ay,
    ltr_from_lateral,
    predict_ltr,
    prediction_errors,
)
from rig.analysis.scoring import ValidationResult, run_estimator, score_reference_against_truth, validate_estimate
from rig.analysis.steering import (
    LateralTyreModel,
    SteeringModel,
    SteeringReconstruction,
    estimate_ay_delay,
    reconstruct_steering,
)
from rig.core.config import ValidationConfig, VehicleConfig, VehicleProfile
from rig.core.quality import StreamQuality
from rig.data.verdicts import check_inputs
from vsccore.angles import FloatArray, azimuth_to_yaw
from vsccore.errors import AnalysisError, ConfigError

if TYPE_CHECKING:
    from rig.data.inputs import SessionInputs, Signal

__all__ = [
    "CROSS_CHECK_MAX_FRACTION",
    "MAX_MARK_S",
    "RolloverReport",
    "SessionValidation",
    "SteeringReport",
    "demand_model",
    "marks_to_spans",
    "roll_model",
    "rollover_session",
    "steering_model",
    "steering_session",
    "tolerances_from_config",
    "validate_session",
]

log = logging.getLogger(__name__)

G = 9.80665
CROSS_CHECK_MAX_FRACTION = 0.10
"""Fraction of common epochs beyond k·σ above which the GNSS/optical cross-check is flagged (≈ 5 % expected)."""
MAX_MARK_S = 60.0
"""Longest span an operator mark labels when no later mark closes it (s)."""
_END_MARKS = frozenset({"end", "stop", "-", "."})
_ROLE_MAX_GAP_S = 0.25

Progress = Callable[[str], None]
"""Called with the name of each step as it starts (the CLI turns it into a progress bar)."""


def _noop(_step: str) -> None:
    return None


# --------------------------------------------------------------------------------------------
# Vehicle-profile helpers
# --------------------------------------------------------------------------------------------


def roll_model(v: VehicleConfig) -> RollModel:
    """The body's roll model from the vehicle profile."""
    return RollModel.from_vehicle(v)


def _ratio_table(profile: VehicleProfile) -> tuple[tuple[float, ...], tuple[float, ...]]:
    cal = profile.calibration
    if cal.steering_ratio is not None and cal.steering_ratio_swa_deg is not None:
        return tuple(cal.steering_ratio_swa_deg), tuple(cal.steering_ratio)
    return tuple(profile.vehicle.steering_ratio_swa_deg), tuple(profile.vehicle.steering_ratio)


def steering_model(profile: VehicleProfile) -> SteeringModel:
    """The steering reconstruction's vehicle quantities from the profile (roll gain from the roll model; yaw
    inertia and tyre characteristic for the dynamic reconstruction, see :mod:`rig.analysis.steering`)."""
    v = profile.vehicle
    return SteeringModel(
        wheelbase_m=v.wheelbase_m, mass_kg=v.mass_kg, front_axle_load_share=v.cg_to_rear_axle_m / v.wheelbase_m,
        cornering_stiffness_front_n_per_rad=v.cornering_stiffness_front_n_per_rad,
        cornering_stiffness_rear_n_per_rad=v.cornering_stiffness_rear_n_per_rad,
        roll_gain_rad_per_mps2=roll_model(v).roll_gain_rad_per_mps2,
        yaw_inertia_kgm2=v.yaw_inertia_kgm2,
        tyres=LateralTyreModel(
            track_front_m=v.track_front_m, track_rear_m=v.track_rear_m, roll_axis_height_m=v.roll_axis_height_m,
            roll_stiffness_front_nm_per_rad=v.roll_stiffness_front_nm_per_rad,
            roll_stiffness_rear_nm_per_rad=v.roll_stiffness_rear_nm_per_rad,
            peak_mu=v.tyre_peak_mu, shape_c=v.tyre_shape_c, curvature_e=v.tyre_curvature_e,
        ),
    )


def demand_model(profile: VehicleProfile) -> LtrDemandModel:
    """The ARX predictor's steady-state LTR demand from the profile (steering ratio in force)."""
    v = profile.vehicle
    sm = steering_model(profile)
    bp, ratio = _ratio_table(profile)
    return LtrDemandModel(
        wheelbase_m=v.wheelbase_m, understeer_gradient_rad_per_mps2=sm.understeer_gradient_rad_per_mps2,
        peak_mu=v.tyre_peak_mu, cg_height_m=v.cg_height_m, roll_axis_height_m=v.roll_axis_height_m,
        track_m=0.5 * (v.track_front_m + v.track_rear_m), roll_gain_rad_per_mps2=sm.roll_gain_rad_per_mps2,
        ratio_swa_deg=bp, ratio=ratio,
    )


def _steering_ratio_fn(profile: VehicleProfile) -> Callable[[FloatArray], FloatArray]:
    bp, ratio = _ratio_table(profile)

    def fn(swa: FloatArray) -> FloatArray:
        return np.asarray(np.interp(np.degrees(swa), bp, ratio), dtype=float)

    return fn


def tolerances_from_config(session_config: Mapping[str, Any]) -> tuple[Tolerances, ValidationConfig]:
    """The ``[validation]`` table of a recorded session configuration (defaults where absent).

    Raises:
        ConfigError: the recorded table is invalid (names the key).
    """
    raw = session_config.get("validation")
    try:
        vc = ValidationConfig.model_validate(raw if isinstance(raw, Mapping) else {})
    except ValueError as exc:
        raise ConfigError(f"recorded [validation] table: {exc}") from None
    return Tolerances.from_degrees(rmse_deg=vc.rmse_deg, max_abs_deg=vc.max_abs_deg, bias_deg=vc.bias_deg), vc


def _tolerance_text(tol: Tolerances) -> str:
    parts = []
    for name, v in (("RMSE", tol.rmse_rad), ("max |e|", tol.max_abs_rad), ("|bias|", tol.bias_rad),
                    ("P95", tol.p95_rad)):
        if v is not None:
            parts.append(f"{name} ≤ {math.degrees(v):.2f}°")
    if tol.max_lag_s is not None:
        parts.append(f"|lag| ≤ {tol.max_lag_s:.2f} s")
    if tol.min_valid_fraction is not None:
        parts.append(f"reference valid ≥ {100 * tol.min_valid_fraction:.0f} %")
    return ", ".join(parts)


def marks_to_spans(inp: SessionInputs, t_end_s: float) -> list[tuple[float, float, str]]:
    """Operator marks as (t_start, t_stop, label) spans (module docstring, step 4)."""
    marks = sorted(inp.marks, key=lambda e: e.t_s)
    spans: list[tuple[float, float, str]] = []
    for i, m in enumerate(marks):
        text = m.text.strip()
        if text.lower() in _END_MARKS:
            continue
        if m.end_t_s is not None:
            spans.append((m.t_s, m.end_t_s, text))
            continue
        stop = min(m.t_s + MAX_MARK_S, t_end_s)
        if i + 1 < len(marks):
            stop = min(stop, marks[i + 1].t_s)
        if stop > m.t_s:
            spans.append((m.t_s, stop, text))
    return spans


def _imu(inp: SessionInputs) -> tuple[ImuSeries, Signal]:
    r = inp.signal("yaw_rate")
    t, y = r.t_s[r.valid], r.values[r.valid]
    keep = np.concatenate(([True], np.diff(t) > 0))
    t, y = t[keep], y[keep]
    ay = None
    if "lat_accel" in inp.can:
        ay = inp.can["lat_accel"].at(t, max_gap_s=_ROLE_MAX_GAP_S)
    if t.size < 2:
        raise AnalysisError(f"session {inp.path}: the CAN yaw rate has fewer than two valid samples")
    return ImuSeries(t, y, ay), r


def _role_grid(inp: SessionInputs, t_lo: float, t_hi: float) -> FloatArray:
    r = inp.signal("yaw_rate")
    dt = float(np.median(np.diff(r.t_s))) if len(r) > 1 else 0.01
    dt = min(max(dt, 1e-3), 0.1)
    return np.arange(t_lo, t_hi + 0.5 * dt, dt)


def _estimate(inp: SessionInputs, t: FloatArray, estimator: str | None) -> tuple[FloatArray, str]:
    if estimator is None:
        s = inp.signal("vsc_beta_estimate")
        return s.at(t, max_gap_s=_ROLE_MAX_GAP_S), f"CAN role vsc_beta_estimate ({s.source})"
    grid = _role_grid(inp, float(t[0]), float(t[-1]))
    roles = {name: s.at(grid, max_gap_s=_ROLE_MAX_GAP_S) for name, s in inp.can.items()}
    beta = run_estimator(estimator, grid, roles)
    ok = np.isfinite(beta)
    if np.count_nonzero(ok) < 2:
        raise AnalysisError(f"estimator {estimator}: returned fewer than two finite values")
    out = np.interp(t, grid[ok], beta[ok], left=np.nan, right=np.nan)
    rate = 1.0 / float(grid[1] - grid[0])
    return np.asarray(out, dtype=float), f"estimator {estimator} (offline, on the CAN roles at {rate:.0f} Hz)"


# --------------------------------------------------------------------------------------------
# rig validate
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SessionValidation:
    """Everything ``rig validate`` computed for one session (arrays on the GNSS epochs ``t_s``)."""

    session_name: str
    session_path: Path
    t_s: FloatArray
    reference: ReferenceSideslip
    estimate_rad: FloatArray
    error_rad: FloatArray
    """Estimate − GNSS reference (NaN where either is missing)."""
    ay_mps2: FloatArray
    speed_mps: FloatArray
    track_east_m: FloatArray
    track_north_m: FloatArray
    result: ValidationResult
    tolerances: Tolerances
    optical: OpticalSideslip | None
    cross_check: CrossCheck | None
    cross_check_flagged: bool
    truth_beta_rad: FloatArray | None
    tyre_slip: Mapping[str, Mapping[str, float]]
    """Per optical wheel sensor: agreement of its slip angle with the reference tyre slip (degrees)."""
    steering: SteeringReconstruction | None
    warnings: tuple[str, ...]
    timing_warnings: tuple[str, ...] = ()
    """Degraded time-base verdicts of the streams used (:mod:`rig.core.quality`): the report's headline."""
    time_base: Mapping[str, StreamQuality] = field(default_factory=dict)
    """The time-base verdict of every stream the validation used."""

    @property
    def passed(self) -> bool:
        return self.result.passed

    @property
    def tolerance_text(self) -> str:
        return _tolerance_text(self.tolerances)

    @property
    def invalid_summary(self) -> str:
        counts = {k: v for k, v in self.reference.reason_counts().items() if v}
        return "invalid epochs: " + (", ".join(f"{k.lower()} {v}" for k, v in counts.items()) or "none")

    def to_dict(self) -> dict[str, object]:
        """The metrics JSON (``--json``, ``metrics.json``): keys documented in the README section."""
        d: dict[str, object] = {
            "session": self.session_name,
            "path": str(self.session_path),
            "passed": self.passed,
            "tolerances": {
                "rmse_deg": _deg_or_none(self.tolerances.rmse_rad),
                "max_abs_deg": _deg_or_none(self.tolerances.max_abs_rad),
                "bias_deg": _deg_or_none(self.tolerances.bias_rad),
                "p95_deg": _deg_or_none(self.tolerances.p95_rad),
                "max_lag_s": self.tolerances.max_lag_s,
                "min_valid_fraction": self.tolerances.min_valid_fraction,
            },
            "duration_s": float(self.t_s[-1] - self.t_s[0]) if self.t_s.size else 0.0,
            "n_epochs": int(self.t_s.size),
            "reference": self.reference.to_dict(),
            "manoeuvres": [m.to_dict() for m in self.result.manoeuvres],
            "cross_check": None if self.cross_check is None else {
                **self.cross_check.to_dict(), "sensor": None if self.optical is None else self.optical.sensor,
                "flagged": self.cross_check_flagged,
            },
            "tyre_slip": {k: dict(v) for k, v in self.tyre_slip.items()},
            "steering": None if self.steering is None else self.steering.to_dict(),
            "warnings": list(self.warnings),
            "timing_warnings": list(self.timing_warnings),
            "time_base": {k: q.to_json() for k, q in self.time_base.items()},
        }
        d.update(self.result.to_dict())
        return _clean(d)


def _deg_or_none(x: float | None) -> float | None:
    return None if x is None else math.degrees(x)


def _clean(x: Any) -> Any:
    """NaN/inf → None, numpy scalars → Python (strict JSON)."""
    if isinstance(x, Mapping):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def session_reference(
    inp: SessionInputs, *, method: ReferenceMethod | str = ReferenceMethod.RTS, gnss_spec: GnssSpec | None = None,
) -> tuple[ReferenceSideslip, ImuSeries]:
    """The session's reference sideslip as :func:`validate_session` computes it (the vehicle profile's antenna
    geometry, mounting offset, vehicle points and roll model; the recorded ``[validation]`` minimum speed), and
    the IMU series it used. Shared with the MAT export's sideslip struct (``rig.export.mat``).

    Raises:
        AnalysisError: no dual-antenna GNSS or no CAN yaw rate.
        ConfigError: an invalid recorded ``[validation]`` table.
    """
    prof = inp.profile
    _tol, vcfg = tolerances_from_config(inp.session.config)
    gnss = inp.require_gnss()
    imu, _r = _imu(inp)
    ant = prof.antennas
    geometry = AntennaGeometry(
        a_xy=ant.a.xy, baseline_length_m=ant.baseline_length_m, baseline_tolerance_m=ant.baseline_tolerance_m,
        mount_offset_rad=math.radians(prof.calibration.mount_offset_deg), z=ant.a.z_m,
    )
    v = prof.vehicle
    points = vehicle_points(v.cg_to_front_axle_m, v.cg_to_rear_axle_m, v.track_front_m, v.track_rear_m,
                            {o.name: o.mount.xy for o in prof.optical})
    ref = reference_sideslip(
        gnss.to_epochs(), imu, geometry, method=method, points=points, gnss_spec=gnss_spec,
        imu_spec=ImuSpec(roll_gain_rad_per_mps2=steering_model(prof).roll_gain_rad_per_mps2),
        min_speed_mps=max(vcfg.min_speed_kmh / 3.6, 0.5), roll_model=roll_model(v),
    )
    return ref, imu


def session_estimate(inp: SessionInputs, t: FloatArray, estimator: str | None = None) -> tuple[FloatArray, str]:
    """The sideslip estimate on ``t`` (the CAN ``vsc_beta_estimate``, or ``estimator``'s output) and its source."""
    return _estimate(inp, t, estimator)


def validate_session(
    source: Path | str | SessionInputs,
    *,
    estimator: str | None = None,
    method: ReferenceMethod | str = ReferenceMethod.RTS,
    tolerances: Tolerances | None = None,
    gnss_spec: GnssSpec | None = None,
    segmentation: SegmentationParams | None = None,
    progress: Progress | None = None,
) -> SessionValidation:
    """Reference sideslip, estimate, manoeuvres and scores of one session (module docstring).

    Raises:
        AnalysisError: the session lacks what validation needs (dual-antenna GNSS, the CAN yaw
            rate, the estimate), or no valid reference epoch.
        SessionFileError: the session cannot be read.
        ConfigError: an invalid recorded ``[validation]`` table.
    """
    from rig.data.inputs import load_inputs

    step = progress or _noop
    warnings: list[str] = []
    if isinstance(source, Path | str):
        step("read session")
        inp = load_inputs(source)
    else:
        inp = source
    step("time-base verdicts")
    timing, time_base = check_inputs(inp, what=f"rig validate {inp.name}")
    warnings.extend(timing)
    warnings.extend(inp.warnings)
    prof = inp.profile
    tol_cfg, vcfg = tolerances_from_config(inp.session.config)
    tol = tolerances if tolerances is not None else tol_cfg
    gnss = inp.require_gnss()
    step("reference sideslip")
    ref, imu = session_reference(inp, method=method, gnss_spec=gnss_spec)
    sm = steering_model(prof)
    t = ref.t
    yaw = imu.yaw_rate
    r_t = np.interp(t, imu.t, yaw)
    ay = inp.can["lat_accel"].at(t, max_gap_s=_ROLE_MAX_GAP_S) if "lat_accel" in inp.can else np.full(t.size, np.nan)
    if "swa" in inp.can:
        swa = inp.can["swa"].at(t, max_gap_s=_ROLE_MAX_GAP_S)
    else:
        swa = np.zeros(t.size)
        warnings.append("no CAN role 'swa': manoeuvres classified without the steering-wheel angle")
    speed = np.where(np.isfinite(ref.speed), ref.speed, gnss.speed_mps)

    step("estimate")
    est, est_source = _estimate(inp, t, estimator)

    truth_beta: FloatArray | None = None
    if inp.truth is not None:
        tr = inp.truth
        truth_beta = np.asarray(np.interp(t, tr.t_s, tr.truth.beta_cg, left=np.nan, right=np.nan), dtype=float)

    step("manoeuvres and metrics")
    spans = marks_to_spans(inp, float(t[-1]))
    seg = segmentation or SegmentationParams(low_speed_mps=max(vcfg.min_speed_kmh / 3.6, 0.5))
    res = validate_estimate(
        ref, est, speed_mps=speed, swa_rad=swa, yaw_rate_rps=r_t, ay_mps2=np.nan_to_num(ay), marks=spans,
        tolerances=tol, segmentation=seg, estimate_source=est_source, truth_rad=truth_beta,
    )

    step("optical cross-check")
    opt: OpticalSideslip | None = None
    cc: CrossCheck | None = None
    flagged = False
    tyre: dict[str, dict[str, float]] = {}
    extra_truth = []
    for o in inp.optical.values():
        if o.kind != "body":
            continue
        vx, vy = o.corrected()
        r_o = np.interp(o.t_s, imu.t, yaw)
        os_ = optical_sideslip(o.t_s, vx, vy, r_o, o.mount_xy_m, zero_rad=0.0, valid=o.valid, sensor=o.name,
                               min_speed_mps=max(vcfg.min_speed_kmh / 3.6, 0.5))
        beta_ep = resample_mean(o.t_s, os_.beta, t)
        sig_ep = resample_mean(o.t_s, os_.sigma, t)
        ok = np.isfinite(beta_ep)
        opt = OpticalSideslip(t, beta_ep, sig_ep, ok, o.name)
        try:
            cc = cross_check(t, ref.beta, ref.sigma, beta_ep, sig_ep)
            flagged = cc.fraction_disagree > CROSS_CHECK_MAX_FRACTION or bool(cc.segments)
            if flagged:
                warnings.append(
                    f"GNSS and optical ({o.name}) references disagree beyond their uncertainty on "
                    f"{100 * cc.fraction_disagree:.1f} % of the common epochs ({len(cc.segments)} stretches ≥ 0.5 s)"
                )
        except AnalysisError as exc:
            warnings.append(f"optical {o.name}: no cross-check ({exc})")
        if truth_beta is not None and np.any(ok):
            extra_truth.append(score_reference_against_truth(f"optical ({o.name})", t, beta_ep, sig_ep, truth_beta,
                                                             valid=ok))
        break  # the first body sensor is the optical reference
    if extra_truth:
        res = dataclasses.replace(res, truth=res.truth + tuple(extra_truth))
    wheel_sensors = [o for o in inp.optical.values() if o.kind == "wheel" and o.wheel is not None]
    if wheel_sensors:
        steer_front = None
        if "swa" in inp.can:
            sw = inp.can["swa"].at(t, max_gap_s=_ROLE_MAX_GAP_S)
            steer_front = sw / _steering_ratio_fn(prof)(sw)
        steer: dict[str, npt.ArrayLike | float] = {}
        if steer_front is not None:
            steer = {"fl": steer_front, "fr": steer_front}
        alphas = tyre_slip_angles(ref, steer)
        for o in wheel_sensors:
            assert o.wheel is not None
            a_opt = resample_mean(o.t_s, np.where(o.valid, o.slip_angle_rad - o.zero_in_force_rad + o.zero_applied_rad,
                                                  np.nan), t)
            try:
                c = cross_check(t, alphas[o.wheel], ref.sigma, a_opt, np.full(t.size, math.radians(0.1)))
                tyre[o.name] = {k: float(v) for k, v in c.to_dict().items() if isinstance(v, int | float)}
            except AnalysisError as exc:
                warnings.append(f"optical wheel sensor {o.name}: no tyre-slip comparison ({exc})")

    step("steering reconstruction")
    steering: SteeringReconstruction | None = None
    if "lat_accel" in inp.can and "swa" in inp.can:
        try:
            steering = reconstruct_steering(t, speed, ay, sm, swa_rad=swa, steering_ratio=_steering_ratio_fn(prof))
        except AnalysisError as exc:
            warnings.append(f"steering reconstruction: {exc}")

    overall = res.overall.metrics
    if overall is not None:
        warnings.extend(overall.warnings)
    return SessionValidation(
        session_name=inp.name, session_path=inp.path, t_s=t, reference=ref, estimate_rad=est,
        error_rad=error_series(est, ref.beta), ay_mps2=np.asarray(ay, dtype=float), speed_mps=speed,
        track_east_m=gnss.a.east_m, track_north_m=gnss.a.north_m, result=res, tolerances=tol, optical=opt,
        cross_check=cc, cross_check_flagged=flagged, truth_beta_rad=truth_beta, tyre_slip=tyre, steering=steering,
        warnings=tuple(dict.fromkeys(warnings)), timing_warnings=timing, time_base=time_base,
    )


# --------------------------------------------------------------------------------------------
# rig rollover
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RolloverReport:
    """LTR of a session, its prediction and (simulated sessions) the comparison with the true LTR."""

    session_name: str
    t_s: FloatArray
    """Uniform grid of the LTR estimate (the CAN lateral acceleration's rate)."""
    ltr: FloatArray
    roll_rad: FloatArray
    prediction: LtrPrediction
    model: str
    formula: str
    truth_t_s: FloatArray | None
    truth_ltr: FloatArray | None
    ltr_error_rms: float | None
    ltr_error_max: float | None
    prediction_errors: tuple[PredictionError, ...]
    """Against the true LTR over the evaluated span (empty without truth)."""
    evaluation: str
    """Which span the prediction errors cover."""
    timing_warnings: tuple[str, ...] = ()
    """Degraded time-base verdicts of the streams used (:mod:`rig.core.quality`)."""
    time_base: Mapping[str, StreamQuality] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        pred = self.prediction
        first = pred.first_warning_s()
        d: dict[str, object] = {
            "session": self.session_name,
            "model": self.model,
            "formula": self.formula,
            "duration_s": float(self.t_s[-1] - self.t_s[0]),
            "peak_abs_ltr": float(np.nanmax(np.abs(self.ltr))),
            "threshold": pred.threshold,
            "horizons_s": list(pred.horizons_s),
            "first_warning_s": first,
            "warning_intervals_s": [list(w) for w in pred.warning_intervals],
            "truth": None,
            "timing_warnings": list(self.timing_warnings),
            "time_base": {k: q.to_json() for k, q in self.time_base.items()},
        }
        if self.truth_ltr is not None:
            d["truth"] = {
                "peak_abs_ltr": float(np.max(np.abs(self.truth_ltr))),
                "ltr_error_rms": self.ltr_error_rms,
                "ltr_error_max": self.ltr_error_max,
                "evaluation": self.evaluation,
                "prediction_errors": [
                    {"horizon_s": e.horizon_s, "mean_abs_error": e.mean_abs_error,
                     "percent_of_peak": e.percent_of_peak, "n": e.n}
                    for e in self.prediction_errors
                ],
            }
        return _clean(d)


LTR_FORMULA = ("LTR = (2/t)·(h·a_y/g + (h − h_r)·sin φ) − 2·I_x·φ̈/(m·g·t); a_y = (a_m − g·sin φ)/cos φ from the "
               "body-fixed CAN lateral acceleration a_m; φ from I_x·φ̈ + C_φ·φ̇ + K_φ·φ = m·(h − h_r)·a_m")


def rollover_session(
    source: Path | str | SessionInputs,
    *,
    model: str = "auto",
    threshold: float = 0.9,
    progress: Progress | None = None,
) -> RolloverReport:
    """LTR and its prediction for a session (module docstring). ``model``: ``auto`` (physics-informed
    when the session has ``swa``, else AR), ``ar``, ``arx`` or ``physics`` (the vehicle model of the
    profile driven by the measured steering and speed, :class:`rig.analysis.rollover.VehicleLtrModel`).

    Raises:
        AnalysisError: no CAN lateral acceleration, or ``arx``/``physics`` without ``swa``.
    """
    from rig.data.inputs import load_inputs

    step = progress or _noop
    if model not in ("auto", "ar", "arx", "physics"):
        raise ConfigError(f"--model must be auto, ar, arx or physics, got {model!r}")
    if isinstance(source, Path | str):
        step("read session")
        inp = load_inputs(source, optical=False)
    else:
        inp = source
    use_arx = model in ("arx", "physics") or (model == "auto" and "swa" in inp.can)
    step("time-base verdicts")
    timing, time_base = check_inputs(
        inp, what=f"rig rollover {inp.name}", gnss=use_arx and inp.gnss is not None, optical=False,
        can=("lat_accel", "swa", "long_accel", "vehicle_speed") if use_arx else ("lat_accel",))
    step("LTR")
    prof = inp.profile
    v = prof.vehicle
    am = inp.signal("lat_accel")
    ts = am.t_s[am.valid]
    dt = float(np.median(np.diff(ts))) if ts.size > 1 else 0.01
    dt = min(max(dt, 1e-3), 0.1)
    grid = np.arange(float(ts[0]), float(ts[-1]) + 0.5 * dt, dt)
    a_m = am.at(grid, max_gap_s=_ROLE_MAX_GAP_S)
    rm = roll_model(v)
    phi, phidd = rm.roll_from_body_ay(grid, a_m)
    track = 0.5 * (v.track_front_m + v.track_rear_m)
    ltr = ltr_from_lateral(horizontal_ay(a_m, phi), phi, cg_height_m=v.cg_height_m,
                           roll_axis_height_m=v.roll_axis_height_m, track_m=track, roll_accel_rps2=phidd,
                           roll_inertia_kgm2=v.roll_inertia_kgm2, mass_kg=v.mass_kg)
    ex: LtrExogenous | None = None
    if use_arx:
        swa = inp.signal("swa").at(grid, max_gap_s=_ROLE_MAX_GAP_S)
        if inp.gnss is not None:
            speed = np.interp(grid, inp.gnss.t_s, inp.gnss.speed_mps, left=np.nan, right=np.nan)
        else:
            speed = inp.signal("vehicle_speed").at(grid, max_gap_s=_ROLE_MAX_GAP_S)
        ax = inp.can["long_accel"].at(grid, max_gap_s=_ROLE_MAX_GAP_S) if "long_accel" in inp.can else None
        ex = (LtrExogenous(swa, speed, ax, demand_model(prof)) if model == "arx"
              else LtrExogenous(swa, speed, ax, None, VehicleLtrModel.from_vehicle(v)))
    step("prediction")
    pred = predict_ltr(grid, ltr, exogenous=ex, threshold=threshold)
    truth_t = truth_l = None
    rms = mx = None
    errs: tuple[PredictionError, ...] = ()
    evaluation = ""
    if inp.truth is not None:
        step("truth")
        tr = inp.truth
        truth_t, truth_l = tr.t_s, np.asarray(tr.truth.ltr, dtype=float)
        at = np.interp(grid, truth_t, truth_l, left=np.nan, right=np.nan)
        d = ltr - at
        ok = np.isfinite(d)
        if np.any(ok):
            rms = float(np.sqrt(np.mean(d[ok] ** 2)))
            mx = float(np.max(np.abs(d[ok])))
        steer = np.flatnonzero(np.abs(tr.truth.swa) > math.radians(5.0))
        on = float(truth_t[steer[0]]) if steer.size else float(truth_t[0])
        end = float(min(truth_t[-1], grid[-1]))
        evaluation = (f"predictions issued at t ≥ {on:.2f} s (first |SWA| > 5°) whose target t + h ≤ {end:.2f} s "
                      "(end of the record); % of the peak true |LTR| over that span")
        try:
            errs = tuple(prediction_errors(pred, truth_t, truth_l, t_start_s=on, t_stop_s=end, issued_from_s=on))
        except AnalysisError as exc:
            evaluation += f" — not scored: {exc}"
    return RolloverReport(
        session_name=inp.name, t_s=grid, ltr=ltr, roll_rad=phi, prediction=pred, model=pred.model,
        formula=LTR_FORMULA, truth_t_s=truth_t, truth_ltr=truth_l, ltr_error_rms=rms, ltr_error_max=mx,
        prediction_errors=errs, evaluation=evaluation, timing_warnings=timing, time_base=time_base,
    )


# --------------------------------------------------------------------------------------------
# rig steering reconstruct
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SteeringReport:
    session_name: str
    reconstruction: SteeringReconstruction
    timing_warnings: tuple[str, ...] = ()
    """Degraded time-base verdicts of the streams used (:mod:`rig.core.quality`)."""
    time_base: Mapping[str, StreamQuality] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        return _clean({"session": self.session_name, **self.reconstruction.to_dict(),
                       "timing_warnings": list(self.timing_warnings),
                       "time_base": {k: q.to_json() for k, q in self.time_base.items()}})


def steering_session(
    source: Path | str | SessionInputs,
    *,
    min_speed_kmh: float = 18.0,
    start_s: float | None = None,
    stop_s: float | None = None,
) -> SteeringReport:
    """δ from GNSS speed and CAN a_y on the GNSS epochs (within [start_s, stop_s] on the session's time
    base when given), against CAN SWA / steering ratio in force. The a_y time-stamp delay is estimated
    against the dual-antenna heading in the same span (:func:`rig.analysis.steering.estimate_ay_delay`).

    Raises:
        AnalysisError: no GNSS, ``lat_accel`` or ``swa``, or no epoch in the span.
    """
    from rig.data.inputs import load_inputs

    inp = load_inputs(source, optical=False, truth=False) if isinstance(source, Path | str) else source
    gnss = inp.require_gnss()
    timing, time_base = check_inputs(inp, what=f"rig steering reconstruct {inp.name}", can=("lat_accel", "swa"),
                                     optical=False)
    span = np.ones(len(gnss), dtype=bool)
    if start_s is not None:
        span &= gnss.t_s >= start_s
    if stop_s is not None:
        span &= gnss.t_s <= stop_s
    if np.count_nonzero(span) < 2:
        raise AnalysisError(f"session {inp.path}: fewer than two GNSS epochs in [{start_s}, {stop_s}] s")
    t = gnss.t_s[span]
    ay = inp.signal("lat_accel").at(t, max_gap_s=_ROLE_MAX_GAP_S)
    # the ratio in force maps the true SWA: remove the sensor's zero offset (calibrate-steering-ratio) first
    swa = inp.signal("swa").at(t, max_gap_s=_ROLE_MAX_GAP_S) - math.radians(inp.profile.calibration.swa_zero_offset_deg)
    speed = np.where(gnss.valid, gnss.speed_mps, np.nan)[span]
    sm = steering_model(inp.profile)
    # a_y's time stamps lag the motion (sensing filter, CAN latency): measured against the dual-antenna heading
    heading = gnss.heading_rad(math.radians(inp.profile.calibration.mount_offset_deg))
    yaw = np.where(gnss.valid & gnss.rtk_fixed_both, azimuth_to_yaw(heading), np.nan)[span]
    delay = estimate_ay_delay(t, speed, ay, yaw, sm, min_speed_mps=min_speed_kmh / 3.6)
    rec = reconstruct_steering(t, speed, ay, sm, swa_rad=swa, steering_ratio=_steering_ratio_fn(inp.profile),
                               min_speed_mps=min_speed_kmh / 3.6, ay_delay_s=delay.delay_s)
    return SteeringReport(inp.name, rec, timing, time_base)


def validation_lines(sv: SessionValidation) -> list[str]:
    """The summary that ``rig validate`` prints: overall metrics, per-manoeuvre verdicts, truth scores."""
    res = sv.result
    o = res.overall.metrics
    lines = [
        (f"session {sv.session_name}: {sv.t_s[-1] - sv.t_s[0]:.1f} s, reference {res.reference_method}, "
        f"valid {100 * (o.valid_fraction if o is not None else res.reference_valid_fraction):.1f} % of the epochs "
        f"of the manoeuvres that need it ({100 * res.reference_valid_fraction:.1f} % of all {sv.t_s.size})"),
        *sv.timing_warnings,
        *([sv.reference.source_summary()] if sv.reference.source is not None else []),
        f"estimate: {res.estimate_source}",
    ]
    if o is not None:
        lag = "–" if math.isnan(o.lag_s) else f"{o.lag_s:+.3f} s"
        lines.append(f"overall: RMSE {math.degrees(o.rmse_rad):.3f}°  bias {math.degrees(o.bias_rad):+.3f}°  "
                     f"max {math.degrees(o.max_abs_rad):.3f}°  P95 {math.degrees(o.p95_abs_rad):.3f}°  lag {lag}  "
                     f"(n = {o.n_compared})")
    lines.append(f"{'manoeuvre':<24} {'start':>7} {'stop':>7} {'RMSE°':>7} {'bias°':>7} {'max°':>7}  verdict")
    for row in res.table_rows():
        if row["n"] == 0:
            continue
        verdict = "PASS" if row["passed"] else "FAIL"
        lines.append(f"{row['kind']!s:<24} {row['t_start_s']:7.1f} {row['t_stop_s']:7.1f} {row['rmse_deg']:7.3f} "
                     f"{row['bias_deg']:+7.3f} {row['max_abs_deg']:7.3f}  {verdict}")
    for s in res.truth:
        lines.append(f"truth: {s.name} RMS {math.degrees(s.metrics.rmse_rad):.3f}° bias "
                     f"{math.degrees(s.metrics.bias_rad):+.3f}°, within k·σ {100 * s.coverage:.1f} %")
    if sv.cross_check is not None:
        flag = "FLAGGED" if sv.cross_check_flagged else "ok"
        lines.append(f"GNSS/optical cross-check {flag}: RMS difference "
                     f"{math.degrees(sv.cross_check.rms_diff_rad):.3f}°, "
                     f"{100 * sv.cross_check.fraction_disagree:.1f} % beyond k·σ")
    return lines
