"""A live view of one NovAtel receiver at the bench: solution, satellites, position and velocity, differential
age, message rates, CRC failures, connection state (``rig gnss monitor``)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from vsccore.errors import ConfigError, EncodeError

if TYPE_CHECKING:  # the NovAtel driver and rich are imported where used: ``rig --help`` stays fast
    from rich.console import Console
    from rich.table import Table

    from drivers.novatel import BestPos, BestVel
    from drivers.novatel.commands import LogRequest
    from drivers.novatel.receiver import (
        NovatelReceiver,
        ReceivedChunk,
        ReceiverEvent,
        ReceiverHealth,
        ReceiverSettings,
    )

if TYPE_CHECKING:  # the NovAtel driver and rich are imported where used: ``rig --help`` stays fast
    from rich.console import Console
    from rich.table import Table

    from drivers.novatel import BestPos, BestVel
    from drivers.novatel.commands import LogRequest
    from drivers.novatel.receiver import (
        NovatelReceiver,
        ReceivedChunk,
        ReceiverEvent,
        ReceiverHealth,
        ReceiverSettings,
    )

#: A solution older than this (host time) is shown as stale.
STALE_AFTER_S = 2.0


_MPS_TO_KMH = 3.6


#: Events whose message becomes the view's "last error" (CONFIGURATION_FAILED only sums up the
#: COMMAND_FAILED events before it, which name the command; it shows in the connection state).
_ERROR_EVENTS = frozenset({"CONNECT_FAILED", "COMMAND_FAILED", "DISCONNECTED", "CALLBACK_FAILED"})
"""Names of the :class:`~drivers.novatel.receiver.ReceiverEventKind` members (the driver is imported lazily)."""



def parse_log_option(text: str) -> LogRequest:
    """``NAME@PERIOD_S`` (``BESTPOSB@0.05``) or ``NAME@TRIGGER`` (``MARKPOSB@ONNEW``) → request.

    Raises:
        ConfigError: not of that form (names the option value).
    """
    from drivers.novatel.commands import LogRequest, LogTrigger

    name, sep, when = text.strip().partition("@")
    if not sep or not name or not when:
        raise ConfigError(f"--log {text!r}: expected NAME@PERIOD_S or NAME@TRIGGER, e.g. BESTPOSB@0.05")
    name = name.upper()
    trigger = LogTrigger.__members__.get(when.upper())
    if trigger is not None:
        return LogRequest(name, trigger)
    try:
        period = float(when)
    except ValueError:
        raise ConfigError(
            f"--log {text!r}: {when!r} is neither a period in seconds nor one of "
            f"{', '.join(LogTrigger.__members__)}"
        ) from None
    if not period > 0:
        raise ConfigError(f"--log {text!r}: the period must be > 0 s")
    return LogRequest(name, LogTrigger.ONTIME, period)


def monitor_commands(logs: list[LogRequest]) -> tuple[str, ...]:
    """Commands of the monitor: stop the logs of the port it is connected to, then request ``logs``.

    Only ``THISPORT`` is touched, so a receiver that also feeds a recording on another port keeps
    its logs there.

    Raises:
        ConfigError: a log request cannot be sent (names it).
    """
    from drivers.novatel.commands import standard_configuration, unlogall_command

    try:
        return (unlogall_command("THISPORT"), *standard_configuration("THISPORT", logs, unlogall=False))
    except EncodeError as exc:
        raise ConfigError(f"--log: {exc}") from exc


@dataclass(frozen=True, slots=True)
class MonitorView:
    """What the live view shows, as plain data (so it can be checked without a terminal)."""

    elapsed_s: float
    health: ReceiverHealth
    configure: bool
    position: BestPos | None
    position_age_s: float | None
    velocity: BestVel | None
    velocity_age_s: float | None
    last_error: str | None
    last_error_age_s: float | None
    stopped: bool = False
    configuration_failed: bool = False

    @property
    def state(self) -> str:
        h = self.health
        if self.stopped:
            return "stopped"
        if not h.connected:
            return "lost" if h.disconnects else "connecting"
        if not self.configure:
            return "listening"
        if h.configured:
            return "configured"
        return "configuration failed" if self.configuration_failed else "configuring"


class ReceiverMonitor:
    """One receiver session plus what the view needs beyond ``health()``: the last position and
    velocity (host receive time) and the last error event.

    Callbacks run on the session's I/O thread and only store references under a lock.
    """

    def __init__(
        self,
        settings: ReceiverSettings,
        *,
        configure: bool = True,
        receiver_factory: Callable[..., NovatelReceiver] | None = None,
    ) -> None:
        self.configure = configure
        self._lock = threading.Lock()
        self._position: tuple[int, BestPos] | None = None
        self._velocity: tuple[int, BestVel] | None = None
        self._error: tuple[int, str] | None = None
        self._config_failed = False
        self._started = time.monotonic()
        self._stopped = False
        factory = receiver_factory
        if factory is None:
            from drivers.novatel.receiver import NovatelReceiver

            factory = NovatelReceiver
        self.receiver = factory(settings, on_data=self._on_data, on_event=self._on_event)

    def _on_data(self, chunk: ReceivedChunk) -> None:
        from drivers.novatel import BestPos, BestVel

        position = velocity = None
        for frame in chunk.frames:
            log = frame.log
            if log is None:
                continue
            if isinstance(log.body, BestPos):
                position = log.body
            elif isinstance(log.body, BestVel):
                velocity = log.body
        if position is not None or velocity is not None:
            with self._lock:
                if position is not None:
                    self._position = (chunk.host_ns, position)
                if velocity is not None:
                    self._velocity = (chunk.host_ns, velocity)

    def _on_event(self, event: ReceiverEvent) -> None:
        from drivers.novatel.receiver import ReceiverEventKind

        if event.kind in (ReceiverEventKind.CONNECTED, ReceiverEventKind.CONFIGURATION_FAILED):
            with self._lock:
                self._config_failed = event.kind is ReceiverEventKind.CONFIGURATION_FAILED
        if event.kind.name in _ERROR_EVENTS:
            what = f" ({event.command})" if event.command and event.command not in event.message else ""
            with self._lock:
                self._error = (event.host_ns, f"{event.kind.value}{what}: {event.message}")

    def start(self) -> None:
        self._started = time.monotonic()
        self.receiver.start()

    def stop(self) -> None:
        self.receiver.stop()
        self._stopped = True

    def snapshot(self) -> MonitorView:
        health = self.receiver.health()
        now = time.time_ns()
        with self._lock:
            position, velocity, error = self._position, self._velocity, self._error
            config_failed = self._config_failed

        def age(t_ns: int | None) -> float | None:
            return None if t_ns is None else max(0.0, (now - t_ns) / 1e9)

        return MonitorView(
            elapsed_s=time.monotonic() - self._started,
            health=health,
            configure=self.configure,
            position=position[1] if position else None,
            position_age_s=age(position[0] if position else None),
            velocity=velocity[1] if velocity else None,
            velocity_age_s=age(velocity[0] if velocity else None),
            last_error=error[1] if error else None,
            last_error_age_s=age(error[0] if error else None),
            stopped=self._stopped,
            configuration_failed=config_failed,
        )


def _stale(age_s: float | None) -> str:
    return f" (stale {age_s:.1f} s)" if age_s is not None and age_s > STALE_AFTER_S else ""


def _rates_text(rates: dict[str, float]) -> str:
    shown = sorted((k, v) for k, v in rates.items() if v > 0)
    return " ".join(f"{k} {v:.1f}" for k, v in shown) + " /s" if shown else "none"


def _connection_text(view: MonitorView) -> str:
    h = view.health
    text = view.state
    if h.baud is not None:
        text += f" {h.baud} Bd"
    if h.disconnects:
        gap = f", last gap {h.last_gap_ns / 1e9:.1f} s" if h.last_gap_ns is not None else ""
        text += f" ({h.disconnects} disconnects{gap})"
    return text


def _solution_texts(view: MonitorView) -> dict[str, str]:
    """The solution fields as short texts (ASCII only: they also go to pipes and log files)."""
    pos, vel = view.position, view.velocity
    out = {
        "solution": "no BESTPOS yet",
        "satellites": "-",
        "position": "-",
        "sigma": "-",
        "velocity": "no BESTVEL yet",
        "diff_age": "-",
    }
    if pos is not None:
        stale = _stale(view.position_age_s)
        out["solution"] = f"{pos.pos_type.name} {pos.sol_status.name}{stale}"
        out["satellites"] = f"{pos.num_svs} tracked {pos.num_soln_svs} used"
        out["position"] = f"lat {pos.lat_deg:.9f} lon {pos.lon_deg:.9f} h {pos.hgt_m:.3f} m"
        out["sigma"] = f"{pos.lat_sigma_m:.3f}/{pos.lon_sigma_m:.3f}/{pos.hgt_sigma_m:.3f} m"
        out["diff_age"] = f"{pos.diff_age_s:.1f} s" if pos.diff_age_s > 0 else "none"
    if vel is not None:
        out["velocity"] = (
            f"speed {vel.hor_spd_mps:.2f} m/s ({vel.hor_spd_mps * _MPS_TO_KMH:.1f} km/h) "
            f"course {vel.trk_gnd_deg:.1f} deg vertical {vel.vert_spd_mps:+.2f} m/s{_stale(view.velocity_age_s)}"
        )
    return out


def _errors_text(view: MonitorView) -> str:
    h = view.health
    text = f"crc {h.crc_failures} rejected {h.rejected_bytes} B"
    if h.command_failures:
        text += f" commands failed {h.command_failures}"
    return text


def last_error_text(view: MonitorView) -> str:
    if view.last_error is None:
        return "none"
    age = f" ({view.last_error_age_s:.1f} s ago)" if view.last_error_age_s is not None else ""
    return view.last_error + age


def monitor_line(view: MonitorView) -> str:
    """One plain status line (output that is not a terminal)."""
    h = view.health
    sol = _solution_texts(view)
    parts = [
        f"{view.elapsed_s:7.1f} s",
        f"{h.receiver} {_connection_text(view)}",
        sol["solution"],
        f"sats {sol['satellites']}",
        f"{sol['position']} sd {sol['sigma']}",
        sol["velocity"],
        f"diff age {sol['diff_age']}",
        f"rates {_rates_text(h.rates_hz)}",
        _errors_text(view),
        f"last error {last_error_text(view)}",
    ]
    return " | ".join(parts)


def render_monitor(view: MonitorView) -> Table:
    """The live view (a rich table) of one receiver."""
    from rich.table import Table

    h = view.health
    sol = _solution_texts(view)
    table = Table(title=f"NovAtel receiver {h.receiver} on {h.port}", show_header=False, expand=False)
    table.add_column("what", style="bold")
    table.add_column("value")
    state_style = {"configured": "green", "listening": "green", "lost": "red bold", "configuration failed": "red"}.get(
        view.state, "yellow"
    )
    table.add_row("connection", f"[{state_style}]{_connection_text(view)}[/]")
    good = view.position is not None and view.position.sol_status.name == "SOL_COMPUTED"
    table.add_row("solution", f"[{'green' if good else 'yellow'}]{sol['solution']}[/]")
    table.add_row("satellites", sol["satellites"])
    table.add_row("position", sol["position"])
    table.add_row("std dev lat/lon/h", sol["sigma"])
    table.add_row("velocity", sol["velocity"])
    table.add_row("differential age", sol["diff_age"])
    rates = Table(show_header=False, box=None, pad_edge=False)
    for key, value in sorted(h.rates_hz.items()):
        rates.add_row(key, f"{value:6.1f} /s", f"{h.message_counts.get(key, 0)} total")
    table.add_row("message rates", rates if h.rates_hz else "none")
    table.add_row("errors", _errors_text(view))
    error_style = "red" if view.last_error is not None else "green"
    table.add_row("last error", f"[{error_style}]{last_error_text(view)}[/]")
    table.add_row("running", f"{view.elapsed_s:.1f} s, {h.bytes_in} bytes in")
    return table


def run_monitor(
    monitor: ReceiverMonitor,
    *,
    duration_s: float | None,
    interval_s: float,
    console: Console,
    live: bool,
    stop: threading.Event | None = None,
) -> MonitorView:
    """Run the view until ``duration_s``, ``stop`` or Ctrl-C; always stops the session.

    Returns the last view (taken after the session stopped).
    """
    from rich.live import Live

    stop = stop if stop is not None else threading.Event()
    deadline = None if duration_s is None else time.monotonic() + duration_s
    period = min(interval_s, 0.25) if live else interval_s
    view_live = Live(render_monitor(monitor.snapshot()), console=console, auto_refresh=False) if live else None
    monitor.start()
    try:
        if view_live is not None:
            view_live.start()
        next_line = time.monotonic() + interval_s
        while True:
            now = time.monotonic()
            wait = period if deadline is None else min(period, deadline - now)
            if wait > 0 and stop.wait(wait):
                break
            view = monitor.snapshot()
            if view_live is not None:
                view_live.update(render_monitor(view), refresh=True)
            elif time.monotonic() >= next_line - 1e-3:
                console.print(monitor_line(view), highlight=False, soft_wrap=True, markup=False)
                next_line += interval_s
            if deadline is not None and time.monotonic() >= deadline:
                break
    finally:
        if view_live is not None:
            view_live.stop()
        monitor.stop()
    return monitor.snapshot()
