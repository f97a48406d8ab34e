"""Road-wheel angle from speed and lateral acceleration: steady-state physics, the simulator's DLC, the error model."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rig.analysis.steering import (
    LateralTyreModel,
    SteeringModel,
    _Axles,
    error_model,
    error_table,
    reconstruct_steering,
)
from rig.core.config import VehicleConfig, VehicleProfile
from rig.evaluate.validate import steering_model
from sim_devices.vehicle import GRAVITY, GroundTruth, SteeringGear, VehicleParams, make_scenario, simulate
from vsccore.errors import AnalysisError

P = VehicleParams()
H_ROLL = P.cg_height_m - P.roll_axis_height_m
# static roll gain of the simulated body: m·h'·a_y = (K_φ − m·g·h')·φ
K_ROLL = P.roll_stiffness_front_nm_per_rad + P.roll_stiffness_rear_nm_per_rad
K_PHI = P.mass_kg * H_ROLL / (K_ROLL - P.mass_kg * GRAVITY * H_ROLL)
MODEL = SteeringModel(
    wheelbase_m=P.wheelbase_m,
    mass_kg=P.mass_kg,
    front_axle_load_share=P.cg_to_rear_axle_m / P.wheelbase_m,
    cornering_stiffness_front_n_per_rad=P.cornering_stiffness_front_n_per_rad,
    cornering_stiffness_rear_n_per_rad=P.cornering_stiffness_rear_n_per_rad,
    roll_gain_rad_per_mps2=K_PHI,
)
TYRES = LateralTyreModel(
    track_front_m=P.track_front_m, track_rear_m=P.track_rear_m, roll_axis_height_m=P.roll_axis_height_m,
    roll_stiffness_front_nm_per_rad=P.roll_stiffness_front_nm_per_rad,
    roll_stiffness_rear_nm_per_rad=P.roll_stiffness_rear_nm_per_rad,
    peak_mu=P.tyre_peak_mu, shape_c=P.tyre_shape_c, curvature_e=P.tyre_curvature_e,
)
DYNAMIC = dataclasses.replace(MODEL, yaw_inertia_kgm2=P.yaw_inertia_kgm2, tyres=TYRES)
"""The quantities a test engineer's profile gives: geometry, inertia, tyres (no simulator internals)."""
GEAR = SteeringGear(P)


def _gear_ratio(swa: np.ndarray) -> np.ndarray:
    d = GEAR.road_wheel_angle(swa)
    return np.where(np.abs(d) > 1e-9, swa / np.where(np.abs(d) > 1e-9, d, 1.0), 16.0)


def test_understeer_gradient_matches_the_vehicle() -> None:
    assert MODEL.understeer_gradient_rad_per_mps2 == pytest.approx(P.understeer_gradient_rad_per_mps2, rel=1e-12)


def test_steady_state_circle_physics() -> None:
    """R = 40 m at 50 km/h: a_y = v²/R, δ = l/R + K·a_y; a body-fixed sensor reads a_y (1 + g k_φ)."""
    v, radius = 50 / 3.6, 40.0
    ay = v * v / radius
    delta_true = P.wheelbase_m / radius + MODEL.understeer_gradient_rad_per_mps2 * ay
    t = np.arange(0.0, 2.0, 0.01)
    rec = reconstruct_steering(t, np.full(t.size, v), np.full(t.size, ay * MODEL.roll_factor), MODEL,
                               swa_rad=np.full(t.size, 16.0 * delta_true), steering_ratio=16.0)
    np.testing.assert_allclose(rec.delta, delta_true, rtol=1e-12)
    assert rec.max_abs_error_rad == pytest.approx(0.0, abs=1e-12)
    # the uncorrected value is off by exactly γ at this speed
    gamma = float(error_model(MODEL, [v]).gamma[0])
    np.testing.assert_allclose(1.0 - rec.delta_kinematic / delta_true, gamma, rtol=1e-9)


