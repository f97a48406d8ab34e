"""Timing of ``rig replay`` at 1x on this machine, as a receiving recorder sees it, and where the error comes from.

A short simulated session is recorded (the shipped simulated car, a step steer; or ``--session PATH``), then
its CAN frames are replayed at ``--speed`` by :class:`rig.replay.Replayer` and received by the rig's live
reader (:class:`drivers.can.bus.CanBusSession`) in three set-ups:

- ``virtual/in``: a python-can virtual bus, the reader in the player's process (the bus stamps each frame
  in the player's own ``send``; the reader's thread competes with the player for the interpreter lock);
- ``scand/in``: a socketcand server on 127.0.0.1 and the reader, both in the player's process (the server's
  bus stamps each frame when its ``< send >`` has crossed TCP and the server's command thread has run);
- ``scand/out``: the same server and reader in another process (the acceptance set-up: as on a bench, the
  receiving side stamps, and nothing of it runs in the player's process).

Each set-up runs with the player's final approach on (``--spin-ms``, default 1.5: sleep to that much before
each due time, then spin on the clock) and off (sleep alone). Printed per run, in µs:

- send lateness: the player's own clock reading just before each ``send`` minus the frame's due time;
- spacing error: each frame's received spacing from its predecessor minus the recorded spacing / speed
  (the acceptance figure: within 1 ms at 1x), and the frames over 1 ms;

with the load average before each run, since the figures measure the host's scheduling as much as the player.

Run: ``.venv/bin/python benchmarks/bench_replay.py [--session PATH] [--speed X] [--repeat N] [--spin-ms MS]``
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import tempfile
import threading
import time
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from drivers.can.bus import BusEvent, BusOpened, CanBusConfig, CanBusSession, CanFrame, open_bus
from rig.dataset import load_session
from rig.replay import Replayer, ReplayPlan, ReplayStats, build_plan, parse_bus_spec
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from vsccore.clock import ScaledClock, SystemClock


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
    """The rig's CAN reader keeping each frame's stamp (the bus's, else the host receive time)."""

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

    def __enter__(self) -> Receiver:
        self.session.start()
        if not self.opened.wait(5.0):
            raise SystemExit("receiving bus did not open")
        return self

    def __exit__(self, *exc: object) -> None:
        self.session.stop()

    def wait_for(self, count: int, timeout_s: float) -> np.ndarray:
        with self.cond:
            self.cond.wait_for(lambda: len(self.stamps) >= count, timeout_s)
            return np.asarray(self.stamps, dtype=np.int64)


def _socketcand_rx(host: str, port: int) -> CanBusConfig:
    return CanBusConfig(interface="socketcand", channel="vsc0", options={"host": host, "port": port}, name="rx")


def _receiving_side(channel: str, count: int, conn: Connection) -> None:
    """Child process of ``scand/out``: a socketcand server and the reader; sends the stamps back."""
    with SocketcandServer(virtual_channel_opener({"vsc0": channel}), rawmode_settle_s=0.0) as server:
        host, port = server.address
        with Receiver(_socketcand_rx(host, port)) as rx:
            conn.send((host, port))
            stamps = rx.wait_for(count, 60.0)
    conn.send(stamps)
    conn.close()


def play(plan: ReplayPlan, tx_spec: str, speed: float, spin_s: float) -> ReplayStats:
    bus = open_bus(parse_bus_spec(tx_spec))
    try:
        return Replayer(plan, bus, ScaledClock(time.time_ns()), speed=speed, spin_s=spin_s).run()
    finally:
        bus.shutdown()


def run_once(plan: ReplayPlan, setup: str, channel: str, speed: float, spin_s: float) -> tuple[ReplayStats, np.ndarray]:
    n = len(plan)
    if setup == "virtual/in":
        with Receiver(CanBusConfig(interface="virtual", channel=channel, name="rx")) as rx:
            stats = play(plan, f"virtual:{channel}", speed, spin_s)
            return stats, rx.wait_for(n, 10.0)
    if setup == "scand/in":
        with SocketcandServer(virtual_channel_opener({"vsc0": channel}), rawmode_settle_s=0.0) as srv:
            host, port = srv.address
            with Receiver(_socketcand_rx(host, port)) as rx:
                stats = play(plan, f"socketcand:vsc0,host={host},port={port}", speed, spin_s)
                return stats, rx.wait_for(n, 10.0)
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_receiving_side, args=(channel, n, child), name="bench-receiving-side")
    proc.start()
    child.close()
    try:
        if not parent.poll(60.0):
            raise SystemExit("receiving side did not start")
        host, port = parent.recv()
        stats = play(plan, f"socketcand:vsc0,host={host},port={port}", speed, spin_s)
        if not parent.poll(70.0):
            raise SystemExit("receiving side did not answer")
        return stats, parent.recv()
    finally:
        proc.join(10.0)
        parent.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--session", type=Path, help="A recorded session to replay (default: record one)")
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--spin-ms", type=float, default=Replayer.SPIN_S * 1e3)
    parser.add_argument("--setup", action="append", choices=("virtual/in", "scand/in", "scand/out"))
    args = parser.parse_args()
    setups = args.setup or ["virtual/in", "scand/in", "scand/out"]
    with tempfile.TemporaryDirectory() as tmp:
        source = args.session or record_source(Path(tmp))
        session = load_session(source, include=lambda t: t.startswith("/can/") and t.endswith("/frames"))
        plan = build_plan(session)
        print(f"{len(plan)} frames over {plan.duration_ns / 1e9:.1f} s on {os.cpu_count()} CPUs; replay at "
              f"{args.speed:g}x")
        print(f"{'set-up':<11} {'spin ms':>7} {'load':>5} {'send late µs p50/p99/max':>26} {'>1 ms':>6} "
              f"{'spacing error µs p50/p99/p99.9/max':>36} {'>1 ms':>6}")
        k = 0
        for setup in setups:
            for spin_ms in (args.spin_ms, 0.0):
                for _ in range(args.repeat):
                    k += 1
                    load = os.getloadavg()[0]
                    stats, got = run_once(plan, setup, f"bench-replay-{k}", args.speed, spin_ms / 1e3)
                    if got.size != len(plan):
                        raise SystemExit(f"{setup}: received {got.size} of {len(plan)} frames")
                    spacing = np.abs(np.diff(got) - np.diff(plan.t_ns) / args.speed)
                    sp = np.percentile(spacing, [50, 99, 99.9, 100]) / 1e3
                    lat = stats.lateness_us
                    print(f"{setup:<11} {spin_ms:>7.1f} {load:>5.1f} "
                          f"{lat['p50']:>8.0f}/{lat['p99']:.0f}/{lat['max']:<8.0f} {stats.late_frames:>6} "
                          f"{'/'.join(f'{v:.0f}' for v in sp):>36} {int(np.count_nonzero(spacing > 1e6)):>6}")


if __name__ == "__main__":
    main()
