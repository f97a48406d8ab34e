"""`rig can monitor` on a virtual bus fed by the simulated ECU (typer's CliRunner, in-process)."""

from __future__ import annotations

import re
import time
from pathlib import Path

import can
from typer.testing import CliRunner

from rig.cli.main import app
from sim_devices.vsc_ecu import VscEcu, vsc_sim_dbc_path
from tests.can_live.truth_builders import steady_circle
from vsccore.clock import SystemClock

REPO = Path(__file__).resolve().parents[2]
runner = CliRunner()


def _run_with_ecu(channel: str, args: list[str]) -> str:
    truth = steady_circle(15.0, 100.0, 30.0)
    clock = SystemClock()
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as bus:
        ecu = VscEcu(truth, bus, clock, time.time_ns() - 1_000_000_000)  # already 1 s into the drive
        with ecu:
            result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return result.output


def test_monitor_shows_rates_load_and_role_values(channel: str) -> None:
    roles = REPO / "examples" / "roles" / "vsc_sim.toml"
    out = _run_with_ecu(
        channel,
        [
            "can",
            "monitor",
            "--interface",
            "virtual",
            "--channel",
            channel,
            "--roles",
            str(roles),
            "--dbc",
            str(vsc_sim_dbc_path()),
            "--duration",
            "1.6",
            "--interval",
            "0.5",
        ],
    )
    rates = [float(x) for x in re.findall(r"([\d.]+) frames/s", out)]
    # the sim car sends 100 + 100 + 50 + 50 + 50 + 10 = 360 frames/s
    assert rates
    assert abs(rates[-1] - 360.0) < 20.0
    loads = [float(x) for x in re.findall(r"load\s+([\d.]+) %", out)]
    assert 7.0 < loads[-1] < 12.0  # 360 frames of ~115-130 bits at 500 kbit/s
    yaw = re.findall(r"yaw_rate=([-\d.e]+) rad/s", out)
    assert yaw
    assert abs(float(yaw[-1]) - 0.15) < 0.01
    assert "swa=" in out
    assert "flagged" not in out


def test_monitor_takes_the_bus_from_a_session_configuration(channel: str) -> None:
    out = _run_with_ecu(
        channel,
        [
            "can",
            "monitor",
            "--config",
            str(REPO / "examples" / "sim.toml"),
            "--channel",
            channel,
            "--duration",
            "1.1",
            "--interval",
            "0.5",
        ],
    )
    assert "CAN bus 'vsc' (virtual" in out
    assert "vsc_beta_estimate=" in out


def test_monitor_without_a_bus_is_a_one_line_error() -> None:
    result = runner.invoke(app, ["can", "monitor", "--duration", "0.1"])
    assert result.exit_code != 0
