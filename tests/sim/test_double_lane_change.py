"""ISO 3888-1 double lane change at 50 km/h: the car's body stays inside every coned lane."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.vehicle import GroundTruth, VehicleParams, iso3888_1_course, make_scenario, simulate
from tests.sim.helpers import PhaseInfo, phase

PARAMS = VehicleParams()


@pytest.fixture(scope="module", params=["left", "right"])
def run(request: pytest.FixtureRequest) -> tuple[str, GroundTruth, PhaseInfo]:
    truth = simulate(make_scenario("double_lane_change", speed_kmh=50.0, turn=request.param), PARAMS)
    return request.param, truth, phase(truth, "double_lane_change")


def _course_frame(truth: GroundTruth, ph: PhaseInfo) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    sel = ph.mask(truth)
    yaw0 = ph.number("course_yaw_rad")
    c, s = math.cos(yaw0), math.sin(yaw0)
    de = truth.east[sel] - ph.number("course_east_m")
    dn = truth.north[sel] - ph.number("course_north_m")
    return c * de + s * dn, -s * de + c * dn, truth.yaw[sel] - yaw0, sel


def test_speed_is_50_kmh(run: tuple[str, GroundTruth, PhaseInfo]) -> None:
    _, truth, ph = run
    np.testing.assert_allclose(truth.speed[ph.mask(truth)] * 3.6, 50.0, atol=0.5)


def test_path_error_bounded(run: tuple[str, GroundTruth, PhaseInfo]) -> None:
    turn, truth, ph = run
    course = iso3888_1_course(PARAMS.body_width_m, turn=1 if turn == "left" else -1)
    x, y, _, _ = _course_frame(truth, ph)
    assert x[-1] > course.sections[-1][1]  # drove past the last gate
    assert np.max(np.abs(y - course.reference_y(x))) < 0.15


def test_body_inside_every_lane(run: tuple[str, GroundTruth, PhaseInfo]) -> None:
    """Every body corner (width × length with overhangs) stays between the cone lines of sections 1, 3, 5."""
    turn, truth, ph = run
    course = iso3888_1_course(PARAMS.body_width_m, turn=1 if turn == "left" else -1)
    x, y, yaw, _ = _course_frame(truth, ph)
    p = PARAMS
    front = p.cg_to_front_axle_m + p.front_overhang_m
    rear = -(p.cg_to_rear_axle_m + p.rear_overhang_m)
    half = 0.5 * p.body_width_m
    c, s = np.cos(yaw), np.sin(yaw)
    corners_x = np.stack([x + c * bx - s * by for bx in (front, rear) for by in (half, -half)])
    corners_y = np.stack([y + s * bx + c * by for bx in (front, rear) for by in (half, -half)])
    for x_start, x_end, y_centre, width in course.sections:
        inside = (corners_x >= x_start) & (corners_x <= x_end)
        assert inside.any()
        lo, hi = y_centre - 0.5 * width, y_centre + 0.5 * width
        assert np.all(corners_y[inside] > lo), f"{turn}: hit a cone at y = {lo:.2f} m in [{x_start}, {x_end}] m"
        assert np.all(corners_y[inside] < hi), f"{turn}: hit a cone at y = {hi:.2f} m in [{x_start}, {x_end}] m"


def test_course_dimensions_follow_iso_3888_1() -> None:
    w = 1.8
    course = iso3888_1_course(w)
    (x1, x2, y1, w1), (x3, x4, y3, w3), (x5, x6, y5, w5) = course.sections
    assert (x2 - x1, x3 - x2, x4 - x3, x5 - x4, x6 - x5) == pytest.approx((15.0, 30.0, 25.0, 25.0, 15.0))
    assert (w1, w3, w5) == pytest.approx((1.1 * w + 0.25, 1.2 * w + 0.25, 1.3 * w + 0.25))
    # Offset 3.5 m between the right-hand cone lines of sections 1 and 3; sections 1 and 5 share theirs.
    assert (y3 - 0.5 * w3) - (y1 - 0.5 * w1) == pytest.approx(3.5)
    assert (y5 - 0.5 * w5) == pytest.approx(y1 - 0.5 * w1)