def test_dlc_50_kmh_against_the_simulator(dlc: GroundTruth) -> None:
    """Issue 16 §3: on the simulator's noise-free DLC at 50 km/h the published ≤ 0.18° and ≤ 5.7 % at the peaks.

    The steady-state formula (issue 9) misses them (0.38° / 7.9 %): it neither follows the yaw and sideslip
    transients nor the tyres' non-linearity under load transfer; inverting the single-track dynamics does.
    """
    for step in (10, 50):  # 100 Hz and the GNSS's 20 Hz
        t, v, ay, swa = dlc.t[::step], dlc.speed[::step], dlc.ay_meas[::step], dlc.swa[::step]
        rec = reconstruct_steering(t, v, ay, DYNAMIC, swa_rad=swa, steering_ratio=_gear_ratio)
        steady = reconstruct_steering(t, v, ay, MODEL, swa_rad=swa, steering_ratio=_gear_ratio)
        summary, old = rec.to_dict(), steady.to_dict()
        print(f"steering reconstruction, DLC 50 km/h at {1000 // step:.0f} Hz: {summary['method']}: mean |error| "
              f"{summary['mean_abs_error_deg']:.3f}°, max |error| {summary['max_abs_error_deg']:.3f}°, max relative "
              f"error at the peaks {summary['max_relative_error_at_peaks_percent']:.2f} % (steady state: "
              f"{old['max_abs_error_deg']:.3f}°, {old['max_relative_error_at_peaks_percent']:.2f} %)")
        assert rec.method.startswith("single-track dynamics, non-linear") and steady.method == "steady state"
        assert summary["max_abs_error_deg"] <= 0.18
        assert summary["max_relative_error_at_peaks_percent"] <= 5.7
        assert len(rec.peaks_t) == 4  # two lane changes: four steering peaks
        assert rec.beyond_tyre_peak == 0
        # the steady-state formula (the previous model) does not reach the published figures
        assert old["max_abs_error_deg"] > 0.3 and old["max_relative_error_at_peaks_percent"] > 7.0
        np.testing.assert_array_equal(rec.delta_steady_state, steady.delta)
        # both corrections are needed: linear axles alone leave ≈ 0.26° / 5 %
        lin = reconstruct_steering(t, v, ay, dataclasses.replace(DYNAMIC, tyres=None), swa_rad=swa,
                                   steering_ratio=_gear_ratio)
        assert lin.max_abs_error_rad > math.radians(0.2)
        assert rec.max_abs_error_rad < 0.5 * lin.max_abs_error_rad
        # the corrections help: the uncorrected estimate is worse
        kin_err = np.nanmean(np.abs(rec.delta_kinematic - rec.delta_from_swa))  # type: ignore[operator]
        assert kin_err > 3.0 * rec.mean_abs_error_rad


@pytest.mark.parametrize(("speed_kmh", "max_deg", "max_rel"), [(30.0, 0.18, 0.057), (60.0, 0.18, 0.057),
                                                               (70.0, 0.6, 0.07)])
def test_dlc_other_speeds(speed_kmh: float, max_deg: float, max_rel: float) -> None:
    """Not tuned to 50 km/h: the published figures hold at 30 and 60 km/h (a_y up to 6.2 m/s²); at 70 km/h the
    DLC reaches 8.5 m/s², near the tyres' limit, where the quasi-static load transfer leaves ≈ 0.5° (the
    steady-state formula: 5°)."""
    tr = simulate(make_scenario("double_lane_change", speed_kmh=speed_kmh), rate_hz=20.0)
    rec = reconstruct_steering(tr.t, tr.speed, tr.ay_meas, DYNAMIC, swa_rad=tr.swa, steering_ratio=_gear_ratio)
    steady = reconstruct_steering(tr.t, tr.speed, tr.ay_meas, MODEL, swa_rad=tr.swa, steering_ratio=_gear_ratio)
    assert math.degrees(rec.max_abs_error_rad) <= max_deg, speed_kmh
    assert rec.max_relative_error_at_peaks <= max_rel, speed_kmh
    assert rec.max_abs_error_rad < 0.25 * steady.max_abs_error_rad


def test_dynamic_reduces_to_the_steady_state_formula_on_a_circle() -> None:
    """Linear axles in steady state: δ = a_y·l/v² + K·a_y exactly; the tyre model adds slip near the limit."""
    v, radius = 50 / 3.6, 40.0
    ay = v * v / radius
    t = np.arange(0.0, 3.0, 0.05)
    lin = dataclasses.replace(MODEL, yaw_inertia_kgm2=P.yaw_inertia_kgm2)
    for model in (lin, DYNAMIC):
        rec = reconstruct_steering(t, np.full(t.size, v), np.full(t.size, ay * MODEL.roll_factor), model)
        assert rec.delta_steady_state is not None
        if model.tyres is None:
            np.testing.assert_allclose(rec.delta, rec.delta_steady_state, rtol=2e-3)
        else:  # 4.8 m/s²: the non-linear axles need more steering than the linear ones, never less
            assert np.all(rec.delta > rec.delta_steady_state)
        assert np.ptp(rec.delta) < 1e-9  # started in steady state, stays there


