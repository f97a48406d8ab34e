"""Road-wheel angle from speed and lateral acceleration: steady-state physics, the simulator's DLC, the error model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.analysis.steering import SteeringModel, error_model, error_table, reconstruct_steering
from sim_devices.vehicle import GRAVITY, GroundTruth, SteeringGear, VehicleParams
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
    """Issue 9: on the simulated DLC at 50 km/h, δ from GNSS speed and a_y against SWA / ratio."""
    gear = SteeringGear(P)

    def ratio(swa: np.ndarray) -> np.ndarray:
        d = gear.road_wheel_angle(swa)
        return np.where(np.abs(d) > 1e-9, swa / np.where(np.abs(d) > 1e-9, d, 1.0), 16.0)

    step = 10
    rec = reconstruct_steering(dlc.t[::step], dlc.speed[::step], dlc.ay_meas[::step], MODEL,
                               swa_rad=dlc.swa[::step], steering_ratio=ratio)
    summary = rec.to_dict()
    print(f"steering reconstruction, DLC 50 km/h: mean |error| {summary['mean_abs_error_deg']:.3f}°, "
          f"max |error| {summary['max_abs_error_deg']:.3f}°, max relative error at the peaks "
          f"{summary['max_relative_error_at_peaks_percent']:.1f} % (peaks at {summary['peaks_t_s']} s)")
    peak = math.degrees(float(np.max(np.abs(dlc.road_wheel_angle))))
    assert math.degrees(rec.mean_abs_error_rad) < 0.02 * peak  # the steady-state model holds most of the time
    assert math.degrees(rec.max_abs_error_rad) < 0.12 * peak  # but lags the fast steering reversals
    assert rec.max_relative_error_at_peaks < 0.12
    assert len(rec.peaks_t) == 4  # two lane changes: four steering peaks
    # the corrections help: the uncorrected estimate is worse
    kin_err = np.nanmean(np.abs(rec.delta_kinematic - rec.delta_from_swa))  # type: ignore[operator]
    assert kin_err > rec.mean_abs_error_rad


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
