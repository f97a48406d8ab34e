"""``rig gnss monitor`` against the simulated rover (sim_devices.gnss) on a pseudo-terminal.

The plain lines (output not a terminal) must show the rover's solution: the position near the
simulated antenna's ground-truth track, the speed and course of the truth, satellites, the rates
the monitor asked for; the rich view renders the same figures; ``--no-configure`` only listens;
Ctrl-C ends a monitor process cleanly; a port that never opens is an error naming it.
"""

from __future__ import annotations

import io
import math
import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pymap3d
import pytest
from rich.console import Console
from typer.testing import CliRunner

from drivers.novatel.commands import LogRequest, LogTrigger
from drivers.novatel.receiver import ReceiverSettings
from rig.cli.main import app
from rig.live.gnss_monitor import (
    ReceiverMonitor,
    monitor_commands,
    parse_log_option,
    render_monitor,
    run_monitor,
)
from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.vehicle import GroundTruth, make_scenario, simulate
from tests.sigint import ctrl_c_reaches_children
from vsccore.angles import wrap_180, yaw_to_azimuth
from vsccore.errors import ConfigError

runner = CliRunner()
SPEED_KMH = 50.0
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

_LINE = re.compile(
    r"^\s*(?P<t>[\d.]+) s \| (?P<name>\S+) (?P<state>\w+).*? \| (?P<type>\w+) (?P<status>\w+)"
    r".*? \| sats (?P<svs>\d+) tracked (?P<used>\d+) used"
    r" \| lat (?P<lat>-?[\d.]+) lon (?P<lon>-?[\d.]+) h (?P<h>-?[\d.]+) m sd (?P<sd>[\d./]+) m"
    r" \| speed (?P<speed>[\d.]+) m/s \([\d.]+ km/h\) course (?P<course>[\d.]+) deg.*?"
    r" \| diff age (?P<diff>[^|]+) \| rates (?P<rates>[^|]+) \| crc (?P<crc>\d+) rejected (?P<rejected>\d+) B"
    r"(?P<rest>.*)$"
)


@pytest.fixture(scope="module")
def truth() -> GroundTruth:
    return simulate(make_scenario("straight", speed_kmh=SPEED_KMH, duration_s=60.0), rate_hz=50.0)


def _rover(truth: GroundTruth, **options: Any) -> SimRover:
    timebase = SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)
    return SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase,
                    clock=timebase.make_clock(speed=1.0), **options)


@pytest.fixture(scope="module")
def rover(truth: GroundTruth) -> Iterator[SimRover]:
    sim = _rover(truth)
    sim.start()
    yield sim
    sim.stop()


def _parse(output: str) -> list[dict[str, str]]:
    lines = [line for line in output.splitlines() if line.strip()]
    parsed = []
    for line in lines:
        m = _LINE.match(line)
        assert m is not None, f"line does not show a solution: {line!r}"
        parsed.append(m.groupdict())
    return parsed


def _rates(text: str) -> dict[str, float]:
    return {k: float(v) for k, v in re.findall(r"(\S+) ([\d.]+)", text.replace(" /s", ""))}


def _check_against_truth(line: dict[str, str], truth: GroundTruth) -> None:
    # Position: horizontal distance to the truth track (CG; antenna 0.6 m ahead), SINGLE solution
    # noise about 1 m (1 sigma): within 8 m.
    e, n, _ = pymap3d.geodetic2enu(float(line["lat"]), float(line["lon"]), float(line["h"]),
                                   truth.lat0_deg, truth.lon0_deg, truth.h0_m)
    distance = float(np.min(np.hypot(truth.east - e, truth.north - n)))
    assert distance < 8.0, f"reported position {distance:.1f} m from the track"
    # Speed and course of the truth (straight run): within 0.5 m/s and 2 degrees.
    speed = float(np.median(np.hypot(truth.vx, truth.vy)))
    assert float(line["speed"]) == pytest.approx(speed, abs=0.5)
    course = math.degrees(float(yaw_to_azimuth(float(np.median(truth.yaw)))))
    assert abs(wrap_180(float(line["course"]) - course)) < 2.0


