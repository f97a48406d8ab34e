"""GNSS and optical reference sideslip against ground truth (sign conventions, masks, accuracy, coverage)."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from rig.analysis.reference import (
    AntennaGeometry,
    GnssEpochs,
    ImuSeries,
    InvalidReason,
    ReferenceMethod,
    cross_check,
    optical_sideslip,
    reference_sideslip,
    resample_mean,
    tyre_slip_angles,
    vehicle_points,
)
from sim_devices.vehicle import GroundTruth, VehicleParams
from tests.analysis.obs import (
    A_XY,
    B_XY,
    BASELINE_M,
    ImuNoise,
    RtkNoise,
    gnss_spec_for,
    observe_reference_inputs,
)
from vsccore.errors import AnalysisError

CAR = VehicleParams()
POINTS = vehicle_points(
    CAR.cg_to_front_axle_m, CAR.cg_to_rear_axle_m, CAR.track_front_m, CAR.track_rear_m, extra={"optical": (1.8, 0.3)}
)


def _exact_epochs(truth: GroundTruth, mount_offset: float = 0.0) -> tuple[GnssEpochs, ImuSeries, np.ndarray]:
    idx = np.arange(0, len(truth), max(1, int(round(0.05 / truth.dt))))
    ea, na, ua = truth.point_enu(*A_XY, 1.0)
    eb, nb, ub = truth.point_enu(*B_XY, 1.0)
    # a baseline turned clockwise by the mounting offset (about A)
    c, s = math.cos(-mount_offset), math.sin(-mount_offset)
    de, dn = eb - ea, nb - na
    eb2, nb2 = ea + c * de - s * dn, na + s * de + c * dn
    ve, vn = truth.point_velocity_enu(*A_XY)
    g = GnssEpochs.from_enu(
        truth.t[idx], (ea[idx], na[idx], ua[idx]), (eb2[idx], nb2[idx], ub[idx]), (ve[idx], vn[idx])
    )
    step = max(1, int(round(0.01 / truth.dt)))
    imu = ImuSeries(truth.t[::step], truth.yaw_rate[::step], truth.ay_meas[::step])
    return g, imu, idx


def test_baseline_azimuth_and_course_signs() -> None:
    # A north-east of B: baseline azimuth 45°; moving east: course 90°; β = 45 − 90 = −45° (velocity right of x)
    g = GnssEpochs.from_enu([0.0], ([1.0], [1.0], [0.0]), ([0.0], [0.0], [0.0]), ([10.0], [0.0]))
    assert math.degrees(g.baseline_azimuth[0]) == pytest.approx(45.0)
    assert g.baseline_length[0] == pytest.approx(math.sqrt(2.0))
    imu = ImuSeries(np.array([-0.01, 0.01]), np.zeros(2))
    geom = AntennaGeometry(a_xy=(0.0, 0.0), baseline_length_m=math.sqrt(2.0))
    ref = reference_sideslip(g, imu, geom, method="raw")
    assert math.degrees(ref.beta[0]) == pytest.approx(-45.0)
    assert math.degrees(ref.heading[0]) == pytest.approx(45.0)


def test_geodetic_baseline_matches_enu() -> None:
    lat0, lon0, h0 = 48.7758, 9.1829, 300.0
    az = math.radians(250.0)
    # A 1.58 m from B at azimuth 250°, 5 km away from the origin (meridian convergence must not matter)
    e_b, n_b = 3000.0, 4000.0
    lat_b, lon_b, h_b = pymap3d.enu2geodetic(e_b, n_b, 0.0, lat0, lon0, h0)
    lat_a, lon_a, h_a = pymap3d.enu2geodetic(
        BASELINE_M * math.sin(az), BASELINE_M * math.cos(az), 0.0, lat_b, lon_b, h_b
    )
    g = GnssEpochs.from_geodetic(
        [0.0], ([lat_a], [lon_a], [h_a]), ([lat_b], [lon_b], [h_b]), [math.radians(100.0)], [12.0]
    )
    assert g.baseline_azimuth[0] == pytest.approx(az, abs=1e-7)
    assert g.baseline_length[0] == pytest.approx(BASELINE_M, abs=1e-6)
    assert math.degrees(math.atan2(g.velocity_east[0], g.velocity_north[0])) == pytest.approx(100.0)


@pytest.mark.parametrize("method", list(ReferenceMethod))
def test_noise_free_reference_is_exact(circle: GroundTruth, method: ReferenceMethod) -> None:
    offset = math.radians(1.5)
    g, imu, idx = _exact_epochs(circle, mount_offset=offset)
    geom = AntennaGeometry(a_xy=A_XY, baseline_length_m=BASELINE_M, mount_offset_rad=offset)
    ref = reference_sideslip(g, imu, geom, method=method, points=POINTS)
    ok = ref.valid
    assert ref.method is method
    assert ok.all()  # above the minimum speed, fixed, right length throughout
    tol = math.radians(0.002) if method is ReferenceMethod.RAW else math.radians(0.02)
    if method is ReferenceMethod.RTS:
        # the simulated circle starts with a step of the steering (β from 0 to 1.4° in 0.2 s): the smoother
        # lags that edge by up to 0.06° in the first epochs
        ok = ok & (ref.t > 0.5)
    np.testing.assert_allclose(ref.beta[ok], circle.beta_cg[idx][ok], atol=tol)
    for name, xy in POINTS.items():
        np.testing.assert_allclose(ref.points[name][ok], circle.point_sideslip(*xy)[idx][ok], atol=tol)
    # sideslip grows rearwards on a left-hand circle (rear axle more to the right of its velocity)
    assert np.all(ref.points["rear_axle"][ok][-50:] < ref.points["front_axle"][ok][-50:])


def test_tyre_slip_angles(circle: GroundTruth) -> None:
    g, imu, idx = _exact_epochs(circle)
    ref = reference_sideslip(g, imu, AntennaGeometry(A_XY, BASELINE_M), method="raw", points=POINTS)
    delta = circle.road_wheel_angle[idx]
    alpha = tyre_slip_angles(ref, {"fl": delta, "fr": delta, "front_axle": delta})
    vx, vy, r = circle.vx[idx], circle.vy[idx], circle.yaw_rate[idx]
    a, b = CAR.cg_to_front_axle_m, CAR.cg_to_rear_axle_m
    alpha_front = np.arctan2(vy + a * r, vx) - delta  # single-track definition at the axle centre
    alpha_rear = np.arctan2(vy - b * r, vx)
    ok = ref.valid
    np.testing.assert_allclose(alpha["front_axle"][ok], alpha_front[ok], atol=1e-6)
    np.testing.assert_allclose(alpha["rear_axle"][ok], alpha_rear[ok], atol=1e-6)
    # steady left turn: the front tyres slip to the right of their plane (α < 0, force to the left)
    assert np.all(alpha["front_axle"][ok][-50:] < 0.0) and np.all(alpha["rl"][ok][-50:] < 0.0)


def test_invalid_masks() -> None:
    n = 10
    t = np.arange(n) * 0.05
    speed = np.full(n, 10.0)
    speed[1] = 1.0
    length = np.full(n, BASELINE_M)
    length[3] = BASELINE_M + 0.2
    az = np.full(n, 0.3)
    az[4] = np.nan
    fixed_a = np.ones(n, bool)
    fixed_a[5] = False
    fixed_b = np.ones(n, bool)
    fixed_b[6] = False
    g = GnssEpochs(t, az, length, speed * math.sin(0.3), speed * math.cos(0.3), fixed_a, fixed_b)  # type: ignore[arg-type]
    t_imu = np.arange(-0.1, 0.6, 0.01)
    r = np.zeros(t_imu.size)
    r[(t_imu > 0.33) & (t_imu < 0.37)] = np.nan  # epoch 7 (0.35 s) has no yaw rate within 0.02 s
    geom = AntennaGeometry(A_XY, BASELINE_M)
    ref = reference_sideslip(g, ImuSeries(t_imu, r), geom, method="raw", max_imu_gap_s=0.02)
    expected = {
        1: InvalidReason.LOW_SPEED,
        3: InvalidReason.BASELINE_LENGTH,
        4: InvalidReason.NO_DATA,
        5: InvalidReason.A_NOT_FIXED,
        6: InvalidReason.B_NOT_FIXED,
        7: InvalidReason.NO_YAW_RATE,
    }
    for i in range(n):
        assert ref.reasons[i] == int(expected.get(i, 0)), i
        assert ref.valid[i] == (i not in expected)
        assert np.isnan(ref.beta[i]) == (i in expected)
    assert ref.reason_counts()["LOW_SPEED"] == 1
    assert ref.to_dict()["valid_fraction"] == pytest.approx(0.4)
    with pytest.raises(AnalysisError, match="no valid epoch"):
        reference_sideslip(g, ImuSeries(t_imu, r), AntennaGeometry(A_XY, BASELINE_M), min_speed_mps=100.0)
    with pytest.raises(AnalysisError, match="unknown reference method"):
        reference_sideslip(g, ImuSeries(t_imu, r), AntennaGeometry(A_XY, BASELINE_M), method="kalman")


def _score(truth: GroundTruth, noise: RtkNoise, seeds: range) -> dict[str, tuple[float, float]]:
    """RMS error (deg) at the CG and fraction of epochs whose stated 95 % uncertainty covers the truth."""
    geom = AntennaGeometry(A_XY, BASELINE_M)
    spec = gnss_spec_for(noise)
    errs: dict[str, list[np.ndarray]] = {m.value: [] for m in ReferenceMethod}
    covered: dict[str, list[np.ndarray]] = {m.value: [] for m in ReferenceMethod}
    for seed in seeds:
        g, imu, idx = observe_reference_inputs(truth, noise=noise, imu_noise=ImuNoise(), seed=seed)
        beta_true = truth.beta_cg[idx]
        for m in ReferenceMethod:
            ref = reference_sideslip(g, imu, geom, method=m, gnss_spec=spec)
            e = (ref.beta - beta_true)[ref.valid]
            errs[m.value].append(e)
            covered[m.value].append(np.abs(e) <= ref.u95[ref.valid])
    out: dict[str, tuple[float, float]] = {}
    for name in errs:
        e = np.concatenate(errs[name])
        out[name] = (math.degrees(float(np.sqrt(np.mean(e**2)))), float(np.mean(np.concatenate(covered[name]))))
    lines = [f"{m}: {v[0]:.4f}°, {v[1]:.3f}" for m, v in out.items()]
    print("\n  ".join(["method: RMS error at the CG, 95 % coverage", *lines]))
    return out


def test_dlc_reference_meets_005_deg_with_honest_coverage(dlc: GroundTruth) -> None:
    """Issue 9: DLC at 50 km/h, 1.58 m baseline, RTK-level noise (tests/calibration/observe.py).

    The RTS smoother's β at the CG is within 0.05° RMS of the truth and its stated 95 % band
    covers the truth at ≥ 95 % of the epochs (10 noise realisations).
    """
    out = _score(dlc, RtkNoise(), range(10))
    rms_rts, cov_rts = out["rts"]
    assert rms_rts < 0.05
    assert cov_rts >= 0.95
    assert out["raw"][0] > 3 * rms_rts  # the fusion is what gets there
    assert out["raw"][1] >= 0.93  # the raw σ from the specs is right
    assert out["wavelet"][0] < out["raw"][0]


def test_dlc_reference_with_correlated_baseline_noise(dlc: GroundTruth) -> None:
    """Pessimistic: 5 mm per antenna and axis not common to both, correlated over 1 s.

    The raw heading noise is then ≈ 0.25° and changes slowly, so fewer independent samples exist
    over the 14 s run; the smoother is less accurate but says so (coverage stays ≥ 95 %).
    """
    noise = RtkNoise(relative_sigma_m=0.005, relative_tau_s=1.0, velocity_sigma_mps=0.03)
    out = _score(dlc, noise, range(8))
    rms_rts, cov_rts = out["rts"]
    assert rms_rts < 0.15
    assert out["raw"][0] > 2 * rms_rts
    assert cov_rts >= 0.95


def test_optical_reference_and_cross_check(dlc: GroundTruth) -> None:
    xy = (1.8, 0.3)
    zero = math.radians(0.7)
    vx, vy = dlc.point_velocity(*xy)
    # the sensor head is turned by the zero offset: it reports the slip angle plus the zero
    c, s = math.cos(zero), math.sin(zero)
    vx_m, vy_m = c * vx - s * vy, s * vx + c * vy
    opt = optical_sideslip(dlc.t, vx_m, vy_m, dlc.yaw_rate, xy, zero_rad=zero)
    np.testing.assert_allclose(opt.beta, dlc.beta_cg, atol=1e-9)
    # onto the GNSS epochs by block averaging, then cross-checked against an exact GNSS reference
    g, imu, idx = _exact_epochs(dlc)
    ref = reference_sideslip(g, imu, AntennaGeometry(A_XY, BASELINE_M), method="raw")
    beta_opt = resample_mean(dlc.t, opt.beta, ref.t)
    assert np.nanmax(np.abs(beta_opt - dlc.beta_cg[idx])) < math.radians(0.01)
    bad = beta_opt.copy()
    bad[(ref.t > 8.0) & (ref.t < 9.0)] += math.radians(1.0)  # a 1 s disagreement
    sig = np.full(ref.t.size, math.radians(0.1))
    cc = cross_check(ref.t, ref.beta, sig, bad, sig)
    assert len(cc.segments) == 1
    assert cc.segments[0][0] == pytest.approx(8.05, abs=0.06) and cc.segments[0][1] == pytest.approx(8.95, abs=0.06)
    assert cc.fraction_disagree == pytest.approx(19 / np.count_nonzero(ref.valid), abs=2 / ref.t.size)
    assert cc.to_dict()["max_abs_diff_deg"] == pytest.approx(1.0, abs=0.02)


def test_tyre_slip_angles_on_the_noisy_dlc(dlc: GroundTruth) -> None:
    """α at the rear wheels and the front axle from the RTS reference, against the simulator's wheel kinematics."""
    gnss, imu, idx = observe_reference_inputs(dlc, seed=21)
    ref = reference_sideslip(gnss, imu, AntennaGeometry(A_XY, BASELINE_M), gnss_spec=gnss_spec_for(RtkNoise()),
                             points=POINTS)
    delta = dlc.road_wheel_angle[idx]
    alpha = tyre_slip_angles(ref, {"front_axle": delta, "fl": delta, "fr": delta})
    ok = ref.valid
    for name in ("rl", "rr", "front_axle"):
        x, y = POINTS[name]
        truth = dlc.point_sideslip(x, y)[idx] - (delta if name == "front_axle" else 0.0)
        rms = math.degrees(float(np.sqrt(np.mean((alpha[name][ok] - truth[ok]) ** 2))))
        assert rms < 0.05, (name, rms)
