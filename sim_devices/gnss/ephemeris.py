"""Broadcast ephemerides of the simulated constellation (GPSEPHEM and GLOEPHEMERIS bodies).

GLONASS (:func:`glonass_ephemeris`): the satellite's integrated state at tb (the middle of its
30-minute interval, on the whole and half hours of GLONASS time), the lunisolar acceleration the
truth holds over the interval, τn = −(clock offset at tb) and γn = the clock's rate; see
:mod:`sim_devices.gnss.glonass`.

GPS:

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

import datetime as dt
import math

from drivers.novatel.rawobs import Bool, GloEphemeris, GloSatType, GpsEphem
from sim_devices.gnss.constellation import OMEGA_E, Constellation, GnssSystem, Satellite
from sim_devices.gnss.glonass import INTERVAL_S, TIME_OFFSET_S, GlonassTruth
from sim_devices.gnss.rawlogs import GLONASS_PRN_OFFSET
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S, SECONDS_PER_WEEK

__all__ = ["EPHEMERIS_INTERVAL_S", "glonass_ephemeris", "gps_ephemeris"]

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


_GPS_EPOCH = dt.datetime(1980, 1, 6)


def glonass_ephemeris(constellation: Constellation, sat: Satellite, t_gps_ns: int) -> GloEphemeris:
    """The ephemeris a GLONASS satellite broadcasts at ``t_gps_ns`` (tb = the middle of the 30-minute interval).

    Times follow the simulator's 18 leap seconds (GLONASS time = GPS time + 3 h − 18 s).

    Raises:
        SimulationError: ``sat`` is not a GLONASS satellite of ``constellation``.
    """
    if sat.system is not GnssSystem.GLONASS or sat not in constellation.satellites:
        raise SimulationError(f"no GLONASS broadcast ephemeris for {sat.system.value} satellite {sat.prn}")
    tb = GlonassTruth.tb_s(t_gps_ns / NS_PER_S)
    state, acc = constellation.glonass_state(sat, tb)
    week, sow = divmod(tb, SECONDS_PER_WEEK)
    glo = _GPS_EPOCH + dt.timedelta(seconds=tb + TIME_OFFSET_S)  # GLONASS date and time (UTC + 3 h)
    tod = glo.hour * 3600 + glo.minute * 60 + glo.second
    four_year_start = dt.datetime(glo.year - (glo.year - 1996) % 4, 1, 1)
    issue = tod // 900
    clock = constellation.clock_offset_s(sat) + constellation.clock_rate(sat) * sow
    return GloEphemeris(
        sloto=sat.prn + GLONASS_PRN_OFFSET, freqo=sat.fcn + 7, sat_type=int(GloSatType.GLO_SAT_M), false_iod=0,
        ephem_week=int(week), ephem_time_ms=int(sow) * 1000, time_offset_s=TIME_OFFSET_S,
        nt_day=(glo - four_year_start).days + 1, reserved1=0, reserved2=0, issue=issue, health=0,
        pos_x_m=float(state[0]), pos_y_m=float(state[1]), pos_z_m=float(state[2]), vel_x_mps=float(state[3]),
        vel_y_mps=float(state[4]), vel_z_mps=float(state[5]), ls_acc_x_mps2=float(acc[0]),
        ls_acc_y_mps2=float(acc[1]), ls_acc_z_mps2=float(acc[2]), tau_n_s=-clock, delta_tau_n_s=0.0,
        gamma_n=constellation.clock_rate(sat), tk_s=tod - INTERVAL_S // 2, p=0, ft=0, age_days=0,
        flags=1 | (issue & 1) << 2,  # P1: 30 min between tb; P2: tb odd
    )
