"""Configuration error paths: files that are not UTF-8, and values outside what physics or the
receiver allows, each reported with the file, key path and line."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.core.config import (
    NOVATEL_BAUDS,
    ConfigFileError,
    check_file,
    load_profile,
    load_session,
)
from tests.conftest import REPO
from vsccore.errors import ConfigError

EXAMPLE = REPO / "examples" / "sim.toml"


def _with(tmp_path: Path, old: str, new: str) -> Path:
    text = EXAMPLE.read_text(encoding="utf-8")
    assert old in text, old
    f = tmp_path / "session.toml"
    f.write_text(text.replace(old, new, 1), encoding="utf-8")
    # keep the example's relative paths (DBC, roles) resolvable
    for item in EXAMPLE.parent.iterdir():
        if item.name != "sim.toml" and not (tmp_path / item.name).exists():
            (tmp_path / item.name).symlink_to(item)
    return f


def _line_of(f: Path, needle: str) -> int:
    return next(i for i, line in enumerate(f.read_text(encoding="utf-8").splitlines(), start=1) if needle in line)


def test_a_config_file_that_is_not_utf8_names_the_byte_offset(tmp_path: Path) -> None:
    f = tmp_path / "latin1.toml"
    content = "[vehicle]\nname = 'Citroën C5'\n".encode("latin-1")
    f.write_bytes(content)
    offset = content.index(b"\xeb")
    with pytest.raises(ConfigError) as info:
        check_file(f)
    text = str(info.value)
    assert str(f) in text
    assert f"byte offset {offset}" in text
    assert "0xeb" in text
    assert "line 2" in text


def test_not_utf8_through_the_cli_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    from rig.cli.main import main

    f = tmp_path / "bad.toml"
    f.write_bytes(b"[vehicle]\nname = '\xff\xfe'\n")
    with pytest.raises(SystemExit) as info:
        main(["config", "check", str(f)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert "byte offset 18" in err  # len(b"[vehicle]\nname = '")


@pytest.mark.parametrize(
    ("old", "new", "path"),
    [
        ("mount_offset_deg = 0.0", "mount_offset_deg = 9.2e18", "calibration.mount_offset_deg"),
        ("mount_offset_deg = 0.0", "mount_offset_deg = -10.5", "calibration.mount_offset_deg"),
        ("mount_offset_deg = 0.0", "mount_offset_deg = nan", "calibration.mount_offset_deg"),
        ("optical_zero_deg = { body = 0.0 }", "optical_zero_deg = { body = 45.0 }", "calibration.optical_zero_deg"),
        ("a = { x_m = 0.60,", "a = { x_m = 60.0,", "antennas.a.x_m"),
        ("b = { x_m = -0.98, y_m = 0.0,", "b = { x_m = -0.98, y_m = 2.0,", "antennas.b.y_m"),
        ("mount = { x_m = -2.10, y_m = 0.0, z_m = 0.40 }", "mount = { x_m = -2.10, y_m = 0.0, z_m = -40 }",
         "optical.0.mount.z_m"),
        ('port = "sim://base"\nbaud = 115200', 'port = "sim://base"\nbaud = 115201', "receivers.0.baud"),
    ],
)
def test_implausible_values_are_rejected_with_key_path_and_line(tmp_path: Path, old: str, new: str, path: str) -> None:
    f = _with(tmp_path, old, new)
    with pytest.raises(ConfigFileError) as info:
        load_session(f)
    problems = {p.path: p for p in info.value.problems}
    assert path in problems, [str(p) for p in info.value.problems]
    key = new.split("=")[0].strip().split("\n")[-1]
    assert problems[path].line == _line_of(f, new.split("\n")[-1]) or problems[path].line == _line_of(f, key)
    assert "pydantic" not in str(info.value).lower()


def test_true_mount_offset_in_the_simulation_has_the_same_bound(tmp_path: Path) -> None:
    text = EXAMPLE.read_text(encoding="utf-8")
    assert "true_mount_offset_deg" in text
    with pytest.raises(ConfigFileError) as info:
        load_session(EXAMPLE, {"simulation.true_mount_offset_deg": 12.0})
    assert "simulation.true_mount_offset_deg" in {p.path for p in info.value.problems}
    # the bound is inclusive and symmetric
    assert load_session(EXAMPLE, {"simulation.true_mount_offset_deg": -10.0}).simulation is not None


def test_log_period_must_be_one_the_receiver_schedules(tmp_path: Path) -> None:
    f = _with(tmp_path, '{ name = "RTCM1006", period_s = 1.0 }', '{ name = "RTCM1006", period_s = 0.3 }')
    with pytest.raises(ConfigFileError) as info:
        load_session(f)
    (problem,) = [p for p in info.value.problems if p.path.startswith("receivers.0.logs.0")]
    assert "0.3" in problem.message and "whole number of seconds" in problem.message
    assert problem.line == _line_of(f, "period_s = 0.3")
    for ok in ("0.02", "0.25", "2.0", "10"):
        (tmp_path / ok).mkdir()
        g = _with(tmp_path / ok, '{ name = "RTCM1006", period_s = 1.0 }', f'{{ name = "RTCM1006", period_s = {ok} }}')
        assert load_session(g).receivers[0].logs[0].period_s == pytest.approx(float(ok))


def test_baud_set_covers_the_receiver_driver_autobaud_rates() -> None:
    from drivers.novatel.receiver import AUTOBAUD_RATES

    assert set(AUTOBAUD_RATES) <= set(NOVATEL_BAUDS)


def test_lever_arm_bounds_in_a_vehicle_profile(tmp_path: Path) -> None:
    f = tmp_path / "car.toml"
    f.write_text("[antennas]\na = { x_m = 0.6, y_m = 0.0, z_m = 1.0 }\nb = { x_m = -0.98, z_m = 9.0 }\n"
                 "baseline_length_m = 1.58\n", encoding="utf-8")
    with pytest.raises(ConfigFileError) as info:
        load_profile(f)
    (problem,) = info.value.problems
    assert problem.path == "antennas.b.z_m"
    assert problem.line == 3
    assert "outside the car" in problem.message
