"""A reset of the simulated rover does what it does to an OEM7: a silent moment, the saved configuration back
(logs not saved with SAVECONFIG gone), the time status UNKNOWN → COARSE → FINESTEERING in the log headers, and
no RTK before FINESTEERING (OEM7 Commands and Logs Reference: RESET, SAVECONFIG, GPS Reference Time Status)."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

import pytest
import serial

from drivers.novatel import BestPos, Frame, FrameKind, PositionType, TimeStatus
from sim_devices.gnss import RtkParams, SimBase, SimRover, SimTimeBase
from sim_devices.gnss.receiver import StartupTiming
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader

Opener = Callable[..., PortReader]
FAST_RTK = RtkParams(max_correction_age_s=2.5, float_hold_s=4.0, psrdiff_timeout_s=6.0, time_to_float_s=1.0,
                     time_to_fix_s=3.0)
STARTUP = StartupTiming(silent_s=1.0, coarse_s=2.0, finesteering_s=5.0)
_ORDER = {TimeStatus.UNKNOWN: 0, TimeStatus.COARSE: 1, TimeStatus.FINESTEERING: 2}


@pytest.fixture
def linked(truth: GroundTruth, timebase: SimTimeBase) -> Iterator[SimRover]:
    """A rover whose COM2 gets a base's RTCM3 over a relay."""
    clock = timebase.make_clock(speed=SPEED)
    base = SimBase("base", position=(truth.lat0_deg, truth.lon0_deg, truth.h0_m), timebase=timebase, clock=clock)
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, clock=clock,
                     rtk=FAST_RTK, startup=STARTUP)
    base.start()
    rover.start()
    src = serial.Serial(base.port_path, 115200, timeout=0.02)
    dst = serial.Serial(rover.correction_port_path, 115200, timeout=0.02)
    stop = threading.Event()

    def relay() -> None:
        while not stop.is_set():
            data = src.read(4096)
            if data:
                dst.write(data)

    thread = threading.Thread(target=relay, name="test-relay")
    thread.start()
    yield rover
    stop.set()
    thread.join(5.0)
    src.close()
    dst.close()
    rover.stop()
    base.stop()


def _bestpos(frames: list[Frame]) -> list[Frame]:
    return [f for f in frames if f.log is not None and isinstance(f.log.body, BestPos)]


@pytest.mark.parametrize("via", ["command", "method"])
def test_reset_restarts_the_receiver(linked: SimRover, open_port: Opener, via: str) -> None:
    rover = linked
    port = open_port(rover.port_path)
    for cmd in ("INTERFACEMODE COM2 RTCMV3 NONE OFF", "LOG BESTPOSB ONTIME 0.2", "LOG TIMEA ONTIME 1", "SAVECONFIG",
                "LOG PSRDOPA ONTIME 0.5"):  # PSRDOP is not saved
        assert port.command(cmd).message.ok, cmd
    port.until(lambda fs: any(f.log.body.pos_type is PositionType.NARROW_INT for f in _bestpos(fs)), timeout_s=10.0)
    assert any(f.log is not None and f.log.name == "PSRDOP" for f in port.frames)
    start = len(port.frames)
    if via == "command":
        assert port.command("RESET").message.ok
    else:
        rover.reset()
    assert rover.resets == 1

    def back_to_rtk(fs: list[Frame]) -> bool:
        pos = _bestpos(fs[start:])
        restart = next((i for i, f in enumerate(pos) if f.log.header.time_status is TimeStatus.UNKNOWN), None)
        return restart is not None and any(f.log.body.pos_type is PositionType.NARROW_INT for f in pos[restart:])

    port.until(back_to_rtk, timeout_s=10.0)
    after = port.frames[start:]
    first = next(i for i, f in enumerate(after) if f.log is not None and f.log.header.time_status is TimeStatus.UNKNOWN)
    after = after[first:]
    logs = [f.log for f in after if f.log is not None]
    assert logs and {lg.name for lg in logs} <= {"BESTPOS", "TIME"}  # the unsaved PSRDOP is gone
    statuses = [lg.header.time_status for lg in logs]
    assert [_ORDER[s] for s in statuses] == sorted(_ORDER[s] for s in statuses)  # UNKNOWN → COARSE → FINESTEERING
    assert {TimeStatus.UNKNOWN, TimeStatus.COARSE, TimeStatus.FINESTEERING} <= set(statuses)
    unknown = [lg for lg in logs if lg.header.time_status is TimeStatus.UNKNOWN]
    # silent first: the first log is at least silent_s after the reset; no GPS time yet: week 0
    assert all(lg.header.week == 0 for lg in unknown) and unknown[0].header.seconds >= STARTUP.silent_s
    assert all(lg.body.pos_type is PositionType.NONE for lg in unknown if isinstance(lg.body, BestPos))
    before_fine = [lg.body.pos_type for lg in logs
                   if isinstance(lg.body, BestPos) and lg.header.time_status is not TimeStatus.FINESTEERING]
    assert set(before_fine) <= {PositionType.NONE, PositionType.SINGLE}  # no RTK before FINESTEERING
    assert not any(f.kind is FrameKind.RESPONSE for f in after)  # nothing answered while silent


def test_a_reset_drops_what_was_not_saved(linked: SimRover, open_port: Opener) -> None:
    rover = linked
    port = open_port(rover.port_path)
    assert port.command("LOG BESTPOSB ONTIME 0.5").message.ok
    assert port.command("INTERFACEMODE COM2 RTCMV3 NONE OFF").message.ok
    assert port.command("SERIALCONFIG COM3 57600").message.ok
    rover.reset()
    assert rover.logged() == []  # nothing was saved
    assert rover.port_settings("COM2").rx_mode == "NOVATEL"
    assert rover.port_settings("COM3").baud == 9600
