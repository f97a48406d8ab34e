"""Fuzz: 240 mutated copies of a real recorded part (fixed seed). For each: no crash, no message of an
intact chunk lost (by topic and sequence), nothing invented, the damage reported; every 6th one is
also recovered and read back with mcap's own reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig.store import recover, scan_part
from rig.store.reader import DamageKind
from tests.recorder.helpers import read_with_mcap
from tests.recorder.test_damage import Recorded, got_messages, recorded  # noqa: F401 - the fixture

FILES = 240
SEED = 20240614


def _mutate(r: Recorded, rng: np.random.Generator) -> tuple[bytearray, set[int], int | None, str]:
    """A mutated copy, the offsets touched, where it was cut (None: not cut), and what was done."""
    raw = bytearray(r.data)
    touched: set[int] = set()
    cut: int | None = None
    kind = int(rng.integers(0, 6))
    chunks = r.scan.chunks

    def flip(at: int) -> None:
        raw[at] ^= 1 << int(rng.integers(0, 8))
        touched.add(at)

    if kind == 0:  # one bit in a chunk's data
        c = chunks[int(rng.integers(0, len(chunks)))]
        flip(int(rng.integers(c.offset + 60, c.offset + c.length)))
    elif kind == 1:  # one bit in a chunk's header
        c = chunks[int(rng.integers(0, len(chunks)))]
        flip(c.offset + int(rng.integers(0, 60)))
    elif kind == 2:  # one bit in the summary, footer or closing magic
        flip(int(rng.integers(r.summary_start, len(raw))))
    elif kind == 3:  # a truncation
        cut = int(rng.integers(9, len(raw) - 1))
    elif kind == 4:  # a run of random bytes over chunk data (a bad sector)
        c = chunks[int(rng.integers(0, len(chunks)))]
        at = int(rng.integers(c.offset, c.offset + c.length))
        n = int(rng.integers(1, 65))
        for q in range(at, min(at + n, len(raw))):
            old = raw[q]
            raw[q] = int(rng.integers(0, 256))
            if raw[q] != old:
                touched.add(q)
    else:  # several flips in chunks, then maybe a cut
        for _ in range(int(rng.integers(2, 5))):
            c = chunks[int(rng.integers(0, len(chunks)))]
            flip(int(rng.integers(c.offset, c.offset + c.length)))
        if rng.random() < 0.5:
            cut = int(rng.integers(len(raw) // 2, len(raw) - 1))
    if cut is not None:
        del raw[cut:]
        touched = {t for t in touched if t < cut}
    return raw, touched, cut, f"kind {kind}, touched {sorted(touched)[:6]}, cut {cut}"


def test_fuzz_mutated_sessions(recorded: Recorded, tmp_path: Path) -> None:  # noqa: F811 - the fixture
    r = recorded
    rng = np.random.default_rng(SEED)
    cid_of = {ch.topic: cid for cid, ch in r.scan.channels.items()}
    path = tmp_path / "f.000.mcap"
    out = tmp_path / "f.rec.mcap"
    damaged_reported = 0
    for k in range(FILES):
        raw, touched, cut, what = _mutate(r, rng)
        if not touched and cut is None:
            continue
        path.write_bytes(bytes(raw))
        scan = scan_part(path)  # no crash: damage is reported in the result
        expected = r.intact(touched, cut)
        got = got_messages(scan)
        assert got <= r.all_msgs, (k, what)
        missing = expected - got
        if missing:  # only messages whose Channel record was lost with a damaged chunk (and no usable summary)
            orphaned = {t for d in scan.damage if d.kind is DamageKind.CHANNEL for t in d.topics}
            assert {f"channel {cid_of[t]}" for t, _s in missing} <= orphaned, (k, what, scan.problem)
            assert sum(d.messages or 0 for d in scan.damage if d.kind is DamageKind.CHANNEL) >= len(missing)
        assert scan.problem is not None, (k, what)
        damaged_reported += 1
        if k % 6 == 0:
            rep = recover(path, out, overwrite=True)
            msgs, summary = read_with_mcap(out)
            n = scan.message_count + sum(scan.orphans.values())
            assert summary is not None and len(msgs) == rep.messages == n, (k, what)
            back = {(topic, seq) for topic, seq, _l, _p, _d in msgs}
            # messages on channels whose definition was lost come back under a placeholder topic
            assert {m for m in back if not m[0].startswith("/unknown/")} == got, (k, what)
            assert len(back) - len(got) == sum(scan.orphans.values()), (k, what)
    assert damaged_reported >= 200
