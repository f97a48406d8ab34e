"""Timing of ``rig replay`` at 1x on this machine, as a receiving recorder sees it, and where the error comes from.

A short simulated session is recorded (the shipped simulated car, a step steer; or ``--session PATH``), then
its CAN frames are replayed at ``--speed`` by :class:`rig.replay.player.Replayer` and received by the rig's live
reader (:class:`drivers.can.bus.CanBusLink`) in three set-ups:

- ``virtual/in``: a python-can virtual bus, the reader in the player's process (the bus stamps each frame
  in the player's own ``send``; the reader's thread competes with the player for the interpreter lock);
- ``scand/in``: a socketcand server on 127.0.0.1 and the reader, both in the player's process;
- ``scand/out``: the same server and reader in another process (the acceptance set-up: as on a bench, the
  receiving side stamps, and nothing of it runs in the player's process).

Each set-up runs with each ``--spin-ms`` (default 1.5 and 0: the player's final approach, sleep to that
much before each due time then spin on the clock; 0 is sleep alone). Printed per run, in µs, with the load
average before it (the figures measure the host's scheduling as much as the player):

- send lateness: the player's own clock reading just before each ``send`` minus the frame's due time;
- per stage, each frame's spacing from its predecessor minus the recorded spacing / speed (p50/p99/p99.9/max
  of its size, frames over 1 ms) and the stage's delay after the player's send (p50/p99/max):

  - ``sent``: the player's wall clock just before each ``send`` call;
  - ``arrival``: the kernel's receive stamp of the ``< send >`` at the socketcand server (``SO_TIMESTAMPNS``);
  - ``handled``: the wall clock when the server's command thread puts the frame on its bus;
  - ``recorded``: the bus stamp the receiving reader records as the frame's device time (the acceptance
    figure). The server stamps a client's frame with its arrival (``--stamp arrival``, the server's
    default) or, as it did before, when its thread handles it (``--stamp handled``);
  - ``host rx``: the receiving reader's host receive time (its own clock when the frame reached it).

``--stress N`` runs N busy processes (pure-Python loops) during the runs, for the figures under load. The
closing lines sum the runs per set-up: runs with every recorded frame within 1 ms, frames over 1 ms.

``--slice-us`` asks for a shorter scheduler time slice for the player thread (:class:`rig.replay.player.Replayer`'s
``slice_s``). ``--rt-priority`` puts the player thread on SCHED_FIFO at that priority (``rt_priority``; 0:
ordinary scheduling; needs root or CAP_SYS_NICE). Variants (spin, slice, priority) run interleaved,
``--repeat`` rounds.

Run: ``.venv/bin/python benchmarks/bench_replay.py [--session PATH] [--speed X] [--repeat N] [--spin-ms MS ...]
[--slice-us US ...] [--rt-priority P ...] [--setup SETUP ...] [--stamp arrival|handled] [--stress N]``
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import can
import numpy as np

from drivers.can.bus import BusEvent, BusOpened, CanBusConfig, CanBusLink, CanFrame, open_bus
from rig.data import load_session
from rig.replay.plan import ReplayPlan, build_plan
from rig.replay.player import Replayer, ReplayStats, parse_bus_spec
from rig.replay.scheduling import realtime_priority
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from vsccore.clock import ScaledClock, SystemClock

MS = 1_000_000


def record_source(out: Path) -> Path:
    from rig.core.config import load_session as load_config
    from rig.sim.record import record_simulated
    from rig.workflows.demo import demo_config_path
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
    """The rig's CAN reader keeping each frame's recorded stamp (the bus's, else the host's) and host receive time."""

    def __init__(self, config: CanBusConfig) -> None:
        self.recorded: list[int] = []
        self.host: list[int] = []
        self.opened = threading.Event()
        self.cond = threading.Condition()
        self.session = CanBusLink(config, self.on_frame, self.on_event, clock=SystemClock(), stats_period_s=None)

    def on_frame(self, f: CanFrame) -> None:
        with self.cond:
            self.recorded.append(f.device_ts_ns if f.device_ts_ns is not None else f.host_ts_ns)
            self.host.append(f.host_ts_ns)
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

    def wait_for(self, count: int, timeout_s: float) -> dict[str, np.ndarray]:
        with self.cond:
            self.cond.wait_for(lambda: len(self.recorded) >= count, timeout_s)
            return {"recorded": np.asarray(self.recorded, dtype=np.int64),
                    "host rx": np.asarray(self.host, dtype=np.int64)}


@dataclass
class ServerStages:
    """A socketcand opener whose buses note, for each frame a client sends, its arrival stamp and handling time."""

    channel: str
    stamp: str
    arrival: list[int] = field(default_factory=list)
    handled: list[int] = field(default_factory=list)

    def opener(self) -> Callable[[str], can.BusABC]:
        base = virtual_channel_opener({"vsc0": self.channel}, preserve_timestamps=self.stamp == "arrival")

        def open_channel(name: str) -> can.BusABC:
            bus = base(name)
            send = bus.send

            def noting_send(msg: can.Message, timeout: float | None = None) -> None:
                self.handled.append(time.time_ns())
                self.arrival.append(round(msg.timestamp * 1e9))
                send(msg, timeout)

            bus.send = noting_send  # type: ignore[method-assign]
            return bus

        return open_channel

    def stages(self) -> dict[str, np.ndarray]:
        return {"arrival": np.asarray(self.arrival, dtype=np.int64),
                "handled": np.asarray(self.handled, dtype=np.int64)}


def _socketcand_rx(host: str, port: int) -> CanBusConfig:
    return CanBusConfig(interface="socketcand", channel="vsc0", options={"host": host, "port": port}, name="rx")


def _receiving_side(channel: str, stamp: str, count: int, conn: Connection, rx_rt_priority: int = 0) -> None:
    """Child process of ``scand/out``: a socketcand server and the reader; sends the stages back.
    ``rx_rt_priority``: every thread of it on SCHED_FIFO at that priority (threads inherit the policy) and a
    0.2 ms interpreter switch interval, as a bench's receiving side stamps in hardware, unaffected by load."""
    if rx_rt_priority:
        sys.setswitchinterval(0.0002)
    stages = ServerStages(channel, stamp)
    with realtime_priority(rx_rt_priority or None), SocketcandServer(stages.opener(),
                                                                     rawmode_settle_s=0.0) as server:
        host, port = server.address
        with Receiver(_socketcand_rx(host, port)) as rx:
            conn.send((host, port))
            got = rx.wait_for(count, 60.0)
    conn.send({**stages.stages(), **got})
    conn.close()


