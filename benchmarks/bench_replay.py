"""Timing of ``rig replay`` at 1x on this machine, as a receiving reader sees it.

A short simulated session is recorded (the shipped simulated car, a step steer; or ``--session PATH``),
then its CAN frames are replayed at ``--speed`` onto

- a python-can virtual bus (the bus stamps each frame when the player sends it), and
- a socketcand server on 127.0.0.1 (python-can's socketcand client; the server's bus stamps the frame when
  the ``< send >`` command has crossed TCP and the server's thread),

and received by the rig's live reader (:class:`drivers.can.bus.CanBusSession`). Printed per transport, in µs:

- spacing error: each frame's received spacing from its predecessor minus the recorded spacing / speed
  (the acceptance figure: within 1 ms at 1x);
- schedule error: each frame's received time from the first frame's minus its recorded offset / speed
  (would grow along the replay if lateness accumulated);
- the player's own send lateness after each due time, and the frames more than 1 ms late;

with the load average, since the figures measure the host's scheduling as much as the player.

Run: ``.venv/bin/python benchmarks/bench_replay.py [--session PATH] [--speed X] [--repeat N]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
from pathlib import Path

import numpy as np

from drivers.can.bus import BusEvent, BusOpened, CanBusConfig, CanBusSession, CanFrame
from rig.replay import ReplayPlan, parse_bus_spec, replay_session
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from vsccore.clock import SystemClock


def record_source(out: Path) -> Path:
    from rig.config import load_session as load_config
    from rig.demo import demo_config_path
    from rig.simworld import record_simulated
    from sim_devices.gnss import RtkParams
    from sim_devices.vehicle.scenarios import make_scenario

    cfg = load_config(demo_config_path(), {"simulation.speed": 1.0})
    drive = make_scenario("step_steer", speed_kmh=60.0, lead_s=0.5, rise_s=0.2, hold_s=4.0)
    rtk = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=0.5,
                    time_to_fix_s=2.0)
    rec = record_simulated(cfg, out, name="src", drive=drive, lead_s=1.5, rtk=rtk)
    if not rec.completed:
        raise SystemExit("recording the source session failed")
    return out / "src"


class Receiver:
    def __init__(self, config: CanBusConfig) -> None:
        self.stamps: list[int] = []
        self.opened = threading.Event()
        self.cond = threading.Condition()
        self.session = CanBusSession(config, self.on_frame, self.on_event, clock=SystemClock(), stats_period_s=None)

    def on_frame(self, f: CanFrame) -> None:
        with self.cond:
            self.stamps.append(f.device_ts_ns if f.device_ts_ns is not None else f.host_ts_ns)
            self.cond.notify_all()

    def on_event(self, e: BusEvent) -> None:
        if isinstance(e, BusOpened):
            self.opened.set()


def run_once(source: Path, rx_cfg: CanBusConfig, tx_spec: str, speed: float) -> dict[str, np.ndarray | int]:
    plans: list[ReplayPlan] = []
    rx = Receiver(rx_cfg)
    rx.session.start()
    try:
        if not rx.opened.wait(5.0):
            raise SystemExit("receiving bus did not open")
        stats = replay_session(source, parse_bus_spec(tx_spec), speed=speed, on_plan=plans.append)
        with rx.cond:
            rx.cond.wait_for(lambda: len(rx.stamps) >= len(plans[0]), 10.0)
    finally:
        rx.session.stop()
    plan = plans[0]
    got = np.asarray(rx.stamps, dtype=np.int64)
    if got.size != len(plan):
        raise SystemExit(f"received {got.size} of {len(plan)} frames")
    spacing = np.abs(np.diff(got) - np.diff(plan.t_ns) / speed)
    schedule = (got - got[0]) - (plan.t_ns - plan.t_ns[0]) / speed
    return {"spacing": spacing, "schedule": np.abs(schedule - np.median(schedule)),
            "late": stats.late_frames, "send_p99": int(stats.lateness_us.get("p99", 0)),
            "send_max": int(stats.lateness_us.get("max", 0)), "frames": len(plan)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--session", type=Path, help="A recorded session to replay (default: record one)")
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        source = args.session or record_source(Path(tmp))
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; replay at {args.speed:g}x")
        print(f"{'transport':<11} {'frames':>6} {'spacing error µs p50/p99/p99.9/max':>38} "
              f"{'schedule error µs p50/p99/max':>32} {'send late µs p99/max':>21} {'>1 ms':>6}")
        for transport in ("virtual", "socketcand"):
            for k in range(args.repeat):
                channel = f"bench-replay-{transport}-{k}"
                if transport == "virtual":
                    r = run_once(source, CanBusConfig(interface="virtual", channel=channel, name="rx"),
                                 f"virtual:{channel}", args.speed)
                else:
                    with SocketcandServer(virtual_channel_opener({"vsc0": channel}), rawmode_settle_s=0.0) as srv:
                        host, port = srv.address
                        rx = CanBusConfig(interface="socketcand", channel="vsc0", options={"host": host, "port": port},
                                          name="rx")
                        r = run_once(source, rx, f"socketcand:vsc0,host={host},port={port}", args.speed)
                sp = np.percentile(np.asarray(r["spacing"]), [50, 99, 99.9, 100]) / 1e3
                sc = np.percentile(np.asarray(r["schedule"]), [50, 99, 100]) / 1e3
                print(f"{transport:<11} {r['frames']:>6} {'/'.join(f'{v:.0f}' for v in sp):>38} "
                      f"{'/'.join(f'{v:.0f}' for v in sc):>32} {r['send_p99']:>10}/{r['send_max']:<10} "
                      f"{r['late']:>6}")


if __name__ == "__main__":
    main()
