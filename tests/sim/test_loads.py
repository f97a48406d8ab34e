"""Vertical wheel loads and the lateral load-transfer ratio (LTR)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, make_scenario, simulate

PARAMS = VehicleParams()
# A tall, grippy car (SUV-like) whose inside wheels lift in a fishhook before its tyres slide.
TALL = PARAMS.replace(cg_height_m=0.95, roll_axis_height_m=0.35, tyre_peak_mu=1.2, track_front_m=1.5, track_rear_m=1.5)


@pytest.fixture(scope="module")
def straight_then_brake() -> GroundTruth:
    """80 km/h straight, then a transition down to 20 km/h (braking at 2 m/s²), then straight again."""
    drive = Drive(
        [make_scenario("straight", speed_kmh=80.0, duration_s=3.0), make_scenario("straight", speed_kmh=20.0,
                                                                                 duration_s=2.0)],
        gap_s=1.0,
    )
    return simulate(drive, PARAMS, rate_hz=200.0)


@pytest.fixture(scope="module")
def fishhook_tall() -> GroundTruth:
    return simulate(make_scenario("fishhook", speed_kmh=70.0), TALL, rate_hz=1000.0)


def test_loads_sum_to_weight(straight_then_brake: GroundTruth, fishhook_tall: GroundTruth) -> None:
    for truth, params in ((straight_then_brake, PARAMS), (fishhook_tall, TALL)):
        np.testing.assert_allclose(truth.wheel_load.sum(axis=1), params.mass_kg * 9.80665, rtol=1e-12)
        assert np.all(truth.wheel_load >= 0.0)


def test_ltr_zero_driving_straight(straight_then_brake: GroundTruth) -> None:
    truth = straight_then_brake
    assert np.max(np.abs(truth.ltr)) < 1e-9
    np.testing.assert_allclose(truth.wheel_load[:, 0], truth.wheel_load[:, 1], rtol=1e-9)


def test_longitudinal_load_transfer_when_braking(straight_then_brake: GroundTruth) -> None:
    """Pitch moment balance: the front axle gains m·|a_x|·h/L when braking."""
    truth = straight_then_brake
    p = PARAMS
    braking = truth.ax < -1.0
    assert braking.sum() > 100
    front = truth.wheel_load[braking, 0] + truth.wheel_load[braking, 1]
    static_front = p.static_axle_loads_n[0]
    expected = static_front - p.mass_kg * truth.ax[braking] * p.cg_height_m / p.wheelbase_m
    # The model's loads use the acceleration of the previous 1 ms step; the ramp is smooth, so 1 % holds.
    np.testing.assert_allclose(front, expected, rtol=0.01)


def test_ltr_reaches_one_exactly_when_the_inside_pair_unloads(fishhook_tall: GroundTruth) -> None:
    truth = fishhook_tall
    fz, ltr = truth.wheel_load, truth.ltr
    left_lifted = (fz[:, 0] == 0.0) & (fz[:, 2] == 0.0)
    right_lifted = (fz[:, 1] == 0.0) & (fz[:, 3] == 0.0)
    assert left_lifted.any() and right_lifted.any(), "the manoeuvre must lift each pair once"
    assert np.all(ltr[left_lifted] == 1.0)
    assert np.all(ltr[right_lifted] == -1.0)
    neither = ~(left_lifted | right_lifted)
    assert np.all(np.abs(ltr[neither]) < 1.0)
    # Sign: LTR > 0 means the right wheels carry more, i.e. turning left (a_y > 0).
    strong = np.abs(truth.ay) > 3.0
    assert np.all(np.sign(ltr[strong]) == np.sign(truth.ay[strong]))
