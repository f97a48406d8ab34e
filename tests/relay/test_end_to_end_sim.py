"""End to end with the simulated receivers: base → relay → two rovers. The rovers reach NARROW_INT
only while the relay runs, fall back when it stops, and their BESTPOS differential age is fed into
the relay's statistics."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
import serial

from drivers.novatel import BestPos, Framer, PositionType
from drivers.relay import Relay, open_sink, open_source
from sim_devices.gnss import RtkParams, SimBase, SimRover, SimTimeBase
from sim_devices.vehicle import Drive, GroundTruth, make_scenario, simulate

SPEED = 2.0  # receivers run 2x real time on a free-running clock: a relay held up 0.25 s of wall time by a busy
# host was 2.5 s of correction age at 10x (a CI run on 4 workers saw fixed logs past the 2.5 s age limit)
RTK = RtkParams(
    max_correction_age_s=2.5, float_hold_s=4.0, psrdiff_timeout_s=6.0, time_to_float_s=1.0, time_to_fix_s=3.0
)


@pytest.fixture(scope="module")
def truth() -> GroundTruth:
    return simulate(Drive([make_scenario("straight", speed_kmh=50.0, duration_s=40.0)]), rate_hz=50.0)


class Bestpos:
    """Reads a rover's log port and keeps its BESTPOS logs (waits with timeouts, no sleeps)."""

    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, 115200, timeout=0.02)
        self.framer = Framer()
        self.logs: list[BestPos] = []

    def command(self, line: str) -> None:
        self.port.write(line.encode() + b"\r\n")

    def until(self, done: Callable[[list[BestPos]], bool], timeout_s: float, since: int = 0) -> list[BestPos]:
        """Read until ``done(logs[since:])``; return ``logs[since:]``."""
        deadline = time.monotonic() + timeout_s
        while not done(self.logs[since:]):
            assert time.monotonic() < deadline, f"timed out; last types {[b.pos_type.name for b in self.logs[-5:]]}"
            data = self.port.read(65536)
            for f in self.framer.feed(data) if data else []:
                if f.log is not None and isinstance(f.log.body, BestPos):
                    self.logs.append(f.log.body)
        return self.logs[since:]

    def close(self) -> None:
        self.port.close()


@pytest.fixture
def rig(truth: GroundTruth) -> Iterator[tuple[SimBase, list[SimRover]]]:
    timebase = SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)
    clock = timebase.make_clock(speed=SPEED)
    base = SimBase(
        "base", position=(truth.lat0_deg, truth.lon0_deg, truth.h0_m), timebase=timebase, clock=clock, station_id=42
    )
    rovers = [
        SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, clock=clock, rtk=RTK),
        SimRover("rover_b", truth=truth, lever_arm=(-0.98, 0.0, 1.0), timebase=timebase, clock=clock, rtk=RTK, seed=5),
    ]
    base.start()
    for r in rovers:
        r.start()
    yield base, rovers
    for r in rovers:
        r.stop()
    base.stop()


def _n_fixed(n: int) -> Callable[[list[BestPos]], bool]:
    return lambda logs: sum(1 for b in logs if b.pos_type is PositionType.NARROW_INT) >= n


def test_rovers_fix_only_with_the_relay_running(rig: tuple[SimBase, list[SimRover]]) -> None:
    base, rovers = rig
    readers = [Bestpos(r.port_path) for r in rovers]
    relay = Relay(
        open_source(base.port_path),
        [open_sink(r.correction_port_path) for r in rovers],
        clock=base.clock,
    )
    try:
        for rd in readers:
            rd.command("INTERFACEMODE COM2 RTCMV3 NONE OFF")  # raw RTCM3 in; the factory NOVATEL mode ignores it
            rd.command("LOG BESTPOSB ONTIME 0.2")
        # Without the relay: no corrections, no RTK.
        for rd in readers:
            rd.until(lambda logs: len(logs) >= 10, timeout_s=10)
            assert {b.pos_type for b in rd.logs} == {PositionType.SINGLE}
        relay.start()
        for rd, rover in zip(readers, rovers, strict=True):
            start = len(rd.logs)
            got = rd.until(_n_fixed(10), timeout_s=15, since=start)
            fixed = [b for b in got if b.pos_type is PositionType.NARROW_INT]
            assert all(b.stn_id == "42" and 0.0 <= b.diff_age_s < 2.5 for b in fixed)
            relay.note_rover_diff_age(rover.name, fixed[-1].diff_age_s)
        stats = relay.stats()
        assert stats.rejected_frames == 0
        assert {"RTCM 1006", "RTCM 1077", "RTCM 1087"} <= set(stats.frames_by_type)
        assert all(s.frames_out > 0 and s.dropped_total == 0 for s in stats.sinks)
        assert set(stats.rovers) == {"rover_a", "rover_b"}
        assert all(r.age_s is not None and r.age_s < 2.5 for r in stats.rovers.values())
        # Relay stopped: the rovers lose the fix as the correction age passes the limits.
        relay.stop()
        for rd in readers:
            start = len(rd.logs)
            later = rd.until(
                lambda logs: any(b.pos_type is PositionType.PSRDIFF for b in logs), timeout_s=15, since=start
            )
            tail = later[[b.pos_type for b in later].index(PositionType.PSRDIFF) :]
            assert PositionType.NARROW_INT not in {b.pos_type for b in tail}
            assert max(b.diff_age_s for b in tail) > 2.5
    finally:
        relay.stop()
        for rd in readers:
            rd.close()
