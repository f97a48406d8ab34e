"""Simulated GLONASS: orbits that ARE the broadcast-ephemeris model, FDMA observations, GLOEPHEMERISB logs.

The satellite position is computed from the *decoded* GLOEPHEMERISB bytes with the ICD GLONASS 5.1
A.3.1.2 user algorithm (RK4 over 60 s steps from tb with the lunisolar acceleration held), written
here independently of the simulator, and the observations are inverted with the model RTKLIB uses
(transmission time from the pseudorange, Earth-rotation correction, clock −τn + γn·(t − tb)).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pymap3d
import pytest

from drivers.novatel import Frame, Header, TimeStatus, decode_binary, encode_binary
from drivers.novatel.rawobs import GloEphemeris, decode_gloephemeris, encode_gloephemeris
from sim_devices.gnss import SimTimeBase
from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import Constellation, GnssSystem, Satellite
from sim_devices.gnss.ephemeris import glonass_ephemeris
from sim_devices.gnss.observations import Band, ObservationGenerator, ionosphere_m, troposphere_m
from sim_devices.gnss.rover import SimRover
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK

C = 299_792_458.0
OMEGA_E = 7.2921151467e-5
START_NS = 2400 * NS_PER_WEEK + 345600 * NS_PER_S


def _icd_orbit(eph: GloEphemeris, t_gps: float | int) -> tuple[tuple[float, float, float], float]:
    """ECEF position (m) and clock offset (s) at GPS time ``t_gps`` (int: ns, exact; float: s) since the GPS epoch:
    ICD A.3.1.2, RK4, 60 s steps."""
    mu, ae, j2, w = 398_600.4418e9, 6_378_136.0, 1_082_625.75e-9, 7.2921151467e-5
    ax, ay, az = eph.lunisolar_mps2()

    def f(s: list[float]) -> list[float]:
        x, y, z, vx, vy, vz = s
        r = math.sqrt(x * x + y * y + z * z)
        k = 1.5 * j2 * mu * ae * ae / r**5
        g = -mu / r**3 - k * (1.0 - 5.0 * z * z / (r * r))
        return [vx, vy, vz, (g + w * w) * x + 2 * w * vy + ax, (g + w * w) * y - 2 * w * vx + ay,
                (-mu / r**3 - k * (3.0 - 5.0 * z * z / (r * r))) * z + az]

    s = [*eph.position_m(), *eph.velocity_mps()]
    tb_ns = round(eph.tb_gps_s) * NS_PER_S
    dt = (t_gps - tb_ns) / NS_PER_S if isinstance(t_gps, int) else t_gps - eph.tb_gps_s
    clock_dt = dt
    while abs(dt) > 1e-9:
        h = dt if abs(dt) < 60.0 else math.copysign(60.0, dt)
        k1 = f(s)
        k2 = f([a + h / 2 * b for a, b in zip(s, k1, strict=True)])
        k3 = f([a + h / 2 * b for a, b in zip(s, k2, strict=True)])
        k4 = f([a + h * b for a, b in zip(s, k3, strict=True)])
        s = [a + h / 6 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(s, k1, k2, k3, k4, strict=True)]
        dt -= h
    return (s[0], s[1], s[2]), -eph.tau_n_s + eph.gamma_n * clock_dt


def _wire(eph: GloEphemeris) -> GloEphemeris:
    header = Header("GLOEPHEMERIS", 723, "COM1", 0, 50.0, TimeStatus.FINESTEERING, eph.ephem_week,
                    eph.ephem_time_ms / 1000, 0, 0, 0)
    return decode_gloephemeris(decode_binary(encode_binary(header, encode_gloephemeris(eph))).body)  # type: ignore[arg-type]


def _glonass(const: Constellation) -> list[Satellite]:
    return [s for s in const.satellites if s.system is GnssSystem.GLONASS]


@pytest.mark.parametrize("t_ns", [START_NS, START_NS + 3 * 3600 * NS_PER_S + 777 * NS_PER_S],
                         ids=["start", "three-hours-on"])
def test_broadcast_ephemeris_is_the_simulated_orbit(t_ns: int) -> None:
    """Every GLONASS satellite over its whole 30-minute interval (tb ± 15 min): the ICD algorithm on the decoded
    GLOEPHEMERISB gives the simulated position within 0.1 mm, and the clock exactly."""
    const = Constellation()
    worst = 0.0
    for sat in _glonass(const):
        eph = _wire(glonass_ephemeris(const, sat, t_ns))
        assert eph.slot == sat.prn and eph.fcn == sat.fcn
        assert eph.tb_gps_s - 900 <= t_ns / NS_PER_S < eph.tb_gps_s + 900
        tb_ns = round(eph.tb_gps_s) * NS_PER_S
        for dt_s in (-899.5, -123.25, 0.0, 456.5, 899.0):
            t = tb_ns + round(dt_s * NS_PER_S)
            pos, clk = _icd_orbit(eph, t)
            truth = const.ecef_at(t)[const.index(sat)]
            worst = max(worst, float(np.linalg.norm(np.array(pos) - truth)))
            assert clk == pytest.approx(const.satellite_clock_s(sat, t), abs=1e-15)
    assert worst < 1e-4, f"broadcast orbit differs from the simulation by {worst * 1000:.4f} mm"


def test_glonass_orbits_are_not_keplerian_and_ephemerides_change_every_30_minutes() -> None:
    """J2 is in the truth (the orbit leaves the circle), tb is on the GLONASS quarter hours, sets change each 30 min."""
    const = Constellation()
    sat = _glonass(const)[4]
    a = glonass_ephemeris(const, sat, START_NS)
    b = glonass_ephemeris(const, sat, START_NS + 1800 * NS_PER_S)
    assert b.tb_gps_s - a.tb_gps_s == 1800 and b.issue == a.issue + 2
    tod_glo = (round(a.tb_gps_s) + a.time_offset_s) % 86400
    assert tod_glo % 1800 == 900 and a.issue == tod_glo // 900 and a.time_offset_s == 3 * 3600 - 18
    radii = [float(np.linalg.norm(const.ecef_at(START_NS + k * 600 * NS_PER_S)[const.index(sat)]))
             for k in range(12)]
    assert 10.0 < max(radii) - min(radii) < 20_000.0  # J2 makes the orbit breathe; no Keplerian circle
    assert a.gamma_n == const.clock_rate(sat) and abs(a.tau_n_s) < 1e-4
    assert max(abs(v) for v in a.lunisolar_mps2()) <= 6.2e-6
    with pytest.raises(SimulationError, match="GPS satellite 3"):
        glonass_ephemeris(const, Satellite(GnssSystem.GPS, 3), START_NS)


def test_glonass_observations_follow_the_broadcast_model_with_fdma_wavelengths() -> None:
    """Code residuals are noise and carrier residuals a constant integer on each satellite's own wavelengths."""
    const = Constellation()
    gen = ObservationGenerator(const, seed=5)
    ant = AntennaState(48.7758, 9.1829, 347.9, 0.0, 0.0, 0.0)
    rr = np.array(pymap3d.geodetic2ecef(ant.lat_deg, ant.lon_deg, ant.height_m))
    amb: dict[tuple[int, Band], list[float]] = {}
    code_res: list[float] = []
    for k in range(10):
        t_ns = START_NS + k * 2 * NS_PER_S
        for o in gen.epoch(ant, t_ns):
            if o.sat.system is not GnssSystem.GLONASS:
                continue
            freq = o.sat.l1_hz() if o.band is Band.L1 else o.sat.l2_hz()
            assert o.wavelength_m == C / freq
            eph = glonass_ephemeris(const, o.sat, t_ns)
            t_tx = t_ns / NS_PER_S - o.pseudorange_m / C
            _, dts = _icd_orbit(eph, t_tx)
            rs, dts = _icd_orbit(eph, t_tx - dts)
            rho = float(np.linalg.norm(np.array(rs) - rr)) + OMEGA_E * (rs[0] * rr[1] - rs[1] * rr[0]) / C
            el = math.radians(o.elevation_deg)
            common = rho - C * dts + troposphere_m(el, ant.height_m)
            sigma = 0.15 + 0.35 / max(math.sin(el), 0.1)
            code_res.append((o.pseudorange_m - common - ionosphere_m(el, freq)) / sigma)
            amb.setdefault((o.sat.prn, o.band), []).append(
                (o.carrier_cycles * o.wavelength_m - common + ionosphere_m(el, freq)) / o.wavelength_m)
    sats = {k[0] for k in amb}
    assert 6 <= len(sats) <= 10, sats
    assert abs(float(np.mean(code_res))) < 0.3 and 0.6 < float(np.std(code_res)) < 1.4
    for key, series in amb.items():
        values = np.array(series)
        assert np.max(np.abs(values - np.round(values))) < 0.05, key
        assert np.all(np.round(values) == round(values[0])), key