def test_axle_characteristic() -> None:
    """Linear for small slip with the axle's cornering stiffness; inverse exact; scalar path equals the vector one."""
    ax = _Axles(DYNAMIC)
    small = np.array([1e-5])
    assert float(ax.force(small, np.zeros(1), 0)[0]) == pytest.approx(2 * P.cornering_stiffness_front_n_per_rad * 1e-5,
                                                                    rel=1e-6)
    alpha = np.linspace(-0.08, 0.08, 33)
    ay = np.linspace(-6.0, 6.0, 33)
    for axle in (0, 1):
        f = ax.force(alpha, ay, axle)
        back, over = ax.slip(f, ay, axle)
        np.testing.assert_allclose(back, alpha, atol=1e-9)
        assert not over.any()
        assert [ax.force_scalar(float(x), float(y), axle) for x, y in zip(alpha, ay, strict=True)] == pytest.approx(
            f.tolist(), rel=1e-12, abs=1e-9)
    # load transfer lowers the axle's force at the same slip
    assert float(ax.force(np.array([0.03]), np.array([6.0]), 0)[0]) < float(ax.force(np.array([0.03]),
                                                                                       np.zeros(1), 0)[0])
    # a force beyond the peak is flagged, not extrapolated
    _, over = ax.slip(np.array([2.0 * P.mass_kg * GRAVITY]), np.zeros(1), 0)
    assert over.all()


def test_profile_model_is_the_dynamic_one() -> None:
    """rig validate / rig steering reconstruct build the dynamic, non-linear model from the vehicle profile."""
    sm = steering_model(VehicleProfile(vehicle=VehicleConfig()))
    assert sm.yaw_inertia_kgm2 == VehicleConfig().yaw_inertia_kgm2 and sm.tyres is not None
    assert sm.tyres.peak_mu == VehicleConfig().tyre_peak_mu


def test_error_model_sign_change() -> None:
    """Roll makes the plain estimate read high at low speed, understeer low at high speed; zero at √(l g k_φ / K)."""
    m = SteeringModel.from_degrees_per_g(
        wheelbase_m=2.8, mass_kg=1550.0, front_axle_load_share=0.6, cornering_stiffness_n_per_rad_per_tyre=60000.0,
        roll_gain_deg_per_g=4.0,
    )
    k = 1550.0 * (0.6 - 0.4) / (2 * 60000.0)
    assert m.understeer_gradient_rad_per_mps2 == pytest.approx(k)
    v0 = math.sqrt(2.8 * math.radians(4.0) / k)
    em = error_table(m, [20.0, 3.6 * v0, 120.0])
    assert em.sign_change_speed_mps == pytest.approx(v0)
    assert em.gamma[0] < 0.0 and em.gamma[1] == pytest.approx(0.0, abs=1e-12) and em.gamma[2] > 0.0
    d = em.to_dict()
    assert d["sign_change_speed_kmh"] == pytest.approx(3.6 * v0)
    # neutral steer and no roll: never wrong
    neutral = SteeringModel(2.8, 1500.0, 0.5, 60000.0, 60000.0)
    assert error_model(neutral, [10.0, 40.0]).sign_change_speed_mps is None
    np.testing.assert_allclose(error_model(neutral, [10.0, 40.0]).gamma, 0.0, atol=1e-15)
    with pytest.raises(AnalysisError, match="front_axle_load_share"):
        SteeringModel(2.8, 1500.0, 1.2, 6e4, 6e4)
    with pytest.raises(AnalysisError, match="needs a steering_ratio"):
        reconstruct_steering([0.0, 1.0], [10.0, 10.0], [1.0, 1.0], neutral, swa_rad=[0.1, 0.1])


def test_ay_delay_is_measured_against_the_heading_and_removed(dlc: GroundTruth) -> None:
    """a_y stamped 30 ms late (sensing filter + CAN latency): found from the GNSS heading, not from the SWA."""
    step = 50  # 20 Hz, the GNSS epochs
    t, v, swa = dlc.t[::step], dlc.speed[::step], dlc.swa[::step]
    late = np.interp(t - 0.030, dlc.t, dlc.ay_meas)
    rng = np.random.default_rng(3)
    heading = dlc.yaw[::step] + 0.3 + rng.normal(0.0, math.radians(0.05), t.size)  # any offset, dual-antenna noise
    from rig.analysis.steering import estimate_ay_delay

    d = estimate_ay_delay(t, v, late, heading, DYNAMIC)
    assert d.delay_s == pytest.approx(0.030, abs=0.004) and d.se_s < 0.004 and d.n > 200
    on_time = estimate_ay_delay(t, v, dlc.ay_meas[::step], heading, DYNAMIC)
    assert abs(on_time.delay_s) < 0.004
    raw = reconstruct_steering(t, v, late, DYNAMIC, swa_rad=swa, steering_ratio=_gear_ratio)
    fixed = reconstruct_steering(t, v, late, DYNAMIC, swa_rad=swa, steering_ratio=_gear_ratio, ay_delay_s=d.delay_s)
    assert math.degrees(raw.max_abs_error_rad) > 0.25  # 30 ms late costs more than the whole budget
    assert math.degrees(fixed.max_abs_error_rad) <= 0.18 and fixed.max_relative_error_at_peaks <= 0.057
    assert fixed.to_dict()["ay_delay_s"] == pytest.approx(d.delay_s)
    with pytest.raises(AnalysisError, match="yaw_inertia_kgm2"):
        estimate_ay_delay(t, v, late, heading, MODEL)
