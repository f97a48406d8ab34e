"""Fixtures of the simulated-GNSS tests: a short drive, leak checks for fds, and a pty port reader."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator

import pytest
import serial

from drivers.novatel import Frame, Framer
from sim_devices.gnss import SimTimeBase
from sim_devices.vehicle import Drive, GroundTruth, make_scenario, simulate

#: How much faster than real time the receivers run in these tests.
SPEED = 10.0


@pytest.fixture(scope="session")
def truth() -> GroundTruth:
    """Step steer at 60 km/h, then 20 s straight: ~30 s of drive at 100 Hz."""
    drive = Drive([make_scenario("step_steer", speed_kmh=60.0), make_scenario("straight", speed_kmh=60.0,
                                                                               duration_s=20.0)], gap_s=1.0)
    return simulate(drive, rate_hz=100.0)


@pytest.fixture
def timebase() -> SimTimeBase:
    return SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)


def _fds() -> dict[str, str]:
    out = {}
    for fd in os.listdir("/proc/self/fd"):
        try:
            out[fd] = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
    return out


@pytest.fixture(autouse=True)
def _no_fd_leaks() -> Iterator[None]:
    """Every pty, pipe and port a test opens is closed when it ends."""
    before = _fds()
    yield
    after = _fds()
    leaked = {fd: target for fd, target in after.items() if (before.get(fd) != target and "pts" in target)
              or (fd not in before and target.startswith(("pipe:", "/dev/pt")))}
    assert not leaked, f"file descriptors left open: {leaked}"


class PortReader:
    """Reads a pyserial port through the codec's framer, waiting with timeouts (never bare sleeps)."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port
        self.framer = Framer()
        self.frames: list[Frame] = []

    def poll(self) -> list[Frame]:
        data = self.port.read(65536)
        new = self.framer.feed(data) if data else self.framer.flush()
        self.frames.extend(new)
        return new

    def until(self, done: Callable[[list[Frame]], bool], timeout_s: float = 5.0) -> list[Frame]:
        """Read until ``done(all frames so far)`` is true; fail after ``timeout_s`` of wall time."""
        deadline = time.monotonic() + timeout_s
        while not done(self.frames):
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s} s; got {len(self.frames)} frames")
            self.poll()
        return self.frames

    def command(self, line: str, timeout_s: float = 3.0) -> Frame:
        """Send a command and return its response frame."""
        start = len(self.frames)
        self.port.write(line.encode("ascii") + b"\r\n")
        frames = self.until(lambda fs: any(f.kind.value == "response" for f in fs[start:]), timeout_s)
        return next(f for f in frames[start:] if f.kind.value == "response")


@pytest.fixture
def open_port() -> Iterator[Callable[..., PortReader]]:
    """Open pyserial ports (closed at the end of the test)."""
    ports: list[serial.Serial] = []

    def opener(path: str, baud: int = 115200) -> PortReader:
        s = serial.Serial(path, baud, timeout=0.02)
        ports.append(s)
        return PortReader(s)

    yield opener
    for s in ports:
        s.close()
