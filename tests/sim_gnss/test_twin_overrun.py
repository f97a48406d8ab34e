"""A port at the factory 9600 Bd that is asked for more than it carries overruns, and the simulated receiver
says so as an OEM7 does: the COM port tx buffer overrun bit of the receiver status word (in every log header
and in RXSTATUS) and the port's own bit in the auxiliary status (OEM7 Commands and Logs Reference: RXSTATUS;
Serial Port Communications: "If the buffer overrun flag is present in the RXSTATUS log, log at a higher baud
rate"), besides the twin's ``bytes_overrun`` counter. RXSTATUS is checked against NovAtel's EDIE."""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from drivers.novatel import BestPos, Frame, FrameKind, RawBody
from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.gnss.receiver import ReceiverStatus
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader

oem = pytest.importorskip("novatel_edie.oem")

Opener = Callable[..., PortReader]
OVERRUN = int(ReceiverStatus.COM_TX_BUFFER_OVERRUN)
AUX2_COM1, AUX2_COM3 = 0x200, 0x800  # RXSTATUS, Auxiliary 2 Status: COM1 / COM3 buffer overrun


def _rxstatus(frames: list[Frame]) -> list[tuple[int, list[int], bytes]]:
    """(error word, [receiver status, aux1 … aux4], raw frame) of each binary RXSTATUS."""
    out = []
    for f in frames:
        if f.log is not None and f.log.name == "RXSTATUS" and f.kind is FrameKind.NOVATEL_BINARY:
            body = f.log.body
            assert isinstance(body, RawBody)
            error, count = struct.unpack_from("<II", body.data)
            words = [struct.unpack_from("<I", body.data, 8 + 16 * k)[0] for k in range(count)]
            out.append((error, words, f.raw))
    return out


def _edie(raw: bytes) -> dict[str, Any]:
    parser = oem.Parser()
    parser.write(raw)
    return dict(parser.read().to_dict())


@pytest.fixture
def usb_rover(truth: GroundTruth, timebase: SimTimeBase) -> Iterator[SimRover]:
    """The laptop on USB1; COM1 cabled and left at the factory 9600 N 8 1."""
    rx = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase,
                  clock=timebase.make_clock(speed=SPEED), port_name="USB1", extra_ports=("COM1",), baud=None)
    rx.start()
    yield rx
    rx.stop()


def test_a_factory_9600_port_that_carries_20_hz_logs_overruns_and_says_so(usb_rover: SimRover,
                                                                          open_port: Opener) -> None:
    rover = usb_rover
    usb = open_port(rover.port_path)
    com1 = open_port(str(rover.port("COM1").path), 9600)
    assert usb.command("LOG RXSTATUSB ONCHANGED").message.ok
    assert usb.command("LOG TIMEB ONTIME 0.5").message.ok
    clean = usb.until(lambda fs: bool(_rxstatus(fs)))
    assert _rxstatus(clean)[0][1][0] & OVERRUN == 0  # nothing overrun yet
    # 20 Hz BESTPOSB + BESTXYZB is ~5 kB/s; 9600 Bd carries 960 B/s
    assert usb.command("LOG COM1 BESTPOSB ONTIME 0.05").message.ok
    assert usb.command("LOG COM1 BESTXYZB ONTIME 0.05").message.ok
    usb.until(lambda fs: any(w[0] & OVERRUN for _, w, _ in _rxstatus(fs)), timeout_s=10.0)
    error, words, raw = next(r for r in _rxstatus(usb.frames) if r[1][0] & OVERRUN)
    assert error == 0 and len(words) == 5
    assert words[2] & AUX2_COM1 and not words[2] & AUX2_COM3
    ref = _edie(raw)  # NovAtel's decoder reads the same words
    assert ref["rx_error"] == 0
    assert [w["status_word"] for w in ref["status_words"]] == words
    # every log header carries the receiver status word
    usb.until(lambda fs: any(f.log is not None and f.log.name == "TIME" and f.log.header.receiver_status & OVERRUN
                             for f in fs))
    assert rover.bytes_overrun("COM1") > 0 and rover.bytes_overrun("USB1") == 0
    # the overrun port's own logs carry it too (those that fit: fewer than asked for)
    com1.until(lambda fs: any(f.log.header.receiver_status & OVERRUN for f in fs
                              if f.log is not None and isinstance(f.log.body, BestPos)), timeout_s=10.0)


def test_a_port_without_a_cable_overruns_all_the_same(truth: GroundTruth, timebase: SimTimeBase,
                                                      open_port: Opener) -> None:
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase,
                     clock=timebase.make_clock(speed=SPEED))
    rover.start()
    try:
        port = open_port(rover.port_path)
        assert port.command("LOG RXSTATUSB ONCHANGED").message.ok
        assert port.command("LOG COM3 BESTPOSB ONTIME 0.05").message.ok  # COM3: factory 9600, no cable
        assert port.command("LOG COM3 BESTXYZB ONTIME 0.05").message.ok
        port.until(lambda fs: any(w[2] & AUX2_COM3 for _, w, _ in _rxstatus(fs)), timeout_s=10.0)
        assert rover.bytes_overrun("COM3") > 0 and rover.bytes_overrun() == 0
    finally:
        rover.stop()
