"""Vectorised CAN decoding vs cantools ``decode_message`` per frame.

1 million frames of one realistic message (eight signals: Intel and Motorola, signed and
unsigned, a 1-bit flag, a 4-bit counter, non-trivial scale/offset). cantools is timed on a
subset (default 100 000 frames) and scaled linearly to 1 million, which the output states.
A second figure times the role path (units, sign bit, quality bit, MQB CRC and counter checks)
on the VW MQB ESP_02 message when the shared DBC is present.

Run: ``/work/venv/bin/python benchmarks/bench_can_decode.py [--frames N] [--cantools-frames M]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion

from drivers.can.checks import VwMqbCrc8
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleMap
from drivers.can.vector_decode import FrameBatch, VectorDecoder, VectorRoleDecoder


def _message() -> Message:
    def conv(scale: float, offset: float) -> BaseConversion:
        return BaseConversion.factory(scale=scale, offset=offset)

    signals = [
        Signal("YawRate", 7, 16, byte_order="big_endian", is_signed=True, conversion=conv(0.005, 0.0)),
        Signal("LatAcc", 23, 12, byte_order="big_endian", is_signed=True, conversion=conv(0.01, 0.0)),
        Signal("LongAcc", 32, 10, is_signed=True, conversion=conv(0.03125, -2.0)),
        Signal("Swa", 42, 12, is_signed=False, conversion=conv(0.1, -200.0)),
        Signal("SwaSign", 54, 1),
        Signal("Valid", 55, 1),
        Signal("Status", 56, 2),
        Signal("Counter", 60, 4),
    ]
    return Message(0x130, "VSC_SENSOR", 8, signals, strict=True)


def _time(fn, repeat: int = 3) -> float:  # type: ignore[no-untyped-def]
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--cantools-frames", type=int, default=100_000)
    args = parser.parse_args()
    n, m = args.frames, min(args.cantools_frames, args.frames)

    msg = _message()
    db = Database(messages=[msg])
    rng = np.random.default_rng(1)
    data = rng.integers(0, 256, size=(n, 8), dtype=np.uint8)
    batch = FrameBatch(np.arange(n, dtype=np.int64) * 10_000_000, np.full(n, 0x130), data, np.full(n, 8))
    decoder = VectorDecoder(db)

    t_vec = _time(lambda: decoder.decode(batch))
    payloads = [bytes(row) for row in data[:m]]
    decode = db.decode_message
    t_ct = _time(lambda: [decode(0x130, p, decode_choices=False) for p in payloads], repeat=1)
    t_ct_full = t_ct * n / m
    print(f"message {msg.name}: {len(msg.signals)} signals (Intel + Motorola, signed + unsigned), {n:,} frames")
    print(f"  vectorised VectorDecoder.decode : {t_vec:8.3f} s  ({n / t_vec / 1e6:6.2f} M frames/s)")
    print(f"  cantools decode_message         : {t_ct:8.3f} s for {m:,} frames -> {t_ct_full:8.3f} s scaled to {n:,}")
    print(f"  speed-up                        : {t_ct_full / t_vec:8.1f} x  (goal >= 20 x)")

    # Spot check: the two agree on the subset.
    result = decoder.decode(batch).messages[msg.name]
    for i in range(0, m, max(1, m // 1000)):
        ref = decode(0x130, payloads[i], decode_choices=False)
        for name, value in ref.items():
            assert result.values[name][i] == value, (i, name)

    # A whole bus: the simulated car's six messages interleaved (one multiplexed), all signals.
    from sim_devices.vsc_ecu import vsc_sim_dbc_path

    sim = load_dbc(vsc_sim_dbc_path())
    ids = np.array([msg_.frame_id for msg_ in sim.messages], dtype=np.uint32)
    mixed_ids = ids[rng.integers(0, ids.size, n)]
    mixed = rng.integers(0, 256, size=(n, 8), dtype=np.uint8)
    diag = sim.get_message_by_name("VSC_Diag").frame_id
    mixed[mixed_ids == diag, 0] &= 1  # valid multiplexer pages only
    mixed_batch = FrameBatch(np.arange(n, dtype=np.int64) * 1_000_000, mixed_ids, mixed, np.full(n, 8))
    sim_decoder = VectorDecoder(sim)
    t_mixed = _time(lambda: sim_decoder.decode(mixed_batch))
    frames_mixed = [(int(i), bytes(row)) for i, row in zip(mixed_ids[:m], mixed[:m], strict=True)]
    sim_decode = sim.decode_message
    t_ct_mixed = _time(lambda: [sim_decode(i, p, decode_choices=False) for i, p in frames_mixed], repeat=1) * n / m
    print(f"simulated car bus: {len(sim.messages)} messages interleaved (one multiplexed), {n:,} frames")
    print(f"  vectorised VectorDecoder.decode : {t_mixed:8.3f} s  ({n / t_mixed / 1e6:6.2f} M frames/s)")
    print(f"  cantools decode_message         : {t_ct_mixed:8.3f} s (scaled from {m:,} frames)")
    print(f"  speed-up                        : {t_ct_mixed / t_mixed:8.1f} x  (goal >= 20 x)")

    dbc = Path(__file__).resolve().parents[1].parent / "shared" / "dbc" / "vw_mqb.dbc"
    roles = Path(__file__).resolve().parents[1] / "examples" / "roles" / "vw_mqb.toml"
    if dbc.is_file():
        vw = load_dbc(dbc)
        rm = RoleMap.from_toml(roles, vw)
        esp = rng.integers(0, 256, size=(n, 8), dtype=np.uint8)
        esp[:, 1] = (esp[:, 1] & 0xF0) | (np.arange(n) % 16).astype(np.uint8)
        esp[:, 0] = VwMqbCrc8().compute_many(0x101, esp).astype(np.uint8)
        vw_batch = FrameBatch(np.arange(n, dtype=np.int64) * 20_000_000, np.full(n, 0x101), esp, np.full(n, 8))
        role_dec = VectorRoleDecoder(vw, rm)
        t_roles = _time(lambda: role_dec.decode(vw_batch))
        ok = int((role_dec.decode(vw_batch).roles["yaw_rate"].flags & 0x1E == 0).sum())
        print(f"VW MQB ESP_02 roles (CRC-8H2F + counter + units + sign/quality bits), {n:,} frames:")
        rate = n / t_roles / 1e6
        print(f"  VectorRoleDecoder.decode        : {t_roles:8.3f} s  ({rate:6.2f} M frames/s), {ok:,} pass checks")
    else:
        print(f"(VW MQB role benchmark skipped: {dbc} not found)")


if __name__ == "__main__":
    main()
