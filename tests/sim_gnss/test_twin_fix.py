"""FIX POSITION on the simulated base as on an OEM7: the height is above MSL under the factory ``UNDULATION
EGM96`` (the EGM96 geoid of the site), ellipsoidal after ``UNDULATION USER 0``; a fixed position 25-50 m off
the antenna is INTEGRITY_WARNING, worse INVALID_FIX, and then no corrections go out (OEM7 Commands and Logs
Reference: FIX, UNDULATION)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pymap3d
import pytest
from pyrtcm import RTCMReader

from drivers.novatel import BestPos, Frame, FrameKind, SolutionStatus
from sim_devices.gnss import SimBase, SimTimeBase
from sim_devices.gnss.geoid import egm96_undulation_m
from tests.sim_gnss.conftest import SPEED, PortReader

Opener = Callable[..., PortReader]
POSITION = (48.7758, 9.1829, 300.0)  # ellipsoidal height
#: EGM96 geoid heights (m) from PROJ's egm96_15.gtx (NGA's 15' grid), bilinear: Stuttgart, NovAtel's Calgary
#: (the FIX page's example), the Gulf of Guinea.
EGM96_15 = {(48.7758, 9.1829): 48.55, (51.116, -114.038): -16.99, (0.0, 0.0): 17.16}


@pytest.fixture
def base(timebase: SimTimeBase) -> Iterator[SimBase]:
    b = SimBase("base", position=POSITION, timebase=timebase, clock=timebase.make_clock(speed=SPEED), station_id=7)
    b.start()
    yield b
    b.stop()


def _rtcm(frames: list[Frame]) -> list[Frame]:
    return [f for f in frames if f.kind is FrameKind.RTCM3]


def _bestpos(frames: list[Frame]) -> list[BestPos]:
    return [f.log.body for f in frames if f.log is not None and isinstance(f.log.body, BestPos)]


def _after_command(port: PortReader, command: str, n: int = 4) -> tuple[BestPos, list[Frame]]:
    """Send a command; return the first BESTPOS made after it and every frame from there on to the n-th."""
    assert port.command(command).message.ok, command
    start = len(port.frames)
    port.until(lambda fs: len(_bestpos(fs[start:])) >= n)
    tail = port.frames[start:]
    first = next(i for i, f in enumerate(tail) if f.log is not None and isinstance(f.log.body, BestPos))
    # the first BESTPOS after the command may still be an epoch before it: take the next one
    second = next(i for i, f in enumerate(tail) if i > first and f.log is not None and isinstance(f.log.body, BestPos))
    body = tail[second].log.body
    assert isinstance(body, BestPos)
    return body, tail[second:]


def test_the_grid_is_egm96() -> None:
    for (lat, lon), n in EGM96_15.items():
        assert egm96_undulation_m(lat, lon) == pytest.approx(n, abs=0.5)


def test_factory_undulation_is_the_egm96_geoid_of_the_site(base: SimBase, open_port: Opener) -> None:
    port = open_port(base.port_path)
    assert port.command("LOG BESTPOSA ONTIME 1").message.ok
    port.until(lambda fs: bool(_bestpos(fs)) and any(RTCMReader.parse(f.raw).identity == "1006" for f in _rtcm(fs)))
    pos = _bestpos(port.frames)[0]
    assert pos.undulation_m == pytest.approx(EGM96_15[POSITION[:2]], abs=0.5)
    assert pos.hgt_m + pos.undulation_m == pytest.approx(POSITION[2], abs=1e-3)  # the saved FIX is MSL
    assert pos.sol_status is SolutionStatus.SOL_COMPUTED
    msg = next(m for m in map(RTCMReader.parse, (f.raw for f in _rtcm(port.frames))) if m.identity == "1006")
    assert pytest.approx(pymap3d.geodetic2ecef(*POSITION), abs=1e-3) == (msg.DF025, msg.DF026, msg.DF027)


def test_fix_height_is_ellipsoidal_after_undulation_user_0(base: SimBase, open_port: Opener) -> None:
    port = open_port(base.port_path)
    lat, lon, h = POSITION
    for cmd in ("UNLOGALL", "LOG RTCM1006 ONTIME 1", "LOG BESTPOSA ONTIME 0.5", "UNDULATION USER 0"):
        assert port.command(cmd).message.ok, cmd
    pos, tail = _after_command(port, f"FIX POSITION {lat} {lon} {h}")
    assert (pos.hgt_m, pos.undulation_m, pos.sol_status) == (pytest.approx(h), 0.0, SolutionStatus.SOL_COMPUTED)
    msg = RTCMReader.parse(_rtcm(tail)[0].raw)
    assert pytest.approx(pymap3d.geodetic2ecef(lat, lon, h), abs=1e-3) == (msg.DF025, msg.DF026, msg.DF027)
    # back to EGM96, the same FIX means 300 m above MSL: ~48 m above the antenna (order does not matter)
    pos, tail = _after_command(port, "UNDULATION EGM96")
    assert pos.sol_status is SolutionStatus.INTEGRITY_WARNING
    assert not _rtcm(tail)


@pytest.mark.parametrize(("north_m", "status"), [(30.0, SolutionStatus.INTEGRITY_WARNING),
                                                 (200.0, SolutionStatus.INVALID_FIX)])
def test_a_fixed_position_off_the_antenna_is_flagged_and_stops_the_corrections(
        base: SimBase, open_port: Opener, north_m: float, status: SolutionStatus) -> None:
    port = open_port(base.port_path)
    lat, lon, h = POSITION
    msl = h - base.undulation_m
    assert port.command("LOG BESTPOSB ONTIME 0.5").message.ok
    off_lat, off_lon, _ = pymap3d.enu2geodetic(0.0, north_m, 0.0, lat, lon, h)
    pos, tail = _after_command(port, f"FIX POSITION {off_lat:.9f} {off_lon:.9f} {msl:.4f}", n=6)
    assert pos.sol_status is status
    assert all(b.sol_status is status for b in _bestpos(tail))
    assert not _rtcm(tail)  # 2 s of 1 Hz RTCM: none
    pos, tail = _after_command(port, f"FIX POSITION {lat:.9f} {lon:.9f} {msl:.4f}", n=6)
    assert pos.sol_status is SolutionStatus.SOL_COMPUTED
    assert _rtcm(tail)
