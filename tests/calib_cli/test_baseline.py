"""rig calibrate-baseline against a full simulated recording with an injected mounting offset."""

from __future__ import annotations

import json
import math
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from calibration.mount import OffsetEstimate
from rig.core.config import AntennaConfig, SessionConfig
from rig.data.inputs import load_inputs
from rig.evaluate.calibrate import BaselineOptions, calibrate_baseline
from tests.calib_cli.conftest import TRUE_OFFSET_DEG, TRUE_OPTICAL_ZERO_DEG
from tests.calib_cli.synth import REPO, run_cli
from vsccore.errors import CalibrationError


def test_offset_recovered_from_two_opposite_runs(truth_straights: Path) -> None:
    """Issue 8: the injected offset is recovered within 0.02° from two ≥ 5 s runs at 40 km/h in opposite
    directions with RTK-level relative noise (1 mm 2-D RMS per rover, correlated over 0.2 s: 0.04° of baseline
    heading per epoch), and the stated 95 % interval covers it."""
    cal = calibrate_baseline(load_inputs(truth_straights))
    segs = cal.mount.estimate.segments
    assert len(segs) == 2
    assert all(s.duration_s >= 5.0 and abs(3.6 * s.mean_speed_mps - 40.0) < 0.5 for s in segs)
    assert sorted(round(math.degrees(s.course_rad)) % 360 for s in segs) == [0, 180]
    err = cal.offset_deg - TRUE_OFFSET_DEG
    assert abs(err) < 0.02
    assert abs(err) <= cal.u95_deg
    assert 0.0 < cal.u95_deg < 0.03
    assert cal.yaw_rate_source.startswith("CAN yaw_rate")
    assert cal.mount.baseline.mean_m == pytest.approx(1.58, abs=0.002) and cal.length_ok


def _lag_s(t: np.ndarray, x: np.ndarray, t_ref: np.ndarray, x_ref: np.ndarray) -> float:
    """Time shift of the series (t, x) against the reference by least squares over ±4 s."""
    lags = np.arange(-4.0, 4.0, 0.01)
    err = [np.nanmean((x - np.interp(t - lag, t_ref, x_ref)) ** 2) for lag in lags]
    return float(lags[int(np.argmin(err))])


def _half_width_999(estimate: OffsetEstimate) -> float:
    """The estimate's 99.9 % half width (rad), from its own Student-t (its equivalent degrees of freedom): one
    recording's error falls outside its own u95 one time in twenty by construction (seen once under load: optical
    zero 0.0069° against u95 0.0066°), which a single-recording test must not fail on; the 95 % coverage of the
    estimator's interval is checked over many realisations in tests/calibration/test_coverage.py."""
    return estimate.std_error_rad * float(stats.t.ppf(0.9995, estimate.dof))


def test_recorded_simulation_end_to_end(straights_session: Path) -> None:
    """The whole chain: simulated receivers on pseudo-terminals, relay, virtual CAN, simulated DAQ, recorder, reader.

    Under machine load the simulated devices can miss epochs (a gap splits a run), so at least one run is
    required here; the estimate must sit within its own 99.9 % interval of the truth (`_half_width_999`). The
    recorded optical stream must be on the common time base, and the optical sensor's zero (0.25°) is checked
    likewise.
    """
    inp = load_inputs(straights_session)
    cal = calibrate_baseline(inp)
    assert cal.mount.estimate.segments
    assert cal.truth_offset_deg == TRUE_OFFSET_DEG
    err = cal.offset_deg - TRUE_OFFSET_DEG
    assert abs(err) <= math.degrees(_half_width_999(cal.mount.estimate)) and abs(err) < 0.03
    assert cal.mount.baseline.mean_m == pytest.approx(1.58, abs=0.003) and cal.length_ok
    (opt,) = cal.optical
    assert opt.sensor == "body"
    tr = inp.require_truth()
    o = inp.optical_sensor("body")
    lag = _lag_s(o.t_s[o.valid][::5], o.slip_angle_rad[o.valid][::5], tr.t_s, tr.truth.point_sideslip(-2.1, 0.0))
    assert abs(lag) <= 0.1, f"/optical/body is {lag:+.2f} s off the GNSS/truth time base"
    zero_err = math.degrees(opt.zero_rad) - TRUE_OPTICAL_ZERO_DEG
    assert abs(zero_err) < 0.02 and abs(zero_err) <= math.degrees(_half_width_999(opt.result.estimate))


def test_wrong_configured_length_is_flagged(truth_straights: Path) -> None:
    inp = load_inputs(truth_straights)
    wrong = inp.profile.model_copy(update={"antennas": AntennaConfig(baseline_length_m=1.62,
                                                                     baseline_tolerance_m=0.02)})
    cal = calibrate_baseline(load_inputs(truth_straights, profile=wrong))
    assert not cal.length_ok
    assert any("differs from the configured 1.620 m" in w for w in cal.warnings)
    assert cal.to_dict()["baseline"]["flagged"] is True  # type: ignore[index]


