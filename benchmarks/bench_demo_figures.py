"""`rig demo --fast` measured stage by stage: wall times, the governed clock, and the figures issue 15 judges.

Runs the demo's record, calibrate, steering-ratio, validate and rollover stages (a stage that fails
is reported and the others still run) and prints each stage's summary, the backward ``log_time``
steps per topic in the file, the recorder's clamps and live verdicts, and the total wall time. Run
it on an idle machine and under a CPU stress load (``benchmarks/stress_suite.sh --demo`` runs it
three times under 6 busy processes) and compare:
mounting offset error against its u95, the GNSS reference β RMS / coverage against truth, the CAN
timing error against truth, the governed clock's paused time and effective speed.

Usage: .venv/bin/python benchmarks/bench_demo_figures.py OUT_DIR
"""

from __future__ import annotations

import sys
import time
import traceback
from pathlib import Path


def main(out: Path) -> int:
    from rig.core.config import load_session
    from rig.core.quality import backward_steps
    from rig.data import load_session as load_recording
    from rig.workflows import demo as D  # noqa: N812 - the demo's stage functions
    from sim_devices.vehicle import VehicleParams, simulate

    t_all = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_session(D.demo_config_path())
    sim = cfg.simulation
    if sim is None or cfg.vehicle is None:
        print("the demo configuration has no [simulation] or vehicle", file=sys.stderr)
        return 2
    params = VehicleParams.from_mapping(cfg.vehicle.model_dump(), section="vehicle")
    drive = D.demo_drive_for(cfg, fast=True)
    truth = simulate(drive, params, origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                     initial_heading_deg=sim.initial_heading_deg, seed=sim.seed)
    session = out / "session" / "demo"
    stages = [
        ("record", lambda: D._record(cfg, out / "session", truth, drive, fast=True, config=D.demo_config_path())),
        ("calibrate", lambda: D._calibrate(session, out)),
        ("steering-ratio", lambda: D._steering_ratio(session, out)),
        ("validate", lambda: D._validate(session, out / "report")),
        ("rollover", lambda: D._rollover(session, out)),
    ]
    failed = 0
    for name, fn in stages:
        t0 = time.perf_counter()
        try:
            text, _files = fn()
        except Exception as exc:  # report the stage and go on: the others' figures still count
            failed += 1
            text = "FAILED: " + "".join(traceback.format_exception_only(exc)).strip()
        print(f"[{name}] ({time.perf_counter() - t0:.1f} s) {text}", flush=True)
    if (out / "session" / "demo.000.mcap").exists():
        ds = load_recording(session)
        last: dict[str, int] = {}
        for topic in sorted(ds.topic_counts):
            times = ds.message_times(topic)[0]
            n, largest = backward_steps(times)
            if n:
                print(f"backward log_time: {topic}: {n} step(s), largest {largest:.3f} ms")
            if len(times) and topic.startswith(("/can/", "/gnss/", "/daq/", "/optical/")):
                last[topic] = int(times.max())
        for _t, ev in ds.events:  # what the recorder had to clamp, and the verdicts it gave at the end
            if ev.details.get("clamped"):
                print("log_time clamped by the recorder: " + ", ".join(
                    f"{topic} {n}× (largest {ms:.3f} ms)" for topic, (n, ms) in sorted(ev.details["clamped"].items())))
            if "verdicts" in ev.details:
                print("time-base verdicts: " + ", ".join(
                    f"{k} {v['verdict']}" for k, v in sorted(ev.details["verdicts"].items())))
            if ev.details.get("slew_ns"):
                print(f"time-base slew: {ev.text}")
        if last:  # the quality gate's early end: a stream that stops before the last one
            end = max(last.values())
            print("stream ends before the last stream: " + ", ".join(
                f"{topic} {(end - t) / 1e9:.2f} s" for topic, t in sorted(last.items(), key=lambda kv: kv[1])[:4]))
    print(f"total wall {time.perf_counter() - t_all:.1f} s, {failed} stage(s) failed")
    return 1 if failed else 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1])))
