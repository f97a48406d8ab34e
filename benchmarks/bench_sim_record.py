"""Simulated recording through the real ``rig record`` path: CPU, keeping up, and timing against the truth.

Records the shipped simulated car (``rig/examples/sim.toml``) at several clock speeds and prints, per
run: wall and CPU time, messages, drops, frames the simulated ECU had to skip, the share of RTK-fixed
BESTPOS, the horizontal BESTPOS error against the true antenna position, and each stream's time
error against the simulator's true times (CAN: the ECU's transmit stamps; DAQ: its sample clock).

    python benchmarks/bench_sim_record.py [--drive j_turn] [--speeds 1,3,5]
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pymap3d

from rig.core.config import load_session
from rig.data import align
from rig.data import load_session as load_recording
from rig.sim.record import record_simulated
from rig.sim.truth import timing_vs_truth
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle.geodesy import point_geodetic

RTK = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=0.5,
                time_to_fix_s=2.0)


def run(drive: str, speed: float, out: Path) -> None:
    cfg = load_session(demo_config_path(), {"simulation.drive": drive})
    cpu0 = time.process_time()
    rec = record_simulated(cfg, out, name="bench", speed=speed, rtk=RTK, lead_s=5.0)
    cpu = time.process_time() - cpu0
    ds = load_recording(out / "bench")
    truth = ds.truth()
    gt = dataclasses.replace(truth.truth, meta={"cg_height_m": cfg.profile.vehicle.cg_height_m})
    health = rec.world.health()
    skipped = sum(v.get("frames_skipped", 0) for v in health.values())
    s = rec.summary.recording
    sim_s = rec.world.duration_s + rec.world.lead_s
    print(f"{drive} at {speed:g}×: {sim_s:.1f} s simulated in {rec.wall_s:.1f} s wall, CPU {cpu:.1f} s "
          f"({cpu / sim_s * 1e3:.0f} ms per simulated second), {s.messages} messages, dropped {s.dropped}, "
          f"ECU frames skipped {skipped}")
    arms = rec.world.antenna_lever_arms()
    for rx, ant in (("rover_a", "a"), ("rover_b", "b")):
        g = ds.gnss(rx)
        bp = g.bestpos
        inside = (bp.time_ns >= truth.time_ns[0]) & (bp.time_ns <= truth.time_ns[-1])
        sel = inside & g.rtk_fixed
        lat, lon, h = point_geodetic(gt, *arms[ant])
        ref = [align(bp.time_ns[sel], truth.time_ns, v) for v in (lat, lon, h)]
        e, n, _u = pymap3d.geodetic2enu(bp["lat_deg"][sel], bp["lon_deg"][sel],
                                        bp["height_msl_m"][sel] + bp["undulation_m"][sel], *ref)
        hor = np.hypot(e, n)
        print(f"    {rx}: RTK fixed {100 * sel.sum() / max(1, inside.sum()):.0f} % of the drive, horizontal error "
              f"rms {100 * np.sqrt(np.mean(hor**2)):.1f} cm, max {100 * hor.max():.1f} cm")
    for t in timing_vs_truth(ds, cfg):
        print(f"    {t.stream}: time error mean {t.mean_ns / 1e3:+.1f} µs, rms {t.rms_ns / 1e3:.1f} µs, "
              f"max {t.max_abs_ns / 1e3:.1f} µs")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drive", default="j_turn")
    ap.add_argument("--speeds", default="1,3,5")
    args = ap.parse_args()
    for speed in (float(x) for x in args.speeds.split(",")):
        out = Path(tempfile.mkdtemp(prefix="bench-sim-record-"))
        try:
            run(args.drive, speed, out)
        finally:
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
