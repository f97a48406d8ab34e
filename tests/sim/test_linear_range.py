"""Linear range against the analytic linear single-track (bicycle) model with the same parameters.

Analytic values, with per-axle cornering stiffnesses C_f, C_r, CG a behind the front and b ahead of
the rear axle, wheelbase L and mass m:
- understeer gradient K = m/L·(b/C_f − a/C_r): road-wheel angle δ = δ_kin + K·a_y on a constant radius;
- steady-state yaw-rate gain r/δ = v/(L + K v²);
- CG sideslip on a circle β = b/R − m·a·v²/(L·C_r·R), which changes sign at v₀ = √(b·L·C_r/(m·a)).
"Linear range" here is a_y ≤ 1.5 m/s² (0.15 g), where the load-sensitive tyres of the model add
less than 1 % to K (the model's K grows by ≈ 2.4 % at 2 m/s² and ≈ 6 % at 3 m/s²).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.vehicle import GroundTruth, VehicleParams, make_scenario, simulate
from tests.sim.helpers import phase

PARAMS = VehicleParams()
K = PARAMS.understeer_gradient_rad_per_mps2
L = PARAMS.wheelbase_m
A = PARAMS.cg_to_front_axle_m
B = PARAMS.cg_to_rear_axle_m
C_R = PARAMS.axle_cornering_stiffness_n_per_rad[1]
V0 = math.sqrt(B * L * C_R / (PARAMS.mass_kg * A))

R_LARGE = 150.0
AY_LEVELS = (0.5, 1.0, 1.5)
GAIN_SPEEDS_KMH = (50.0, 80.0, 110.0)


def _steady_circle(ay: float) -> tuple[float, float]:
    """(mean a_y, mean road-wheel angle) over the last 1.5 s of 9 s at constant speed on R = 150 m."""
    speed_kmh = math.sqrt(ay * R_LARGE) * 3.6
    scenario = make_scenario(
        "steady_state_circle", radius_m=R_LARGE, speed_start_kmh=speed_kmh, speed_end_kmh=speed_kmh,
        settle_s=9.0, hold_s=0.0,
    )
    truth = simulate(scenario, PARAMS, rate_hz=100.0)
    sel = truth.t > truth.t[-1] - 1.5
    return float(np.mean(truth.ay[sel])), float(np.mean(truth.road_wheel_angle[sel]))


@pytest.fixture(scope="module")
def circles() -> np.ndarray:
    return np.array([_steady_circle(ay) for ay in AY_LEVELS])


@pytest.fixture(scope="module")
def step_steers() -> list[GroundTruth]:
    return [
        simulate(make_scenario("step_steer", speed_kmh=v, ay_mps2=1.0, hold_s=4.0), PARAMS, rate_hz=100.0)
        for v in GAIN_SPEEDS_KMH
    ]


@pytest.fixture(scope="module")
def large_ramp() -> GroundTruth:
    """R = 300 m, v²/R raised by 0.05 m/s³ from 60 to 72 km/h (a_y 0.93 … 1.33 m/s²), across v₀ ≈ 66 km/h."""
    scenario = make_scenario(
        "steady_state_circle", radius_m=300.0, speed_start_kmh=60.0, speed_end_kmh=72.0, ay_rate_mps3=0.05,
        settle_s=4.0, hold_s=0.0,
    )
    return simulate(scenario, PARAMS, rate_hz=200.0)


def test_understeer_gradient(circles: np.ndarray) -> None:
    ay, delta = circles[:, 0], circles[:, 1]
    np.testing.assert_allclose(ay, AY_LEVELS, rtol=0.01)
    slope, intercept = np.polyfit(ay, delta, 1)
    assert slope == pytest.approx(K, rel=0.03)
    # The intercept is the kinematic angle of the rear axle's radius √(R² − b²).
    assert intercept == pytest.approx(math.atan(L / math.sqrt(R_LARGE**2 - B**2)), rel=0.01)


def test_steady_state_yaw_rate_gain(step_steers: list[GroundTruth]) -> None:
    for speed_kmh, truth in zip(GAIN_SPEEDS_KMH, step_steers, strict=True):
        sel = truth.t > truth.t[-1] - 0.5
        r, delta, v = (float(np.mean(x[sel])) for x in (truth.yaw_rate, truth.road_wheel_angle, truth.speed))
        assert np.ptp(truth.yaw_rate[sel]) < 1e-3 * abs(r), "not yet steady"
        assert v == pytest.approx(speed_kmh / 3.6, rel=0.005)
        assert r / delta == pytest.approx(v / (L + K * v * v), rel=0.03), f"at {speed_kmh} km/h"


def test_sideslip_changes_sign_at_the_linear_model_speed(large_ramp: GroundTruth) -> None:
    truth = large_ramp
    ph = phase(truth, "circle")
    sel = ph.mask(truth, start_offset=2.0)
    beta, v = truth.beta_cg[sel], truth.speed[sel]
    assert beta[0] > 0.0 and beta[-1] < 0.0  # positive below v₀ (left turn), negative above
    assert np.all(np.diff(np.sign(beta)) <= 0)  # one crossing, from + to −
    i = int(np.argmax(beta < 0.0))
    v_cross = np.interp(0.0, [beta[i], beta[i - 1]], [v[i], v[i - 1]])
    assert v_cross == pytest.approx(V0, rel=0.01)
    # And the sideslip itself follows the linear formula along the way.
    expected = B / 300.0 - PARAMS.mass_kg * A * v**2 / (L * C_R * 300.0)
    assert np.max(np.abs(np.degrees(beta - expected))) < 0.01
