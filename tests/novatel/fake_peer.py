"""A scripted NovAtel receiver on a pseudo-terminal, for the receiver-session tests.

The peer owns the pty master; the session under test opens the slave through a symlink (as a
udev ``/dev/serial/by-id/…`` link), so "unplug" (master closed, link removed) and "replug" (new
pty, link re-pointed) look to the session like a USB adapter going away and coming back.

It answers each command line with ``<OK`` + prompt, or ``<ERROR:…`` for scripted commands, or
nothing for "silent" ones; ``LOG <port> BESTPOSB|BESTVELB|TIMEB|…A ONTIME <period>`` makes it
stream encoded logs at that period until ``UNLOGALL``. With ``baud`` set it answers only while the
host side's termios speed is that rate and sends line noise otherwise (baud detection tests).
Everything it writes is kept, so a test can check that the session delivered the stream
losslessly.
"""

from __future__ import annotations

import contextlib
import os
import queue
import select
import termios
import threading
import time
import tty
from pathlib import Path

from drivers.novatel import (
    BestVel,
    ClockModelStatus,
    PositionType,
    SolutionStatus,
    Time,
    UTCStatus,
    encode_ascii,
    encode_binary,
    encode_error,
    encode_ok,
    encode_prompt,
    make_header,
)
from drivers.novatel.messages import Message
from tests.novatel.gen import sample_bestpos

NOISE = bytes([0xFF, 0x00, 0xF0, 0x0F, 0xFE, 0x80]) * 4


def _body(name: str, i: int) -> Message | None:
    if name == "BESTPOS":
        return sample_bestpos(i)
    if name == "BESTVEL":
        return BestVel(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 0.02, 1.0, 13.9, 87.5, 0.01, 0.0)
    if name == "TIME":
        return Time(ClockModelStatus.VALID, 1e-9, 2e-9, -18.0, 2024, 3, 1, 12, 0, 0, UTCStatus.VALID)
    return None


class FakePeer:
    """Scripted receiver on a pty, reachable at ``link``."""

    def __init__(
        self,
        link: Path,
        *,
        port_name: str = "COM1",
        errors: dict[str, str] | None = None,
        silent: tuple[str, ...] = (),
        baud: int | None = None,
    ) -> None:
        self.link = link
        self.port_name = port_name
        self.errors = dict(errors or {})
        self.silent = silent
        self.baud = baud
        self.commands: queue.Queue[str] = queue.Queue()
        self.history: list[str] = []
        self.received = bytearray()
        self.corrections: queue.Queue[bytes] = queue.Queue()
        self.written: list[bytearray] = []  # bytes written, one entry per plug
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._master = -1
        self._slave = -1
        self._logs: dict[str, tuple[float, bool, float]] = {}  # name -> (period, binary, next due)
        self._seq = 0

    # --- control ---

    def plug(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        self.link.symlink_to(os.ttyname(self._slave))
        self.written.append(bytearray())
        self._logs.clear()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="fake-novatel-peer", daemon=True)
        self._thread.start()

    def unplug(self) -> None:
        """The device goes away: the link disappears and the session's reads fail."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            assert not self._thread.is_alive()
            self._thread = None
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    close = unplug

    def inject(self, data: bytes) -> None:
        """Write raw bytes to the line (garbage, hand-made frames)."""
        self._write(data)

    def next_command(self, timeout_s: float = 5.0) -> str:
        return self.commands.get(timeout=timeout_s)

    @property
    def all_written(self) -> bytes:
        with self._lock:
            return b"".join(self.written)

    # --- the peer's thread ---

    def _write(self, data: bytes) -> None:
        with self._lock:
            os.write(self._master, data)
            self.written[-1] += data

    def _baud_matches(self) -> bool:
        if self.baud is None:
            return True
        speed = termios.tcgetattr(self._slave)[4]
        return bool(speed == getattr(termios, f"B{self.baud}"))

    def _run(self) -> None:
        pending = b""
        while not self._stop.is_set():
            self._emit_due()
            ready, _, _ = select.select([self._master], [], [], 0.005)
            if not ready:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:  # nobody has the slave open right now
                time.sleep(0.005)
                continue
            self.received += data
            pending += data
            pending = self._take_corrections(pending)
            while True:
                cut = min((i for i in (pending.find(b"\r"), pending.find(b"\n")) if i >= 0), default=-1)
                if cut < 0:
                    break
                crlf = pending[cut : cut + 2] == b"\r\n"
                line, pending = pending[:cut], pending[cut + (2 if crlf else 1) :]
                self._line(line)

    def _take_corrections(self, pending: bytes) -> bytes:
        """Cut RTCM3 frames out of the input (a receiver in RTCMV3 input mode decodes them apart)."""
        while True:
            start = pending.find(b"\xd3")
            if start < 0 or len(pending) < start + 3:
                return pending
            end = start + (((pending[start + 1] & 0x03) << 8) | pending[start + 2]) + 6
            if len(pending) < end:
                return pending
            self.corrections.put(pending[start:end])
            pending = pending[:start] + pending[end:]

    def _line(self, raw: bytes) -> None:
        if not self._baud_matches():
            self._write(NOISE)
            return
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            return  # binary input (corrections): a receiver does not answer it
        if not line:
            if raw == b"":
                self._write(encode_prompt(self.port_name))
            return
        self.history.append(line)
        self.commands.put(line)
        if any(line.startswith(s) for s in self.silent):
            return
        for prefix, reason in self.errors.items():
            if line.startswith(prefix):
                self._write(encode_error(reason) + encode_prompt(self.port_name))
                return
        self._apply(line.split())
        self._write(encode_ok() + encode_prompt(self.port_name))

    def _apply(self, tokens: list[str]) -> None:
        if tokens[0] == "UNLOGALL":
            self._logs.clear()
        elif tokens[0] == "LOG" and len(tokens) >= 5 and tokens[3] == "ONTIME":
            name = tokens[2]
            self._logs[name[:-1]] = (float(tokens[4]), name.endswith("B"), time.monotonic())

    def _emit_due(self) -> None:
        now = time.monotonic()
        for name, (period, binary, due) in list(self._logs.items()):
            if now < due:
                continue
            body = _body(name, self._seq)
            self._logs[name] = (period, binary, due + period)
            if body is None:
                continue
            self._seq += 1
            header = make_header(body, week=2300, seconds=345600.0 + self._seq * 0.05, port=self.port_name,
                                 sequence=self._seq % 65536)
            self._write(encode_binary(header, body) if binary else encode_ascii(header, body))
