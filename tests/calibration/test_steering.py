"""Steering ratio from driven circles (against the simulator's nonlinear gear) and from tape measurements."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from calibration.segments import Direction, find_constant_swa_segments
from calibration.steering import (
    ManualMethod,
    SasZeroSource,
    SteeringRatioRow,
    SteeringRatioTable,
    antenna_to_rear_axle,
    apply_sas_zero,
    circumradius,
    combine_sas_zero,
    fit_circle,
    manual_ratio_from_chords,
    manual_ratio_from_diameter,
    road_wheel_angle,
    sas_zero_from_circle_pairs,
    sas_zero_from_straights,
    steering_ratio_from_circles,
)
from sim_devices.vehicle import Drive, GroundTruth, SteeringGear, VehicleParams, make_scenario, simulate
from tests.calibration.observe import A_XY, observe
from vsccore.errors import CalibrationError

PARAMS = VehicleParams()
SPEED_KMH = 5.0
ARC_DEG = 100.0
"""Arc each circle is held for (the hold follows from the expected radius)."""
FAST_STEP_DEG = 65.0
"""SWA spacing of the default run (±65 … ±520°); RIG_SLOW_TESTS=1 adds the 30° sweep (≈ 2400 s simulated)."""


def circles_drive(angles_deg: list[float], arc_deg: float = ARC_DEG) -> Drive:
    """Per angle X: circles at −X, 0, +X forward, then +X, 0, −X in reverse, each held for ``arc_deg``.

    The rear-axle circle of radius R = L / tan δ(X) takes arc·R / v: 100° of it is 5 s at 520°
    (R ≈ 4 m) but 110 s at 30° (R ≈ 85 m), the radius growing as 1/δ.
    """
    gear = SteeringGear(PARAMS)
    v = SPEED_KMH / 3.6
    parts = []
    for x in angles_deg:
        radius = PARAMS.wheelbase_m / math.tan(gear.road_wheel_angle(math.radians(x)))
        parts.append(make_scenario("swa_circles", speed_kmh=SPEED_KMH, swa_max_deg=x, swa_step_deg=x,
                                   direction="both", swa_rate_dps=360.0, settle_s=0.5,
                                   hold_s=math.radians(arc_deg) * radius / v))
    return Drive(parts, gap_s=0.5)


def _angles(step_deg: float) -> list[float]:
    return [float(x) for x in np.arange(step_deg, 520.0 - 1e-9, step_deg)] + [520.0]


@pytest.fixture(
    scope="module",
    params=[
        FAST_STEP_DEG,
        pytest.param(30.0, marks=[pytest.mark.slow, pytest.mark.skipif(
            not os.environ.get("RIG_SLOW_TESTS"), reason="30° sweep (≈ 15 s of simulation); set RIG_SLOW_TESTS=1")]),
    ],
    ids=lambda s: f"step{s:g}",
)
def circles(request: pytest.FixtureRequest) -> tuple[float, GroundTruth]:
    """Constant-SWA circles at 5 km/h, forward then reverse, at ±step … ±520°, each ≈ 100° of arc."""
    step = float(request.param)
    return step, simulate(circles_drive(_angles(step)), PARAMS, rate_hz=20.0)


def test_ratio_table_matches_simulated_gear_within_1_percent(circles: tuple[float, GroundTruth]) -> None:
    """Issue 8: SWA/δ from circle fits on the rear-axle-centre track within 1 % of the ratio the simulator applied.

    RTK-level noise on both antennas (1 cm common Gauss–Markov τ 30 s, 2 mm per antenna) and on the
    yaw rate; the CAN steering-wheel angle with 0.05° noise in 0.1° steps. Tyre slip at 5 km/h makes
    the kinematic δ = atan(L/R) smaller than the applied one by K·a_y, K·v²/L = 0.18 % of δ here.
    """
    step, truth = circles
    obs = observe(truth, seed=3)
    rng = np.random.default_rng(3)
    swa_meas = truth.swa[obs.idx] + rng.standard_normal(obs.idx.size) * math.radians(0.05)
    swa_meas = np.radians(np.round(np.degrees(swa_meas), 1))  # the SAS resolution
    v_signed = np.sign(truth.vx[obs.idx]) * obs.speed  # the wheel speeds' direction bit, in a real car
    segs = find_constant_swa_segments(obs.t, swa_meas, v_signed, yaw_rate_rps=obs.yaw_rate,
                                      min_turn_rad=math.radians(80.0))
    east, north = antenna_to_rear_axle(obs.a_enu[0], obs.a_enu[1], obs.heading, A_XY, (-PARAMS.cg_to_rear_axle_m, 0.0))
    table = steering_ratio_from_circles(segs, obs.t, east, north, wheelbase_m=PARAMS.wheelbase_m)
    angles = _angles(step)
    expected = {(d, round(s * a)) for d in Direction for a in angles for s in (-1, 1)}
    got = {(r.direction, round(r.swa_deg)) for r in table.rows}
    assert got == expected
    # the SWA ≈ 0 holds are straight lines: skipped with a warning (those of ≥ 10 s: the short ones are no candidates)
    assert 0 < len(table.warnings) <= 2 * len(angles)
    assert all(w.startswith(("SWA +0°", "SWA -0°")) and "skipped" in w for w in table.warnings)
    gear = SteeringGear(PARAMS)
    k_slip = PARAMS.understeer_gradient_rad_per_mps2 * (SPEED_KMH / 3.6) ** 2 / PARAMS.wheelbase_m
    lines = [f"step {step:g}°, slip limit K·v²/L = {100 * k_slip:.2f} %",
             f"{'dir':<8} {'SWA °':>7} {'R m':>7} {'arc °':>6} {'ratio':>8} {'applied':>8} {'err %':>7}"]
    errors: dict[Direction, list[float]] = {d: [] for d in Direction}
    for r in sorted(table.rows, key=lambda r: (r.direction is Direction.REVERSE, r.swa_rad)):
        m = (truth.t >= r.t_start_s) & (truth.t <= r.t_start_s + r.duration_s)
        applied = float(np.mean(truth.swa[m]) / np.mean(truth.road_wheel_angle[m]))  # what the simulator steered
        assert applied == pytest.approx(r.swa_rad / gear.road_wheel_angle(r.swa_rad), rel=2e-3)
        err = r.ratio / applied - 1.0
        errors[r.direction].append(err)
        lines.append(f"{r.direction.value:<8} {r.swa_deg:7.1f} {r.radius_m:7.2f} {math.degrees(r.arc_rad):6.0f} "
                     f"{r.ratio:8.3f} {applied:8.3f} {100 * err:+7.2f}")
        assert math.degrees(r.arc_rad) >= 90.0
        assert abs(err) < 0.01, lines[-1]
        assert math.copysign(1.0, r.delta_rad) == math.copysign(1.0, r.swa_rad)
        assert r.rms_residual_m < 0.02
    worst = max(abs(e) for v in errors.values() for e in v)
    print("\n".join(lines) + f"\nworst {100 * worst:.2f} % over ±520°, forward and reverse")
    # tyre slip: understeer forward (radius too large, ratio high); reversing the car oversteers (ratio low)
    assert float(np.mean(errors[Direction.FORWARD])) > 0.0 > float(np.mean(errors[Direction.REVERSE]))
    # the measured table interpolates like the gear between set points
    mid = math.radians(0.5 * (angles[1] + angles[2]))
    assert float(table.ratio_at(mid)) == pytest.approx(mid / gear.road_wheel_angle(mid), rel=0.01)
    again = SteeringRatioTable.from_dict(table.to_dict())
    assert [(r.direction, r.ratio) for r in again.rows] == [(r.direction, r.ratio) for r in table.rows]
    np.testing.assert_allclose([r.swa_rad for r in again.rows], [r.swa_rad for r in table.rows], rtol=1e-12)


def test_short_arcs_are_skipped_not_guessed(circles: tuple[float, GroundTruth]) -> None:
    """A circle is used only when enough of it was driven; the warning names the angle and the arc."""
    _, truth = circles
    obs = observe(truth, seed=4)
    segs = find_constant_swa_segments(obs.t, truth.swa[obs.idx], np.sign(truth.vx[obs.idx]) * obs.speed,
                                      yaw_rate_rps=obs.yaw_rate, min_turn_rad=math.radians(80.0))
    east, north = antenna_to_rear_axle(obs.a_enu[0], obs.a_enu[1], obs.heading, A_XY, (-PARAMS.cg_to_rear_axle_m, 0.0))
    with pytest.raises(CalibrationError, match=r"of the circle driven \(need 400°\)"):
        steering_ratio_from_circles(segs, obs.t, east, north, wheelbase_m=PARAMS.wheelbase_m,
                                    min_arc_rad=math.radians(400.0))


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


# ---------------------------------------------------------------------------------------------
# steering-angle sensor zero offset (issue 16 §2)


def _row(swa_meas: float, delta: float, direction: Direction, delta_se: float = math.radians(0.002),
         duration_s: float = 20.0) -> SteeringRatioRow:
    radius = PARAMS.wheelbase_m / math.tan(abs(delta))
    return SteeringRatioRow(swa_rad=swa_meas, direction=direction, radius_m=radius, delta_rad=delta,
                            ratio=swa_meas / delta, n_points=400, rms_residual_m=0.003, arc_rad=math.radians(100.0),
                            t_start_s=0.0, duration_s=duration_s, delta_se_rad=delta_se,
                            ratio_u95=1.96 * delta_se / abs(delta))


@pytest.mark.parametrize("holds", ["true angles (robot)", "measured angles (driver)"])
@pytest.mark.parametrize("offset_deg", [-1.9, 0.8, 1.5])
def test_sas_zero_from_left_right_pairs_of_the_nonlinear_gear(holds: str, offset_deg: float) -> None:
    """c from pairs at ±65 … ±520° of the simulator's (odd, nonlinear) gear, forward and reverse, with the
    slip bias (δ_kin = δ(1 ∓ 0.2 %), the same on both sides) and whichever angles were held symmetric."""
    gear = SteeringGear(PARAMS)
    c = math.radians(offset_deg)
    rows = []
    for direction, slip in ((Direction.FORWARD, -0.002), (Direction.REVERSE, 0.002)):
        for x in (65.0, 130.0, 260.0, 520.0):
            for sgn in (1.0, -1.0):
                held = sgn * math.radians(x)
                true = held if holds.startswith("true") else held - c
                delta = float(gear.road_wheel_angle(true)) * (1.0 + slip)
                rows.append(_row(true + c, delta, direction))
    src = sas_zero_from_circle_pairs(rows)
    assert src is not None and src.method == "circle pairs" and src.n == 8
    assert math.degrees(src.offset_rad) == pytest.approx(offset_deg, abs=0.01)
    # one side only: no pair, no estimate
    assert sas_zero_from_circle_pairs([r for r in rows if r.swa_rad > 0]) is None


def test_sas_zero_from_straight_runs_while_the_driver_weaves() -> None:
    """SWA = c + G·κ: the intercept at zero curvature, though the mean SWA is biased by the weaving."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 20.0, 0.05)
    v = np.full(t.size, 40.0 / 3.6)
    kappa = 0.0008 + 0.0015 * np.sin(2 * math.pi * 0.2 * t)  # a slow weave, mostly to one side
    c = math.radians(-1.3)
    gain = 16.0 * (PARAMS.wheelbase_m + PARAMS.understeer_gradient_rad_per_mps2 * v[0] ** 2)
    swa = c + gain * kappa + rng.normal(0.0, math.radians(0.05), t.size)
    halves = [t < 9.0, t > 11.0]
    src = sas_zero_from_straights(t, swa, kappa * v, v, halves)
    assert src is not None and src.n == int(sum(int(h.sum()) for h in halves))
    assert math.degrees(src.offset_rad) == pytest.approx(-1.3, abs=3 * math.degrees(src.se_rad))
    assert math.degrees(src.se_rad) < 0.02
    assert abs(float(np.mean(swa)) - c) > math.radians(0.5)  # the plain mean would be wrong
    assert sas_zero_from_straights(t, swa, kappa * v, v, [t < 1.0]) is None  # too few samples
    with pytest.raises(CalibrationError, match="mask has shape"):
        sas_zero_from_straights(t, swa, kappa * v, v, [np.ones(3, dtype=bool)])


