"""One recorded synthetic session (several parts) and a copy whose last part was cut short, per module."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from rig.store import find_parts, scan_part
from tests.inspect.synth import Synth, write_session


@pytest.fixture(scope="package")
def synth(tmp_path_factory: pytest.TempPathFactory) -> Synth:
    return write_session(tmp_path_factory.mktemp("session"))


def _raw_bytes(path: Path) -> int:
    scan = scan_part(path, want=lambda t: t.endswith("/raw"))
    return sum(len(d) for tm in scan.topics.values() for d in tm.data)


@pytest.fixture(scope="package")
def truncated(synth: Synth, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The session as a recorder killed inside its last chunk with raw data would have left it.

    The parts before the one holding that chunk are copied whole, the part itself is cut in the
    middle of the chunk, later parts do not exist. The cut is found from the chunk positions, so
    raw stream bytes are lost whatever way the writer thread grouped messages into chunks and
    parts. Returns (base of the copy, the original of its cut part).
    """
    out = tmp_path_factory.mktemp("crashed")
    parts = find_parts(synth.base)
    k = max(i for i, p in enumerate(parts) if _raw_bytes(p) > 0)
    for p in parts[:k]:
        shutil.copy(p, out / p.name)
    cut = out / parts[k].name
    data = parts[k].read_bytes()
    full = _raw_bytes(parts[k])
    for chunk in reversed(scan_part(parts[k], collect=False).chunks):
        cut.write_bytes(data[: chunk.offset + chunk.length // 2])
        if _raw_bytes(cut) < full:
            return out / synth.base.name, parts[k]
    raise AssertionError(f"no chunk of {parts[k]} holds raw data")
