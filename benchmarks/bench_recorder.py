"""Recorder and dataset throughput: prints figures (run by hand: ``python benchmarks/bench_recorder.py``).

1. Saturation: small raw messages pushed from three producer threads through the recorder's queues
   into MCAP, against mcap's own Writer writing the same messages in the same run.
2. Realistic mix (2 receivers × 20 Hz BESTPOS/BESTVEL/raw, CAN 10 IDs × 1 kHz = 10 000 frames/s in
   10 ms blocks, DAQ 8 channels × 1 kHz in 100 ms blocks): ``--seconds`` of session data generated
   ahead, then pushed as fast as the writer takes it; the ratio to real time is the headroom.
3. Reading that session back with rig.data (GNSS tables, CAN frames with their time mapping,
   DAQ channels).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapWriter

import rig.core.topics as T  # noqa: N812 - short alias
from rig.data import load_session
from rig.store import Recorder, RecorderOptions, Source

LEAP = 18
G0 = 1_450_000_000_000_000_000
H0 = 1_750_000_000_000_000_000


def _opts(**kw: object) -> RecorderOptions:
    base: dict[str, object] = {
        "min_free_bytes": 0, "warn_free_bytes": 0, "reserve_bytes": 0, "rollover_size_bytes": None,
    }
    base.update(kw)
    return RecorderOptions(**base)  # type: ignore[arg-type]


def saturation(tmp: Path, n_per_source: int = 100_000, size: int = 64) -> None:
    payloads = [os.urandom(size) for _ in range(1024)]
    names = ("a", "b", "c")
    n_total = n_per_source * len(names)
    # raw mcap writer, same messages, one thread
    t0 = time.perf_counter()
    with open(tmp / "raw.mcap", "wb") as f:
        w = McapWriter(f, chunk_size=4 * 1024 * 1024, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
        w.start()
        sid = w.register_schema(T.SCHEMA_RAW_BYTES.name, T.LAYOUT_SCHEMA_ENCODING, T.SCHEMA_RAW_BYTES.data)
        cids = [w.register_channel(T.gnss_raw(n), T.BINARY_ENCODING, sid) for n in names]
        for i in range(n_per_source):
            p = payloads[i & 1023]
            for c in cids:
                w.add_message(c, H0 + i, p, H0 + i, i)
        w.finish()
    raw_s = time.perf_counter() - t0
    raw_mb = (tmp / "raw.mcap").stat().st_size / 1e6

    rec = Recorder(tmp, "sat", options=_opts())
    rec.start()
    srcs = [rec.source(n, maxsize=n_per_source) for n in names]

    def produce(k: int) -> None:
        src = srcs[k]
        topic = T.gnss_raw(names[k])
        for i in range(n_per_source):
            src.put(topic, H0 + i, H0 + i, payloads[i & 1023])

    t0 = time.perf_counter()
    threads = [threading.Thread(target=produce, args=(k,)) for k in range(len(names))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    summary = rec.stop()
    rec_s = time.perf_counter() - t0
    assert summary.error is None
    written = sum(s.written for s in summary.sources if s.name in names)
    dropped = summary.dropped
    payload_mb = n_total * size / 1e6
    print("== saturation (3 producer threads, 64-byte raw messages, zstd) ==")
    print(f"raw mcap Writer : {n_total / raw_s:10.0f} msg/s  {payload_mb / raw_s:6.1f} MB/s payload  "
          f"(file {raw_mb:.1f} MB)")
    print(f"rig Recorder    : {written / rec_s:10.0f} msg/s  {payload_mb / rec_s:6.1f} MB/s payload  "
          f"= {raw_s / rec_s * 100:.0f} % of the raw writer; dropped {dropped}")


def realistic(tmp: Path, seconds: int) -> tuple[Path, float, int]:
    rng = np.random.default_rng(0)
    rec = Recorder(tmp, "mix", options=_opts(rollover_size_bytes=200_000_000))
    gnss_src = {r: rec.source(r, maxsize=1_000_000) for r in ("rover_a", "rover_b")}
    can_src = rec.source("can0", maxsize=1_000_000)
    daq_src = rec.source("daq1", maxsize=1_000_000)
    # pre-generate one second of each stream, then repeat with shifted times
    can_payload = rng.integers(0, 256, (10_000, 8), dtype=np.uint8)
    can_ids = np.tile(np.arange(0x100, 0x10A), 1000)
    daq_volts = rng.normal(size=(8, 1000)).astype(np.float32)
    names = tuple(f"ai{i}" for i in range(8))
    raw_gnss = os.urandom(180)
    msgs: list[tuple[Source, str, int, int, bytes]] = []
    for s in range(seconds):
        for k in range(20):
            g = G0 + s * 1_000_000_000 + k * 50_000_000
            h = H0 + (g - G0) + 25_000_000
            u = g + 315_964_800_000_000_000 - LEAP * 1_000_000_000
            for r, src in gnss_src.items():
                pos = {"gps_time_ns": g, "sol_status": "SOL_COMPUTED", "pos_type": "NARROW_INT", "lat_deg": 48.7,
                       "lon_deg": 9.18, "height_msl_m": 300.0, "lat_std_m": 0.01, "lon_std_m": 0.01,
                       "height_std_m": 0.02}
                vel = {"gps_time_ns": g, "sol_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY", "latency_s": 0.0,
                       "hor_speed_mps": 20.0, "track_over_ground_deg": 90.0, "vert_speed_mps": 0.0}
                msgs.append((src, T.gnss_raw(r), u, h, raw_gnss))
                msgs.append((src, T.gnss_bestpos(r), u, h, T.encode_json(pos)))
                msgs.append((src, T.gnss_bestvel(r), u, h, T.encode_json(vel)))
                if k == 0:
                    tm = {"gps_time_ns": g, "clock_status": "VALID", "utc_offset_s": -18.0, "leap_seconds": LEAP,
                          "utc_status": "VALID"}
                    msgs.append((src, T.gnss_time(r), u, h, T.encode_json(tm)))
        for b in range(100):  # CAN: 10 ms blocks of 100 frames
            t_host = H0 + s * 1_000_000_000 + b * 10_000_000 + np.arange(100) * 100_000
            sl = slice(b * 100, b * 100 + 100)
            block = T.pack_can_columns(t_host - H0, t_host, can_ids[sl], np.full(100, 0x10), np.full(100, 8),
                                       np.full(100, 8), can_payload[sl])
            msgs.append((can_src, T.can_frames("can0"), int(t_host[0]), int(t_host[-1]), block))
        for b in range(10):  # DAQ: 100 ms blocks
            chunk = np.ascontiguousarray(daq_volts[:, b * 100 : b * 100 + 100])
            blk = T.DaqBlock(s * 1000 + b * 100, 1000.0, names, chunk)
            t = H0 + s * 1_000_000_000 + b * 100_000_000
            msgs.append((daq_src, T.daq_samples("daq1"), t, t, T.pack_daq_block(blk)))
    payload = sum(len(m[4]) for m in msgs)
    rec.start()
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    for src, topic, lt, pt, data in msgs:
        src.put(topic, lt, pt, data)
    summary = rec.stop()
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    assert summary.error is None and summary.dropped == 0
    size = sum(p.stat().st_size for p in summary.parts)
    print(f"== realistic mix, {seconds} s of data: {len(msgs)} messages, {payload / 1e6:.1f} MB payload "
          f"({len(msgs) / seconds:.0f} msg/s, {payload / seconds / 1e3:.0f} kB/s in real time) ==")
    print(f"recorded in {wall:.2f} s wall, {cpu:.2f} s CPU: {len(msgs) / wall:.0f} msg/s, "
          f"{payload / wall / 1e6:.1f} MB/s; "
          f"{seconds / wall:.0f}x real time; CPU at real-time load ≈ {cpu / seconds * 100:.1f} % of one core; "
          f"file {size / 1e6:.1f} MB (zstd {payload / size:.1f}:1); dropped {summary.dropped}")
    return tmp / "mix", payload, len(msgs)


def read_back(base: Path, seconds: int) -> None:
    t0 = time.perf_counter()
    s = load_session(base)
    t1 = time.perf_counter()
    n_pos = sum(len(s.gnss(r).bestpos) + len(s.gnss(r).bestvel) for r in s.receivers())
    t2 = time.perf_counter()
    frames = s.can_frames("can0")
    t3 = time.perf_counter()
    d = s.daq("daq1")
    t4 = time.perf_counter()
    print(f"== dataset read of the {seconds} s session ==")
    print(f"scan all parts {t1 - t0:.2f} s; GNSS tables ({n_pos} rows) {t2 - t1:.2f} s; CAN {len(frames)} frames "
          f"with interface→host→GPS mapping {t3 - t2:.2f} s; DAQ {d.volts.shape} {t4 - t3:.2f} s; "
          f"total {t4 - t0:.2f} s = {seconds / (t4 - t0):.0f}x real time "
          f"(1 h session ≈ {3600 / seconds * (t4 - t0):.0f} s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=int, default=60, help="seconds of realistic session data")
    ap.add_argument("--saturation-messages", type=int, default=100_000, help="messages per producer")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        saturation(tmp, args.saturation_messages)
        base, _payload, _n = realistic(tmp, args.seconds)
        read_back(base, args.seconds)


if __name__ == "__main__":
    main()