def test_log_option_forms() -> None:
    assert parse_log_option("bestposb@0.05") == LogRequest("BESTPOSB", LogTrigger.ONTIME, 0.05)
    assert parse_log_option("MARKPOSB@onnew") == LogRequest("MARKPOSB", LogTrigger.ONNEW)
    for bad in ("BESTPOSB", "BESTPOSB@", "@1", "BESTPOSB@fast", "BESTPOSB@0", "BESTPOSB@-1"):
        with pytest.raises(ConfigError, match="--log"):
            parse_log_option(bad)
    commands = monitor_commands([parse_log_option("BESTPOSB@0.05"), parse_log_option("TIMEB@1")])
    assert commands == ("UNLOGALL THISPORT", "LOG THISPORT BESTPOSB ONTIME 0.05", "LOG THISPORT TIMEB ONTIME 1")


def test_plain_lines_show_the_rovers_solution_and_rates(rover: SimRover, truth: GroundTruth) -> None:
    lost_before = sum(rover.bytes_lost().values())
    result = runner.invoke(app, ["gnss", "monitor", rover.port_path, "--duration", "2.5", "--interval", "0.5"])
    assert result.exit_code == 0, result.output
    # Bytes the port could not take while the monitor had it open: its reader fell a whole pty buffer behind
    # (a busy host). The write that filled the buffer left a frame's head in it, which the monitor rejects (a
    # 1-2 byte head as garbage, a longer one also as a CRC failure). Without a loss the strict checks hold.
    lost = sum(rover.bytes_lost().values()) - lost_before
    lines = _parse(result.output)
    assert len(lines) >= 4
    *running, final = lines
    assert final["state"] == "stopped" and all(line["state"] == "configured" for line in running[1:])
    for line in lines:
        assert line["name"] == os.path.basename(rover.port_path)
        # No corrections reach this rover: a single-point solution, computed, with satellites.
        assert (line["type"], line["status"]) == ("SINGLE", "SOL_COMPUTED")
        assert int(line["svs"]) >= 5 and 4 <= int(line["used"]) <= int(line["svs"])
        assert line["diff"].strip() == "none"
        # Nothing fails its CRC; at most the tail of a frame is rejected when the rover already
        # streamed before the monitor opened the port, and nothing after that, unless bytes were lost.
        if lost == 0:
            assert line["crc"] == "0" and line["rejected"] == lines[0]["rejected"], (line, lost)
            assert "last error none" in line["rest"]
        # each loss leaves at most one frame's head (< 200 B) and loses a byte at least
        assert int(line["rejected"]) < 200 * (1 + lost), (line, lost)
        _check_against_truth(line, truth)
    # Rates: the 20 Hz BESTPOS/BESTVEL and 1 Hz TIME the monitor requested.
    rates = _rates(final["rates"])
    assert rates["BESTPOS"] == pytest.approx(20.0, abs=2.5)
    assert rates["BESTVEL"] == pytest.approx(20.0, abs=2.5)
    assert 0.3 <= rates["TIME"] <= 2.5
    # The positions move along the track at the truth's speed between lines.
    first, last = lines[0], lines[-1]
    e0, n0, _ = pymap3d.geodetic2enu(float(first["lat"]), float(first["lon"]), 0, truth.lat0_deg, truth.lon0_deg, 0)
    e1, n1, _ = pymap3d.geodetic2enu(float(last["lat"]), float(last["lon"]), 0, truth.lat0_deg, truth.lon0_deg, 0)
    moved = math.hypot(e1 - e0, n1 - n0)
    span = float(last["t"]) - float(first["t"])
    assert moved == pytest.approx(span * SPEED_KMH / 3.6, abs=8.0)


