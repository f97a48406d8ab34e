"""The simulated GPS broadcast ephemerides and observations, checked with the IS-GPS-200 algorithm.

The satellite position is computed from the *decoded* GPSEPHEMB bytes with the full IS-GPS-200
user algorithm (Kepler's equation, harmonic corrections, OMEGA_DOT), written here independently of
the simulator, and the observations are inverted with the model RTKLIB uses (transmission time
from the pseudorange, Earth-rotation correction, broadcast clock).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pymap3d
import pytest

from drivers.novatel import Frame, Header, TimeStatus, decode_binary, encode_binary
from drivers.novatel.rawobs import GpsEphem, decode_gpsephem, encode_gpsephem
from sim_devices.gnss import SimTimeBase
from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import Constellation, GnssSystem, Satellite
from sim_devices.gnss.ephemeris import gps_ephemeris
from sim_devices.gnss.observations import Band, ObservationGenerator, ionosphere_m, troposphere_m
from sim_devices.gnss.rover import SimRover
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK, SECONDS_PER_WEEK

MU = 3.986005e14
OMEGA_E = 7.2921151467e-5
C = 299_792_458.0


def is_gps_200(eph: GpsEphem, t_gps_s: float) -> tuple[np.ndarray, float]:
    """Satellite ECEF (m) and clock offset (s) at GPS time ``t_gps_s`` (s since the GPS epoch)."""
    tk = t_gps_s - (eph.week * SECONDS_PER_WEEK + eph.toe_s)
    n = math.sqrt(MU / eph.a_m**3) + eph.delta_n_rad_s
    m = eph.m0_rad + n * tk
    e = m
    for _ in range(30):
        e = m + eph.ecc * math.sin(e)
    nu = math.atan2(math.sqrt(1.0 - eph.ecc**2) * math.sin(e), math.cos(e) - eph.ecc)
    phi = nu + eph.omega_rad
    du = eph.cus_rad * math.sin(2 * phi) + eph.cuc_rad * math.cos(2 * phi)
    dr = eph.crs_m * math.sin(2 * phi) + eph.crc_m * math.cos(2 * phi)
    di = eph.cis_rad * math.sin(2 * phi) + eph.cic_rad * math.cos(2 * phi)
    u = phi + du
    r = eph.a_m * (1.0 - eph.ecc * math.cos(e)) + dr
    i = eph.i0_rad + di + eph.idot_rad_s * tk
    x_p, y_p = r * math.cos(u), r * math.sin(u)
    omega = eph.omega0_rad + (eph.omega_dot_rad_s - OMEGA_E) * tk - OMEGA_E * eph.toe_s
    pos = np.array([
        x_p * math.cos(omega) - y_p * math.cos(i) * math.sin(omega),
        x_p * math.sin(omega) + y_p * math.cos(i) * math.cos(omega),
        y_p * math.sin(i),
    ])
    tc = t_gps_s - (eph.week * SECONDS_PER_WEEK + eph.toc_s)
    rel = -2.0 * math.sqrt(MU) / C**2 * eph.ecc * math.sqrt(eph.a_m) * math.sin(e)
    return pos, eph.af0_s + eph.af1_s_s * tc + eph.af2_s_s2 * tc * tc + rel


def _wire(eph: GpsEphem) -> GpsEphem:
    """The ephemeris through a GPSEPHEMB frame and back."""
    header = Header("GPSEPHEM", 7, "COM1", 0, 50.0, TimeStatus.FINESTEERING, eph.week, eph.tow_s, 0, 0, 0)
    return decode_gpsephem(decode_binary(encode_binary(header, encode_gpsephem(eph))).body)  # type: ignore[arg-type]


# 2400 weeks + 345600 s; one day boundary and one week boundary inside the checked spans
START_NS = 2400 * NS_PER_WEEK + 345600 * NS_PER_S


@pytest.mark.parametrize(
    "t_ns",
    [START_NS, START_NS + 86400 * NS_PER_S - 1800 * NS_PER_S, 2401 * NS_PER_WEEK - 3600 * NS_PER_S],
    ids=["mid-week", "over-midnight", "over-week-rollover"],
)
def test_broadcast_ephemeris_reproduces_the_simulated_orbits(t_ns: int) -> None:
    """Every GPS satellite, over the 2 h of its ephemeris set (and past a day and week boundary), within 1 mm."""
    const = Constellation()
    worst = 0.0
    for sat in (s for s in const.satellites if s.system is GnssSystem.GPS):
        eph = _wire(gps_ephemeris(const, sat, t_ns))
        toe_ns = (eph.week * SECONDS_PER_WEEK + round(eph.toe_s)) * NS_PER_S
        for dt_s in (0.0, 1234.567, 3600.0, 7199.9):
            t = toe_ns + round(dt_s * NS_PER_S)
            pos, clk = is_gps_200(eph, t / NS_PER_S)
            truth = const.ecef_at(t)[const.index(sat)]
            worst = max(worst, float(np.linalg.norm(pos - truth)))
            assert clk == const.clock_offset_s(sat)
    assert worst < 1e-3, f"ephemeris orbit differs from the simulation by {worst * 1000:.3f} mm"


def test_ephemeris_sets_change_every_two_hours_and_only_for_gps() -> None:
    const = Constellation()
    sat = Satellite(GnssSystem.GPS, 5)
    a = gps_ephemeris(const, sat, START_NS)
    b = gps_ephemeris(const, sat, START_NS + 7199 * NS_PER_S)
    c = gps_ephemeris(const, sat, START_NS + 7200 * NS_PER_S)
    assert replace(a, tow_s=b.tow_s) == b and c.toe_s == a.toe_s + 7200 and c.iode1 != a.iode1 and c.iodc == c.iode1
    with pytest.raises(SimulationError, match="GLONASS satellite 3"):
        gps_ephemeris(const, const.satellites[26], START_NS)


def _rtklib_range(eph: GpsEphem, rr: np.ndarray, t_rx_s: float, pseudorange_m: float) -> tuple[float, float]:
    """RTKLIB's geometric range (satpos at t_rx − P/c − dts, plus the Sagnac term) and dts."""
    t_tx = t_rx_s - pseudorange_m / C
    _, dts = is_gps_200(eph, t_tx)
    rs, dts = is_gps_200(eph, t_tx - dts)
    rho = float(np.linalg.norm(rs - rr)) + OMEGA_E * (rs[0] * rr[1] - rs[1] * rr[0]) / C
    return rho, dts


