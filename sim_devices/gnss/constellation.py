"""A synthetic, deterministic GPS + GLONASS constellation: orbits, satellite clocks, geometry.

The real constellations' radius, inclination and plane layout (GPS: 24 satellites in 6 planes at
55°; GLONASS: 24 in 3 planes at 64.8°, with the real frequency-channel pattern), Earth rotation
included.

- GPS: circular Keplerian orbits, no perturbations, a constant clock offset per satellite. They are
  exactly the IS-GPS-200 broadcast-ephemeris model with e = 0, Δn = 0, ω = 0, no harmonic terms and
  OMEGA_DOT = 0 (the orbital planes are fixed in inertial space), so :mod:`sim_devices.gnss.ephemeris`
  can broadcast them without approximation and a post-processing engine positions with them.
- GLONASS: the ICD's equations of motion (central body, J2, Earth rotation, lunisolar acceleration)
  integrated by RK4 from the circular orbit's state at the start of each GPS week
  (:mod:`sim_devices.gnss.glonass`), so that the broadcast state at tb, integrated by a receiver,
  is the satellite's motion; each clock runs with a constant relative frequency offset γ from its
  offset at the week's start (the broadcast −τn + γn·(t − tb)).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from fractions import Fraction

import numpy as np
import numpy.typing as npt
import pymap3d

from sim_devices.gnss.glonass import GlonassTruth
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK

__all__ = ["GPS_MU", "OMEGA_E", "SPEED_OF_LIGHT", "Constellation", "GnssSystem", "SatObservation", "Satellite", "dops"]

FloatArray = npt.NDArray[np.float64]

SPEED_OF_LIGHT = 299_792_458.0
#: IS-GPS-200 gravitational constant (m³/s²) and Earth rotation rate (rad/s).
GPS_MU = 3.986005e14
OMEGA_E = 7.2921151467e-5
_MU = GPS_MU
_OMEGA_E = OMEGA_E
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

        # satellite clock offsets (s): a fixed, deterministic ±50 µs spread
        self._clock_s = np.array([((7 * i) % 21 - 10) * 5.0e-6 for i in range(len(sats))])
        self._index = {sat: i for i, sat in enumerate(self.satellites)}
        self._day_phase: dict[int, tuple[FloatArray, float]] = {}
        self._glo = np.array([i for i, s in enumerate(sats) if s.system is GnssSystem.GLONASS], dtype=np.intp)
        # GLONASS clock rates γ (s/s): a fixed, deterministic ±2e-12 spread, from the offset at the GPS week's start
        self._gamma = np.array([((5 * i) % 11 - 5) * 4.0e-13 if s.system is GnssSystem.GLONASS else 0.0
                                for i, s in enumerate(sats)])
        self._glo_at: dict[int, tuple[FloatArray, FloatArray]] = {}  # whole GPS second -> (states, acc)
        self.glonass_truth = _shared_truth(tuple(sats[i].prn for i in self._glo), self._glonass_kepler)

    def index(self, sat: Satellite) -> int:
        """Row of ``sat`` in :meth:`ecef` results."""
        return self._index[sat]

    def elements(self, sat: Satellite) -> tuple[float, float, float, float, float]:
        """(radius m, inclination rad, RAAN rad, argument of latitude at t = 0 rad, mean motion rad/s).

        The orbit: argument of latitude u(t) = arg0 + n t; ascending node longitude in ECEF
        Ω(t) = RAAN − ω_E t (t in s since the GPS epoch).
        """
        i = self._index[sat]
        return (float(self._radius[i]), float(self._inc[i]), float(self._raan[i]), float(self._arg0[i]),
                float(self._n[i]))

    def clock_offset_s(self, sat: Satellite) -> float:
        """Satellite clock offset from GPS time (s): constant for GPS, at the GPS week's start for GLONASS."""
        return float(self._clock_s[self._index[sat]])

    def clock_rate(self, sat: Satellite) -> float:
        """Relative frequency offset γ of the satellite clock (0 for GPS)."""
        return float(self._gamma[self._index[sat]])

    def satellite_clock_s(self, sat: Satellite, t_gps_ns: int) -> float:
        """Satellite clock minus GPS time (s) at ``t_gps_ns``: the GPS offset, or a GLONASS clock's offset at the
        week's start plus γ times the seconds of the week."""
        i = self._index[sat]
        sow = (t_gps_ns % NS_PER_WEEK) / NS_PER_S
        return float(self._clock_s[i] + self._gamma[i] * sow)

    def _glonass_kepler(self, t_s: int) -> FloatArray:
        """States (n, 6: position m, velocity m/s; ECEF) of the GLONASS satellites on their circular orbits at the
        whole GPS second ``t_s``: where each day's integration starts."""
        t_ns = t_s * NS_PER_S
        day = t_ns // (86400 * NS_PER_S)
        r = (t_ns - day * 86400 * NS_PER_S) / NS_PER_S
        n_phase, e_phase = self.phase_at_day(int(day))
        g = self._glo
        n = self._n[g]
        u = self._arg0[g] + n_phase[g] + n * r
        omega = self._raan[g] - e_phase - _OMEGA_E * r
        rad = self._radius[g]
        x_p, y_p = rad * np.cos(u), rad * np.sin(u)
        dx_p, dy_p = -rad * n * np.sin(u), rad * n * np.cos(u)
        ci, si = np.cos(self._inc[g]), np.sin(self._inc[g])
        co, so = np.cos(omega), np.sin(omega)
        x = x_p * co - y_p * ci * so
        y = x_p * so + y_p * ci * co
        z = y_p * si
        vx = dx_p * co + x_p * so * _OMEGA_E - dy_p * ci * so + y_p * ci * co * _OMEGA_E
        vy = dx_p * so - x_p * co * _OMEGA_E + dy_p * ci * co + y_p * ci * so * _OMEGA_E
        vz = dy_p * si
        return np.stack([x, y, z, vx, vy, vz], axis=1)

    def glonass_state(self, sat: Satellite, t_gps_s: int) -> tuple[FloatArray, FloatArray]:
        """(state (6,): ECEF position m and velocity m/s, lunisolar acceleration (3,) m/s²) of a GLONASS satellite
        at the whole GPS second ``t_gps_s``: what it broadcasts for that tb.

        Raises:
            ValueError: ``sat`` is not a GLONASS satellite of this constellation.
        """
        if sat.system is not GnssSystem.GLONASS or sat not in self._index:
            raise ValueError(f"{sat.system.value} satellite {sat.prn} is not a GLONASS satellite of the constellation")
        row = int(np.flatnonzero(self._glo == self._index[sat])[0])
        cached = self._glo_at.get(t_gps_s)
        if cached is None:
            cached = (self.glonass_truth.states_ns(t_gps_s * NS_PER_S, np.zeros(len(self._glo))),
                      self.glonass_truth.acc(float(t_gps_s)))
            if len(self._glo_at) >= 4:
                self._glo_at.pop(next(iter(self._glo_at)))
            self._glo_at[t_gps_s] = cached
        return cached[0][row].copy(), cached[1][row].copy()

    def phase_at_day(self, day: int) -> tuple[FloatArray, float]:
        """(n·T mod 2π per satellite, ω_E·T mod 2π) at T = ``day`` × 86400 s, accurate to ~1e-16 rad.

        Exact rational arithmetic on the float64 rates, so that a phase at ~1.4e9 s keeps the
        precision that a product in float64 would lose (~3e-11 rad, ~1 mm on the orbit).
        """
        cached = self._day_phase.get(day)
        if cached is None:
            t = Fraction(day * 86400)
            two_pi = Fraction(2.0 * math.pi)
            n_phase = np.array([float((Fraction(float(n)) * t) % two_pi) for n in self._n])
            cached = (n_phase, float((Fraction(_OMEGA_E) * t) % two_pi))
            if len(self._day_phase) > 64:
                self._day_phase.clear()
            self._day_phase[day] = cached
        return cached

    def ecef_at(self, t_gps_ns: int, dt_s: float | FloatArray = 0.0) -> FloatArray:
        """ECEF positions (m), shape (n_sat, 3), at GPS time ``t_gps_ns`` + ``dt_s``.

        ``t_gps_ns`` is integer ns since the GPS epoch; ``dt_s`` (one offset, or one per satellite:
        signal transmission times differ by satellite) is added in double precision.
        """
        day = t_gps_ns // (86400 * NS_PER_S)
        r = (t_gps_ns - day * 86400 * NS_PER_S) / NS_PER_S + np.broadcast_to(np.asarray(dt_s, dtype=np.float64),
                                                                               self._n.shape)
        n_phase, e_phase = self.phase_at_day(int(day))
        u = self._arg0 + n_phase + self._n * r
        omega = self._raan - e_phase - _OMEGA_E * r  # orbital planes fixed in inertial space
        x_p = self._radius * np.cos(u)
        y_p = self._radius * np.sin(u)
        ci, si = np.cos(self._inc), np.sin(self._inc)
        co, so = np.cos(omega), np.sin(omega)
        x = x_p * co - y_p * ci * so
        y = x_p * so + y_p * ci * co
        z = y_p * si
        out = np.stack([x, y, z], axis=1)
        g = self._glo
        if len(g):
            dt = np.broadcast_to(np.asarray(dt_s, dtype=np.float64), self._n.shape)[g]
            out[g] = self.glonass_truth.states_ns(t_gps_ns, dt)[:, :3]
        return out

    def ecef(self, t_gps_s: float) -> FloatArray:
        """ECEF positions (m), shape (n_sat, 3), at GPS time ``t_gps_s`` (s since the GPS epoch)."""
        whole = math.floor(t_gps_s)
        return self.ecef_at(whole * NS_PER_S, t_gps_s - whole)

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


_TRUTHS: dict[tuple[int, ...], GlonassTruth] = {}


def _shared_truth(slots: tuple[int, ...], initial: Callable[[int], FloatArray]) -> GlonassTruth:
    """One integration per set of slots for every Constellation (they are identical and deterministic)."""
    truth = _TRUTHS.get(slots)
    if truth is None:
        truth = _TRUTHS.setdefault(slots, GlonassTruth(slots, initial))
    return truth


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
