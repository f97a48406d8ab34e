"""Steering ratio from driven circles (against the simulator's nonlinear gear) and from tape measurements."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.segments import Direction, find_constant_swa_segments
from calibration.steering import (
    ManualMethod,
    SteeringRatioTable,
    antenna_to_rear_axle,
    circumradius,
    fit_circle,
    manual_ratio_from_chords,
    manual_ratio_from_diameter,
    road_wheel_angle,
    steering_ratio_from_circles,
)
from sim_devices.vehicle import GroundTruth, SteeringGear, VehicleParams, make_scenario, simulate
from tests.calibration.observe import A_XY, observe
from vsccore.errors import CalibrationError

PARAMS = VehicleParams()


@pytest.fixture(scope="module")
def circles() -> GroundTruth:
    """Constant-SWA circles at 5 km/h, forward then reverse, at 0, ±130, ±260, ±390, ±520°."""
    return simulate(make_scenario("swa_circles", swa_step_deg=130.0, settle_s=3.0, hold_s=16.0), rate_hz=20.0)


def test_ratio_table_matches_simulated_gear_within_1_percent(circles: GroundTruth) -> None:
    """Issue 8: SWA/δ from circle fits on the rear-axle-centre track within 1 % of the true nonlinear gear."""
    obs = observe(circles, seed=3)
    rng = np.random.default_rng(3)
    swa_meas = circles.swa[obs.idx] + rng.standard_normal(obs.idx.size) * math.radians(0.1)
    v_signed = np.sign(circles.vx[obs.idx]) * obs.speed  # the wheel speeds' direction bit, in a real car
    segs = find_constant_swa_segments(obs.t, swa_meas, v_signed, yaw_rate_rps=obs.yaw_rate)
    east, north = antenna_to_rear_axle(obs.a_enu[0], obs.a_enu[1], obs.heading, A_XY, (-PARAMS.cg_to_rear_axle_m, 0.0))
    table = steering_ratio_from_circles(segs, obs.t, east, north, wheelbase_m=PARAMS.wheelbase_m,
                                        min_arc_rad=math.radians(60.0))
    gear = SteeringGear(PARAMS)
    expected = {(d, a) for d in Direction for a in (-520, -390, -260, -130, 130, 260, 390, 520)}
    got = {(r.direction, round(r.swa_deg)) for r in table.rows}
    assert got == expected  # the SWA ≈ 0 runs are straight lines: skipped with a warning
    assert sum("skipped" in w for w in table.warnings) == 2
    worst = 0.0
    for r in table.rows:
        true_ratio = r.swa_rad / gear.road_wheel_angle(r.swa_rad)
        err = r.ratio / true_ratio - 1.0
        worst = max(worst, abs(err))
        assert abs(err) < 0.01, (r.direction, r.swa_deg, r.ratio, true_ratio)
        assert math.copysign(1.0, r.delta_rad) == math.copysign(1.0, r.swa_rad)
        assert r.rms_residual_m < 0.02
    print(f"steering ratio: worst relative error {100 * worst:.2f} % over ±520°, forward and reverse")
    # the measured table interpolates like the gear between set points
    mid = math.radians(195.0)
    assert float(table.ratio_at(mid)) == pytest.approx(mid / gear.road_wheel_angle(mid), rel=0.01)
    again = SteeringRatioTable.from_dict(table.to_dict())
    assert [(r.direction, r.ratio) for r in again.rows] == [(r.direction, r.ratio) for r in table.rows]
    np.testing.assert_allclose([r.swa_rad for r in again.rows], [r.swa_rad for r in table.rows], rtol=1e-12)


def test_circle_fit_on_a_short_noisy_arc() -> None:
    rng = np.random.default_rng(1)
    cx, cy, r = 4.2e5, 5.4e6, 37.0  # far from the origin, like UTM coordinates
    ang = np.linspace(0.3, 0.3 + math.radians(70.0), 300)
    x = cx + r * np.cos(ang) + rng.standard_normal(ang.size) * 0.01
    y = cy + r * np.sin(ang) + rng.standard_normal(ang.size) * 0.01
    fit = fit_circle(x, y)
    assert fit.radius_m == pytest.approx(r, abs=0.05)
    assert fit.east_m == pytest.approx(cx, abs=0.05) and fit.north_m == pytest.approx(cy, abs=0.05)
    assert fit.rms_residual_m == pytest.approx(0.01, rel=0.15)
    assert math.degrees(fit.swept_rad) == pytest.approx(70.0, abs=0.5)
    with pytest.raises(CalibrationError, match="straight line"):
        fit_circle(np.arange(10.0), 2.0 * np.arange(10.0))
    with pytest.raises(CalibrationError, match="at least 3"):
        fit_circle(np.array([1.0, 2.0]), np.array([1.0, 3.0]))


def test_rear_axle_track_from_antenna() -> None:
    # heading 90° (east), antenna 0.6 m ahead of the CG: the rear axle (1.6 m behind the CG) is 2.2 m west of it
    e, n = antenna_to_rear_axle(np.array([10.0]), np.array([5.0]), np.array([math.pi / 2]), (0.6, 0.0), (-1.6, 0.0))
    assert e[0] == pytest.approx(7.8) and n[0] == pytest.approx(5.0)
    # heading 0° (north), a point 1 m to the left is 1 m west
    e, n = antenna_to_rear_axle(np.array([0.0]), np.array([0.0]), np.array([0.0]), (0.0, 0.0), (0.0, 1.0))
    assert e[0] == pytest.approx(-1.0) and n[0] == pytest.approx(0.0, abs=1e-12)


def test_manual_three_chords() -> None:
    """Three points on the inner rear wheel's track; the chords between them give the radius (R = abc / 4S)."""
    r_inner = 4.0
    pts = [(r_inner * math.cos(a), r_inner * math.sin(a)) for a in (0.2, 1.9, 4.0)]
    chords = tuple(math.dist(pts[i], pts[j]) for i, j in ((0, 1), (1, 2), (2, 0)))
    assert circumradius(*chords) == pytest.approx(r_inner, rel=1e-12)
    swa = math.radians(500.0)
    res = manual_ratio_from_chords(swa, chords, wheelbase_m=2.8, track_rear_m=1.55)  # type: ignore[arg-type]
    assert res.method is ManualMethod.CHORDS
    assert res.radius_m == pytest.approx(4.775)
    assert res.delta_rad == pytest.approx(math.atan(2.8 / 4.775))
    assert res.ratio == pytest.approx(swa / math.atan(2.8 / 4.775))
    # tape σ 1 cm per chord → first-order σ of the ratio agrees with a Monte-Carlo of the same formula
    rng = np.random.default_rng(0)
    sims = [
        swa / road_wheel_angle(circumradius(*(np.array(chords) + rng.standard_normal(3) * 0.01)) + 0.775, 2.8)
        for _ in range(4000)
    ]
    assert res.ratio_sigma == pytest.approx(float(np.std(sims)), rel=0.1)
    with pytest.raises(CalibrationError, match="collinear"):
        circumradius(1.0, 2.0, 3.0)
    with pytest.raises(CalibrationError, match="not a triangle"):
        circumradius(1.0, 1.0, 3.0)


def test_manual_half_circle() -> None:
    res = manual_ratio_from_diameter(math.radians(-300.0), 12.0, wheelbase_m=2.8, track_rear_m=1.55)
    assert res.method is ManualMethod.DIAMETER
    assert res.radius_m == pytest.approx(6.775)
    assert res.delta_rad == pytest.approx(-math.atan(2.8 / 6.775))
    assert res.ratio > 0.0 and res.radius_sigma_m == pytest.approx(0.005)
    assert res.to_dict()["method"] == "half circle"
    with pytest.raises(CalibrationError, match="diameter must be a positive length"):
        manual_ratio_from_diameter(1.0, -2.0, wheelbase_m=2.8, track_rear_m=1.55)