def test_observations_follow_the_broadcast_model_and_keep_their_ambiguities() -> None:
    """Code residuals are noise; carrier residuals are a constant integer number of cycles while locked."""
    const = Constellation()
    gen = ObservationGenerator(const, seed=4)
    ant = AntennaState(48.7758, 9.1829, 347.9, 0.0, 0.0, 0.0)
    rr = np.array(pymap3d.geodetic2ecef(ant.lat_deg, ant.lon_deg, ant.height_m))
    ambiguities: dict[tuple[int, Band], list[float]] = {}
    code_res: list[float] = []
    for k in range(20):
        t_ns = START_NS + k * NS_PER_S
        for o in gen.epoch(ant, t_ns):
            if o.sat.system is not GnssSystem.GPS:
                continue
            eph = gps_ephemeris(const, o.sat, t_ns)
            rho, dts = _rtklib_range(eph, rr, t_ns / NS_PER_S, o.pseudorange_m)
            el = math.radians(o.elevation_deg)
            freq = C / o.wavelength_m
            common = rho - C * dts + troposphere_m(el, ant.height_m)
            sigma = 0.15 + 0.35 / max(math.sin(el), 0.1)
            code_res.append((o.pseudorange_m - common - ionosphere_m(el, freq)) / sigma)
            amb = (o.carrier_cycles * o.wavelength_m - common + ionosphere_m(el, freq)) / o.wavelength_m
            ambiguities.setdefault((o.sat.prn, o.band), []).append(amb)
    assert len(ambiguities) >= 8  # ≥ 4 GPS satellites × 2 signals
    assert abs(float(np.mean(code_res))) < 0.2 and 0.7 < float(np.std(code_res)) < 1.3
    for key, series in ambiguities.items():
        values = np.array(series)
        assert len(values) == 20, key
        assert np.max(np.abs(values - np.round(values))) < 0.05, key  # integer (2 mm noise ~ 0.01 cycle)
        assert np.all(np.round(values) == round(values[0])), key  # constant while locked


