"""The terminal dashboard of ``rig record``: a rich live view, or plain status lines off a terminal.

:class:`Dashboard` runs one thread that renders :class:`~rig.record.status.StatusBoard` snapshots a few
times a second. On a terminal it also reads keys: ``m`` starts an operator mark *at the moment the
key is pressed*, the typed text becomes its note, Enter records it (Esc records it without a note).
Keys are handled by :class:`MarkInput`, a small state machine with no terminal in it, so it is
tested directly. Off a terminal (CI, ``nohup``, a pipe) it prints one :func:`~rig.record.status.status_line`
every ``plain_period_s`` and reads no keys.

Alarms: a device the session marks DEGRADED (a stalled stream, :mod:`rig.record.recording`; a receiver
without a solution) is a bold red ``ALARM`` line above the table (:func:`alarm_lines`), and in the
plain output an ``ALARM`` line each period while it lasts.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import sys
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TextIO

from rich.console import Console, Group
from rich.live import Live
from rich.text import Text

from rig.record.status import DeviceState, RecordingStatus, StatusBoard, render_status, status_line
from vsccore.clock import Clock

__all__ = ["Dashboard", "Mark", "MarkInput", "alarm_lines"]

log = logging.getLogger(__name__)

_ESC = "\x1b"
_BACKSPACE = ("\x7f", "\b")


def alarm_lines(status: RecordingStatus) -> list[str]:
    """One line per device in the DEGRADED state (its detail, and the latest event naming it)."""
    out = []
    for d in status.devices:
        if d.state is DeviceState.DEGRADED:
            ev = next((e for e in reversed(status.recent_events) if e.startswith(f"{d.name}:")), "")
            out.append(f"ALARM {d.name} degraded" + (f" — {ev.removeprefix(d.name + ':').strip()}" if ev else "")
                       + (f" ({d.detail})" if d.detail else ""))
    return out


@dataclass(frozen=True, slots=True)
class Mark:
    """An operator mark: when the key was pressed (host clock) and the note typed after it."""

    host_ns: int
    note: str


class MarkInput:
    """Keys → marks. ``m`` opens a mark at the time of the key; Enter or Esc closes it."""

    def __init__(self, max_note: int = 200) -> None:
        self._open_ns: int | None = None
        self._text: list[str] = []
        self._max = max_note

    @property
    def editing(self) -> bool:
        return self._open_ns is not None

    @property
    def prompt(self) -> str:
        """What the dashboard shows under the table."""
        if self._open_ns is None:
            return "press m to mark"
        return "mark note (Enter to save, Esc to save without note): " + "".join(self._text)

    def feed(self, key: str, host_ns: int) -> Mark | None:
        """Handle one key pressed at ``host_ns``; return a finished mark, if this key finished one."""
        if self._open_ns is None:
            if key in ("m", "M"):
                self._open_ns = host_ns
                self._text = []
            return None
        if key in ("\r", "\n"):
            return self._close("".join(self._text).strip())
        if key == _ESC:
            return self._close("")
        if key in _BACKSPACE:
            if self._text:
                self._text.pop()
            return None
        if key.isprintable() and len(self._text) < self._max:
            self._text.append(key)
        return None

    def _close(self, note: str) -> Mark:
        assert self._open_ns is not None
        mark = Mark(self._open_ns, note)
        self._open_ns = None
        self._text = []
        return mark


@contextlib.contextmanager
def _cbreak(stream: TextIO) -> Iterator[bool]:
    """Put a terminal in cbreak mode (keys without Enter, no echo) for the duration; restore it."""
    try:
        import termios
        import tty
    except ImportError:  # pragma: no cover - not on POSIX
        yield False
        return
    fd = stream.fileno()
    try:
        saved = termios.tcgetattr(fd)
    except termios.error:
        yield False
        return
    try:
        tty.setcbreak(fd, termios.TCSANOW)  # TCSAFLUSH would drop keys typed before the switch
        yield True
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


class Dashboard:
    """Renders the session status until stopped; turns operator keys into marks."""

    def __init__(
        self,
        board: StatusBoard,
        clock: Clock,
        *,
        on_mark: Callable[[Mark], None],
        console: Console | None = None,
        keys: TextIO | None = None,
        refresh_hz: float = 4.0,
        plain_period_s: float = 5.0,
    ) -> None:
        self._board = board
        self._clock = clock
        self._on_mark = on_mark
        self._console = console or Console(stderr=True)
        self._keys = keys if keys is not None else sys.stdin
        self._refresh_s = 1.0 / refresh_hz
        self._plain_s = plain_period_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._marks = MarkInput()

    @property
    def interactive(self) -> bool:
        """A live view with keys: both the console and the key stream are terminals."""
        try:
            keys_tty = self._keys.isatty()
        except (ValueError, AttributeError):
            keys_tty = False
        return self._console.is_terminal and keys_tty

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="dashboard")
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    def _render(self) -> Group:
        now = self._clock.now_ns()
        snap = self._board.snapshot(now)
        alarms = [Text(a, style="bold white on red") for a in alarm_lines(snap)]
        return Group(*alarms, render_status(snap, now), Text(self._marks.prompt, style="cyan"))

    def _run(self) -> None:
        if not self.interactive:
            self._run_plain()
            return
        with _cbreak(self._keys) as keys_ok, Live(self._render(), console=self._console, auto_refresh=False) as live:
            while not self._stop.is_set():
                if keys_ok:
                    self._read_keys()
                else:
                    self._stop.wait(self._refresh_s)
                live.update(self._render(), refresh=True)

    def _read_keys(self) -> None:
        fd = self._keys.fileno()
        ready, _, _ = select.select([fd], [], [], self._refresh_s)
        if not ready:
            return
        data = os.read(fd, 64).decode("utf-8", errors="ignore")
        now = self._clock.now_ns()
        for ch in data:
            mark = self._marks.feed(ch, now)
            if mark is not None:
                self._on_mark(mark)

    def _run_plain(self) -> None:
        while not self._stop.wait(self._plain_s):
            self._print_plain()
        self._print_plain()

    def _print_plain(self) -> None:
        snap = self._board.snapshot(self._clock.now_ns())
        for a in alarm_lines(snap):
            self._console.print(a, highlight=False)
        self._console.print(status_line(snap), highlight=False)
