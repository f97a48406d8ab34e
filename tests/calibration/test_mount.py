"""Mounting offset, baseline-length check and optical zero from straight runs, against the simulator and geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.mount import (
    apply_mount_offset,
    apply_optical_zero,
    calibrate_mount_offset,
    check_baseline_length,
    estimate_mount_offset,
    estimate_optical_zero,
    length_reference,
)
from calibration.segments import Segment, find_straight_segments
from sim_devices.vehicle import Drive, GroundTruth, make_scenario, simulate
from tests.calibration.observe import BASELINE_M, observe
from tests.calibration.synth import straight_drive
from vsccore.errors import CalibrationError

OFFSET = math.radians(1.3)


@pytest.fixture(scope="module")
def two_straights() -> GroundTruth:
    """Two straight runs at 40 km/h, course 80° and 260°.

    Each scenario lasts 6 s so that, after the simulated driver has settled from the U-turn
    (yaw rate below the 0.5 °/s threshold), at least 5 s of each qualifies as straight.
    """
    drive = Drive(
        [
            make_scenario("straight", speed_kmh=40.0, duration_s=6.0, heading_deg=80.0),
            make_scenario("straight", speed_kmh=40.0, duration_s=6.0, heading_deg=260.0),
        ],
        gap_s=2.0,
    )
    return simulate(drive, rate_hz=100.0)


def test_offset_recovered_within_002_deg_from_two_opposite_runs(two_straights: GroundTruth) -> None:
    """Issue 8: an injected mounting offset comes back within 0.02° from two ≥ 5 s runs (12 noise realisations).

    Noise (tests.calibration.observe.RtkNoise): each antenna 2 mm per horizontal axis of its own, white,
    so the A − B difference has 2.8 mm per axis, i.e. 0.10° of baseline heading per epoch at 1.58 m.
    That is RTK-level for the *relative* error: dual-antenna receivers specify about 0.08° RMS heading at
    2 m separation (2.8 mm across the baseline). On top, 1 cm per axis common to both antennas
    (Gauss–Markov, τ = 30 s), which cancels in the baseline, and Doppler velocity noise of 1.5 cm/s per
    axis (0.08° of course at 40 km/h). The relative error is white here; when it wanders slowly (the
    simulator's default: 70 % Gauss–Markov with τ = 1 s, 3.35 mm per axis) two 5 s runs cannot give
    0.02° (RMS error ≈ 0.03–0.04°) and the stated interval says so (test_coverage).
    """
    errors, covered, half_widths = [], [], []
    for seed in range(12):
        obs = observe(two_straights, mount_offset_rad=OFFSET, seed=seed)
        segs = find_straight_segments(obs.t, obs.speed, obs.yaw_rate, obs.course, obs.rtk_fixed)
        assert len(segs) == 2 and all(s.duration_s >= 5.0 for s in segs)
        res = estimate_mount_offset(segs, obs.t, obs.heading, obs.course, obs.baseline_length, BASELINE_M,
                                    rtk_fixed_mask=obs.rtk_fixed)
        est = res.estimate
        errors.append(math.degrees(res.offset_rad - OFFSET))
        covered.append(est.ci_low_rad <= OFFSET <= est.ci_high_rad)
        half_widths.append(math.degrees(est.ci_high_rad - est.offset_rad))
        assert res.baseline.ok and not res.warnings
        assert "antenna baseline length" in est.uncertainty_method
    err = np.abs(errors)
    print(f"offset error: RMS {math.sqrt(np.mean(err**2)):.4f}°, max {err.max():.4f}°; "
          f"95 % half width median {np.median(half_widths):.4f}°; coverage {np.mean(covered):.2f}")
    assert math.sqrt(np.mean(err**2)) < 0.01
    assert np.count_nonzero(err < 0.02) >= 11
    assert np.mean(covered) >= 10 / 12
    assert np.median(half_widths) < 0.03


def test_segment_report_and_groups(two_straights: GroundTruth) -> None:
    obs = observe(two_straights, mount_offset_rad=OFFSET, seed=99)
    segs = find_straight_segments(obs.t, obs.speed, obs.yaw_rate, obs.course, obs.rtk_fixed)
    res = estimate_mount_offset(segs, obs.t, obs.heading, obs.course, obs.baseline_length, BASELINE_M)
    est = res.estimate
    assert [round(math.degrees(s.course_rad)) for s in est.segments] == [80, 260]
    assert [round(math.degrees(g.course_rad)) for g in est.groups] == [80, 260]
    for s in est.segments:
        assert s.mean_speed_mps * 3.6 == pytest.approx(40.0, abs=0.3)
        assert s.ci_low_rad < s.offset_rad < s.ci_high_rad
        assert math.degrees(abs(s.offset_rad - OFFSET)) < 0.05
    assert "direction-balanced" in est.method
    d = res.to_dict()
    assert d["offset_deg"] == pytest.approx(1.3, abs=0.03)
    assert len(res.estimate.segments) == 2 and d["baseline"]["ok"] is True  # type: ignore[index]
    # the vehicle heading from the baseline: truth within the noise
    heading = apply_mount_offset(obs.heading, res.offset_rad)
    true_az = np.mod(np.pi / 2 - two_straights.yaw[obs.idx], 2 * np.pi)
    dev = np.degrees(np.angle(np.exp(1j * (heading - true_az))))
    assert np.sqrt(np.mean(dev**2)) < 0.25


def test_cross_wind_cancels_and_is_flagged() -> None:
    """A cross wind gives β = +0.3° one way and −0.3° the other: the balanced mean cancels it and warns."""
    rng = np.random.default_rng(5)
    d = straight_drive(
        offset_rad=OFFSET, rng=rng, courses_deg=(80.0, 260.0), straight_s=8.0, pos_sigma_m=0.002, tau_s=0.05,
        vel_sigma_mps=0.01, beta_on_straights=(math.radians(0.3), math.radians(-0.3)),
    )
    segs = find_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed)
    res = estimate_mount_offset(segs, d.t, d.heading, d.course, d.baseline_length, BASELINE_M)
    assert math.degrees(abs(res.offset_rad - OFFSET)) < 0.02
    g80, g260 = res.estimate.groups
    # heading − course = offset + β
    assert math.degrees(g80.offset_rad - OFFSET) == pytest.approx(0.3, abs=0.03)
    assert math.degrees(g260.offset_rad - OFFSET) == pytest.approx(-0.3, abs=0.03)
    assert any("opposite directions disagree" in w for w in res.warnings)


def test_one_direction_and_several_runs_per_direction() -> None:
    rng = np.random.default_rng(6)
    d = straight_drive(offset_rad=-OFFSET, rng=rng, courses_deg=(10.0, 60.0, 20.0), straight_s=6.0)
    segs = find_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed)
    res = estimate_mount_offset(segs, d.t, d.heading, d.course, d.baseline_length, BASELINE_M)
    # 10°, 60° and 20° are all within ±90° of the longest run: one group, with a warning
    assert len(res.estimate.groups) == 1 and res.estimate.groups[0].n_segments == 3
    assert any("one direction" in w for w in res.warnings)
    assert res.estimate.ci_low_rad <= -OFFSET <= res.estimate.ci_high_rad


def test_baseline_length_check() -> None:
    rng = np.random.default_rng(7)
    d = straight_drive(offset_rad=0.0, rng=rng, baseline_m=1.63)  # configured 1.58 m, truly 1.63 m
    segs = find_straight_segments(d.t, d.speed, d.yaw_rate, d.course, d.rtk_fixed)
    res = estimate_mount_offset(segs, d.t, d.heading, d.course, d.baseline_length, BASELINE_M)
    assert not res.baseline.ok
    assert res.baseline.mean_m == pytest.approx(1.63, abs=0.005)
    assert res.baseline.std_m == pytest.approx(0.01 * math.sqrt(2), rel=0.3)
    assert any("differs from the configured 1.580 m" in w for w in res.warnings)
    # right length, but a few epochs with a wrong fix (decimetre jumps)
    length = d.baseline_length - 0.05
    length[segs[0].start_index + 10 : segs[0].start_index + 14] += 0.3
    chk = check_baseline_length(segs, d.t, length, BASELINE_M)
    assert chk.ok and chk.n_gross == 4
    res2 = estimate_mount_offset(segs, d.t, d.heading, d.course, length, BASELINE_M)
    assert any("intermittent wrong fix" in w for w in res2.warnings)
    with pytest.raises(CalibrationError, match="nominal baseline length must be positive"):
        check_baseline_length(segs, d.t, length, 0.0)


def test_optical_zero(two_straights: GroundTruth) -> None:
    """A Correvit head turned by 0.8° reads slip 0.8° on a straight; the zero comes back and corrects it."""
    zero = math.radians(0.8)
    xy = (1.8, 0.3)
    rng = np.random.default_rng(8)
    tr = two_straights
    vx, vy = tr.point_velocity(*xy)
    c, s = math.cos(zero), math.sin(zero)
    vx_m = c * vx - s * vy + rng.standard_normal(len(tr)) * 0.02
    vy_m = s * vx + c * vy + rng.standard_normal(len(tr)) * 0.02
    obs = observe(tr, seed=8)
    segs = find_straight_segments(obs.t, obs.speed, obs.yaw_rate, obs.course, obs.rtk_fixed)
    res = estimate_optical_zero(segs, tr.t, vx_m, vy_m, tr.yaw_rate, xy)
    assert math.degrees(abs(res.zero_rad - zero)) < 0.01
    assert res.estimate.ci_low_rad <= zero <= res.estimate.ci_high_rad
    assert res.to_dict()["zero_deg"] == pytest.approx(0.8, abs=0.01)
    vx_c, vy_c = apply_optical_zero(vx_m, vy_m, res.zero_rad)
    m = segs[0].mask(tr.t)
    assert math.degrees(abs(np.mean(np.arctan2(vy_c[m], vx_c[m])))) < 0.01


def test_no_usable_segment_raises() -> None:
    d = straight_drive(offset_rad=0.0, rng=np.random.default_rng(9), straight_s=3.2, speed_mps=31.0 / 3.6)
    with pytest.raises(CalibrationError, match=r"longest straight segment 3\.2 s at 31 km/h; need 5\.0 s at > 25 km/h"):
        calibrate_mount_offset(d.t, d.heading, d.course, d.speed, d.yaw_rate, d.baseline_length, d.rtk_fixed, 1.58)
    res = calibrate_mount_offset(
        d.t, d.heading, d.course, d.speed, d.yaw_rate, d.baseline_length, d.rtk_fixed, 1.58, min_duration_s=3.0
    )
    assert len(res.estimate.segments) == 2
    t = np.arange(100) * 0.05
    with pytest.raises(CalibrationError, match="no straight segments given"):
        estimate_mount_offset([], t, np.zeros(100), np.zeros(100), np.full(100, 1.58), 1.58)


def test_length_reference_stretches() -> None:
    """The noise reference: RTK-fixed, gap-free stretches of at least 1 s without wrong-fix jumps, nearest first."""
    t = np.arange(2000) * 0.05
    rng = np.random.default_rng(12)
    length = 1.58 + 0.003 * rng.standard_normal(t.size)
    fixed = np.ones(t.size, dtype=bool)
    fixed[500:520] = False  # float solution: cut
    length[900:905] += 0.3  # wrong fix: cut
    t[1500:] += 2.0  # time gap: cut
    fixed[1990:] = False  # leaves a 0.5 s stretch at 1980..1989: too short
    segs = [Segment(100, 300, t[100], t[299], 10.0, 11.0, 0.0, 0.001, 200)]
    ref = length_reference(segs, t, length, usable_mask=fixed)
    sizes = [b.size for b in ref.blocks]
    assert sizes == [500, 380, 595, 490]  # nearest to the run first
    assert ref.duration_s == pytest.approx(sum(sizes) * 0.05)
    assert max(abs(float(b.max()) - 1.58) for b in ref.blocks) < 0.05
    capped = length_reference(segs, t, length, usable_mask=fixed, max_samples=600)
    assert [b.size for b in capped.blocks] == [500, 100]  # the cap takes the next stretch in part
    only_runs = length_reference(segs, t, length)
    assert [b.size for b in only_runs.blocks] == [200]