def test_double_differences_between_two_receivers_are_integers() -> None:
    """Base and rover share satellites, clocks and atmosphere: the double-differenced carrier is λ·integer."""
    const = Constellation()
    base, rover = ObservationGenerator(const, seed=1), ObservationGenerator(const, seed=2)
    a = AntennaState(48.7758, 9.1829, 347.9, 0.0, 0.0, 0.0)
    b = AntennaState(48.7858, 9.1929, 352.0, 0.0, 0.0, 0.0)  # ~1.3 km away
    oa = {(o.sat.prn, o.band): o for o in base.epoch(a, START_NS) if o.sat.system is GnssSystem.GPS}
    ob = {(o.sat.prn, o.band): o for o in rover.epoch(b, START_NS) if o.sat.system is GnssSystem.GPS}
    keys = sorted(set(oa) & set(ob), key=lambda k: (k[0], k[1].value))
    ref = max((k for k in keys if k[1] is Band.L1), key=lambda k: oa[k].elevation_deg)
    ref2 = (ref[0], Band.L2)
    for k in keys:
        r = ref if k[1] is Band.L1 else ref2
        dd_phase = (ob[k].carrier_cycles - oa[k].carrier_cycles) - (ob[r].carrier_cycles - oa[r].carrier_cycles)
        dd_rho = (ob[k].geometric_range_m - oa[k].geometric_range_m) - (ob[r].geometric_range_m
                                                                        - oa[r].geometric_range_m)
        n = dd_phase - dd_rho / ob[k].wavelength_m
        assert abs(n - round(n)) < 0.05, (k, n)


def test_rover_sends_gpsephemb_on_change(truth: GroundTruth, timebase: SimTimeBase,
                                         open_port: Callable[..., PortReader]) -> None:
    """LOG GPSEPHEMB ONCHANGED: each visible GPS satellite's set once; the bytes decode to the broadcast set."""
    clock = timebase.make_clock(speed=SPEED, lead_s=0.0)
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.0, 0.0, 1.5), timebase=timebase, clock=clock)
    rover.start()
    try:
        port = open_port(rover.port_path)
        assert port.command("LOG GPSEPHEMB ONCHANGED").message.ok  # type: ignore[union-attr]
        assert port.command("LOG TIMEB ONTIME 1").message.ok  # type: ignore[union-attr]

        def ephs(fs: list[Frame]) -> list[Frame]:
            return [f for f in fs if f.log is not None and f.log.header.message_name == "GPSEPHEM"]

        # wait for three TIME logs after the first ephemerides: nothing is re-sent meanwhile
        port.until(lambda fs: sum(1 for f in fs if f.log is not None and f.log.header.message_name == "TIME"
                                  and ephs(fs) and f.log.header.gps_ns > ephs(fs)[0].log.header.gps_ns) >= 3,
                   timeout_s=20.0)
        frames = ephs(port.frames)
        decoded = [decode_gpsephem(f.log.body) for f in frames]  # type: ignore[union-attr, arg-type]
        t_ns = frames[0].log.header.gps_ns  # type: ignore[union-attr]
        visible = {g.sat.prn for g in rover.observations.geometry(rover.antenna_state(t_ns), t_ns)
                   if g.sat.system is GnssSystem.GPS}
        assert sorted(e.prn for e in decoded) == sorted(visible) and len(visible) >= 5
        for e in decoded:
            assert e == gps_ephemeris(rover.constellation, Satellite(GnssSystem.GPS, e.prn), t_ns)
    finally:
        rover.stop()


def test_geometry_asked_again_is_the_same_and_follows_a_new_time_or_position() -> None:
    """ObservationGenerator.geometry keeps its last answer (a rover's logs of one epoch ask for the same
    geometry): asked again it is equal, and a new time or antenna position is computed afresh, as a
    generator that never answered before computes it."""
    const = Constellation()
    gen = ObservationGenerator(const, seed=3)
    a = AntennaState(48.7758, 9.1829, 347.9, 0.0, 0.0, 0.0)
    b = AntennaState(48.7758, 9.1829 + 40.0, 347.9, 0.0, 0.0, 0.0)  # another sky
    later = START_NS + 3_600 * 1_000_000_000
    first = gen.geometry(a, START_NS)
    first.clear()  # the caller owns its list: the kept answer is not the one handed out
    again = gen.geometry(a, START_NS)
    assert again and again == ObservationGenerator(const).geometry(a, START_NS)
    for ant, t in ((a, later), (b, START_NS), (a, START_NS)):
        assert gen.geometry(ant, t) == ObservationGenerator(const).geometry(ant, t), (ant, t)
    assert gen.geometry(a, later) != gen.geometry(a, START_NS)
    assert gen.geometry(b, START_NS) != gen.geometry(a, START_NS)
