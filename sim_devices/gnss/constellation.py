"""A synthetic, deterministic GPS + GLONASS constellation for plausible observations and DOPs.

Circular orbits with the real constellations' radius, inclination and plane layout (GPS: 24
satellites in 6 planes at 55°; GLONASS: 24 in 3 planes at 64.8°, with the real frequency-channel
pattern), Earth rotation included, no perturbations. Good enough for observation messages that
a decoder accepts, satellite counts that change as the car drives, and DOPs of the right size; not
for positioning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt
import pymap3d

__all__ = ["SPEED_OF_LIGHT", "Constellation", "GnssSystem", "SatObservation", "Satellite", "dops"]

FloatArray = npt.NDArray[np.float64]

SPEED_OF_LIGHT = 299_792_458.0
_MU = 3.986005e14
_OMEGA_E = 7.2921151467e-5
#: GLONASS frequency channel number of slots 1..24 (antipodal satellites share a channel).
_GLONASS_FCN = (1, -4, 5, 6, 1, -4, 5, 6, -2, -7, 0, -1, -2, -7, 0, -1, 4, -3, 3, 2, 4, -3, 3, 2)


class GnssSystem(Enum):
    """Satellite system."""

    GPS = "GPS"
    GLONASS = "GLONASS"


@dataclass(frozen=True, slots=True)
class Satellite:
    """One satellite: system, PRN (GPS) or slot (GLONASS) 1..24, GLONASS frequency channel."""

    system: GnssSystem
    prn: int
    fcn: int = 0

    def l1_hz(self) -> float:
        """L1 carrier frequency (Hz)."""
        if self.system is GnssSystem.GLONASS:
            return 1602.0e6 + self.fcn * 0.5625e6
        return 1575.42e6

    def l2_hz(self) -> float:
        """L2 carrier frequency (Hz)."""
        if self.system is GnssSystem.GLONASS:
            return 1246.0e6 + self.fcn * 0.4375e6
        return 1227.60e6


@dataclass(frozen=True, slots=True)
class SatObservation:
    """Geometry of one visible satellite from a receiver."""

    sat: Satellite
    azimuth_deg: float
    elevation_deg: float
    range_m: float
    range_rate_mps: float


@dataclass(frozen=True, slots=True)
class _Orbit:
    radius_m: float
    inclination_rad: float
    raan_rad: float
    arg0_rad: float


class Constellation:
    """GPS and GLONASS satellites on circular orbits (see module docstring)."""

    def __init__(self) -> None:
        sats: list[Satellite] = []
        orbits: list[_Orbit] = []
        a_gps = 26_559_700.0
        for plane in range(6):
            for slot in range(4):
                sats.append(Satellite(GnssSystem.GPS, plane * 4 + slot + 1))
                orbits.append(
                    _Orbit(a_gps, math.radians(55.0), math.radians(60.0 * plane),
                           math.radians(90.0 * slot + 15.0 * plane))
                )
        a_glo = 25_508_200.0
        for plane in range(3):
            for slot in range(8):
                k = plane * 8 + slot + 1
                sats.append(Satellite(GnssSystem.GLONASS, k, _GLONASS_FCN[k - 1]))
                orbits.append(
                    _Orbit(a_glo, math.radians(64.8), math.radians(120.0 * plane),
                           math.radians(45.0 * slot + 15.0 * plane))
                )
        self.satellites: tuple[Satellite, ...] = tuple(sats)
        self._radius = np.array([o.radius_m for o in orbits])
        self._inc = np.array([o.inclination_rad for o in orbits])
        self._raan = np.array([o.raan_rad for o in orbits])
        self._arg0 = np.array([o.arg0_rad for o in orbits])
        self._n = np.sqrt(_MU / self._radius**3)

    def ecef(self, t_gps_s: float) -> FloatArray:
        """ECEF positions (m), shape (n_sat, 3), at GPS time ``t_gps_s`` (s since the GPS epoch)."""
        u = self._arg0 + self._n * t_gps_s  # |n t| ~ 2e5 rad: float64 keeps it to ~1e-11 rad
        x_p = self._radius * np.cos(u)
        y_p = self._radius * np.sin(u)
        ci, si = np.cos(self._inc), np.sin(self._inc)
        omega = self._raan - _OMEGA_E * (t_gps_s % 86164.0905)
        co, so = np.cos(omega), np.sin(omega)
        x = x_p * co - y_p * ci * so
        y = x_p * so + y_p * ci * co
        z = y_p * si
        return np.stack([x, y, z], axis=1)

    def visible(
        self, lat_deg: float, lon_deg: float, height_m: float, t_gps_s: float, mask_deg: float = 5.0
    ) -> list[SatObservation]:
        """Satellites above ``mask_deg`` elevation seen from the given position, sorted by system and PRN."""
        rx = np.array(pymap3d.geodetic2ecef(lat_deg, lon_deg, height_m), dtype=np.float64)
        dt = 0.5
        p0 = self.ecef(t_gps_s - dt)
        p1 = self.ecef(t_gps_s)
        p2 = self.ecef(t_gps_s + dt)
        az, el, rng = pymap3d.ecef2aer(p1[:, 0], p1[:, 1], p1[:, 2], lat_deg, lon_deg, height_m)
        rate = (np.linalg.norm(p2 - rx, axis=1) - np.linalg.norm(p0 - rx, axis=1)) / (2 * dt)
        out = [
            SatObservation(sat, float(az[i]), float(el[i]), float(rng[i]), float(rate[i]))
            for i, sat in enumerate(self.satellites)
            if el[i] >= mask_deg
        ]
        return out


def dops(observations: list[SatObservation]) -> tuple[float, float, float, float, float]:
    """(GDOP, PDOP, HDOP, HTDOP, TDOP) of a set of satellites (one receiver clock); 99.0 each if < 4."""
    if len(observations) < 4:
        return (99.0, 99.0, 99.0, 99.0, 99.0)
    az = np.radians([o.azimuth_deg for o in observations])
    el = np.radians([o.elevation_deg for o in observations])
    g = np.stack([-np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), -np.sin(el), np.ones_like(el)], axis=1)
    try:
        q = np.linalg.inv(g.T @ g)
    except np.linalg.LinAlgError:
        return (99.0, 99.0, 99.0, 99.0, 99.0)
    d = np.diag(q)
    return (
        float(math.sqrt(d.sum())),
        float(math.sqrt(d[:3].sum())),
        float(math.sqrt(d[:2].sum())),
        float(math.sqrt(d[0] + d[1] + d[3])),
        float(math.sqrt(d[3])),
    )