def test_live_view_renders_the_same_figures(rover: SimRover) -> None:
    settings = ReceiverSettings("rover_a", rover.port_path, 115200,
                                monitor_commands([LogRequest("BESTPOSB", LogTrigger.ONTIME, 0.05),
                                                  LogRequest("BESTVELB", LogTrigger.ONTIME, 0.05)]))
    console = Console(file=io.StringIO(), force_terminal=True, width=160, record=True)
    view = run_monitor(ReceiverMonitor(settings), duration_s=1.5, interval_s=0.5, console=console, live=True)
    assert view.state == "stopped" and view.position is not None and view.velocity is not None
    out = Console(file=io.StringIO(), width=160, record=True)
    out.print(render_monitor(view))
    text = out.export_text()
    pos, vel = view.position, view.velocity
    for expected in (
        "NovAtel receiver rover_a", "SINGLE SOL_COMPUTED", f"{pos.num_svs} tracked {pos.num_soln_svs} used",
        f"lat {pos.lat_deg:.9f} lon {pos.lon_deg:.9f}", f"speed {vel.hor_spd_mps:.2f} m/s",
        f"course {vel.trk_gnd_deg:.1f} deg", "BESTPOS", "BESTVEL", "last error",
        # Joining a rover that already streams (an earlier test configured it) starts mid-frame:
        # those bytes are rejected, never a CRC failure.
        f"crc 0 rejected {view.health.rejected_bytes} B",
    ):
        assert expected in text, expected
    assert view.health.rates_hz["BESTPOS"] == pytest.approx(20.0, abs=3.0)
    assert "BESTPOS" in console.export_text()  # the live display was drawn on the terminal console


def test_no_configure_only_listens_to_what_the_port_sends(truth: GroundTruth) -> None:
    # A receiver whose saved configuration already logs BESTPOSA at 10 Hz on its port.
    sim = _rover(truth, startup_commands=("LOG COM1 BESTPOSA ONTIME 0.1",))
    sim.start()
    try:
        result = runner.invoke(app, ["gnss", "monitor", sim.port_path, "--no-configure", "--duration", "1.5",
                                     "--interval", "0.5"])
    finally:
        sim.stop()
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert all("listening" in line or "stopped" in line for line in lines)
    assert all("no BESTVEL yet" in line for line in lines)  # nothing was requested
    final = lines[-1]
    assert "SINGLE SOL_COMPUTED" in final and "RESPONSE" not in final
    rates = _rates(re.search(r"rates ([^|]+)", final).group(1))  # type: ignore[union-attr]
    assert rates == {"BESTPOS": pytest.approx(10.0, abs=2.0)}


def test_a_port_that_never_opens_is_an_error_naming_it(tmp_path: Any) -> None:
    missing = str(tmp_path / "ttyNOPE")
    result = runner.invoke(app, ["gnss", "monitor", missing, "--duration", "0.3", "--interval", "0.1"])
    assert result.exit_code != 0
    assert missing in str(result.exception)
    assert "never connected" in str(result.exception)
    assert "connecting" in result.output


def test_ctrl_c_stops_the_monitor_process_cleanly(rover: SimRover) -> None:
    # The gnss command group alone (importing every rig command takes seconds), in its own process,
    # so that SIGINT arrives as it does from a terminal.
    script = "import sys; from rig.cli.gnss_cmd import app; app(sys.argv[1:], prog_name='rig gnss')"
    with ctrl_c_reaches_children():
        proc = subprocess.Popen(
            [sys.executable, "-c", script, "monitor", rover.port_path, "--interval", "0.2"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO, text=True,
        )
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 60.0
        first = ""
        while "SOL_COMPUTED" not in first:  # wait for a line that shows a solution
            left = deadline - time.monotonic()
            assert left > 0, "no status line with a solution"
            ready, _, _ = select.select([proc.stdout], [], [], left)
            assert ready, "no status line with a solution"
            first = proc.stdout.readline()
            assert first, f"rig exited early: {proc.stderr.read() if proc.stderr else ''}"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "stopped (Ctrl-C)" in err and "Traceback" not in err
    assert out.splitlines()[-1].split("|")[1].split()[1] == "stopped"


def test_a_rejected_log_request_shows_as_configuration_failed_naming_the_command(rover: SimRover) -> None:
    result = runner.invoke(app, ["gnss", "monitor", rover.port_path, "--log", "NOSUCHLOGB@1", "--duration", "1.0",
                                 "--interval", "0.25"])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert any("configuration failed" in line for line in lines)
    last_error = lines[-1].split("| last error ")[1]
    assert "LOG THISPORT NOSUCHLOGB ONTIME 1" in last_error and "ERROR" in last_error.upper()