def play(plan: ReplayPlan, tx_spec: str, speed: float, spin_s: float,
         slice_s: float | None, rt_priority: int | None) -> tuple[ReplayStats, np.ndarray]:
    """Replay ``plan`` onto ``tx_spec``; the stats and the wall clock just before each ``send``."""
    bus = open_bus(parse_bus_spec(tx_spec))
    sent: list[int] = []
    send = bus.send

    def noting_send(msg: can.Message, timeout: float | None = None) -> None:
        sent.append(time.time_ns())
        send(msg, timeout)

    bus.send = noting_send  # type: ignore[method-assign]
    try:
        stats = Replayer(plan, bus, ScaledClock(time.time_ns()), speed=speed, spin_s=spin_s, slice_s=slice_s,
                         rt_priority=rt_priority).run()
    finally:
        bus.shutdown()
    return stats, np.asarray(sent, dtype=np.int64)


def run_once(plan: ReplayPlan, setup: str, channel: str, speed: float, spin_s: float, slice_s: float | None,
             rt_priority: int | None, stamp: str, rx_rt_priority: int = 0) -> tuple[ReplayStats, dict[str, np.ndarray]]:
    """One replay in ``setup``; the stats and each stage's per-frame times (ns), in send order."""
    n = len(plan)
    if setup == "virtual/in":
        with Receiver(CanBusConfig(interface="virtual", channel=channel, name="rx")) as rx:
            stats, sent = play(plan, f"virtual:{channel}", speed, spin_s, slice_s, rt_priority)
            return stats, {"sent": sent, **rx.wait_for(n, 10.0)}
    if setup == "scand/in":
        stages = ServerStages(channel, stamp)
        with SocketcandServer(stages.opener(), rawmode_settle_s=0.0) as srv:
            host, port = srv.address
            with Receiver(_socketcand_rx(host, port)) as rx:
                stats, sent = play(plan, f"socketcand:vsc0,host={host},port={port}", speed, spin_s, slice_s,
                                   rt_priority)
                got = rx.wait_for(n, 10.0)
        return stats, {"sent": sent, **stages.stages(), **got}
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_receiving_side, args=(channel, stamp, n, child, rx_rt_priority),
                       name="bench-receiving-side")
    proc.start()
    child.close()
    try:
        if not parent.poll(60.0):
            raise SystemExit("receiving side did not start")
        host, port = parent.recv()
        stats, sent = play(plan, f"socketcand:vsc0,host={host},port={port}", speed, spin_s, slice_s, rt_priority)
        if not parent.poll(70.0):
            raise SystemExit("receiving side did not answer")
        return stats, {"sent": sent, **parent.recv()}
    finally:
        proc.join(10.0)
        parent.close()


def _burn() -> None:
    x = 0
    while True:
        x += 1


@dataclass
class Tally:
    runs: int = 0
    clean: int = 0
    over: int = 0
    worst_us: float = 0.0
    loads: list[float] = field(default_factory=list)


def _figures(values_ns: np.ndarray, qs: tuple[float, ...]) -> str:
    return "/".join(f"{v:.0f}" for v in np.percentile(values_ns, qs) / 1e3)


