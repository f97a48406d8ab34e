"""The [[can]] keys for a real car's bus: options, listen_only, timestamp_source, sample points (issue 29)."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.can.bus import CanBusConfig, FrameTime
from rig.core.config import CanConfig, ConfigFileError, load_session
from tests.conftest import REPO

SIM = REPO / "examples" / "sim.toml"


def _session(tmp_path: Path, can_lines: str) -> Path:
    """examples/sim.toml with ``can_lines`` added to its [[can]] table (and its roles file found)."""
    text = SIM.read_text(encoding="utf-8")
    roles = REPO / "examples" / "roles" / "vsc_sim.toml"
    text = text.replace('roles_file = "roles/vsc_sim.toml"', f'roles_file = "{roles.as_posix()}"\n{can_lines}')
    f = tmp_path / "session.toml"
    f.write_text(text, encoding="utf-8")
    return f


def test_new_keys_load_and_reach_the_bus_config(tmp_path: Path) -> None:
    cfg = load_session(_session(tmp_path, 'listen_only = false\ntimestamp_source = "host"\n'
                                          'options = { receive_own_messages = false, rx_queue_size = 1000 }'))
    cc = cfg.can[0]
    assert cc.listen_only is False and cc.timestamp_source == "host"
    bus = CanBusConfig.from_mapping(cc.model_dump(exclude={"dbc", "roles_file", "roles", "checks"}))
    assert bus.options == {"receive_own_messages": False, "rx_queue_size": 1000}
    assert bus.listen_only is False
    assert bus.frame_time is FrameTime.HOST


def test_defaults_leave_the_choices_to_the_interface() -> None:
    cc = CanConfig(dbc=Path("x.dbc"))
    assert (cc.options, cc.listen_only, cc.timestamp_source) == ({}, None, None)
    bus = CanBusConfig.from_mapping(cc.model_dump())
    assert bus.listen_only is None  # the reading link makes it True, rig replay keeps python-can's active
    assert bus.uses_interface_stamps  # virtual: the sender's stamp


def test_an_option_the_interface_does_not_take_is_a_problem_with_its_line(tmp_path: Path) -> None:
    f = _session(tmp_path, "options = { recieve_own_messages = true }")
    with pytest.raises(ConfigFileError) as info:
        load_session(f)
    (problem,) = info.value.problems
    assert problem.path.startswith("can.0")
    assert "options.recieve_own_messages: python-can's 'virtual' interface takes no option" in problem.message
    assert "did you mean 'receive_own_messages'" in problem.message


def test_a_bad_timestamp_source_or_sample_point_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigFileError, match="timestamp_source"):
        load_session(_session(tmp_path, 'timestamp_source = "gps"'))
    with pytest.raises(ConfigFileError, match="sample_point"):
        load_session(_session(tmp_path, "sample_point = 87.5"))  # a fraction, not percent


def test_pcan_fd_without_a_data_bitrate_names_the_keys(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"a PCAN FD bus needs bitrate and data_bitrate.*f_clock, nom_brp"):
        CanConfig(name="pt", interface="pcan", channel="PCAN_USBBUS1", fd=True, dbc=Path("x.dbc"))
    with pytest.raises(ValueError, match="data_bitrate given but fd is false"):
        CanConfig(name="pt", interface="pcan", channel="PCAN_USBBUS1", data_bitrate=2_000_000, dbc=Path("x.dbc"))
