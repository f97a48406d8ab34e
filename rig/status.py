"""Live status of a recording session, and its terminal view.

The session keeps one :class:`StatusBoard` that device threads update (a few fields each, under a
lock); the dashboard thread takes a :class:`SessionStatus` snapshot a few times a second and renders
it with rich. The snapshot is plain data, so tests check what the engineer would see without a
terminal, and the same numbers go into ``/rig/events`` at the end of the session.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field, replace
from enum import StrEnum

from rich.console import Group
from rich.table import Table
from rich.text import Text

__all__ = ["DeviceState", "DeviceStatus", "SessionStatus", "StatusBoard", "render_status"]


class DeviceState(StrEnum):
    """Connection state of one device as the engineer sees it."""

    STARTING = "starting"
    OK = "ok"
    DEGRADED = "degraded"
    LOST = "lost"
    STOPPED = "stopped"


@dataclass(frozen=True, slots=True)
class DeviceStatus:
    """One line of the dashboard."""

    name: str
    kind: str
    state: DeviceState = DeviceState.STARTING
    detail: str = ""
    """Device-specific summary, e.g. ``NARROW_INT 14 sats diff 0.8 s`` or ``load 23 %``."""
    messages: int = 0
    rate_hz: float = 0.0
    last_host_ns: int | None = None
    errors: int = 0


@dataclass(frozen=True, slots=True)
class SessionStatus:
    """Snapshot of the whole session."""

    name: str
    elapsed_s: float
    devices: tuple[DeviceStatus, ...]
    file: str = ""
    bytes_written: int = 0
    messages_written: int = 0
    dropped: int = 0
    recent_events: tuple[str, ...] = ()


@dataclass(slots=True)
class _Counter:
    count: int = 0
    window: deque[int] = field(default_factory=lambda: deque(maxlen=256))


class StatusBoard:
    """Thread-safe status shared by the device threads (writers) and the dashboard (reader)."""

    def __init__(self, name: str, *, now_ns: int, rate_window_s: float = 2.0) -> None:
        self._lock = threading.Lock()
        self._name = name
        self._t0 = now_ns
        self._window_ns = int(rate_window_s * 1e9)
        self._devices: dict[str, DeviceStatus] = {}
        self._counters: dict[str, _Counter] = {}
        self._events: deque[str] = deque(maxlen=6)
        self._file = ""
        self._bytes = 0
        self._written = 0
        self._dropped = 0

    def add_device(self, name: str, kind: str) -> None:
        with self._lock:
            self._devices[name] = DeviceStatus(name, kind)
            self._counters[name] = _Counter()

    def message(self, name: str, host_ns: int) -> None:
        """Count one message received from device ``name`` at host time ``host_ns``."""
        with self._lock:
            c = self._counters[name]
            c.count += 1
            c.window.append(host_ns)
            d = self._devices[name]
            state = DeviceState.OK if d.state in (DeviceState.STARTING, DeviceState.LOST) else d.state
            self._devices[name] = replace(d, messages=c.count, last_host_ns=host_ns, state=state)

    def update(self, name: str, *, state: DeviceState | None = None, detail: str | None = None) -> None:
        with self._lock:
            d = self._devices[name]
            self._devices[name] = replace(
                d, state=d.state if state is None else state, detail=d.detail if detail is None else detail
            )

    def error(self, name: str) -> None:
        with self._lock:
            d = self._devices[name]
            self._devices[name] = replace(d, errors=d.errors + 1)

    def event(self, text: str) -> None:
        with self._lock:
            self._events.append(text)

    def recorder(self, *, file: str, bytes_written: int, messages_written: int, dropped: int) -> None:
        with self._lock:
            self._file, self._bytes, self._written, self._dropped = file, bytes_written, messages_written, dropped

    def snapshot(self, now_ns: int) -> SessionStatus:
        with self._lock:
            devices = []
            for name, d in self._devices.items():
                w = self._counters[name].window
                recent = [t for t in w if now_ns - t <= self._window_ns]
                rate = 0.0
                if len(recent) >= 2 and recent[-1] > recent[0]:
                    rate = (len(recent) - 1) / ((recent[-1] - recent[0]) * 1e-9)
                devices.append(replace(d, rate_hz=rate))
            return SessionStatus(
                name=self._name,
                elapsed_s=(now_ns - self._t0) * 1e-9,
                devices=tuple(devices),
                file=self._file,
                bytes_written=self._bytes,
                messages_written=self._written,
                dropped=self._dropped,
                recent_events=tuple(self._events),
            )


_STATE_STYLE = {
    DeviceState.STARTING: "yellow",
    DeviceState.OK: "green",
    DeviceState.DEGRADED: "yellow",
    DeviceState.LOST: "bold red",
    DeviceState.STOPPED: "dim",
}


def render_status(status: SessionStatus, now_ns: int) -> Group:
    """The dashboard for one snapshot: a device table, the file line and the last events."""
    table = Table(title=f"vsc-rig — {status.name} — {status.elapsed_s:7.1f} s", expand=True)
    for col in ("device", "kind", "state", "rate", "messages", "age", "errors", "detail"):
        table.add_column(col, justify="right" if col in ("rate", "messages", "age", "errors") else "left")
    for d in status.devices:
        age = "-" if d.last_host_ns is None else f"{(now_ns - d.last_host_ns) * 1e-9:.1f} s"
        table.add_row(
            d.name,
            d.kind,
            Text(d.state.value, style=_STATE_STYLE[d.state]),
            f"{d.rate_hz:.1f} Hz",
            str(d.messages),
            age,
            Text(str(d.errors), style="red" if d.errors else ""),
            d.detail,
        )
    mb = status.bytes_written / 1e6
    file_line = Text(
        f"file {status.file or '-'}  {mb:.1f} MB  {status.messages_written} messages  dropped {status.dropped}",
        style="red" if status.dropped else "",
    )
    events = [Text(f"• {e}", style="dim") for e in status.recent_events]
    return Group(table, file_line, *events)