def _variant(spin_ms: float, slice_us: float, prio: int) -> str:
    return (f"spin {spin_ms:g} ms, slice " + (f"{slice_us:g} µs" if slice_us else "default")
            + (f", SCHED_FIFO {prio}" if prio else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--session", type=Path, help="A recorded session to replay (default: record one)")
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--spin-ms", type=float, action="append",
                        help=f"player's spin window, repeatable (default: {Replayer.SPIN_S * 1e3:g} and 0)")
    parser.add_argument("--setup", action="append", choices=("virtual/in", "scand/in", "scand/out"))
    parser.add_argument("--stamp", choices=("arrival", "handled"), default="arrival",
                        help="the socketcand server's stamp of a client's frame (default: arrival, the server's)")
    parser.add_argument("--slice-us", type=float, action="append",
                        help="player thread's requested scheduler slice (Linux >= 6.12), repeatable; 0: the "
                             f"scheduler's default (default: {Replayer.SLICE_S * 1e6:g})")
    parser.add_argument("--rt-priority", type=int, action="append",
                        help="player thread on SCHED_FIFO at this priority, repeatable; 0: ordinary (default: 0)")
    parser.add_argument("--rx-rt-priority", type=int, default=0,
                        help="scand/out: the receiving process's threads on SCHED_FIFO at this priority (0: no)")
    parser.add_argument("--stress", type=int, default=0, help="busy processes running during the runs")
    args = parser.parse_args()
    setups = args.setup or ["virtual/in", "scand/in", "scand/out"]
    spins = args.spin_ms or [Replayer.SPIN_S * 1e3, 0.0]
    slices = args.slice_us or [Replayer.SLICE_S * 1e6]
    priorities = args.rt_priority or [0]
    ctx = multiprocessing.get_context("spawn")
    burners: list[Any] = []
    with tempfile.TemporaryDirectory() as tmp:
        source = args.session or record_source(Path(tmp))
        session = load_session(source, include=lambda t: t.startswith("/can/") and t.endswith("/frames"))
        plan = build_plan(session)
        expected = np.diff(plan.t_ns) / args.speed
        print(f"{len(plan)} frames over {plan.duration_ns / 1e9:.1f} s on {os.cpu_count()} CPUs; replay at "
              f"{args.speed:g}x; server stamp: {args.stamp}; stress: {args.stress} busy processes")
        for _ in range(args.stress):
            proc = ctx.Process(target=_burn, daemon=True, name="bench-replay-stress")
            proc.start()
            burners.append(proc)
        tallies: dict[tuple[str, float, float, int], Tally] = {}
        try:
            k = 0
            for setup in setups:
                for _ in range(args.repeat):  # the variants interleaved, so a change of load hits them all
                    for spin_ms, slice_us, prio in itertools.product(spins, slices, priorities):
                        k += 1
                        load = os.getloadavg()[0]
                        stats, stages = run_once(plan, setup, f"bench-replay-{k}", args.speed, spin_ms / 1e3,
                                                 slice_us / 1e6 if slice_us else None, prio or None, args.stamp,
                                                 args.rx_rt_priority)
                        lat = stats.lateness_us
                        variant = _variant(spin_ms, slice_us, prio)
                        print(f"{setup} {variant}, load {load:.1f}: send lateness µs p50/p99/max "
                              f"{lat['p50']:.0f}/{lat['p99']:.0f}/{lat['max']:.0f}, {stats.late_frames} > 1 ms")
                        print(f"    {'stage':<9} {'spacing error µs p50/p99/p99.9/max':>36} {'>1 ms':>6} "
                              f"{'after send µs p50/p99/max':>27}")
                        for name, times in stages.items():
                            if times.size != len(plan):
                                raise SystemExit(f"{setup}: {name}: {times.size} of {len(plan)} frames")
                            err = np.abs(np.diff(times) - expected)
                            over = int(np.count_nonzero(err > MS))
                            after = "" if name == "sent" else _figures(times - stages["sent"], (50, 99, 100))
                            print(f"    {name:<9} {_figures(err, (50, 99, 99.9, 100)):>36} {over:>6} {after:>27}")
                            if name == "recorded":
                                tally = tallies.setdefault((setup, spin_ms, slice_us, prio), Tally())
                                tally.runs += 1
                                tally.clean += over == 0
                                tally.over += over
                                tally.worst_us = max(tally.worst_us, float(err.max()) / 1e3)
                                tally.loads.append(load)
        finally:
            for proc in burners:
                proc.terminate()
            for proc in burners:
                proc.join(5.0)
    print("recorded spacing (the acceptance figure), per set-up:")
    for (setup, spin_ms, slice_us, prio), t in tallies.items():
        variant = _variant(spin_ms, slice_us, prio)
        print(f"    {setup} {variant}: {t.clean} of {t.runs} runs with every frame within 1 ms; "
              f"{t.over} frames over 1 ms in all; worst {t.worst_us:.0f} µs; "
              f"load {min(t.loads):.1f}-{max(t.loads):.1f}")


if __name__ == "__main__":
    main()
