"""A recorder process for the kill -9 test: records forever, reporting each synced count on stdout.

Run as ``python -m tests.recorder.crash_child OUT_DIR``. Each line ``synced N`` means the first N
messages of source "g" (payload = little-endian counter) are on disk (chunk closed, fsync-ed).
"""

from __future__ import annotations

import sys
from pathlib import Path

import rig.core.topics as T  # noqa: N812 - short alias used throughout the tests
from rig.store import Recorder, RecorderOptions


def main() -> None:
    out = Path(sys.argv[1])
    rec = Recorder(out, "crash", options=RecorderOptions(min_free_bytes=0, reserve_bytes=0, chunk_size=16 * 1024,
                                                        flush_interval_s=0.05))
    rec.start()
    src = rec.source("g", maxsize=1_000_000)
    i = 0
    while True:
        for _ in range(500):
            src.put(T.gnss_raw("g"), 1_700_000_000_000_000_000 + i, 1_700_000_000_000_000_000 + i,
                    i.to_bytes(8, "little") * 8)
            i += 1
        if rec.sync(30):
            sys.stdout.write(f"synced {i}\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
