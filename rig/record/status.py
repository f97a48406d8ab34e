"""Live status of a recording session, and its terminal view.

The session keeps one :class:`StatusBoard` that device threads update (a few fields each, under a
lock); the dashboard thread takes a :class:`RecordingStatus` snapshot a few times a second and renders
it with rich. The snapshot is plain data, so tests check what the engineer would see without a
terminal, and the same numbers go into ``/rig/events`` at the end of the session.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass, field, replace
from enum import StrEnum

from rich.console import Group
from rich.table import Table
from rich.text import Text

__all__ = [
    "DeviceState",
    "DeviceStatus",
    "RecordingStatus",
    "StatusBoard",
    "VehicleStatus",
    "render_status",
    "status_line",
]


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
class VehicleStatus:
    """Live figures of the car from the references (NaN where not available yet)."""

    speed_kmh: float = float("nan")
    baseline_m: float = float("nan")
    """Measured antenna A–B distance from the latest pair of RTK positions."""
    baseline_nominal_m: float = float("nan")
    baseline_tolerance_m: float = 0.03
    beta_deg: float = float("nan")
    """Live sideslip at antenna A (heading of the baseline − course), mount offset removed."""
    ltr: float = float("nan")
    ltr_predicted: float = float("nan")
    ltr_warning: bool = False
    correction_age_s: float = float("nan")
    relay_bytes_per_s: float = float("nan")

    @property
    def baseline_ok(self) -> bool:
        return abs(self.baseline_m - self.baseline_nominal_m) <= self.baseline_tolerance_m


@dataclass(frozen=True, slots=True)
class RecordingStatus:
    """Snapshot of the whole session."""

    name: str
    elapsed_s: float
    devices: tuple[DeviceStatus, ...]
    file: str = ""
    bytes_written: int = 0
    messages_written: int = 0
    dropped: int = 0
    recent_events: tuple[str, ...] = ()
    vehicle: VehicleStatus = VehicleStatus()
    free_disk_mb: float = float("nan")


@dataclass(slots=True)
class _Counter:
    """Message count of one device, kept apart from its (frozen) :class:`DeviceStatus`: counting a
    message is then an increment and an append, not a new record (it runs for every CAN frame)."""

    count: int = 0
    last_host_ns: int | None = None
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
        self._vehicle = VehicleStatus()
        self._free_disk_mb = float("nan")

    def add_device(self, name: str, kind: str) -> None:
        with self._lock:
            self._devices[name] = DeviceStatus(name, kind)
            self._counters[name] = _Counter()

    def message(self, name: str, host_ns: int) -> None:
        """Count one message received from device ``name`` at host time ``host_ns`` (a starting or
        lost device is OK again)."""
        with self._lock:
            c = self._counters[name]
            c.count += 1
            c.last_host_ns = host_ns
            c.window.append(host_ns)
            d = self._devices[name]
            if d.state is DeviceState.STARTING or d.state is DeviceState.LOST:
                self._devices[name] = replace(d, state=DeviceState.OK)

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

    def vehicle(self, **figures: float | bool) -> None:
        """Update some of the live vehicle figures (names of :class:`VehicleStatus` fields)."""
        with self._lock:
            self._vehicle = replace(self._vehicle, **figures)  # type: ignore[arg-type]

    def free_disk(self, mb: float) -> None:
        with self._lock:
            self._free_disk_mb = mb

    def snapshot(self, now_ns: int) -> RecordingStatus:
        with self._lock:
            devices = []
            for name, d in self._devices.items():
                w = self._counters[name].window
                recent = [t for t in w if now_ns - t <= self._window_ns]
                rate = 0.0
                if len(recent) >= 2 and recent[-1] > recent[0]:
                    rate = (len(recent) - 1) / ((recent[-1] - recent[0]) * 1e-9)
                c = self._counters[name]
                devices.append(replace(d, rate_hz=rate, messages=c.count, last_host_ns=c.last_host_ns))
            return RecordingStatus(
                name=self._name,
                elapsed_s=(now_ns - self._t0) * 1e-9,
                devices=tuple(devices),
                file=self._file,
                bytes_written=self._bytes,
                messages_written=self._written,
                dropped=self._dropped,
                recent_events=tuple(self._events),
                vehicle=self._vehicle,
                free_disk_mb=self._free_disk_mb,
            )


_STATE_STYLE = {
    DeviceState.STARTING: "yellow",
    DeviceState.OK: "green",
    DeviceState.DEGRADED: "yellow",
    DeviceState.LOST: "bold red",
    DeviceState.STOPPED: "dim",
}


def render_status(status: RecordingStatus, now_ns: int) -> Group:
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
        f"file {status.file or '-'}  {mb:.1f} MB  {status.messages_written} messages  dropped {status.dropped}"
        f"  free disk {_fmt(status.free_disk_mb, '.0f')} MB",
        style="red" if status.dropped else "",
    )
    events = [Text(f"• {e}", style="dim") for e in status.recent_events]
    return Group(table, _vehicle_line(status.vehicle), file_line, *events)


def _fmt(x: float, spec: str) -> str:
    return "-" if math.isnan(x) else format(x, spec)


def _vehicle_line(v: VehicleStatus) -> Text:
    line = Text()
    line.append(f"speed {_fmt(v.speed_kmh, '5.1f')} km/h   β {_fmt(v.beta_deg, '+6.2f')}°   ")
    baseline = f"baseline {_fmt(v.baseline_m, '.3f')} m (nominal {_fmt(v.baseline_nominal_m, '.3f')})   "
    style = "" if math.isnan(v.baseline_m) or v.baseline_ok else "bold red"
    line.append(baseline, style=style)
    line.append(f"LTR {_fmt(v.ltr, '+.2f')} → {_fmt(v.ltr_predicted, '+.2f')}   ")
    if v.ltr_warning:
        line.append("ROLLOVER WARNING   ", style="bold white on red")
    line.append(f"corrections {_fmt(v.correction_age_s, '.1f')} s old, {_fmt(v.relay_bytes_per_s, '.0f')} B/s")
    return line


def status_line(status: RecordingStatus) -> str:
    """One plain line for logs and non-terminal output (no colours, no cursor movement)."""
    devs = " ".join(f"{d.name}={d.state.value}:{d.rate_hz:.0f}Hz" + (f"({d.detail})" if d.detail else "")
                    for d in status.devices)
    v = status.vehicle
    return (
        f"[{status.elapsed_s:7.1f} s] {devs} | speed {_fmt(v.speed_kmh, '.1f')} km/h "
        f"β {_fmt(v.beta_deg, '+.2f')}° baseline {_fmt(v.baseline_m, '.3f')} m LTR {_fmt(v.ltr, '+.2f')}"
        f"{' ROLLOVER WARNING' if v.ltr_warning else ''} | {status.bytes_written / 1e6:.1f} MB "
        f"{status.messages_written} msgs dropped {status.dropped} free {_fmt(status.free_disk_mb, '.0f')} MB"
    )
