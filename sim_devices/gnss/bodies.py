"""Typed NovAtel log bodies from a simulated receiver's :class:`~sim_devices.gnss.receiver.Solution`."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pymap3d

from drivers.novatel import (
    BestPos,
    BestVel,
    BestXyz,
    BodyFormat,
    ComponentType,
    Datum,
    Heading,
    Heading2,
    MarkPos,
    PositionType,
    PsrDop,
    RawBody,
    SolutionStatus,
    Version,
    VersionComponent,
    encode_version,
)
from sim_devices.gnss.commands import LogFormat
from sim_devices.gnss.constellation import GnssSystem, SatObservation, dops
from sim_devices.gnss.rawlogs import GLONASS_PRN_OFFSET, gpgga_sentence
from sim_devices.gnss.solution import Solution
from vsccore.angles import wrap_2pi

__all__ = ["bestpos", "bestvel", "bestxyz", "gpgga", "heading", "markpos", "psrdop", "version"]

#: GPS L1 + L2 and GLONASS L1 + L2 used (OEM7 signal-mask bits).
_GPS_GLO_MASK = 0x33
_DIFF_TYPES = frozenset({PositionType.PSRDIFF, PositionType.NARROW_FLOAT, PositionType.NARROW_INT})


def _ext_status(sol: Solution) -> int:
    return 0x01 if sol.pos_type is PositionType.NARROW_INT else 0x00


def _counts(sol: Solution) -> tuple[int, int]:
    return len(sol.satellites), sol.num_soln_svs


def bestpos(sol: Solution, undulation_m: float, cls: type[BestPos] | type[MarkPos] = BestPos) -> BestPos | MarkPos:
    """BESTPOS (or MARKPOS with ``cls``) of a solution; height above MSL = ellipsoidal − undulation."""
    tracked, used = _counts(sol)
    se, sn, su = sol.sigma_enu_m
    return cls(
        sol.sol_status,
        sol.pos_type,
        sol.lat_deg,
        sol.lon_deg,
        sol.height_m - undulation_m,
        undulation_m,
        Datum.WGS84,
        sn,
        se,
        su,
        sol.station_id if sol.pos_type in _DIFF_TYPES else "",
        sol.diff_age_s if sol.pos_type in _DIFF_TYPES else 0.0,
        0.0,
        tracked,
        used,
        used,
        used,
        0,
        _ext_status(sol),
        0,
        _GPS_GLO_MASK,
    )


def markpos(sol: Solution, undulation_m: float) -> MarkPos:
    """MARKPOS of the solution at an event."""
    body = bestpos(sol, undulation_m, MarkPos)
    assert isinstance(body, MarkPos)
    return body


def _vel_type(sol: Solution) -> PositionType:
    return PositionType.DOPPLER_VELOCITY if sol.pos_type is PositionType.SINGLE else sol.pos_type


def _vel_status(sol: Solution) -> SolutionStatus:
    return SolutionStatus.INSUFFICIENT_OBS if sol.pos_type is PositionType.NONE else SolutionStatus.SOL_COMPUTED


def bestvel(sol: Solution, latency_s: float = 0.0) -> BestVel:
    """BESTVEL: horizontal speed, track over ground (clockwise from north, 0-360°), vertical speed."""
    ve, vn, vu = sol.vel_enu_mps
    track = math.degrees(wrap_2pi(math.atan2(ve, vn)))
    return BestVel(
        _vel_status(sol),
        _vel_type(sol),
        latency_s,
        sol.diff_age_s if sol.pos_type in _DIFF_TYPES else 0.0,
        math.hypot(ve, vn),
        track,
        vu,
        0.0,
    )


def bestxyz(sol: Solution) -> BestXyz:
    """BESTXYZ: ECEF position and velocity with sigmas rotated from ENU."""
    x, y, z = pymap3d.geodetic2ecef(sol.lat_deg, sol.lon_deg, sol.height_m)
    vx, vy, vz = pymap3d.enu2uvw(*sol.vel_enu_mps, sol.lat_deg, sol.lon_deg)
    lat, lon = math.radians(sol.lat_deg), math.radians(sol.lon_deg)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    rot = np.array([[-so, -sl * co, cl * co], [co, -sl * so, cl * so], [0.0, cl, sl]])  # ENU → ECEF
    ps = np.sqrt((rot**2) @ np.square(sol.sigma_enu_m))
    vs = np.sqrt((rot**2) @ np.square(sol.vel_sigma_enu_mps))
    tracked, used = _counts(sol)
    diff = sol.pos_type in _DIFF_TYPES
    return BestXyz(
        sol.sol_status,
        sol.pos_type,
        float(x),
        float(y),
        float(z),
        float(ps[0]),
        float(ps[1]),
        float(ps[2]),
        _vel_status(sol),
        _vel_type(sol),
        float(vx),
        float(vy),
        float(vz),
        float(vs[0]),
        float(vs[1]),
        float(vs[2]),
        sol.station_id if diff else "",
        0.0,
        sol.diff_age_s if diff else 0.0,
        0.0,
        tracked,
        used,
        used,
        used,
        0,
        _ext_status(sol),
        0,
        _GPS_GLO_MASK,
    )


def _prn(s: SatObservation) -> int:
    return s.sat.prn + (GLONASS_PRN_OFFSET if s.sat.system is GnssSystem.GLONASS else 0)


def psrdop(used: Sequence[SatObservation], cutoff_deg: float) -> PsrDop:
    """PSRDOP of the satellites used."""
    gdop, pdop, hdop, htdop, tdop = dops(list(used))
    return PsrDop(gdop, pdop, hdop, htdop, tdop, cutoff_deg, tuple(_prn(s) for s in used))


def heading(
    length_m: float, heading_deg: float, pitch_deg: float, heading_sigma_deg: float, pitch_sigma_deg: float,
    tracked: int, used: int, cls: type[Heading] | type[Heading2] = Heading,
) -> Heading | Heading2:
    """HEADING (or HEADING2) of a dual-antenna baseline in NARROW_INT."""
    if cls is Heading2:
        return Heading2(
            SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, length_m, heading_deg, pitch_deg, 0.0,
            heading_sigma_deg, pitch_sigma_deg, "0", "0", tracked, used, used, used, 0, 0x01, 0, _GPS_GLO_MASK,
        )
    return Heading(
        SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, length_m, heading_deg, pitch_deg, 0.0,
        heading_sigma_deg, pitch_sigma_deg, "0", tracked, used, used, used, 0, 0x01, 0, _GPS_GLO_MASK,
    )


def version(fmt: LogFormat, model: str, psn: str, versions: Sequence[str]) -> RawBody:
    """VERSION body (kept raw by the codec) with one GPSCARD component: ``versions`` are the hardware,
    software and boot versions, the compile date and time."""
    hw, sw, boot, date, time = versions
    body = Version((VersionComponent(ComponentType.GPSCARD, model, psn, hw, sw, boot, date, time),))
    return encode_version(body, BodyFormat.BINARY if fmt is LogFormat.BINARY else BodyFormat.ASCII)


_GGA_QUALITY = {
    PositionType.SINGLE: 1,
    PositionType.PSRDIFF: 2,
    PositionType.NARROW_INT: 4,
    PositionType.NARROW_FLOAT: 5,
    PositionType.FIXEDPOS: 7,
}


def gpgga(sol: Solution, utc_hms: tuple[int, int, float], undulation_m: float, hdop: float) -> bytes:
    """``$GPGGA`` of a solution."""
    diff = sol.pos_type in _DIFF_TYPES
    return gpgga_sentence(
        utc_hms, sol.lat_deg, sol.lon_deg, _GGA_QUALITY.get(sol.pos_type, 1), min(sol.num_soln_svs, 99), hdop,
        sol.height_m - undulation_m, undulation_m, sol.diff_age_s if diff else None, sol.station_id or "0",
    )
