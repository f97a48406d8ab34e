"""rig.data.inputs against a simulated recording and truth-built sessions (physics and truth as references)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rig.core.config import ImuCalibrationConfig, SessionConfig
from rig.data.inputs import load_inputs
from rig.data.sidefiles import calibration_file_path, read_calibration_file, update_calibration_file
from sim_devices.vehicle import make_scenario
from tests.calib_cli.conftest import TRUE_OFFSET_DEG
from tests.calib_cli.synth import simulate_truth, write_truth_session
from vsccore.angles import wrap_pi, yaw_to_azimuth
from vsccore.errors import AnalysisError, SessionFileError


def test_dual_gnss_on_common_epochs(straights_session: Path) -> None:
    inp = load_inputs(straights_session)
    g = inp.require_gnss()
    assert np.array_equal(g.gps_time_ns, np.unique(g.gps_time_ns))
    assert g.rate_hz == pytest.approx(20.0, rel=1e-6)
    assert g.t_s[0] == 0.0 and inp.t0_ns == int(g.time_ns[0])
    assert g.a.receiver == "rover_a" and g.b.receiver == "rover_b"
    fixed = g.rtk_fixed_both & g.valid
    assert fixed.mean() > 0.8
    # measured antenna separation: the configured 1.58 m within RTK noise (1 mm per rover here)
    assert np.median(g.baseline_length_m[fixed]) == pytest.approx(1.58, abs=0.003)
    # baseline azimuth − true heading = injected mounting offset; course = true course (β = 0 on straights)
    tr = inp.require_truth()
    assert tr.simulated and inp.is_simulated
    yaw = np.interp(g.t_s, tr.t_s, np.unwrap(tr.truth.yaw))
    r = np.interp(g.t_s, tr.t_s, tr.truth.yaw_rate)
    straight = fixed & (np.abs(r) < 1e-4) & (g.speed_mps > 10.0)
    assert straight.sum() > 150
    d = np.degrees(wrap_pi(g.baseline_azimuth_rad - yaw_to_azimuth(yaw)))[straight]
    assert np.mean(d) == pytest.approx(TRUE_OFFSET_DEG, abs=0.02)
    c = np.degrees(wrap_pi(g.course_rad - yaw_to_azimuth(yaw)))[straight]
    assert abs(np.mean(c)) < 0.02
    assert np.mean(g.speed_mps[straight]) == pytest.approx(40.0 / 3.6, abs=0.02)
    # the same epochs as the analysis type
    ep = g.to_epochs()
    assert ep.t.shape == g.t_s.shape and np.array_equal(ep.fixed_a, g.a.rtk_fixed & g.a.solution_ok)


def test_streams_profile_events(straights_session: Path) -> None:
    inp = load_inputs(straights_session)
    for role in ("yaw_rate", "lat_accel", "long_accel", "swa", "wheel_speed_fl", "vsc_beta_estimate"):
        s = inp.signal(role)
        assert len(s) > 100 and s.valid_fraction > 0.9, role
    assert "optical.body" in inp.streams and "gnss.baseline" in inp.streams
    opt = inp.optical_sensor("body")
    assert opt.source == "topic" and opt.kind == "body" and opt.mount_xy_m == (-2.1, 0.0)
    assert opt.zero_applied_rad == 0.0
    assert inp.profile.antennas.baseline_length_m == 1.58
    assert inp.simulation is not None and inp.simulation["true_mount_offset_deg"] == TRUE_OFFSET_DEG
    kinds = {e.kind.value for e in inp.events}
    assert {"session_start", "connect"} <= kinds
    with pytest.raises(AnalysisError, match=r"no CAN role 'nope'.*yaw_rate"):
        inp.signal("nope")
    with pytest.raises(AnalysisError, match="no optical sensor 'front'"):
        inp.optical_sensor("front")


def test_truth_session_times_and_marks(circles_session: Path) -> None:
    inp = load_inputs(circles_session)
    tr = inp.require_truth()
    # CAN frames are put on GPS time through the session's clocks: the yaw rate matches the truth
    r = inp.signal("yaw_rate")
    rt = np.interp(r.t_s, tr.t_s, tr.truth.yaw_rate)
    inside = (r.t_s > 1.0) & (r.t_s < tr.t_s[-1] - 1.0)
    assert np.max(np.abs(r.values - rt)[inside]) < math.radians(0.1)
    swa = inp.signal("swa")
    inside = (swa.t_s > 1.0) & (swa.t_s < tr.t_s[-1] - 1.0)
    # SAS_Angle is inverted (clockwise positive) on the wire; 0.05° quantisation + 0.3 ms receive latency
    # (host-stamped frames) at steering rates up to 360°/s
    assert np.max(np.abs(swa.values - np.interp(swa.t_s, tr.t_s, tr.truth.swa))[inside]) < math.radians(0.2)
    marks = inp.marks
    assert len(marks) == 1 and marks[0].t_s == pytest.approx(2.0, abs=1e-6) and "circles" in marks[0].text
    # the calibration file recorded next to the session is in force
    assert inp.profile.calibration.mount_offset_deg == TRUE_OFFSET_DEG
    assert inp.recorded_calibration.mount_offset_deg == 0.0
    assert any("calibration.json" in s for s in inp.calibration_sources)
    assert not load_inputs(circles_session, use_calibration_file=False).profile.calibration.mount_offset_deg


def test_imu_calibration_applied(circles_session: Path) -> None:
    raw = load_inputs(circles_session, optical=False, truth=False)
    imu = ImuCalibrationConfig(gyro_bias_rps=(0.0, 0.0, 0.01), gyro_matrix=((1, 0, 0), (0, 1, 0), (0, 0, 1.02)),
                               accel_bias_mps2=(0.0, 0.2, 0.0), accel_matrix=((1, 0, 0), (0, 0.98, 0), (0, 0, 1)))
    cor = load_inputs(circles_session, optical=False, truth=False, imu_calibration=imu)
    assert cor.imu_corrected and not raw.imu_corrected
    np.testing.assert_allclose(cor.signal("yaw_rate").values, (raw.signal("yaw_rate").values - 0.01) / 1.02)
    np.testing.assert_allclose(cor.signal("lat_accel").values, (raw.signal("lat_accel").values - 0.2) / 0.98)
    np.testing.assert_array_equal(cor.signal("swa").values, raw.signal("swa").values)


def test_calibration_file_round_trip(tmp_path: Path, sim_cfg: SessionConfig) -> None:
    truth = simulate_truth(sim_cfg, make_scenario("straight", speed_kmh=30.0, duration_s=2.0))
    base = write_truth_session(tmp_path, "cf", sim_cfg, truth, offset_deg=0.0, can_roles=False)
    assert read_calibration_file(base) == {}
    p = update_calibration_file(base, "optical_zero", {"body": {"zero_deg": 0.3, "u95_deg": 0.01}})
    assert p == calibration_file_path(base.with_name("cf.000.mcap")) == tmp_path / "cf.calibration.json"
    update_calibration_file(base, "steering_ratio", {"swa_deg": [100.0, 300.0], "ratio": [15.0, 14.0]})
    doc = read_calibration_file(tmp_path)  # a directory holding one session
    assert set(doc["results"]) == {"optical_zero", "steering_ratio"}
    inp = load_inputs(base)
    assert inp.profile.calibration.optical_zero_deg["body"] == 0.3
    assert inp.profile.calibration.steering_ratio == (15.0, 14.0)
    assert "can" in inp.missing and "optical" in inp.missing
    p.write_text("{not json", encoding="utf-8")
    with pytest.raises(SessionFileError, match=r"cf\.calibration\.json"):
        load_inputs(base)


def test_missing_antenna_and_file_errors(tmp_path: Path, sim_cfg: SessionConfig) -> None:
    truth = simulate_truth(sim_cfg, make_scenario("straight", speed_kmh=30.0, duration_s=2.0))
    one = write_truth_session(tmp_path, "one", sim_cfg, truth, offset_deg=0.0, receivers=("rover_a",),
                              can_roles=False)
    inp = load_inputs(one)
    assert inp.gnss is None
    with pytest.raises(AnalysisError, match=r"receiver 'rover_b' \(antenna b\) recorded no GNSS data"):
        inp.require_gnss()
    cfg = sim_cfg.model_copy(update={"receivers": tuple(r for r in sim_cfg.receivers if r.name != "rover_b")})
    noant = write_truth_session(tmp_path, "noant", cfg, truth, offset_deg=0.0, receivers=("rover_a",),
                                can_roles=False)
    with pytest.raises(AnalysisError, match="has no receiver for antenna b"):
        load_inputs(noant).require_gnss()
    with pytest.raises(SessionFileError, match="nothere"):
        load_inputs(tmp_path / "nothere")