def test_combining_the_estimates() -> None:
    a = SasZeroSource("circle pairs", math.radians(0.80), math.radians(0.02), 8)
    b = SasZeroSource("straight runs", math.radians(0.81), math.radians(0.02), 300)
    z = combine_sas_zero([a, None, b])
    assert z.offset_deg == pytest.approx(0.805, abs=1e-9) and not z.warnings
    assert z.u95_deg == pytest.approx(1.96 * 0.02 / math.sqrt(2), rel=1e-3)
    far = SasZeroSource("straight runs", math.radians(1.3), math.radians(0.02), 300)
    z2 = combine_sas_zero([a, far])
    assert z2.warnings and "disagree" in z2.warnings[0] and z2.u95_deg > 0.3  # widened by the Birge ratio
    # a quantised steady angle does not average below its resolution
    exact = SasZeroSource("straight runs", math.radians(0.8), 0.0, 300)
    z3 = combine_sas_zero([exact], resolution_rad=math.radians(0.1))
    assert z3.u95_deg == pytest.approx(1.96 * 0.1 / math.sqrt(12.0), rel=1e-3)
    with pytest.raises(CalibrationError, match="no estimate"):
        combine_sas_zero([None, None])
    assert z.to_dict()["sources"][0]["method"] == "circle pairs"  # type: ignore[index]


