"""Straight-run detection and its "what was missing" diagnosis, on kinematic drives with GNSS-like noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.segments import (
    Direction,
    StraightCriterion,
    diagnose_straight_segments,
    find_constant_swa_segments,
    find_straight_segments,
)
from tests.calibration.synth import straight_drive
from vsccore.errors import CalibrationError


def _true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate(([0], mask.astype(int), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def test_straights_found_where_the_car_drives_straight() -> None:
    d = straight_drive(offset_rad=0.0, rng=np.random.default_rng(1), courses_deg=(80.0, 260.0, 170.0), straight_s=8.0)
    segs = find_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed)
    truth = _true_runs(d.straight_mask)
    assert len(segs) == len(truth) == 3
    for seg, (i, j), course in zip(segs, truth, (80.0, 260.0, 170.0), strict=True):
        # the turn ramps reach 0.5 °/s within a sample of the straight's ends
        assert abs(seg.start_index - i) <= 1 and abs(seg.stop_index - j) <= 1
        assert seg.duration_s == pytest.approx(8.0, abs=0.1)
        assert math.degrees(seg.course_rad) == pytest.approx(course, abs=0.2)
        assert seg.mean_speed_mps * 3.6 == pytest.approx(40.0, abs=0.2)
        assert np.count_nonzero(seg.mask(d.t)) == seg.n_samples
    assert segs[0].to_dict()["mean_speed_kmh"] == pytest.approx(40.0, abs=0.2)


def test_missing_duration_is_explained() -> None:
    d = straight_drive(
        offset_rad=0.0, rng=np.random.default_rng(2), courses_deg=(10.0, 190.0), straight_s=3.2, speed_mps=31.0 / 3.6
    )
    diag = diagnose_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed)
    assert diag.n_segments == 0
    assert diag.longest_duration_s == pytest.approx(3.2, abs=0.06)
    assert diag.limiting is StraightCriterion.DURATION
    assert "longest straight segment 3.2 s at 31 km/h" in diag.message
    assert "need 5.0 s at > 25 km/h" in diag.message
    with pytest.raises(CalibrationError, match=r"longest straight segment 3\.2 s at 31 km/h; need 5\.0 s"):
        find_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed)
    # with a 3 s minimum the same drive is usable
    assert len(find_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed, min_duration_s=3.0)) == 2


def test_speed_and_rtk_fix_limits_are_named() -> None:
    slow = straight_drive(offset_rad=0.0, rng=np.random.default_rng(3), speed_mps=20.0 / 3.6, straight_s=7.0)
    diag = diagnose_straight_segments(slow.t, slow.speed, slow.yaw_rate, slow.course, slow.rtk_fixed)
    assert diag.limiting is StraightCriterion.SPEED
    assert dict(diag.failing_fraction)[StraightCriterion.SPEED] == pytest.approx(1.0)
    assert dict(diag.longest_without)[StraightCriterion.SPEED] == pytest.approx(7.0, abs=0.1)
    assert "Most limiting: speed" in diag.message
    # a float solution in the middle of each straight leaves two 3.5 s halves
    d = straight_drive(offset_rad=0.0, rng=np.random.default_rng(3), straight_s=8.0)
    fixed = d.rtk_fixed.copy()
    for i, j in _true_runs(d.straight_mask):
        fixed[(i + j) // 2 - 10 : (i + j) // 2 + 10] = False
    diag = diagnose_straight_segments(d.t, d.speed, d.yaw_rate, d.course, fixed)
    assert diag.n_segments == 0 and diag.limiting is StraightCriterion.RTK_FIXED
    assert diag.to_dict()["limiting"] == "RTK fixed"


def test_slow_curve_is_cut_by_course_stability() -> None:
    """A 0.3 °/s curve passes the yaw-rate test; the course spread within a piece stays below 0.5°."""
    rate_hz, n = 20.0, 600
    t = np.arange(n) / rate_hz
    course = np.radians(30.0 + 0.3 * t)
    segs = find_straight_segments(t, np.full(n, 15.0), np.full(n, math.radians(0.3)), course, np.ones(n, bool))
    assert len(segs) >= 2
    for s in segs:
        assert s.course_std_rad <= math.radians(0.5) + 1e-12
        assert s.duration_s >= 5.0
    # a gap in the time stamps breaks a run
    t2 = t.copy()
    t2[300:] += 2.0
    segs2 = find_straight_segments(t2, np.full(n, 15.0), np.zeros(n), np.full(n, 0.5), np.ones(n, bool))
    assert [(s.start_index, s.stop_index) for s in segs2] == [(0, 300), (300, 600)]


def test_course_wraps_through_north() -> None:
    n = 200
    t = np.arange(n) * 0.05
    course = np.mod(np.radians(np.where(np.arange(n) % 2 == 0, 359.9, 0.1)), 2 * np.pi)
    segs = find_straight_segments(t, np.full(n, 12.0), np.zeros(n), course, np.ones(n, bool))
    assert len(segs) == 1 and segs[0].n_samples == n
    assert min(math.degrees(segs[0].course_rad), 360 - math.degrees(segs[0].course_rad)) < 0.01


def test_bad_inputs() -> None:
    t = np.arange(10) * 0.05
    with pytest.raises(CalibrationError, match="not strictly increasing"):
        find_straight_segments(t[::-1], np.ones(10), np.zeros(10), np.zeros(10), np.ones(10, bool))
    with pytest.raises(CalibrationError, match="speed_mps: length 9"):
        find_straight_segments(t, np.ones(9), np.zeros(10), np.zeros(10), np.ones(10, bool))
    with pytest.raises(CalibrationError, match="min_duration_s must be positive"):
        find_straight_segments(t, np.ones(10), np.zeros(10), np.zeros(10), np.ones(10, bool), min_duration_s=0.0)


def test_constant_swa_segments_split_by_angle_and_direction() -> None:
    rate = 10.0
    t = np.arange(0, 60, 1 / rate)
    swa = np.where(t < 20, math.radians(90.0), np.where(t < 22, np.radians(90 + 60 * (t - 20)), math.radians(210.0)))
    v = np.where(t < 40, 1.4, -1.4)
    v[(t > 39.5) & (t < 40.5)] = 0.0  # stop to change direction
    segs = find_constant_swa_segments(t, swa, v, min_duration_s=10.0)
    got = [(s.direction, round(math.degrees(s.swa_rad))) for s in segs]
    assert got == [(Direction.FORWARD, 90), (Direction.FORWARD, 210), (Direction.REVERSE, 210)]
    # the ramp (20–22 s) and the stop (39.5–40.5 s) are left out; duration counts whole sample periods
    np.testing.assert_allclose([s.duration_s for s in segs], [20.1, 17.5, 19.5], atol=0.15)
    # with the yaw rate given, a shorter run that turned through most of a circle also counts
    r = np.full(t.size, 1.4 / 5.0)  # 5 m radius: a full turn in 22 s
    segs_r = find_constant_swa_segments(t, swa, v, yaw_rate_rps=r, min_duration_s=30.0, min_turn_rad=math.radians(270))
    assert [s.direction for s in segs_r] == [Direction.FORWARD, Direction.FORWARD, Direction.REVERSE]
    assert segs_r[0].turn_rad == pytest.approx(segs_r[0].duration_s * 1.4 / 5.0, rel=1e-9)
    assert find_constant_swa_segments(t, swa, v, yaw_rate_rps=r, min_duration_s=30.0, min_turn_rad=6.0) == []
