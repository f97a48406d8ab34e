"""The simulated base over pyserial: RTCM3 at 1 Hz that pyrtcm decodes, and its commands."""

from __future__ import annotations

import collections
from collections.abc import Callable, Iterator

import pymap3d
import pytest
from pyrtcm import RTCMReader

from drivers.novatel import BestPos, FrameKind, PositionType
from sim_devices.gnss import SimBase, SimTimeBase
from sim_devices.gnss.geoid import egm96_undulation_m
from tests.sim_gnss.conftest import SPEED, PortReader
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK

POSITION = (48.7758, 9.1829, 300.0)


@pytest.fixture
def base(timebase: SimTimeBase) -> Iterator[SimBase]:
    b = SimBase("base", position=POSITION, timebase=timebase, clock=timebase.make_clock(speed=SPEED),
                station_id=42)
    b.start()
    yield b
    b.stop()


def _rtcm(frames: list) -> list:
    return [f for f in frames if f.kind is FrameKind.RTCM3]


def test_streams_rtcm_that_pyrtcm_decodes(base: SimBase, open_port: Callable[..., PortReader]) -> None:
    port = open_port(base.port_path)
    frames = port.until(lambda fs: len(_rtcm(fs)) >= 5 * 4)
    numbers = collections.Counter()
    epochs: dict[int, list[int]] = collections.defaultdict(list)
    for f in _rtcm(frames):
        msg = RTCMReader.parse(f.raw)  # pyrtcm checks the CRC and decodes every field
        numbers[int(msg.identity)] += 1
        assert msg.DF003 == 42
        if msg.identity == "1006":
            ecef = pymap3d.geodetic2ecef(*POSITION)
            assert pytest.approx(ecef, abs=1e-3) == (msg.DF025, msg.DF026, msg.DF027)
        if msg.identity == "1077":
            assert msg.DF004 % 1000 == 0  # epochs on whole GPS seconds
            assert msg.NSat >= 4 and msg.DF393 == 1  # 1087 follows in the same epoch
            epochs[msg.DF004].append(1077)
        if msg.identity == "1087":
            assert msg.NSat >= 4 and msg.DF393 == 0  # last MSM of its epoch
    assert set(numbers) == {1006, 1033, 1077, 1087, 1230}
    assert max(numbers.values()) - min(numbers.values()) <= 1
    tows = sorted(epochs)
    assert all(b - a == 1000 for a, b in zip(tows, tows[1:], strict=False))  # 1 Hz
    assert port.framer.stats.crc_failures[FrameKind.RTCM3] == 0


def test_base_commands(base: SimBase, open_port: Callable[..., PortReader]) -> None:
    port = open_port(base.port_path)
    assert port.command("UNLOGALL").message.ok
    # FIX reads its height above mean sea level (factory UNDULATION EGM96): the antenna's ellipsoidal height
    # less the geoid's, within the receiver's 25 m integrity limit (a fix 10 km away would be INVALID_FIX)
    und = egm96_undulation_m(POSITION[0], POSITION[1])
    assert port.command(f"FIX POSITION {POSITION[0]} {POSITION[1]} {POSITION[2] - und:.4f}").message.ok
    assert port.command("LOG COM1 RTCM1005 ONTIME 2").message.ok
    assert port.command("LOG BESTPOSA ONTIME 1").message.ok
    start = len(port.frames)
    frames = port.until(lambda fs: len(_rtcm(fs[start:])) >= 3)[start:]
    msgs = [RTCMReader.parse(f.raw) for f in _rtcm(frames)]
    assert {m.identity for m in msgs} == {"1005"}
    ecef = pymap3d.geodetic2ecef(*POSITION)  # the MSL height read back onto the ellipsoid
    assert pytest.approx(ecef, abs=1e-3) == (msgs[0].DF025, msgs[0].DF026, msgs[0].DF027)
    pos = [f.log.body for f in frames if f.log is not None and f.log.name == "BESTPOS"]
    assert pos and isinstance(pos[0], BestPos) and pos[0].pos_type is PositionType.FIXEDPOS
    want = (POSITION[0], POSITION[1], POSITION[2] - und)
    assert (pos[0].lat_deg, pos[0].lon_deg, pos[0].hgt_m) == pytest.approx(want)
    assert port.command("FIX NONE").message.ok
    start = len(port.frames)
    later = port.until(lambda fs: sum(1 for f in fs[start:] if f.log is not None) >= 3)[start:]
    assert not _rtcm(later[1:])  # no fixed position: no station message
    assert [f.log.body.pos_type for f in later if f.log is not None][-1] is PositionType.SINGLE
    assert port.command("RESET").message.ok  # back to the saved configuration: streams again
    start = len(port.frames)
    port.until(lambda fs: {RTCMReader.parse(f.raw).identity for f in _rtcm(fs[start:])} >= {"1006", "1077"})
    now_week, now_sow = divmod(base.gps_now_ns(), NS_PER_WEEK)
    for f in port.frames:
        if f.log is not None:  # logs carry the receiver's GPS time, at most a few seconds old
            assert f.log.header.week == now_week and 0 <= now_sow / NS_PER_S - f.log.header.seconds < 10 * SPEED
