"""Steady-state circular driving (ISO 4138 style) against the physics of a car on a circle.

One drive on R = 20 m to the left: 30 s at walking speed (1 m/s), then v²/R raised by
0.15 m/s³ up to 45 km/h (a_y ≈ 7.8 m/s², near the limit), then 3 s held.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim_devices.vehicle import GRAVITY, GroundTruth, VehicleParams, make_scenario, simulate
from tests.sim.helpers import PhaseInfo, phase

R = 20.0
WALK_KMH = 3.6
SETTLE_S = 30.0
HOLD_S = 3.0
PARAMS = VehicleParams()


@pytest.fixture(scope="module")
def circle() -> tuple[GroundTruth, PhaseInfo]:
    scenario = make_scenario(
        "steady_state_circle",
        radius_m=R,
        turn="left",
        speed_start_kmh=WALK_KMH,
        speed_end_kmh=45.0,
        ay_rate_mps3=0.15,
        settle_s=SETTLE_S,
        hold_s=HOLD_S,
    )
    truth = simulate(scenario, PARAMS)
    return truth, phase(truth, "circle")


@pytest.fixture(scope="module")
def right_walk() -> GroundTruth:
    scenario = make_scenario(
        "steady_state_circle", radius_m=R, turn="right", speed_start_kmh=WALK_KMH, speed_end_kmh=WALK_KMH,
        settle_s=SETTLE_S, hold_s=0.0,
    )
    return simulate(scenario, PARAMS, rate_hz=100.0)


def _ramp(truth: GroundTruth, ph: PhaseInfo) -> np.ndarray:
    # From 0.5 s after the speed starts to rise (the speed controller's step in feed-forward) to the end.
    return ph.mask(truth, start_offset=SETTLE_S + 0.5)


def test_path_stays_on_the_circle(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    truth, ph = circle
    sel = ph.mask(truth, start_offset=SETTLE_S - 5.0)
    radius = np.hypot(truth.east[sel] - ph.number("circle_east_m"), truth.north[sel] - ph.number("circle_north_m"))
    assert np.max(np.abs(radius - R)) < 0.005 * R  # the follower holds the radius within 0.5 %


def test_normal_acceleration_is_v2_over_r(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    """Acceleration normal to the CG velocity = v²/R within 1 % over the whole speed ramp (0.4 … 7.8 m/s²)."""
    truth, ph = circle
    sel = _ramp(truth, ph)
    v = truth.speed[sel]
    beta = truth.beta_cg[sel]
    # Rotate the body-axis acceleration into the path frame (normal points to the left of the velocity).
    a_n = truth.ay[sel] * np.cos(beta) - truth.ax[sel] * np.sin(beta)
    expected = v**2 / R
    assert expected.min() < 0.5 and expected.max() > 7.5  # the ramp covers the linear and the non-linear range
    np.testing.assert_allclose(a_n, expected, rtol=0.01)


def test_yaw_rate_is_v_over_r(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    truth, ph = circle
    sel = _ramp(truth, ph)
    np.testing.assert_allclose(truth.yaw_rate[sel], truth.speed[sel] / R, rtol=0.01)


@pytest.mark.parametrize("window", ["walking", "held_at_45_kmh"])
def test_lateral_acceleration_at_constant_speed(circle: tuple[GroundTruth, PhaseInfo], window: str) -> None:
    """At constant speed the body-axis a_y itself is v²/R within 1 % (β ≤ 5°, so cos β ≥ 0.996)."""
    truth, ph = circle
    if window == "walking":
        sel = (truth.t >= ph.t_start + SETTLE_S - 5.0) & (truth.t < ph.t_start + SETTLE_S)
    else:
        sel = ph.mask(truth, start_offset=ph.t_end - ph.t_start - 1.0)
    v = truth.speed[sel]
    np.testing.assert_allclose(truth.ay[sel], v**2 / R, rtol=0.01)
    np.testing.assert_allclose(truth.yaw_rate[sel], v / R, rtol=0.01)


def test_walking_speed_sideslip_is_kinematic(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    """At 1 m/s the CG sideslip is the kinematic atan(b/R) within 0.05°, and positive in a left turn (ISO 8855)."""
    truth, ph = circle
    sel = (truth.t >= ph.t_start + SETTLE_S - 5.0) & (truth.t < ph.t_start + SETTLE_S)
    assert np.allclose(truth.speed[sel], WALK_KMH / 3.6, rtol=0.01)
    beta = truth.beta_cg[sel]
    kinematic = math.atan(PARAMS.cg_to_rear_axle_m / R)
    assert np.all(beta > 0.0)
    assert np.max(np.abs(np.degrees(beta - kinematic))) < 0.05


def test_sideslip_negative_at_walking_speed_in_a_right_turn(right_walk: GroundTruth) -> None:
    truth = right_walk
    sel = truth.t > truth.t[-1] - 3.0
    assert np.all(truth.yaw_rate[sel] < 0.0)
    kinematic = -math.atan(PARAMS.cg_to_rear_axle_m / R)
    assert np.max(np.abs(np.degrees(truth.beta_cg[sel] - kinematic))) < 0.05


def test_sideslip_grows_nonlinearly_near_the_limit(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    """Linear theory: β falls linearly with a_y. Near the limit the saturating tyres make it fall much faster."""
    truth, ph = circle
    sel = _ramp(truth, ph)
    ay, beta = truth.ay[sel], truth.beta_cg[sel]
    low = (ay > 1.0) & (ay < 2.0)
    high = ay > 7.0
    slope_low = np.polyfit(ay[low], beta[low], 1)[0]
    slope_high = np.polyfit(ay[high], beta[high], 1)[0]
    assert slope_low < 0.0
    assert slope_high < 3.0 * slope_low  # more than three times as steep


def _held(truth: GroundTruth, ph: PhaseInfo) -> np.ndarray:
    return ph.mask(truth, start_offset=ph.t_end - ph.t_start - 1.0)


def test_roll_moment_balance(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    """Steady turn: the lateral load transfer balances the roll moment of the whole car about the ground.

    Σ_axles (F_right − F_left)·track/2 = m·a_y·(h_r + h′ cos φ) + m·g·h′·sin φ, with the CG h′ above the
    roll axis (height h_r): inertia force at the rolled CG height plus the sideways shift of its weight.
    """
    truth, ph = circle
    sel = _held(truth, ph)
    p = PARAMS
    fz = truth.wheel_load[sel]
    moment = (fz[:, 1] - fz[:, 0]) * 0.5 * p.track_front_m + (fz[:, 3] - fz[:, 2]) * 0.5 * p.track_rear_m
    phi = truth.roll[sel]
    h_r = p.roll_axis_height_m
    h_p = p.cg_height_m - h_r
    expected = p.mass_kg * (truth.ay[sel] * (h_r + h_p * np.cos(phi)) + GRAVITY * h_p * np.sin(phi))
    assert np.all(phi > math.radians(2.0))  # rolled right side down in a left turn (ISO 8855)
    np.testing.assert_allclose(moment, expected, rtol=0.01)
    assert np.all(truth.ltr[sel] > 0.3)  # right (outer) wheels carry more


def test_accelerometer_includes_roll_gravity(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    """A body-fixed accelerometer measures the specific force a − g in body axes (rotated by the roll)."""
    truth, _ = circle
    specific_force = np.column_stack([truth.ax, truth.ay, np.full_like(truth.ax, GRAVITY)])
    body = Rotation.from_euler("x", truth.roll[:, np.newaxis]).inv().apply(specific_force)
    np.testing.assert_allclose(truth.ay_meas, body[:, 1], atol=1e-9)
    np.testing.assert_allclose(truth.ax_meas, body[:, 0], atol=1e-9)


def test_accelerometer_reads_more_than_ay_in_a_left_turn(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    truth, ph = circle
    sel = _held(truth, ph)
    excess = truth.ay_meas[sel] - truth.ay[sel]
    assert np.all(excess > 0.5)  # g·sin(φ) with φ ≈ 3.5° at 7.7 m/s²
    # The rest, a_y·(1 − cos φ), is below 0.02 m/s² at φ < 4°.
    np.testing.assert_allclose(excess, GRAVITY * np.sin(truth.roll[sel]), atol=0.02)


def test_wheel_speeds_at_walking_speed_follow_the_turn_centre(circle: tuple[GroundTruth, PhaseInfo]) -> None:
    """Rolling without slip about the turn centre on the rear-axle line: each wheel's speed is r × its distance.

    The centre lies √(R² − b²) to the left of the rear axle (R is the CG radius). Drive slip at 1 m/s is
    below 0.2 %, so 0.5 % holds.
    """
    truth, ph = circle
    sel = (truth.t >= ph.t_start + SETTLE_S - 5.0) & (truth.t < ph.t_start + SETTLE_S)
    p = PARAMS
    r = truth.yaw_rate[sel]
    rc = math.sqrt(R**2 - p.cg_to_rear_axle_m**2)
    L = p.wheelbase_m
    hf, hr = 0.5 * p.track_front_m, 0.5 * p.track_rear_m
    distances = (math.hypot(L, rc - hf), math.hypot(L, rc + hf), rc - hr, rc + hr)  # FL FR RL RR
    for j, d in enumerate(distances):
        np.testing.assert_allclose(truth.wheel_speed[sel, j], r * d, rtol=0.005)
    assert np.all(truth.wheel_speed[sel, 1] > truth.wheel_speed[sel, 0])  # outer wheels faster
