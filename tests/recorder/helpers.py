"""Test doubles for the recorder: a manual clock, a gated stream, a byte-limited opener."""

from __future__ import annotations

import errno
import io
import threading
from pathlib import Path
from typing import IO, Any

from mcap.reader import make_reader

from rig.store import RecorderOptions

T0 = 1_700_000_000_000_000_000
"""A host time (ns since the Unix epoch) to start fake clocks at."""


class ManualClock:
    """A clock that moves only when the test says so."""

    def __init__(self, start_ns: int = T0) -> None:
        self._t = start_ns
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        with self._lock:
            return self._t

    def advance(self, dt_ns: int) -> None:
        with self._lock:
            self._t += dt_ns

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        raise AssertionError("the recorder must not sleep on its clock")


def options(**kw: object) -> RecorderOptions:
    """Test options: no disk thresholds, no reserve file, small chunks unless given."""
    base: dict[str, object] = {"min_free_bytes": 0, "warn_free_bytes": 0, "reserve_bytes": 0, "chunk_size": 64 * 1024}
    base.update(kw)
    return RecorderOptions(**base)  # type: ignore[arg-type]


class GatedFile(io.BufferedWriter):
    """A real file whose ``flush`` blocks while ``gate`` is clear (to hold the writer thread)."""

    def __init__(self, path: Path, mode: str, gate: threading.Event, entered: threading.Event) -> None:
        super().__init__(io.FileIO(path, mode.replace("b", "")))
        self.gate = gate
        self.entered = entered

    def flush(self) -> None:
        if not self.gate.is_set():
            self.entered.set()
            assert self.gate.wait(20), "gate never opened"
        super().flush()


class LimitedFile(io.BufferedWriter):
    """A real file that raises ENOSPC once ``limit`` bytes would be exceeded (a full disk)."""

    def __init__(self, path: Path, mode: str, limit: int) -> None:
        super().__init__(io.FileIO(path, mode.replace("b", "")))
        self.limit = limit

    def write(self, b: Any) -> int:
        data = bytes(b)
        room = self.limit - self.tell()
        if len(data) > room:
            if room > 0:
                super().write(data[:room])
            raise OSError(errno.ENOSPC, "No space left on device (simulated)")
        return super().write(data)


def limited_opener(limit: int):
    """An opener whose new files hold at most ``limit`` bytes; reopening ("r+b") is unlimited."""

    def opener(path: Path, mode: str) -> IO[bytes]:
        if mode in ("xb", "wb") and path.suffix == ".mcap":
            return LimitedFile(path, mode, limit)
        return open(path, mode)

    return opener


def read_with_mcap(path: Path) -> tuple[list[tuple[str, int, int, int, bytes]], Any]:
    """Every message of a finalized part through mcap's own (seeking, indexed) reader, and its summary."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = [
            (ch.topic, m.sequence, m.log_time, m.publish_time, bytes(m.data))
            for _schema, ch, m in reader.iter_messages(log_time_order=False)
        ]
    return msgs, summary
