"""rig calibrate-imu with injected bias, scale and misalignment, recovered from CSV runs."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from rig.core.config import load_profile
from rig.data.inputs import load_inputs
from tests.calib_cli.synth import REPO, run_cli

G = 9.80665
M_ACC = np.array([[1.012, 0.004, -0.003], [-0.002, 0.991, 0.006], [0.005, -0.001, 1.004]])
B_ACC = np.array([0.08, -0.05, 0.12])
M_GYR = np.array([[0.985, 0.007, 0.002], [-0.004, 1.021, -0.003], [0.001, 0.005, 1.009]])
B_GYR = np.radians([0.3, -0.2, 0.15])
AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1)}


def _write_accel(path: Path, rng: np.random.Generator, noise: float = 0.01) -> None:
    lines = ["# six static positions, 200 samples each", "position,ax_mps2,ay_mps2,az_mps2"]
    for name, ax in AXES.items():
        m = M_ACC @ (G * np.asarray(ax, float)) + B_ACC
        for s in m + rng.normal(0.0, noise, (200, 3)):
            lines.append(f"{name},{s[0]:.6f},{s[1]:.6f},{s[2]:.6f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _write_gyro(path: Path, rng: np.random.Generator, noise_dps: float = 0.05) -> None:
    lines = ["axis,rate_dps,gx_dps,gy_dps,gz_dps"]
    for name in ("+x", "+y", "+z"):
        for rate in (-100.0, -90.0, -80.0, 80.0, 90.0, 100.0):
            m = M_GYR @ (math.radians(rate) * np.asarray(AXES[name], float)) + B_GYR
            for s in np.degrees(m) + rng.normal(0.0, noise_dps, (100, 3)):
                lines.append(f"{name},{rate:g},{s[0]:.6f},{s[1]:.6f},{s[2]:.6f}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def test_injected_errors_recovered(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(3)
    acc, gyr = tmp_path / "acc.csv", tmp_path / "gyr.csv"
    _write_accel(acc, rng)
    _write_gyro(gyr, rng)
    # a stand-alone vehicle profile: the template's vehicle tables with their comments
    template = (REPO / "rig" / "examples" / "car-template.toml").read_text(encoding="utf-8")
    before = template[: template.index("[[receivers]]")]
    profile = tmp_path / "car.toml"
    profile.write_text(before, encoding="utf-8")
    code = run_cli(["calibrate-imu", "--accel", str(acc), "--gyro", str(gyr), "--json", "--write", str(profile)])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    # noise of the run means: 0.01/√200 m/s² and 0.05/√100 °/s → tolerances a few times that
    np.testing.assert_allclose(out["accel"]["matrix"], M_ACC, atol=1e-4)
    np.testing.assert_allclose(out["accel"]["bias"], B_ACC, atol=1e-3)
    np.testing.assert_allclose(out["gyro"]["matrix"], M_GYR, atol=2e-4)
    np.testing.assert_allclose(out["gyro"]["bias"], B_GYR, atol=math.radians(0.01))
    assert len(out["accel"]["residuals"]) == 6 and len(out["gyro"]["residuals"]) == 18
    assert max(map(abs, np.ravel(out["gyro"]["residuals"]))) < math.radians(0.02)
    prof = load_profile(profile)
    assert prof.calibration.imu is not None
    np.testing.assert_allclose(prof.calibration.imu.gyro_matrix, M_GYR, atol=2e-4)
    np.testing.assert_allclose(prof.calibration.imu.accel_bias_mps2, B_ACC, atol=1e-3)
    comments = [ln.strip() for ln in before.splitlines() if ln.strip().startswith("#")]
    assert all(c in profile.read_text(encoding="utf-8") for c in comments)


def test_applied_to_a_session(circles_session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(4)
    gyr = tmp_path / "gyr.csv"
    _write_gyro(gyr, rng)
    for f in circles_session.parent.glob(f"{circles_session.name}.*"):
        shutil.copy(f, tmp_path / f.name)
    session = tmp_path / circles_session.name
    code = run_cli(["calibrate-imu", "--gyro", str(gyr), "--session", str(session)])
    assert code == 0
    assert "gyroscope (18 runs)" in capsys.readouterr().out
    raw = load_inputs(session, optical=False, truth=False)
    cor = load_inputs(session, optical=False, truth=False, imu_calibration="in_force")
    imu = cor.profile.calibration.imu
    assert imu is not None and imu.gyro_matrix[2][2] == pytest.approx(M_GYR[2, 2], abs=2e-4)
    np.testing.assert_allclose(cor.signal("yaw_rate").values,
                               (raw.signal("yaw_rate").values - imu.gyro_bias_rps[2]) / imu.gyro_matrix[2][2])


def test_csv_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("position,ax_mps2,ay_mps2,az_mps2\n+z,0,0,9.8\n+q,0,0,9.8\n", encoding="utf-8")
    code = run_cli(["calibrate-imu", "--accel", str(bad)])
    assert code == 2
    assert "bad.csv:3: position '+q'" in capsys.readouterr().err
    bad.write_text("axis,rate_dps,gx,gy,gz\n+z,90,0,0,90\n", encoding="utf-8")
    code = run_cli(["calibrate-imu", "--gyro", str(bad)])
    assert code == 2
    assert "gx_rps" in capsys.readouterr().err
    few = tmp_path / "few.csv"
    few.write_text("position,ax_g,ay_g,az_g\n+z,0,0,1\n-z,0,0,-1\n", encoding="utf-8")
    code = run_cli(["calibrate-imu", "--accel", str(few)])
    assert code == 2
    assert "at least 4 runs" in capsys.readouterr().err
    code = run_cli(["calibrate-imu"])
    assert code == 2
    assert "give accelerometer positions and/or gyroscope" in capsys.readouterr().err
