"""Each simulated receiver has its own output latency, drawn per seed in 15-50 ms (OEM7 Commands and Logs
Reference, MARK1TIME: logs leave typically 20-30 ms, 50 ms at most, after their epoch); the rig is never told
it, so the wire has to show it."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import serial

from drivers.novatel import BestPos, Framer
from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.gnss.receiver import LATENCY_RANGE_S
from sim_devices.vehicle import GroundTruth
from vsccore.clock import Clock
from vsccore.gpstime import NS_PER_S

BESTPOSB_TX_S = 104 * 10 / 115200  # a 104-byte BESTPOSB at 115200 Bd


@pytest.fixture
def rovers(truth: GroundTruth, timebase: SimTimeBase) -> Iterator[list[SimRover]]:
    clock = timebase.make_clock(speed=1.0)  # real time: the reader's wake-up is not multiplied
    made = [SimRover(f"rover_{s}", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, clock=clock, seed=s,
                     latency_jitter_s=0.0) for s in (1, 2)]
    for r in made:
        r.start()
    yield made
    for r in made:
        r.stop()


def _arrival_latencies_s(rover: SimRover, clock: Clock, timebase: SimTimeBase, n: int = 30) -> np.ndarray:
    """GPS time each BESTPOSB was complete on the wire minus its epoch, for n logs at 20 Hz."""
    out: list[float] = []
    with serial.Serial(rover.port_path, 115200, timeout=0.5) as port:
        port.write(b"LOG BESTPOSB ONTIME 0.05\r\n")
        framer = Framer()
        deadline = time.monotonic() + 10.0
        while len(out) < n:
            assert time.monotonic() < deadline, f"{len(out)} BESTPOS in 10 s"
            data = port.read(max(1, port.in_waiting))  # returns as soon as a byte is there
            now = timebase.gps_ns(clock.now_ns())
            for f in framer.feed(data):
                if f.log is not None and isinstance(f.log.body, BestPos):
                    out.append((now - f.log.header.gps_ns) / NS_PER_S)
    return np.array(out)


def test_each_receiver_draws_its_own_output_latency(rovers: list[SimRover], timebase: SimTimeBase,
                                                    tmp_path: Path) -> None:
    a, b = rovers
    lo, hi = LATENCY_RANGE_S
    assert lo <= a.output_latency_s <= hi and lo <= b.output_latency_s <= hi
    assert abs(a.output_latency_s - b.output_latency_s) > 0.02  # seeds 1 and 2: 18.6 and 47.3 ms
    again = SimRover("rover_1", truth=a.truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, seed=1,
                     link_dir=tmp_path)
    assert again.output_latency_s == a.output_latency_s  # the same receiver (seed) every session
    for rover in rovers:
        lat = _arrival_latencies_s(rover, rover.clock, timebase)
        # never early; the quickest logs leave at the receiver's own latency (+ serial time, + the reader)
        assert lat.min() >= rover.output_latency_s + BESTPOSB_TX_S - 1e-3
        assert lat.min() < rover.output_latency_s + BESTPOSB_TX_S + 0.015  # the two differ by 29 ms


def test_an_explicit_latency_still_wins(truth: GroundTruth, timebase: SimTimeBase, tmp_path: Path) -> None:
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, output_latency_s=0.02,
                     link_dir=tmp_path)
    assert rover.output_latency_s == 0.02
