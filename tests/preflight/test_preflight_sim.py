"""``rig preflight`` on the simulated car: all GO as configured, and one NO-GO naming each fault a first day in a
real car meets (the twins fail where the hardware fails; the check talks to them through the recorder's drivers).

Each run is bounded by ``--wait`` on the simulated clock (at 8× real time): the simulated rovers need about 10.5 s
of it for their RTK fix, so a run with a fault watches 20 s, and the GO run ends as soon as everything is GO.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Any

import pytest

from rig.cli.main import main
from rig.workflows.demo import demo_config_path

SIM = demo_config_path()  # rig/examples/sim.toml
FAST = ("--set", "simulation.speed=8", "--set", "simulation.drive=straight:speed_kmh=20,duration_s=20")
FAULT_WAIT_S = "20"


def _run(argv: list[str]) -> int:
    """``rig ARGV`` in this process; its exit status (``main`` returns on 0, exits otherwise)."""
    try:
        main(argv)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1
    return 0


def _preflight(capsys: pytest.CaptureFixture[str], tmp_path: Path, *args: str, wait: str = FAULT_WAIT_S,
               as_json: bool = True) -> tuple[int, Any]:
    """Run ``rig preflight`` on the simulated car; (exit status, the JSON document or the plain text)."""
    argv = ["preflight", str(SIM), *FAST, "--wait", wait, "--out", str(tmp_path / "sessions"), *args]
    code = _run([*argv, "--json"] if as_json else argv)
    out = capsys.readouterr().out
    return code, (json.loads(out) if as_json else out)


def _devices(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {d["device"]: d for d in doc["devices"]}


def _no_go(doc: dict[str, Any]) -> set[str]:
    return {d["device"] for d in doc["devices"] if d["verdict"] != "GO"}


def _failed(device: dict[str, Any]) -> dict[str, Any]:
    return next(c for c in device["checks"] if not c["ok"])


@pytest.fixture(scope="module")
def all_go(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict[str, Any]]:
    """The simulated car as configured (shared: the swap test takes rover B's serial number from it)."""
    out = io.StringIO()
    sessions = tmp_path_factory.mktemp("go") / "sessions"
    with contextlib.redirect_stdout(out):
        code = _run(["preflight", str(SIM), *FAST, "--wait", "60", "--out", str(sessions), "--json"])
    return code, json.loads(out.getvalue())


def test_the_simulated_car_is_go(all_go: tuple[int, dict[str, Any]]) -> None:
    code, doc = all_go
    assert code == 0, [(d["device"], d["reason"]) for d in doc["devices"] if d["verdict"] != "GO"]
    devices = _devices(doc)
    assert set(devices) == {"base", "rover_a", "rover_b", "relay", "baseline A-B", "can.vsc", "daq.SimDAQ",
                            "sync switch", "disk"}
    assert doc["verdict"] == "GO" and doc["simulated"]
    # everything GO ends the check before --wait: RTK fixed (the twins' time to fix is 10 s) and a few s of rates
    assert 10.0 < doc["time_to_go_s"] < 20.0
    for name in ("base", "rover_a", "rover_b"):
        figures = devices[name]["figures"]
        assert figures["time_status"] == "FINESTEERING"
        assert figures["serial_number"] and figures["model"] and figures["firmware"]
    assert devices["rover_a"]["figures"]["position_type"] == "NARROW_INT"
    assert devices["base"]["figures"]["solution_status"] == "SOL_COMPUTED"
    assert abs(devices["baseline A-B"]["figures"]["measured_m"] - 1.58) < 0.03
    sync = devices["sync switch"]["figures"]
    assert sync["pairs"] >= 3 and sync["max_residual_us"] < 1000.0
    assert devices["disk"]["figures"]["rate_kb_per_s"] > 0


def test_a_correction_cable_on_the_wrong_port_is_no_go(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Rover A's correction cable on its COM3 (NOVATEL mode) instead of COM2 (RTCMV3): the relay writes, no RTK."""
    code, doc = _preflight(capsys, tmp_path, "--set", "receivers.1.correction_device=sim://rover_a/COM3")
    assert code == 1
    assert _no_go(doc) == {"rover_a", "baseline A-B"}
    rover_a = _devices(doc)["rover_a"]
    check = _failed(rover_a)
    assert check["check"] == "corrections"
    assert "relay wrote" in check["detail"] and "COM3" in check["detail"]
    assert "COM2" in check["fix"] and "RTCMV3" in check["fix"]


def test_a_base_height_read_on_the_wrong_datum_is_no_go(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """The base's surveyed (ellipsoidal) height labelled mean sea level: the rig sends UNDULATION EGM96 and the
    receiver reads 300 m as MSL, the geoid height (~48 m) above the antenna (the simulated car's fix_position is
    the antenna's true position, whatever the label says)."""
    code, doc = _preflight(capsys, tmp_path, "--set", "receivers.0.fix_height=msl")
    assert code == 1
    devices = _devices(doc)
    check = _failed(devices["base"])
    assert check["check"] == "base position"
    assert "INTEGRITY_WARNING" in check["detail"] or "INVALID_FIX" in check["detail"]
    assert "fix_height" in check["fix"] and "UNDULATION" in check["fix"]
    assert "no corrections" in check["detail"]
    assert _failed(devices["relay"])["check"] == "source"  # nothing to relay
    assert _failed(devices["rover_a"])["check"] == "corrections"


def test_swapped_rovers_are_no_go(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                  all_go: tuple[int, dict[str, Any]]) -> None:
    """rover_a's port answers with another serial number than configured (here rover B's): refused by name."""
    psn_b = _devices(all_go[1])["rover_b"]["figures"]["serial_number"]
    code, doc = _preflight(capsys, tmp_path, "--set", f'receivers.1.serial_number="{psn_b}"')
    assert code == 1
    assert _no_go(doc) == {"rover_a"}
    check = _failed(_devices(doc)["rover_a"])
    assert check["check"] == "identity"
    assert "ports swapped" in check["detail"] and psn_b in check["detail"]
    assert "/dev/serial/by-id" in check["fix"]


def test_a_command_port_too_slow_for_its_logs_is_no_go(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Rover A's command port at 115200 Bd while it sends BESTPOS, BESTVEL and RANGECMP at 20 Hz: it overruns.

    The configuration's own baud budget refuses 115200 Bd for the logs it lists, so the 20 Hz RANGECMPB comes
    from extra_commands (which no budget sees) over a configured 1 Hz one: the receiver drops what the port
    cannot carry and says so in RXSTATUS and in every log header.
    """
    code, doc = _preflight(capsys, tmp_path, "--set", "receivers.1.baud=115200",
                           "--set", "receivers.1.logs.5.period_s=1.0",
                           "--set", 'receivers.1.extra_commands=["LOG THISPORT RANGECMPB ONTIME 0.05"]')
    assert code == 1
    rover_a = _devices(doc)["rover_a"]
    check = _failed(rover_a)
    assert check["check"] == "port overrun"
    assert "115200 Bd" in check["detail"] and "COM1" in check["detail"] and "RANGECMP" in check["detail"]
    assert rover_a["figures"]["measured_load_pct"] > 80.0
    assert "baud" in check["fix"]
    assert "rover_b" not in _no_go(doc)


def test_a_dead_can_role_is_no_go(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """A role mapped to a message of the DBC the car's bus does not carry; plain text off a terminal."""
    dbc = tmp_path / "vsc_plus.dbc"
    text = (Path(__file__).resolve().parents[2] / "sim_devices" / "data" / "vsc_sim.dbc").read_text()
    extra = 'BO_ 800 ESC_Status2: 8 ESC\n SG_ ESC_Flags : 0|8@1+ (1,0) [0|255] "" RIG\n\n'
    text = text.replace('\n\nCM_ "Simulated', "\n\n" + extra + 'CM_ "Simulated', 1)
    text += '\nBA_ "GenMsgCycleTime" BO_ 800 20;\n'
    dbc.write_text(text)
    code, out = _preflight(capsys, tmp_path, "--set", f"can.0.dbc={dbc}",
                           "--set", "can.0.roles.esc_flags.message=ESC_Status2",
                           "--set", "can.0.roles.esc_flags.signal=ESC_Flags", as_json=False)
    assert code == 1
    lines = out.splitlines()
    verdicts = {line.split()[1]: line.split()[0] for line in lines if line.startswith(("GO ", "NO-GO "))}
    assert verdicts["can.vsc"] == "NO-GO"
    assert {d for d, v in verdicts.items() if v != "GO"} == {"can.vsc"}
    row = next(line for line in lines if line.startswith("NO-GO  can.vsc"))
    assert "esc_flags (ESC_Status2, 0x320) never seen" in row
    assert lines[-1].startswith("preflight: NO-GO")


def test_a_floating_daq_channel_is_no_go(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """The brake-pressure channel configured for a transducer the simulated car does not have: its input floats."""
    code, doc = _preflight(capsys, tmp_path, "--set", "daq.analog.0.name=fuel_pressure")
    assert code == 1
    assert _no_go(doc) == {"daq.SimDAQ"}
    daq = _devices(doc)["daq.SimDAQ"]
    check = _failed(daq)
    assert check["check"] == "channel p_mc" and "floating" in check["detail"]
    assert daq["figures"]["channels"]["p_mc"]["median_step_v"] > 0.05
    assert all(c["ok"] for c in daq["checks"] if c["check"] != "channel p_mc")


def test_a_configuration_error_exits_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert _run(["preflight", str(SIM), "--set", "receivers.1.baud=12345", "--out", str(tmp_path)]) == 2
    assert "baud" in capsys.readouterr().err


def test_the_command_defaults_are_the_library_defaults() -> None:
    """rig.cli.preflight_cmd keeps its defaults as numbers (``rig --help`` stays fast): the same as the library's."""
    from rig.cli import preflight_cmd
    from rig.record import preflight

    assert preflight_cmd.DEFAULT_WAIT_S == preflight.DEFAULT_WAIT_S
    assert preflight_cmd.DEFAULT_DURATION_MIN == preflight.DEFAULT_DURATION_MIN


def test_a_receiver_on_usb_logs_to_the_laptop_and_logs_sent_to_com1_do_not(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """A PwrPak7 on USB: the laptop is on the receiver's USB1. The rig's logs go to THISPORT, so they reach the
    laptop (GO); logs requested on COM1 (what ``command_port = COM1`` used to send) go to the physical COM1 and
    the laptop gets nothing (NO-GO naming the logs that do not arrive)."""
    code, doc = _preflight(capsys, tmp_path, "--set", "receivers.1.command_port=USB1")
    rover = _devices(doc)["rover_a"]
    assert rover["verdict"] == "GO", rover["reason"]
    code, doc = _preflight(capsys, tmp_path, "--set", "receivers.1.command_port=USB1", "--set",
                           'receivers.1.extra_commands=["UNLOGALL THISPORT", "LOG COM1 BESTPOSB ONTIME 0.05"]')
    assert code == 1
    rover = _devices(doc)["rover_a"]
    failed = [c for c in rover["checks"] if not c["ok"]]
    assert rover["verdict"] != "GO" and any("BESTPOS" in c["detail"] for c in failed), failed