def test_rover_sends_gloephemerisb_on_change(truth: GroundTruth, timebase: SimTimeBase,
                                             open_port: Callable[..., PortReader]) -> None:
    """LOG GLOEPHEMERISB ONCHANGED: each visible GLONASS satellite's set once, the broadcast set byte for byte."""
    clock = timebase.make_clock(speed=SPEED, lead_s=0.0)
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.0, 0.0, 1.5), timebase=timebase, clock=clock)
    rover.start()
    try:
        port = open_port(rover.port_path)
        assert port.command("LOG GLOEPHEMERISB ONCHANGED").message.ok  # type: ignore[union-attr]
        assert port.command("LOG TIMEB ONTIME 1").message.ok  # type: ignore[union-attr]

        def ephs(fs: list[Frame]) -> list[Frame]:
            return [f for f in fs if f.log is not None and f.log.header.message_name == "GLOEPHEMERIS"]

        port.until(lambda fs: sum(1 for f in fs if f.log is not None and f.log.header.message_name == "TIME"
                                  and ephs(fs) and f.log.header.gps_ns > ephs(fs)[0].log.header.gps_ns) >= 3,
                   timeout_s=20.0)
        frames = ephs(port.frames)
        decoded = [decode_gloephemeris(f.log.body) for f in frames]  # type: ignore[union-attr, arg-type]
        t_ns = frames[0].log.header.gps_ns  # type: ignore[union-attr]
        visible = {g.sat.prn for g in rover.observations.geometry(rover.antenna_state(t_ns), t_ns)
                   if g.sat.system is GnssSystem.GLONASS}
        assert sorted(e.slot for e in decoded) == sorted(visible) and len(visible) >= 5
        for e in decoded:
            sat = next(s for s in rover.constellation.satellites if s.system is GnssSystem.GLONASS and s.prn == e.slot)
            assert e == glonass_ephemeris(rover.constellation, sat, t_ns)
    finally:
        rover.stop()


