"""Plausible raw GNSS observations (pseudorange, carrier phase, Doppler, C/N0, lock time) per epoch.

Built on the synthetic :class:`~sim_devices.gnss.constellation.Constellation`: two signals per
satellite (GPS L1 C/A + L2 P(Y), GLONASS L1 C/A + L2 C/A), code noise that grows at low elevation,
a constant integer ambiguity per satellite and signal while it stays locked, and a lock time that
restarts when a satellite was lost for more than 2 s. Used for the base's RTCM MSM messages and a
rover's raw RANGECMP log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import SPEED_OF_LIGHT, Constellation, GnssSystem, Satellite, SatObservation
from vsccore.gpstime import NS_PER_S

__all__ = ["Band", "ObservationGenerator", "SignalObservation"]


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

    def geometry(self, antenna: AntennaState, t_gps_ns: int) -> list[SatObservation]:
        """Satellites above the mask seen from ``antenna`` at ``t_gps_ns``."""
        return self.constellation.visible(
            antenna.lat_deg, antenna.lon_deg, antenna.height_m, t_gps_ns / NS_PER_S, self.mask_deg
        )

    def epoch(self, antenna: AntennaState, t_gps_ns: int) -> list[SignalObservation]:
        """Observations of every visible satellite's two signals at ``t_gps_ns``."""
        out: list[SignalObservation] = []
        for geo in self.geometry(antenna, t_gps_ns):
            sin_el = max(math.sin(math.radians(geo.elevation_deg)), 0.1)
            for band in (Band.L1, Band.L2):
                key = (geo.sat.system, geo.sat.prn, band)
                last = self._last_seen_ns.get(key)
                if last is None or t_gps_ns - last > 2 * NS_PER_S:
                    self._lock_start_ns[key] = t_gps_ns
                    self._ambiguity[key] = int(self._rng.integers(-500, 501))
                self._last_seen_ns[key] = t_gps_ns
                freq = geo.sat.l1_hz() if band is Band.L1 else geo.sat.l2_hz()
                lam = SPEED_OF_LIGHT / freq
                code_sigma = 0.15 + 0.35 / sin_el
                pr = geo.range_m + code_sigma * float(self._rng.standard_normal())
                phase_m = geo.range_m + 0.002 * float(self._rng.standard_normal())
                cycles = phase_m / lam + self._ambiguity[key]
                cnr = 32.0 + 18.0 * sin_el - (4.0 if band is Band.L2 else 0.0)
                lock = (t_gps_ns - self._lock_start_ns[key]) / NS_PER_S
                out.append(
                    SignalObservation(
                        geo.sat, band, pr, cycles, -geo.range_rate_mps / lam, geo.range_rate_mps, cnr, lock, lam,
                        geo.range_m, geo.elevation_deg,
                    )
                )
        return out