def test_no_usable_segment_says_what_was_missing(truth_straights: Path) -> None:
    inp = load_inputs(truth_straights)
    with pytest.raises(CalibrationError,
                       match=r"longest straight segment \d\.\d s at 40 km/h; need 20\.0 s at > 25 km/h"):
        calibrate_baseline(inp, BaselineOptions(min_duration_s=20.0))
    with pytest.raises(CalibrationError, match=r"need 5\.0 s at > 60 km/h"):
        calibrate_baseline(inp, BaselineOptions(min_speed_kmh=60.0))


def test_cli_json_write_record_plot(straights_session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                    ) -> None:
    # work on a copy: the command records next to the session
    for f in straights_session.parent.glob(f"{straights_session.name}.*.mcap"):
        shutil.copy(f, tmp_path / f.name)
    session = tmp_path / straights_session.name
    profile = tmp_path / "car.toml"
    shutil.copy(REPO / "rig" / "examples" / "car-template.toml", profile)
    before = profile.read_text(encoding="utf-8")
    png = tmp_path / "baseline.png"
    code = run_cli(["calibrate-baseline", str(session), "--json", "--write", str(profile), "--plot", str(png)])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("offset_deg", "u95_deg", "ci_low_deg", "ci_high_deg", "segments", "direction_groups", "baseline",
                "optical_zero", "warnings", "uncertainty_method", "simulation_truth", "files"):
        assert key in out, key
    for seg in out["segments"]:
        assert {"t_start_s", "duration_s", "mean_speed_kmh", "direction", "course_deg", "offset_deg"} <= set(seg)
    assert {"mean_m", "std_m", "nominal_m", "flagged"} <= set(out["baseline"])
    assert "AR(1)" in out["uncertainty_method"]
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    # the profile: values written, comments and everything else kept
    after = profile.read_text(encoding="utf-8")
    comments = [ln.strip() for ln in before.splitlines() if ln.strip().startswith("#")]
    assert comments and all(c in after for c in comments)
    # the template is a session configuration with the vehicle profile inline
    prof = SessionConfig.model_validate(tomllib.loads(after)).profile
    assert prof.calibration.mount_offset_deg == pytest.approx(out["offset_deg"], abs=1e-6)
    assert prof.calibration.mount_offset_u95_deg == pytest.approx(out["u95_deg"], abs=1e-6)
    assert prof.calibration.mount_offset_session == "straights" and prof.calibration.mount_offset_date
    assert prof.calibration.optical_zero_deg["body"] == pytest.approx(out["optical_zero"]["body"]["zero_deg"],
                                                                      abs=1e-6)
    orig = SessionConfig.model_validate(tomllib.loads(before)).profile
    assert prof.vehicle == orig.vehicle and prof.antennas == orig.antennas and prof.optical == orig.optical
    changed = [ln for ln in after.splitlines() if ln not in before.splitlines()]
    assert all(("mount_offset" in ln or "optical_zero_deg" in ln) for ln in changed), changed
    # recorded next to the session: later commands see it
    assert Path(out["files"]["calibration_file"]) == tmp_path / "straights.calibration.json"
    inp = load_inputs(session)
    assert inp.profile.calibration.mount_offset_deg == pytest.approx(out["offset_deg"])


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str], straights_session: Path) -> None:
    code = run_cli(["calibrate-baseline", str(tmp_path / "none")])
    assert code == 2
    assert "rig: error:" in capsys.readouterr().err
    code = run_cli(["calibrate-baseline", str(straights_session), "--min-duration-s", "30", "--no-record"])
    assert code == 2
    err = capsys.readouterr().err
    assert "longest straight segment" in err and "need 30.0 s" in err
    linked = tmp_path / "session.toml"
    linked.write_text('vehicle_profile = "car.toml"\n', encoding="utf-8")
    code = run_cli(["calibrate-baseline", str(straights_session), "--no-record", "--write", str(linked)])
    assert code == 2
    assert "write the calibration into that file" in capsys.readouterr().err
    broken = tmp_path / "broken.toml"
    broken.write_text("[calibration]\nmount_offset_deg = 0.0\n[vehicle]\nwheelbase_m = -1\n", encoding="utf-8")
    code = run_cli(["calibrate-baseline", str(straights_session), "--no-record", "--write", str(broken)])
    assert code == 2
    assert "wheelbase_m" in capsys.readouterr().err
    assert broken.read_text(encoding="utf-8").endswith("wheelbase_m = -1\n")  # untouched