def test_applying_the_zero_and_flagging_uncertain_rows() -> None:
    """The zero leaves every row; a row whose ratio is uncertain beyond 1 % (95 %) is flagged, not a result."""
    gear = SteeringGear(PARAMS)
    c = math.radians(1.5)
    rows = []
    for x in (-65.0, 65.0, 260.0):
        s_true = math.radians(x)
        rows.append(_row(s_true + c, float(gear.road_wheel_angle(s_true)), Direction.FORWARD))
    # a short hold at 65°: the radius is poorly determined (δ ± 0.6 %, 1σ)
    d = float(gear.road_wheel_angle(math.radians(65.0)))
    rows.append(_row(math.radians(65.0) + c, d, Direction.REVERSE, delta_se=0.006 * d, duration_s=8.0))
    table = SteeringRatioTable(PARAMS.wheelbase_m, tuple(rows))
    raw_errors = [abs(r.ratio / ((r.swa_rad - c) / r.delta_rad) - 1.0) for r in rows[:2]]
    assert min(raw_errors) > 0.02  # 1.5° at ±65°: 2.3 % off before the zero is removed
    zero = combine_sas_zero([sas_zero_from_circle_pairs(rows)])
    out = apply_sas_zero(table, zero)
    assert [r.direction for r in out.flagged] == [Direction.REVERSE] and len(out.rows) == 3
    assert any("too uncertain for a 1 % row" in w and "8 s hold" in w for w in out.warnings)
    for r, x in zip(out.rows, (-65.0, 65.0, 260.0), strict=True):
        assert r.swa_deg == pytest.approx(x, abs=0.01)  # the true angle again
        assert r.ratio == pytest.approx(float(r.swa_rad / gear.road_wheel_angle(r.swa_rad)), rel=1e-3)
        assert r.swa_zero_removed_rad == pytest.approx(zero.offset_rad) and r.ratio_u95 < 0.01
    again = SteeringRatioTable.from_dict(out.to_dict())
    assert len(again.flagged) == 1 and again.rows[0].ratio_u95 == pytest.approx(out.rows[0].ratio_u95)
    assert out.to_dict()["sas_zero"]["offset_deg"] == pytest.approx(1.5, abs=0.01)  # type: ignore[index]
