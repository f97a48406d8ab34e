"""Raw GNSS observations (pseudorange, carrier phase, Doppler, C/N0, lock time) per epoch.

Built on the synthetic :class:`~sim_devices.gnss.constellation.Constellation`, two signals per
satellite (GPS L1 C/A + L2 P(Y), GLONASS L1 C/A + L2 C/A), with the observation equations that a
positioning engine (RTKLIB) inverts:

    P = ρ − c·dts + T + I_f + ε_P        Φ·λ = ρ − c·dts + T − I_f + λ·N + ε_Φ

- ρ: geometric range from the satellite at transmission time (light time iterated) to the antenna
  at reception, plus the Earth-rotation (Sagnac) term ω_E·(x_s·y_r − y_s·x_r)/c, as RTKLIB's
  ``geodist`` models it; the receiver clock is steered to GPS time (dt_r = 0);
- dts: the satellite clock offset the broadcast ephemeris carries (GPS: af0; GLONASS: −τn + γn·(t − tb));
- T, I_f: one atmosphere for every receiver (:func:`troposphere_m`, :func:`ionosphere_m`), so base
  and rovers see the same delays on short baselines;
- N: an integer ambiguity per satellite and signal, constant while the signal stays locked (a gap
  of more than 2 s restarts the lock time and draws a new one); ε: code noise growing at low
  elevation, 2 mm phase noise, independent per receiver.

Used for the base's RTCM MSM messages and a rover's RANGECMP log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import pymap3d

from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import (
    OMEGA_E,
    SPEED_OF_LIGHT,
    Constellation,
    GnssSystem,
    Satellite,
    SatObservation,
)
from vsccore.gpstime import NS_PER_S

__all__ = ["Band", "ObservationGenerator", "SignalObservation", "ionosphere_m", "troposphere_m"]

_L1_HZ = 1575.42e6
_EARTH_RADIUS_M = 6_371_000.0
_IONO_SHELL_M = 350_000.0
#: Vertical ionospheric delay at GPS L1 (m) and zenith tropospheric delay at sea level (m).
IONO_VERTICAL_L1_M = 3.0
TROPO_ZENITH_M = 2.3


def troposphere_m(elevation_rad: float, height_m: float) -> float:
    """Slant tropospheric delay (m): zenith delay thinning with height, 1/sin(el) mapping."""
    zenith = TROPO_ZENITH_M * math.exp(-max(height_m, 0.0) / 8000.0)
    return zenith / max(math.sin(elevation_rad), 0.05)


def ionosphere_m(elevation_rad: float, freq_hz: float) -> float:
    """Slant ionospheric group delay (m) on ``freq_hz``: thin-shell mapping, 1/f² scaling."""
    x = _EARTH_RADIUS_M * math.cos(elevation_rad) / (_EARTH_RADIUS_M + _IONO_SHELL_M)
    return IONO_VERTICAL_L1_M / math.sqrt(1.0 - x * x) * (_L1_HZ / freq_hz) ** 2


class Band(Enum):
    """Carrier band of a signal."""

    L1 = 1
    L2 = 2


#: RTCM MSM signal IDs (RINEX codes 1C / 2W for GPS, 1C / 2C for GLONASS).
MSM_SIGNAL_ID = {
    (GnssSystem.GPS, Band.L1): 2,
    (GnssSystem.GPS, Band.L2): 10,
    (GnssSystem.GLONASS, Band.L1): 2,
    (GnssSystem.GLONASS, Band.L2): 8,
}


@dataclass(frozen=True, slots=True)
class SignalObservation:
    """One tracked signal at one epoch."""

    sat: Satellite
    band: Band
    pseudorange_m: float
    carrier_cycles: float
    doppler_hz: float
    range_rate_mps: float
    cnr_dbhz: float
    lock_time_s: float
    wavelength_m: float
    geometric_range_m: float
    elevation_deg: float

    @property
    def msm_signal_id(self) -> int:
        return MSM_SIGNAL_ID[(self.sat.system, self.band)]

    @property
    def phaserange_m(self) -> float:
        return self.carrier_cycles * self.wavelength_m


class ObservationGenerator:
    """Seeded observation generator for one receiver (keeps ambiguities and lock times)."""

    def __init__(self, constellation: Constellation, seed: int | None = 0, mask_deg: float = 10.0) -> None:
        self.constellation = constellation
        self.mask_deg = mask_deg
        self._rng = np.random.default_rng(seed)
        self._ambiguity: dict[tuple[GnssSystem, int, Band], int] = {}
        self._lock_start_ns: dict[tuple[GnssSystem, int, Band], int] = {}
        self._last_seen_ns: dict[tuple[GnssSystem, int, Band], int] = {}
        self._geometry: tuple[tuple[float, float, float, int], list[SatObservation]] | None = None

    def geometry(self, antenna: AntennaState, t_gps_ns: int) -> list[SatObservation]:
        """Satellites above the mask seen from ``antenna`` at ``t_gps_ns``.

        The last answer is kept: a rover's logs of one epoch (RANGECMP, and the GPS and GLONASS
        ephemerides it checks for a change at every epoch) ask for the same geometry, which costs a
        GLONASS orbit integration each time (a pure function of its arguments: the same list)."""
        key = (antenna.lat_deg, antenna.lon_deg, antenna.height_m, t_gps_ns)
        cached = self._geometry
        if cached is not None and cached[0] == key:
            return list(cached[1])
        visible = self.constellation.visible(
            antenna.lat_deg, antenna.lon_deg, antenna.height_m, t_gps_ns / NS_PER_S, self.mask_deg
        )
        self._geometry = (key, visible)
        return list(visible)

    def ranges(self, antenna: AntennaState, t_gps_ns: int, sats: list[Satellite]) -> list[float]:
        """Geometric ranges (m) with light time and the Earth-rotation term, as RTKLIB models them."""
        const = self.constellation
        rr = np.array(pymap3d.geodetic2ecef(antenna.lat_deg, antenna.lon_deg, antenna.height_m), dtype=np.float64)
        idx = np.array([const.index(s) for s in sats], dtype=np.intp)
        tau = np.full(len(const.satellites), 0.075)
        rho = np.zeros(len(idx))
        for _ in range(4):  # light time converges to < 1 ps in three passes
            rs = const.ecef_at(t_gps_ns, -tau)[idx]
            rho = np.linalg.norm(rs - rr, axis=1) + OMEGA_E * (rs[:, 0] * rr[1] - rs[:, 1] * rr[0]) / SPEED_OF_LIGHT
            tau[idx] = rho / SPEED_OF_LIGHT
        return [float(r) for r in rho]

    def epoch(self, antenna: AntennaState, t_gps_ns: int) -> list[SignalObservation]:
        """Observations of every visible satellite's two signals at ``t_gps_ns``."""
        out: list[SignalObservation] = []
        geos = self.geometry(antenna, t_gps_ns)
        if not geos:
            return out
        rhos = self.ranges(antenna, t_gps_ns, [g.sat for g in geos])
        for geo, rho in zip(geos, rhos, strict=True):
            el = math.radians(geo.elevation_deg)
            sin_el = max(math.sin(el), 0.1)
            clock_m = SPEED_OF_LIGHT * self.constellation.satellite_clock_s(geo.sat, t_gps_ns)
            tropo = troposphere_m(el, antenna.height_m)
            for band in (Band.L1, Band.L2):
                key = (geo.sat.system, geo.sat.prn, band)
                last = self._last_seen_ns.get(key)
                if last is None or t_gps_ns - last > 2 * NS_PER_S:
                    self._lock_start_ns[key] = t_gps_ns
                    self._ambiguity[key] = int(self._rng.integers(-500, 501))
                self._last_seen_ns[key] = t_gps_ns
                freq = geo.sat.l1_hz() if band is Band.L1 else geo.sat.l2_hz()
                lam = SPEED_OF_LIGHT / freq
                iono = ionosphere_m(el, freq)
                code_sigma = 0.15 + 0.35 / sin_el
                common = rho - clock_m + tropo
                pr = common + iono + code_sigma * float(self._rng.standard_normal())
                phase_m = common - iono + 0.002 * float(self._rng.standard_normal())
                cycles = phase_m / lam + self._ambiguity[key]
                cnr = 32.0 + 18.0 * sin_el - (4.0 if band is Band.L2 else 0.0)
                lock = (t_gps_ns - self._lock_start_ns[key]) / NS_PER_S
                out.append(
                    SignalObservation(
                        geo.sat, band, pr, cycles, -geo.range_rate_mps / lam, geo.range_rate_mps, cnr, lock, lam,
                        rho, geo.elevation_deg,
                    )
                )
        return out
