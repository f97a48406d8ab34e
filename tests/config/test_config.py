"""Session configuration and vehicle profile validation."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from rig.cli.main import app
from rig.core.config import ConfigFileError, load_profile, load_session, parse_override
from tests.conftest import REPO

EXAMPLES = REPO / "examples"
runner = CliRunner()


def test_sim_example_is_valid() -> None:
    cfg = load_session(EXAMPLES / "sim.toml")
    assert {r.name for r in cfg.receivers} == {"base", "rover_a", "rover_b"}
    prof = cfg.profile
    assert prof.vehicle.wheelbase_m == pytest.approx(prof.vehicle.cg_to_front_axle_m + prof.vehicle.cg_to_rear_axle_m)
    assert prof.antennas.baseline_length_m == pytest.approx(1.58)
    assert cfg.simulation is not None
    assert cfg.simulation.true_mount_offset_deg != prof.calibration.mount_offset_deg
    assert cfg.can[0].dbc.is_file(), cfg.can[0].dbc
    assert "yaw_rate" in cfg.can[0].roles


def test_car_template_is_valid() -> None:
    cfg = load_session(EXAMPLES / "car-template.toml")
    assert all(not r.port.startswith("sim://") for r in cfg.receivers)
    assert cfg.simulation is None


@pytest.mark.parametrize("name", ["sim.toml", "car-template.toml"])
def test_config_check_cli_accepts_examples(name: str) -> None:
    result = runner.invoke(app, ["config", "check", str(EXAMPLES / name)])
    assert result.exit_code == 0, result.output
    assert "OK" in result.output


def test_unknown_key_did_you_mean_with_line(tmp_path: Path) -> None:
    f = tmp_path / "car.toml"
    f.write_text("[vehicle]\nname = 'x'\nwheelbse_m = 2.7\n\n[antennas]\nbaseline_length_m = 1.58\n")
    with pytest.raises(ConfigFileError) as info:
        load_profile(f)
    (problem,) = info.value.problems
    assert problem.path == "vehicle.wheelbse_m"
    assert "did you mean 'wheelbase_m'" in problem.message
    assert problem.line == 3


def test_every_problem_is_reported_with_key_path(tmp_path: Path) -> None:
    f = tmp_path / "session.toml"
    f.write_text(
        "[[receivers]]\n"
        "name = 'rover_a'\n"
        "role = 'rover'\n"
        "port = '/dev/ttyUSB0'\n"
        "baud = -5\n"
        "\n"
        "[[receivers]]\n"
        "name = 'rover_b'\n"
        "role = 'rovr'\n"
        "antenna = 'b'\n"
        "port = '/dev/ttyUSB1'\n"
    )
    with pytest.raises(ConfigFileError) as info:
        load_session(f)
    problems = {p.path: p for p in info.value.problems}
    assert "receivers.0.baud" in problems
    assert problems["receivers.0.baud"].line == 5
    assert "receivers.1.role" in problems
    assert problems["receivers.1.role"].line == 9
    text = str(info.value)
    assert "pydantic" not in text.lower()
    assert "errors.pydantic.dev" not in text


def test_geometry_inconsistency_is_named(tmp_path: Path) -> None:
    f = tmp_path / "car.toml"
    f.write_text("[vehicle]\nwheelbase_m = 3.0\ncg_to_front_axle_m = 1.2\ncg_to_rear_axle_m = 1.6\n")
    with pytest.raises(ConfigFileError, match="must equal wheelbase_m"):
        load_profile(f)


def test_toml_syntax_error_has_line(tmp_path: Path) -> None:
    f = tmp_path / "car.toml"
    f.write_text("[vehicle]\nname = 'x'\nmass_kg = = 3\n")
    with pytest.raises(ConfigFileError) as info:
        load_profile(f)
    assert info.value.problems[0].line == 3


def test_missing_file_is_named(tmp_path: Path) -> None:
    result = runner.invoke(app, ["config", "check", str(tmp_path / "nope.toml")])
    assert result.exit_code != 0


def test_relay_endpoint_must_name_a_receiver(tmp_path: Path) -> None:
    f = tmp_path / "s.toml"
    f.write_text("[relay]\nsource = 'receiver:base'\nsinks = ['receiver:rover_a']\n")
    with pytest.raises(ConfigFileError, match="names no receiver"):
        load_session(f)


def test_overrides_apply_before_validation() -> None:
    key, value = parse_override("simulation.true_mount_offset_deg=1.25")
    cfg = load_session(EXAMPLES / "sim.toml", {key: value})
    assert cfg.simulation is not None
    assert cfg.simulation.true_mount_offset_deg == pytest.approx(1.25)
    assert parse_override("simulation.drive=straight") == ("simulation.drive", "straight")


def test_vehicle_profile_file_is_resolved(tmp_path: Path) -> None:
    (tmp_path / "car.toml").write_text("[vehicle]\nname = 'Test car'\n[calibration]\nmount_offset_deg = 0.4\n")
    (tmp_path / "s.toml").write_text("vehicle_profile = 'car.toml'\n")
    cfg = load_session(tmp_path / "s.toml")
    assert cfg.profile.vehicle.name == "Test car"
    assert cfg.profile.calibration.mount_offset_deg == pytest.approx(0.4)
