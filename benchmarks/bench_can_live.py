"""CPU cost of the live CAN path per frame: bit times for the bus load, role decoding, the reader's delivery.

Each figure is timed for the readable reference and for the fast form now used, on the same
frames, best of ``--repeat`` runs:

- ``frame_bit_times`` (exact classic-CAN bit count: CRC-15 and stuff bits; used for the bus load):
  ``_frame_bit_times_reference`` (bit lists) vs the integer/table form, on 8-byte base frames and
  on the simulated car's traffic (its DBC messages with their counters and checksums);
- ``RoleDecoder.decode``: ``compiled=False`` (cantools decode, then the role specs) vs the compiled
  per-message decoders, on the simulated car's traffic with its role map, and on the VW MQB DBC
  with the shipped role map when ../shared is present;
- ``CanBusLink._deliver`` (a ``can.Message`` to a :class:`CanFrame`, bit times, bus-load meter):
  with the reference bit times vs the fast ones.

The bottom line is the share of one core the driver spends on a 1 Mbit/s bus at full load
(8000 frames/s, 8-byte frames): delivery plus role decoding.

Run: ``/work/venv/bin/python benchmarks/bench_can_live.py [--frames N] [--repeat R]``
"""

from __future__ import annotations

import argparse
import random
import time
from collections.abc import Callable
from pathlib import Path

import can
from cantools.database.can import Database

import drivers.can.bus as bus_mod
from drivers.can.bus import CanBusConfig, CanBusLink, _frame_bit_times_reference, frame_bit_times
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap, encode_role_frame
from vsccore.clock import SystemClock

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
FULL_LOAD_FPS = 8000


def _best_us(fn: Callable[[], object], n: int, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def _traffic(dbc: Path, roles: Path, n: int, seed: int) -> tuple[RoleMap, list[tuple[int, bytes]]]:
    """Frames of every role message in turn, counters running, physical values varying, checksums right."""
    db = load_dbc(dbc)
    rolemap = RoleMap.from_toml(roles, db)
    rng = random.Random(seed)
    frames: list[tuple[int, bytes]] = []
    names = list(rolemap.messages)
    k = 0
    while len(frames) < n:
        name = names[k % len(names)]
        msg = db.get_message_by_name(name)
        values = {}
        for spec in rolemap.roles_for_message(name):
            s = msg.get_signal_by_name(spec.signal)
            lo, hi = (s.minimum or 0.0) * 0.5, (s.maximum or 1.0) * 0.5
            values[spec.signal] = rng.uniform(min(lo, hi), max(lo, hi))
        frames.append((msg.frame_id, encode_role_frame(db, rolemap, name, {}, counter=k // len(names), signals=values)))
        k += 1
    return rolemap, frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    n, rep = args.frames, args.repeat
    rng = random.Random(1)

    print(f"live CAN path, µs per frame (best of {rep}; {n:,} frames)")
    print(f"{'':50} {'reference':>10} {'fast':>8} {'speed-up':>9}")

    def row(label: str, ref: float, fast: float) -> None:
        print(f"{label:50} {ref:10.2f} {fast:8.2f} {ref / fast:8.1f}x")

    base8 = [(rng.getrandbits(11), rng.randbytes(8)) for _ in range(n)]
    sim_rm, sim_frames = _traffic(REPO / "sim_devices" / "data" / "vsc_sim.dbc",
                                  REPO / "rig" / "examples" / "roles" / "vsc_sim.toml", n, seed=2)
    for label, frames in (("frame_bit_times, random 8-byte base frames", base8),
                          ("frame_bit_times, simulated car traffic", sim_frames)):
        def bits(fn: Callable[..., tuple[int, int]], fr: list[tuple[int, bytes]] = frames) -> None:
            for i, d in fr:
                fn(i, False, d)

        ref = _best_us(lambda: bits(_frame_bit_times_reference), len(frames), rep)
        fast = _best_us(lambda: bits(frame_bit_times), len(frames), rep)
        assert all(frame_bit_times(i, False, d) == _frame_bit_times_reference(i, False, d) for i, d in frames[:2000])
        row(label, ref, fast)

    decode_fast = decode_ref = 0.0
    cases = [("RoleDecoder.decode, simulated car (vsc_sim)", sim_rm.roles, sim_frames,
              load_dbc(REPO / "sim_devices" / "data" / "vsc_sim.dbc"), sim_rm)]
    if (SHARED / "dbc" / "vw_mqb.dbc").is_file():
        vw_rm, vw_frames = _traffic(SHARED / "dbc" / "vw_mqb.dbc", REPO / "examples" / "roles" / "vw_mqb.toml", n, 3)
        cases.append(("RoleDecoder.decode, VW MQB (ESP_02, LWI_01, ...)", vw_rm.roles, vw_frames,
                      load_dbc(SHARED / "dbc" / "vw_mqb.dbc"), vw_rm))
    for label, _roles, frames, db, rm in cases:
        times = []
        for compiled in (False, True):
            def run(fr: list[tuple[int, bytes]] = frames, c: bool = compiled, db: Database = db, rm: RoleMap = rm
                    ) -> None:
                dec = RoleDecoder(db, rm, compiled=c)  # fresh counters each run
                for t, (i, d) in enumerate(fr):
                    dec.decode(i, d, t)
            times.append(_best_us(run, len(frames), rep))
        check = RoleDecoder(db, rm)
        for t, (i, d) in enumerate(frames):
            check.decode(i, d, t)
        assert check.stats().decoded == len(frames), check.stats()  # every frame good and decoded
        row(label, times[0], times[1])
        if "simulated" in label:
            decode_fast, decode_ref = times[1], times[0]

    session = CanBusLink(CanBusConfig("virtual", "bench", bitrate=1_000_000, name="bench"), lambda f: None,
                            clock=SystemClock(), stats_window_s=1.0)
    msgs = [can.Message(arbitration_id=i, data=d, timestamp=1.7e9 + k * 125e-6, is_extended_id=False)
            for k, (i, d) in enumerate(sim_frames)]
    deliver = session._deliver
    times = []
    for impl in (_frame_bit_times_reference, frame_bit_times):
        bus_mod.frame_bit_times = impl  # the reader looks the function up in its module
        try:
            times.append(_best_us(lambda: [deliver(m, 1_700_000_000_000_000_000 + k) for k, m in enumerate(msgs)],
                                  len(msgs), rep))
        finally:
            bus_mod.frame_bit_times = frame_bit_times
    row("CanBusLink._deliver (with bit times)", times[0], times[1])

    before = (times[0] + decode_ref) * FULL_LOAD_FPS / 1e4
    after = (times[1] + decode_fast) * FULL_LOAD_FPS / 1e4
    print(f"\n1 Mbit/s bus at full load ({FULL_LOAD_FPS} frames/s), delivery + role decoding: "
          f"{before:.1f} % of a core before, {after:.1f} % now")


if __name__ == "__main__":
    main()