def test_daily_restart_of_the_truth_stays_consistent_with_the_ephemerides() -> None:
    """The truth restarts from the circular orbit once a day at 23:30:18 GPS, an ephemeris interval bound: a signal
    sent just before it comes from the orbit the old interval's ephemeris describes, one sent after it from the new
    one, even within one receiver epoch (light time reaches back across the bound)."""
    const = Constellation()
    switch_ns = START_NS + (86400 - 1782) * NS_PER_S
    sats = _glonass(const)
    idx = [const.index(s) for s in sats]
    t_rx = switch_ns + 30_000_000
    dt = np.array([-0.07 if i % 2 else 0.0 for i in range(len(const.satellites))])
    pos = const.ecef_at(t_rx, dt)
    jumps = []
    for sat, i in zip(sats, idx, strict=True):
        t_tx_ns = t_rx + round(dt[i] * NS_PER_S)
        eph = glonass_ephemeris(const, sat, t_tx_ns)
        assert (eph.tb_gps_s < switch_ns / NS_PER_S) == (t_tx_ns < switch_ns)
        icd, _ = _icd_orbit(eph, t_tx_ns)
        assert float(np.linalg.norm(np.array(icd) - pos[i])) < 1e-4, sat
        before = const.ecef_at(switch_ns - 1_000_000)[i]
        after = const.ecef_at(switch_ns)[i]
        jumps.append(float(np.linalg.norm(after - before)))
    assert max(jumps) > 100.0  # the restart is a real jump (J2 drift of a day), hidden at the bound
