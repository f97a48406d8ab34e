"""Configuration checks for the first road test: the baud budget of a receiver port (a log set the port cannot
carry is refused: an OEM7 would drop logs and flag an overrun in RXSTATUS), and no device accepted and dropped."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from rig.cli.main import app
from rig.core.config import load_session, port_budget
from rig.workflows.demo import demo_config_path
from vsccore.errors import ConfigError

runner = CliRunner()


def test_the_budget_adds_the_logs_at_their_rates() -> None:
    rover = next(r for r in load_session(demo_config_path()).receivers if r.name == "rover_a")
    need, carry = port_budget(rover)
    assert carry == 46_080.0  # 460800 Bd, 10 bits a byte
    # BESTPOSB 104 B and BESTVELB 76 B at 20 Hz, TIMEB 76 B at 1 Hz, RANGECMPB (60 observations) at 20 Hz
    assert need == pytest.approx(20 * 104 + 20 * 76 + 76 + 20 * (28 + 4 + 24 * 60 + 4))


def test_a_log_set_the_port_cannot_carry_is_refused_with_the_receiver_named() -> None:
    with pytest.raises(ConfigError, match=r"rover_a.*9600 Bd.*RXSTATUS overrun"):
        load_session(demo_config_path(), {"receivers.1.baud": 9600})


def test_config_check_shows_each_ports_share(tmp_path: Path) -> None:
    res = runner.invoke(app, ["config", "check", str(demo_config_path())])
    assert res.exit_code == 0, res.output
    assert "receivers.rover_a: logs need ~33.2 of 46.1 kB/s at 460800 Bd (72 %)" in res.output
    assert "little margin" in res.output


def test_a_can_output_optical_sensor_is_refused_with_the_reason_not_dropped() -> None:
    """Before: a Correvit whose channels named CAN roles passed the check and was silently not recorded."""
    with pytest.raises(ConfigError, match=r"optical sensor 'body'.*can_role.*not decoded into /optical"):
        load_session(demo_config_path(), {"optical.0.channels.slip_angle": {"can_role": "correvit_angle"}})
