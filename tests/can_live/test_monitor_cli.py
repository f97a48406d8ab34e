"""`rig can monitor` on a virtual bus fed by the simulated ECU (typer's CliRunner, in-process)."""

from __future__ import annotations

import re
import sys
import threading
import time
from pathlib import Path

import can
from can.interfaces import virtual as can_virtual
from typer.testing import CliRunner

from rig.cli.main import app
from sim_devices.vsc_ecu import VscEcu, vsc_sim_dbc_path
from tests.can_live.truth_builders import steady_circle
from tests.waiting import wait_until
from vsccore.clock import SystemClock

REPO = Path(__file__).resolve().parents[2]
runner = CliRunner()


def _run_with_ecu(channel: str, args: list[str], *, max_lag_s: float = 0.5) -> tuple[str, int]:
    """The command's output while the simulated ECU sends on ``channel`` in real time, and the frames the
    ECU skipped (a frame more than ``max_lag_s`` late when its thread came round: a busy host)."""
    truth = steady_circle(15.0, 100.0, 30.0)
    clock = SystemClock()
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as bus:
        ecu = VscEcu(truth, bus, clock, time.time_ns() - 1_000_000_000, max_lag_s=max_lag_s)  # 1 s into the drive
        with ecu:
            result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return result.output, ecu.frames_skipped


def _assert_flags_are_the_skipped_frames(out: str, skipped: int) -> None:
    """The monitor flags nothing but counter jumps, and no more of them than the ECU skipped frames (each
    skipped frame is one jump of its message's rolling counter)."""
    flagged: dict[str, int] = {}
    for text in re.findall(r"flagged: ([^\n]*)", out):
        for name, n in re.findall(r"([A-Z_]+) (\d+)", text):
            flagged[name] = max(flagged.get(name, 0), int(n))
    assert set(flagged) <= {"COUNTER"}, out
    assert flagged.get("COUNTER", 0) <= skipped, f"{flagged} with {skipped} frame(s) skipped:\n{out}"


def _receivers(channel: str) -> int:
    """Buses open on a python-can virtual channel (its module-level registry of their receive queues)."""
    with can_virtual.channels_lock:
        return len(can_virtual.channels.get(channel, ()))


def _monitor_args(channel: str) -> list[str]:
    roles = REPO / "examples" / "roles" / "vsc_sim.toml"
    return [
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
    ]


def test_monitor_shows_rates_load_and_role_values(channel: str) -> None:
    out, skipped = _run_with_ecu(channel, _monitor_args(channel))
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
    # a frame the ECU skipped (its thread > 0.5 s late on a busy host, once in CI) is a counter jump the
    # monitor must flag; nothing else may be flagged
    _assert_flags_are_the_skipped_frames(out, skipped)


def test_frames_a_starved_ecu_skips_are_flagged_as_counter_jumps_and_nothing_else(channel: str) -> None:
    """The ECU's thread starved for 0.4 s mid-run (a thread holding the interpreter, as a busy host does) with
    a 0.1 s lag limit: it skips the frames that fell due meanwhile, and the monitor flags the counter jumps of
    those, no more, and no other check."""
    started = threading.Event()

    def hog() -> None:
        started.set()
        # The monitor's bus joins the channel only once the command has started (0.1-2 s of imports and DBC
        # loading, longer on a busy host): frames the ECU skips before that reach no one, so the hog starts
        # 0.4 s after the monitor listens (the ECU's bus and the monitor's: two receivers on the channel).
        if not wait_until(lambda: _receivers(channel) >= 2 or done.is_set(), 30.0) or done.is_set():
            return  # the monitor ended (or never came): nothing to starve; the test fails on it below
        if done.wait(0.4):
            return
        old = sys.getswitchinterval()
        sys.setswitchinterval(5.0)  # no other thread gets the interpreter while this one computes
        try:
            end = time.monotonic() + 0.4
            while time.monotonic() < end:
                pass
        finally:
            sys.setswitchinterval(old)

    done = threading.Event()
    t = threading.Thread(target=hog, name="hog")
    t.start()
    try:
        assert started.wait(10.0)
        out, skipped = _run_with_ecu(channel, _monitor_args(channel), max_lag_s=0.1)
    finally:
        done.set()
        t.join(10.0)
    assert not t.is_alive()
    assert skipped > 0, "the ECU skipped nothing: nothing was checked"
    _assert_flags_are_the_skipped_frames(out, skipped)
    assert "COUNTER" in out


def test_monitor_takes_the_bus_from_a_session_configuration(channel: str) -> None:
    out, _skipped = _run_with_ecu(
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
