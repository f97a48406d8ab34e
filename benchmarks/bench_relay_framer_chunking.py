"""Benchmark: the relay's correction framer costs the same per byte whatever the chunking.

Run by hand:  python benchmarks/bench_relay_framer_chunking.py [--mbytes 1] [--repeat 3]

A serial port at 460 800 Bd often delivers 1-64 bytes per read. The stream (about 1 MB) is a base
station's output: RTCM3 MSM7 and 1005/1033 frames with random observation bytes (so their payload
holds the false sync candidates real data has), some NovAtel RTCA blocks and RTCAA logs, and a few
CMR frames. It is fed (a) in one call, (b) in random 1-64 byte reads, (c) one byte at a time; the
CPU time of each (best of --repeat) is printed with its ratio to (a). Target: (c) within 3x of (a).
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from drivers.relay.frames import (  # noqa: E402
    CorrectionFramer,
    encode_cmr,
    encode_rtca,
    encode_rtca_ascii,
    encode_rtcm3,
)


def stream(nbytes: int, seed: int = 1) -> tuple[bytes, int]:
    """About ``nbytes`` of a base station's correction output; (bytes, number of frames)."""
    rng = random.Random(seed)
    parts: list[bytes] = []
    total = 0
    while total < nbytes:
        epoch = [
            encode_rtcm3(bytes([0x43, 0x50]) + rng.randbytes(rng.randrange(300, 700))),  # 1077
            encode_rtcm3(bytes([0x43, 0xF0]) + rng.randbytes(rng.randrange(200, 500))),  # 1087
            encode_rtcm3(bytes([0x3E, 0xD0]) + rng.randbytes(17)),  # 1005
        ]
        if rng.random() < 0.2:
            epoch.append(encode_rtca(7, rng.randbytes(rng.randrange(20, 200))))
        if rng.random() < 0.1:
            epoch.append(encode_rtca_ascii(encode_rtca(1, rng.randbytes(rng.randrange(20, 120)))))
        if rng.random() < 0.1:
            epoch.append(encode_cmr(0x93, bytes([0x20, 0x08]) + rng.randbytes(rng.randrange(20, 200))))
        parts += epoch
        total += sum(map(len, epoch))
    return b"".join(parts), len(parts)


def cost(pieces: list[bytes], frames: int) -> float:
    framer = CorrectionFramer()
    feed = framer.feed
    t0 = time.process_time()
    n = 0
    for piece in pieces:
        n += len(feed(piece))
    n += len(framer.finish())
    seconds = time.process_time() - t0
    if n != frames:
        raise SystemExit(f"framer returned {n} frames, expected {frames}")
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mbytes", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    data, frames = stream(int(args.mbytes * 1_000_000))
    rng = random.Random(2)
    cuts = [0]
    while cuts[-1] < len(data):
        cuts.append(min(len(data), cuts[-1] + rng.randint(1, 64)))
    chunkings = {
        "one call": [data],
        "1-64 byte reads": [data[a:b] for a, b in zip(cuts, cuts[1:], strict=False)],
        "1 byte at a time": [data[i : i + 1] for i in range(len(data))],
    }
    print(f"stream: {len(data)} bytes, {frames} frames")
    base = None
    for name, pieces in chunkings.items():
        best = min(cost(pieces, frames) for _ in range(args.repeat))
        base = base or best
        print(f"{name:>18}: {best:7.3f} s CPU  {len(data) / best / 1e6:6.2f} MB/s  {best / base:5.2f}x one call")
    print("target: 1 byte at a time within 3x of one call")


if __name__ == "__main__":
    main()
