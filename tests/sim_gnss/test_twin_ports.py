"""The simulated receiver's ports are an OEM7's: COM1-3, USB1-3 and ICOM1 on every receiver, wired or not;
COM ports at the factory 9600 N 8 1, USB without a baud rate, NOVATEL NOVATEL everywhere; ``LOG`` without a
port logs to THISPORT and ``LOG COM1 …`` sent on USB1 goes to COM1 (OEM7 Commands and Logs Reference:
SERIALCONFIG, INTERFACEMODE, LOG)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from drivers.novatel import Frame, FrameKind
from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.gnss.receiver import FACTORY_BAUD, STANDARD_PORTS, PortSettings
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader

Opener = Callable[..., PortReader]


@pytest.fixture
def rover(truth: GroundTruth, timebase: SimTimeBase) -> Iterator[SimRover]:
    """A rover on the laptop's USB1, its COM1 and COM3 cabled too, every port at factory settings."""
    rx = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase,
                  clock=timebase.make_clock(speed=SPEED), port_name="USB1", correction_port_name="COM3",
                  extra_ports=("COM1",), baud=None, enforce_baud=True)
    rx.start()
    yield rx
    rx.stop()


def _logs(frames: list[Frame], name: str) -> list[Frame]:
    return [f for f in frames if f.log is not None and f.log.name == name]


def test_every_receiver_has_the_oem7_ports_at_factory_settings(rover: SimRover) -> None:
    for name in STANDARD_PORTS:
        settings = rover.port_settings(name)
        serial = name.startswith("COM")
        assert settings == PortSettings(name, FACTORY_BAUD if serial else None, "NOVATEL", "NOVATEL", True,
                                        name in ("USB1", "COM1", "COM3")), name


def test_usb_ignores_the_baud_rate_a_com_port_keeps_its_own(rover: SimRover, open_port: Opener) -> None:
    usb = open_port(rover.port_path, 921600)  # any rate on USB
    assert usb.command("LOG VERSIONA ONCE").message.ok
    assert any(f.kind is FrameKind.PROMPT and f.message.port == "USB1" for f in usb.frames)
    wrong = open_port(str(rover.port("COM1").path), 115200)  # COM1 is at the factory 9600: noise both ways
    with pytest.raises(AssertionError, match="timed out"):
        wrong.command("LOG VERSIONA ONCE", timeout_s=0.5)
    wrong.port.close()
    com1 = open_port(str(rover.port("COM1").path), 9600)
    assert com1.command("LOG VERSIONA ONCE").message.ok
    assert any(f.kind is FrameKind.PROMPT and f.message.port == "COM1" for f in com1.frames)


def test_log_goes_to_thisport_or_to_the_port_it_names(rover: SimRover, open_port: Opener) -> None:
    usb = open_port(rover.port_path)
    com1 = open_port(str(rover.port("COM1").path), 9600)
    com3 = open_port(str(rover.port("COM3").path), 9600)
    assert usb.command("LOG TIMEA ONTIME 1").message.ok  # THISPORT: USB1
    assert usb.command("LOG COM1 BESTPOSA ONTIME 1").message.ok  # sent on USB1, goes out of COM1
    assert usb.command("LOG COM3 BESTVELA ONTIME 1").message.ok
    usb.until(lambda fs: len(_logs(fs, "TIME")) >= 2)
    com1.until(lambda fs: len(_logs(fs, "BESTPOS")) >= 2)
    com3.until(lambda fs: len(_logs(fs, "BESTVEL")) >= 2)
    assert {f.log.header.port for f in _logs(usb.frames, "TIME")} == {"USB1"}
    assert {f.log.header.port for f in _logs(com1.frames, "BESTPOS")} == {"COM1"}
    assert {f.log.header.port for f in _logs(com3.frames, "BESTVEL")} == {"COM3"}
    assert not _logs(usb.frames, "BESTPOS") and not _logs(usb.frames, "BESTVEL")
    assert not _logs(com1.frames, "TIME") and not _logs(com3.frames, "BESTPOS")


def test_unwired_ports_take_their_settings(rover: SimRover, open_port: Opener) -> None:
    usb = open_port(rover.port_path)
    assert usb.command("INTERFACEMODE COM2 RTCMV3 NONE OFF").message.ok  # COM2: no cable here
    assert usb.command("SERIALCONFIG COM2 115200 N 8 1 N OFF").message.ok
    assert usb.command("INTERFACEMODE USB2 NONE NONE OFF").message.ok
    assert rover.port_settings("COM2") == PortSettings("COM2", 115200, "RTCMV3", "NONE", False, False)
    assert rover.port_settings("USB2") == PortSettings("USB2", None, "NONE", "NONE", False, False)
    assert rover.port_settings("COM3").baud == FACTORY_BAUD  # untouched
