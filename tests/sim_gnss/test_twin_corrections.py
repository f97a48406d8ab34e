"""Corrections reach the simulated rover only the ways they reach an OEM7: raw RTCM3 on a port set to RTCMV3
receive, or RTCM logs with a NovAtel header (``RTCM1077B``/``A``) on a port left in the factory NOVATEL mode;
raw RTCM3 on a NOVATEL port is no command and no correction (OEM7 Commands and Logs Reference,
INTERFACEMODE; Transmitting and receiving corrections, Configuration notes)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

import pytest
import serial

from drivers.novatel import BestPos, Frame, FrameKind, Framer, PositionType
from sim_devices.gnss import RtkParams, SimBase, SimRover, SimTimeBase
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader

Opener = Callable[..., PortReader]
FAST_RTK = RtkParams(max_correction_age_s=2.5, float_hold_s=4.0, psrdiff_timeout_s=6.0, time_to_float_s=1.0,
                     time_to_fix_s=3.0)


class Relay:
    """Copies the base's port to the rover's correction port (a radio link) and frames what it copied."""

    def __init__(self, src_path: str, dst_path: str) -> None:
        self.src = serial.Serial(src_path, 115200, timeout=0.02)
        self.dst = serial.Serial(dst_path, 115200, timeout=0.02)
        self.framer = Framer(decode_logs=False, decode_rtcm=False)
        self.kinds: list[FrameKind] = []
        self.back = b""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="test-relay")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            data = self.src.read(4096)
            if data:
                self.kinds.extend(f.kind for f in self.framer.feed(data))
                self.dst.write(data)
            self.back += self.dst.read(4096)  # what the rover's correction port says back

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.src.close()
        self.dst.close()


@pytest.fixture
def pair(truth: GroundTruth, timebase: SimTimeBase) -> Iterator[tuple[SimBase, SimRover]]:
    clock = timebase.make_clock(speed=SPEED)
    base = SimBase("base", position=(truth.lat0_deg, truth.lon0_deg, truth.h0_m), timebase=timebase, clock=clock,
                   station_id=42)
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, clock=clock,
                     rtk=FAST_RTK)
    base.start()
    rover.start()
    yield base, rover
    rover.stop()
    base.stop()


def _types(frames: list[Frame], start: int = 0) -> list[PositionType]:
    return [f.log.body.pos_type for f in frames[start:] if f.log is not None and isinstance(f.log.body, BestPos)]


def test_raw_rtcm_on_a_novatel_port_is_ignored_until_the_port_is_set_to_rtcmv3(
        pair: tuple[SimBase, SimRover], open_port: Opener) -> None:
    base, rover = pair
    port = open_port(rover.port_path)
    assert port.command("LOG BESTPOSB ONTIME 0.1").message.ok
    relay = Relay(base.port_path, rover.correction_port_path)
    try:
        port.until(lambda fs: len(_types(fs)) >= 40)  # 4 s of 1 Hz corrections on the factory NOVATEL port
        assert set(_types(port.frames)) == {PositionType.SINGLE}
        assert rover.corrections_received == 0 and rover.rtcm_ignored("COM2") > 0
        assert FrameKind.RTCM3 in relay.kinds
        assert relay.back == b""  # no command, no answer
        assert port.command("INTERFACEMODE COM2 RTCMV3 NONE OFF").message.ok
        start = len(port.frames)
        port.until(lambda fs: PositionType.NARROW_INT in _types(fs, start), timeout_s=10.0)
        assert rover.corrections_received > 0
    finally:
        relay.close()


def test_rtcm_with_a_novatel_header_is_taken_on_a_novatel_port(
        pair: tuple[SimBase, SimRover], open_port: Opener) -> None:
    base, rover = pair
    bport = open_port(base.port_path)
    for cmd in ("UNLOGALL", "LOG RTCM1006B ONTIME 1", "LOG RTCM1077A ONTIME 1", "LOG RTCM1087B ONTIME 1"):
        assert bport.command(cmd).message.ok, cmd
    bport.port.close()
    port = open_port(rover.port_path)
    assert port.command("LOG BESTPOSB ONTIME 0.1").message.ok
    relay = Relay(base.port_path, rover.correction_port_path)
    try:
        port.until(lambda fs: PositionType.NARROW_INT in _types(fs), timeout_s=10.0)
    finally:
        relay.close()
    assert rover.port_settings("COM2").rx_mode == "NOVATEL"
    assert rover.corrections_received >= 3
    assert FrameKind.NOVATEL_BINARY in relay.kinds and FrameKind.NOVATEL_ASCII in relay.kinds
    assert FrameKind.RTCM3 not in relay.kinds  # every message went with its NovAtel header
    assert relay.back == b""  # a log is no command: no answer


def test_lenient_corrections_keeps_the_old_shortcut(truth: GroundTruth, timebase: SimTimeBase) -> None:
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase,
                     clock=timebase.make_clock(speed=SPEED), lenient_corrections=True)
    rover.start()
    try:
        assert rover.port_settings("COM2").rx_mode == "AUTO"
        assert rover.port_settings("COM1").rx_mode == "NOVATEL"
    finally:
        rover.stop()
