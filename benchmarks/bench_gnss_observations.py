"""Simulated GNSS observation cost with the integrated GLONASS orbits (sim_devices.gnss.glonass).

Prints:

- the first evaluation of a day's GLONASS truth (the RK4 integration from the day's start up to the
  queried time, all GLONASS satellites at once; once per process and day);
- one observation epoch (:meth:`ObservationGenerator.epoch`: visibility, light-time ranges, both
  signals of every visible GPS and GLONASS satellite), ms per epoch and the share of one core a
  20 Hz rover spends on it;
- one GLOEPHEMERIS set (:func:`glonass_ephemeris`) per satellite, ms.

Run: ``.venv/bin/python benchmarks/bench_gnss_observations.py [--epochs N]``
"""

from __future__ import annotations

import argparse
import time

from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.constellation import Constellation, GnssSystem
from sim_devices.gnss.ephemeris import glonass_ephemeris
from sim_devices.gnss.observations import ObservationGenerator
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=400)
    args = ap.parse_args()
    # late in a GPS day (23:00): the longest integration of the day's truth
    t0 = 2400 * NS_PER_WEEK + (345600 + 82800) * NS_PER_S
    const = Constellation()
    start = time.perf_counter()
    const.ecef_at(t0)
    first = time.perf_counter() - start
    print(f"GLONASS truth, first evaluation 23 h into the day: {first * 1e3:.0f} ms")
    gen = ObservationGenerator(const, seed=1)
    ant = AntennaState(48.7758, 9.1829, 347.9, 0.0, 0.0, 0.0)
    obs = gen.epoch(ant, t0)
    start = time.perf_counter()
    for k in range(args.epochs):
        gen.epoch(ant, t0 + k * 50_000_000)
    per = (time.perf_counter() - start) / args.epochs
    n_glo = len({o.sat for o in obs if o.sat.system is GnssSystem.GLONASS})
    n_gps = len({o.sat for o in obs if o.sat.system is GnssSystem.GPS})
    print(f"observation epoch ({n_gps} GPS + {n_glo} GLONASS satellites, 2 signals): {per * 1e3:.2f} ms "
          f"({per * 20 * 100:.1f} % of a core at 20 Hz)")
    sats = [s for s in const.satellites if s.system is GnssSystem.GLONASS]
    start = time.perf_counter()
    for s in sats:
        glonass_ephemeris(const, s, t0 + 1800 * NS_PER_S)
    print(f"GLOEPHEMERIS set: {(time.perf_counter() - start) / len(sats) * 1e3:.3f} ms per satellite")


if __name__ == "__main__":
    main()
