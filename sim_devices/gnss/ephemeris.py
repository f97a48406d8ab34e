"""GPS broadcast ephemerides of the simulated constellation (GPSEPHEM bodies).

The simulated GPS orbits (:class:`~sim_devices.gnss.constellation.Constellation`) are circular
Keplerian orbits whose planes are fixed in inertial space, which is exactly the IS-GPS-200 model
with e = 0, ω = 0, Δn = 0, no harmonic corrections, IDOT = 0 and OMEGA_DOT = 0:

- argument of latitude  u(t) = arg0 + n·t  →  M0 = arg0 + n·toe (ω = 0, so M = E = ν = u);
- node longitude        Ω(t) = RAAN − ω_E·t  →  IS-GPS-200 has Ω = Ω0 + (Ω̇ − ω_E)·tk − ω_E·toe
  = Ω0 − ω_E·(seconds of week), so Ω0 = RAAN − ω_E·(start of the GPS week).

An ephemeris set is issued every two hours (toe on the 2 h grid, IODE/IODC its count in the week);
the satellite clock is af0 = the satellite's constant offset (af1 = af2 = TGD = 0).
"""

from __future__ import annotations

import math

from drivers.novatel.rawobs import Bool, GpsEphem
from sim_devices.gnss.constellation import OMEGA_E, Constellation, GnssSystem, Satellite
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S, SECONDS_PER_WEEK

__all__ = ["EPHEMERIS_INTERVAL_S", "gps_ephemeris"]

#: Time between ephemeris sets (s); toe is on this grid.
EPHEMERIS_INTERVAL_S = 7200


def _wrap_pi(x: float) -> float:
    return math.remainder(x, 2.0 * math.pi)


def gps_ephemeris(constellation: Constellation, sat: Satellite, t_gps_ns: int) -> GpsEphem:
    """The ephemeris set a GPS satellite broadcasts at ``t_gps_ns`` (toe = start of its 2 h slot).

    Raises:
        SimulationError: ``sat`` is not a GPS satellite of ``constellation``.
    """
    if sat.system is not GnssSystem.GPS or sat not in constellation.satellites:
        raise SimulationError(f"no GPS broadcast ephemeris for {sat.system.value} satellite {sat.prn}")
    t_s = t_gps_ns // NS_PER_S
    week, sow = divmod(t_s, SECONDS_PER_WEEK)
    toe = (sow // EPHEMERIS_INTERVAL_S) * EPHEMERIS_INTERVAL_S
    toe_abs = week * SECONDS_PER_WEEK + toe
    radius, inc, raan, arg0, n = constellation.elements(sat)
    i = constellation.index(sat)
    day, rest = divmod(toe_abs, 86400)
    n_day = float(constellation.phase_at_day(day)[0][i])
    m0 = _wrap_pi(arg0 + n_day + n * rest)
    week_day, week_rest = divmod(week * SECONDS_PER_WEEK, 86400)
    e_day = constellation.phase_at_day(week_day)[1]
    omega0 = _wrap_pi(raan - e_day - OMEGA_E * week_rest)
    iod = int(toe // EPHEMERIS_INTERVAL_S) % 256
    return GpsEphem(
        prn=sat.prn, tow_s=float(sow - sow % 6), health=0, iode1=iod, iode2=iod, week=int(week), z_week=int(week),
        toe_s=float(toe), a_m=radius, delta_n_rad_s=0.0, m0_rad=m0, ecc=0.0, omega_rad=0.0, cuc_rad=0.0,
        cus_rad=0.0, crc_m=0.0, crs_m=0.0, cic_rad=0.0, cis_rad=0.0, i0_rad=inc, idot_rad_s=0.0, omega0_rad=omega0,
        omega_dot_rad_s=0.0, iodc=iod, toc_s=float(toe), tgd_s=0.0, af0_s=constellation.clock_offset_s(sat),
        af1_s_s=0.0, af2_s_s2=0.0, anti_spoofing=Bool.TRUE, n_rad_s=n, ura_var_m2=4.0,
    )
