"""Bytes a simulated GNSS port drops because its reader is behind are counted, not lost silently.

A pty holds only so much: a reader that has the port open but does not read fills it, and the
simulated device drops what does not fit. Those bytes are log data the recording never gets, so the
port counts them apart (:attr:`PtyPort.bytes_lost`) from bytes dropped while nobody had it open, and
the receiver reports them per port (:meth:`SimReceiver.bytes_lost`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.gnss.pty import PtyPort
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED

CHUNK = b"#" * 1024


def _fill(port: PtyPort, limit_bytes: int = 16 << 20) -> int:
    """Write until the pty refuses bytes (or ``limit_bytes`` have been offered); bytes offered."""
    offered = 0
    while port.bytes_dropped == 0 and offered < limit_bytes:
        port.write(CHUNK)
        offered += len(CHUNK)
    return offered


@pytest.fixture
def port(tmp_path: Path) -> Iterator[PtyPort]:
    p = PtyPort("COM1", tmp_path / "rx")
    p.plug()
    yield p
    p.unplug()


def test_a_reader_that_does_not_read_loses_the_bytes_past_the_ptys_capacity(port: PtyPort) -> None:
    fd = os.open(port.path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        assert port.readers() == 1
        offered = _fill(port)
        assert port.bytes_dropped > 0, f"the pty took {offered} bytes without refusing any"
        port.write(CHUNK)
        assert port.bytes_lost == port.bytes_dropped >= len(CHUNK)
        assert port.bytes_written + port.bytes_dropped == offered + len(CHUNK)
    finally:
        os.close(fd)


def test_bytes_dropped_while_nobody_has_the_port_open_are_not_counted_as_lost(port: PtyPort) -> None:
    assert port.readers() == 0
    _fill(port)
    assert port.bytes_dropped > 0 and port.bytes_lost == 0
    port.unplug()
    port.write(CHUNK)
    assert port.bytes_dropped > len(CHUNK) and port.bytes_lost == 0


@pytest.fixture
def rover(truth: GroundTruth, timebase: SimTimeBase, tmp_path: Path) -> Iterator[SimRover]:
    rx = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase,
                  clock=timebase.make_clock(speed=SPEED, lead_s=0.0), link_dir=tmp_path)
    rx.start()
    yield rx
    rx.stop()


def _until(done: Callable[[], bool], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, f"not within {timeout_s} s"
        time.sleep(0.01)  # polling a condition set by the receiver's thread, bounded by the deadline


def test_receiver_reports_per_port_the_log_bytes_its_reader_never_got(rover: SimRover) -> None:
    assert rover.bytes_lost() == {"COM1": 0, "COM2": 0}
    fd = os.open(rover.port_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        # ask for a lot of logs, then never read: the pty fills and the receiver drops the rest
        os.write(fd, b"UNLOGALL\r\nLOG RANGEB ONTIME 0.05\r\nLOG BESTPOSB ONTIME 0.05\r\n")
        _until(lambda: rover.bytes_lost()["COM1"] > 0, timeout_s=20.0)
    finally:
        os.close(fd)
    assert rover.error is None
    assert rover.bytes_lost()["COM2"] == 0
    assert rover.port().bytes_lost == rover.bytes_lost()["COM1"]
