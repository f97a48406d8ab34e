"""``rig sim list`` and ``rig sim run``: files read back with pandas / pyarrow, errors as one clear line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from rig.cli.main import main
from sim_devices.vehicle import SCENARIOS

REPO = Path(__file__).resolve().parents[2]
SIM_TOML = REPO / "rig" / "examples" / "sim.toml"
ISSUE_COLUMNS = (
    "t_s", "east_m", "north_m", "lat_deg", "lon_deg", "heading_deg", "speed_mps", "vx_mps", "vy_mps", "yaw_rate_dps",
    "ay_mps2", "ay_meas_mps2", "roll_deg", "beta_cg_deg", "swa_deg", "road_wheel_deg", "ltr",
)
SHORT_STEP = ["step_steer", "-p", "speed_kmh=30", "-p", "lead_s=0.5", "-p", "hold_s=1", "-p", "ay_mps2=4"]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_list_shows_every_scenario_and_parameter(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(["sim", "list"], capsys)
    assert code == 0
    for spec in SCENARIOS.values():
        assert f"{spec.name}: " in out
        for p in spec.params:
            assert p.name in out
            if p.unit:
                assert p.unit in out
    assert "default 50" in out  # the lane change's speed
    assert "ltr" in out


def test_run_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "step.csv"
    code, out, err = _run(["sim", "run", *SHORT_STEP, "--rate", "100", "--out", str(path)], capsys)
    assert code == 0, err
    assert str(path) in out
    df = pd.read_csv(path)
    assert set(ISSUE_COLUMNS) <= set(df.columns)
    assert df.columns[0] == "t_s"
    np.testing.assert_allclose(np.diff(df["t_s"]), 0.01, atol=1e-12)
    assert df["speed_mps"].iloc[0] == pytest.approx(30.0 / 3.6)
    # Units: degrees where the name says so, consistent with the SI velocity columns.
    np.testing.assert_allclose(df["beta_cg_deg"], np.degrees(np.arctan2(df["vy_mps"], df["vx_mps"])), atol=1e-9)
    yaw_rate = np.gradient(np.unwrap(np.radians(-df["heading_deg"].to_numpy())), df["t_s"].to_numpy())
    np.testing.assert_allclose(np.degrees(yaw_rate[5:-5]), df["yaw_rate_dps"].to_numpy()[5:-5], atol=0.5)
    # A left step at 4 m/s²: the car turns left and the lateral acceleration settles near the target.
    assert df["yaw_rate_dps"].iloc[-1] > 0.0
    assert df["ay_mps2"].iloc[-1] == pytest.approx(4.0, rel=0.1)


def test_run_parquet_with_vehicle_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "step.parquet"
    code, out, err = _run(
        ["sim", "run", *SHORT_STEP, "--vehicle", str(SIM_TOML), "--rate", "50", "--out", str(path)], capsys
    )
    assert code == 0, err
    assert "Simulated C-class saloon" in out
    table = pq.read_table(path)
    assert set(ISSUE_COLUMNS) <= set(table.column_names)
    t = table.column("t_s").to_numpy()
    np.testing.assert_allclose(np.diff(t), 0.02, atol=1e-12)
    assert t[-1] == pytest.approx(0.5 + 0.15 + 1.0, abs=0.021)  # lead + rise + hold
    meta = table.schema.metadata
    drive = json.loads(meta[b"vsc_rig.meta"])
    assert drive["scenario"] == "step_steer" and drive["vehicle_name"] == "Simulated C-class saloon"
    origin = json.loads(meta[b"vsc_rig.origin"])
    lat = table.column("lat_deg").to_numpy()
    assert lat[0] == pytest.approx(origin["lat_deg"], abs=1e-9)


def test_vehicle_file_changes_the_car(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    heavy = tmp_path / "heavy.toml"
    heavy.write_text('[vehicle]\nname = "Heavy"\nmass_kg = 2100.0\n')
    path = tmp_path / "heavy.csv"
    code, out, err = _run(["sim", "run", *SHORT_STEP, "--vehicle", str(heavy), "--rate", "100", "--out", str(path)],
                          capsys)
    assert code == 0, err
    assert "Heavy" in out
    df = pd.read_csv(path)
    load = df[["fz_fl_n", "fz_fr_n", "fz_rl_n", "fz_rr_n"]].sum(axis=1)
    np.testing.assert_allclose(load, 2100.0 * 9.80665, rtol=1e-12)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["jturn"], "unknown scenario 'jturn' (did you mean 'j_turn'?)"),
        (["j_turn", "-p", "speed_kph=50"], "no parameter 'speed_kph' (did you mean 'speed_kmh'?)"),
        (["j_turn", "-p", "speed_kmh=fast"], "'speed_kmh' must be a number (km/h), got 'fast'"),
        (["j_turn", "-p", "speed_kmh"], "--param 'speed_kmh': expected NAME=VALUE"),
        (["j_turn", "-p", "turn=left", "-p", "turn=right"], "parameter 'turn' given twice"),
        (["j_turn", "--rate", "0"], "--rate must be a positive number of Hz"),
        (["demo", "-p", "x=1"], "scenario 'demo' takes no --param"),
    ],
)
def test_bad_arguments_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    out = tmp_path / "x.csv"
    code, _, err = _run(["sim", "run", *args, "--out", str(out)], capsys)
    assert code == 2
    assert err.startswith("rig: error: ") and err.count("\n") == 1
    assert message in err
    assert not out.exists()


def test_bad_output_ending(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(["sim", "run", "j_turn", "--out", str(tmp_path / "x.txt")], capsys)
    assert code == 2 and "unknown output format '.txt'" in err and "x.txt" in err


def test_bad_vehicle_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[vehicle]\nmass_kgg = 1500.0\n")
    code, _, err = _run(["sim", "run", "j_turn", "--vehicle", str(bad), "--out", str(tmp_path / "x.csv")], capsys)
    assert code == 2
    assert "mass_kgg" in err and "mass_kg" in err and "bad.toml" in err


def test_unwritable_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "missing-dir" / "x.csv"
    code, _, err = _run(["sim", "run", *SHORT_STEP, "--rate", "10", "--out", str(target)], capsys)
    assert code == 2 and "cannot write the ground truth" in err and str(target) in err
