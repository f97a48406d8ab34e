"""NovAtel receiver session: serial transport + framer + command/response + reconnect, on one thread.

:class:`NovatelReceiver` opens a port (device path or pyserial URL; optional automatic baud
detection), sends its configuration commands one by one and awaits ``<OK`` for each, then streams
everything the receiver sends to the consumer as :class:`ReceivedChunk` (host receive time, the
raw bytes exactly as read, the frames those bytes completed). When the port disappears (USB adapter
unplugged, pseudo-terminal closed) it reports the loss, reconnects with back-off, re-sends the
configuration and reports the gap. ``stop()`` returns at once, also during back-off, and joins the
thread.

One thread does all port I/O: reading, and the command exchanges (configuration, and commands other
threads ask for through :meth:`NovatelReceiver.command`, which are queued to it). Callbacks run on
that thread and must return quickly (the recorder's ``Source.put`` never blocks).

Usage::

    settings = ReceiverSettings(name="rover_a", port="/dev/ttyUSB0", baud=115200,
                                commands=standard_configuration("COM1", [LogRequest("BESTPOSB", period_s=0.05)]))
    rx = NovatelReceiver(settings, on_data=handle_chunk, on_event=handle_event, clock=SystemClock())
    rx.start()
    rx.wait_configured(5.0)      # raises CommandError naming the receiver, port and failing command
    ...
    rx.stop()

Depends on nothing in ``rig``: the application maps its configuration to :class:`ReceiverSettings`.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import Enum

from drivers.novatel.enums import TimeStatus
from drivers.novatel.framer import LOG_KINDS, Frame, FrameKind, Framer, FramerStats
from drivers.novatel.messages import BestPos, Log, Response, Time
from drivers.serialport import SerialTransport, reconnect_delays
from vsccore.clock import Clock, SystemClock
from vsccore.errors import CommandError, CommandTimeoutError, ConfigError, DeviceError, DeviceTimeoutError, RigError

log = logging.getLogger(__name__)

__all__ = [
    "NovatelReceiver",
    "ReceivedChunk",
    "ReceiverEvent",
    "ReceiverEventKind",
    "ReceiverHealth",
    "ReceiverSettings",
]

#: Baud rates tried by automatic detection (after the configured and the last good one).
AUTOBAUD_RATES = (115200, 230400, 460800, 921600, 57600, 38400, 19200, 9600)

#: Frame kinds that prove the host reads the receiver at the right baud rate.
_PROOF_KINDS = frozenset({*LOG_KINDS, FrameKind.RESPONSE, FrameKind.PROMPT})
_ANSWER_KINDS = frozenset({FrameKind.RESPONSE, FrameKind.PROMPT})
"""Frames that answer the rig's commands; any other frame is the receiver's own output."""


@dataclass(frozen=True, slots=True)
class ReceiverSettings:
    """Everything a session needs to run one receiver (plain values; ``rig`` maps its config here).

    Args:
        name: receiver name used in every message and event (``rover_a``).
        port: device path or pyserial URL.
        baud: baud rate (the first one tried when ``autobaud``).
        commands: configuration commands, sent in order after every (re)connect
            (see :func:`drivers.novatel.commands.standard_configuration`).
        command_timeout_s: how long to wait for ``<OK``/``<ERROR`` per command.
        autobaud: detect the receiver's baud rate among ``autobaud_rates``.
        autobaud_rates: rates to try.
        autobaud_probe_s: how long to listen at each rate for a valid frame.
        read_timeout_s: longest a read blocks (bounds command-timeout overshoot).
        reconnect_first_s, reconnect_max_s: back-off between reconnect attempts (doubling).
        rate_window_s: window of the messages-per-second figures.
        max_frame_len: framer bound on one frame (bytes).
        silence_reconfigure_s: a configured receiver whose output (logs, RTCM3, NMEA) stops this long while its port
            stays open
            is configured again (a power dip resets an OEM7 behind an open USB or serial port: it drops every
            unsaved log and starts over at time status UNKNOWN); None: never.
    """

    name: str
    port: str
    baud: int = 115200
    commands: tuple[str, ...] = ()
    command_timeout_s: float = 2.0
    autobaud: bool = False
    autobaud_rates: tuple[int, ...] = AUTOBAUD_RATES
    autobaud_probe_s: float = 0.5
    read_timeout_s: float = 0.05
    reconnect_first_s: float = 0.1
    reconnect_max_s: float = 5.0
    rate_window_s: float = 5.0
    max_frame_len: int = 32768
    silence_reconfigure_s: float | None = None

    def __post_init__(self) -> None:
        where = f"receiver {self.name!r}"
        if not self.name or not self.port:
            raise ConfigError(f"{where}: name and port must not be empty")
        if self.baud <= 0 or any(b <= 0 for b in self.autobaud_rates):
            raise ConfigError(f"{where}: baud rates must be > 0")
        if self.silence_reconfigure_s is not None and not self.silence_reconfigure_s > 0:
            raise ConfigError(f"{where}: silence_reconfigure_s must be > 0 or None, got {self.silence_reconfigure_s}")
        for key in ("command_timeout_s", "autobaud_probe_s", "read_timeout_s", "reconnect_first_s", "rate_window_s"):
            if not getattr(self, key) > 0:
                raise ConfigError(f"{where}: {key} must be > 0, got {getattr(self, key)}")
        if self.reconnect_max_s < self.reconnect_first_s:
            raise ConfigError(f"{where}: reconnect_max_s must be >= reconnect_first_s")
        for command in self.commands:
            if not command.strip() or "\r" in command or "\n" in command:
                raise ConfigError(f"{where}: command {command!r} is empty or holds a line break")


@dataclass(frozen=True, slots=True)
class ReceivedChunk:
    """Bytes read from the port in one read, and the frames they completed.

    ``data`` is exactly what the port delivered (concatenating every chunk's data gives the stream
    losslessly; only bytes heard at a wrong rate while detecting the baud rate are left out); it is
    empty only when a read timeout or a disconnect completed a pending frame.
    ``host_ns`` is the injected clock's time right after the read returned. ``connection`` counts
    connections (1 = first), so a consumer sees where a reconnect cut the stream.
    """

    receiver: str
    host_ns: int
    data: bytes
    frames: tuple[Frame, ...]
    connection: int


class ReceiverEventKind(Enum):
    """What happened to a receiver session."""

    CONNECTED = "connected"  # port open (after a loss: gap_ns says how long it was away)
    CONNECT_FAILED = "connect_failed"  # first failed attempt of a series (then silent back-off)
    BAUD_DETECTED = "baud_detected"  # automatic detection found the rate (baud)
    CONFIGURED = "configured"  # every configuration command answered <OK
    RESET = "reset"  # the receiver fell silent or its time status fell back: configured again (message says which)
    COMMAND_FAILED = "command_failed"  # a command got <ERROR or no answer (command, error)
    CONFIGURATION_FAILED = "configuration_failed"  # the configuration pass ended with failures
    DISCONNECTED = "disconnected"  # port lost (error says why)
    CALLBACK_FAILED = "callback_failed"  # the data consumer raised (error logged with traceback)
    STOPPED = "stopped"  # stop() ended the session


@dataclass(frozen=True, slots=True)
class ReceiverEvent:
    """One session event (for ``/rig/events``)."""

    kind: ReceiverEventKind
    receiver: str
    port: str
    host_ns: int
    message: str
    connection: int
    command: str | None = None
    error: RigError | None = None
    gap_ns: int | None = None
    baud: int | None = None


@dataclass(frozen=True, slots=True)
class ReceiverHealth:
    """A snapshot of a session's health figures."""

    receiver: str
    port: str
    connected: bool
    configured: bool
    baud: int | None
    connection: int
    disconnects: int
    last_gap_ns: int | None
    total_gap_ns: int
    bytes_in: int
    rates_hz: dict[str, float]
    """Messages per second by type over the last ``rate_window_s``: NovAtel log name (``BESTPOS``),
    ``NMEA:GGA``, ``RTCM3:1005``, ``RESPONSE``, ``PROMPT``."""
    message_counts: dict[str, int]
    framer: FramerStats
    crc_failures: int
    rejected_bytes: int
    command_failures: int
    unsolicited_responses: int
    callback_failures: int
    last_rx_ns: int | None
    solution_status: str | None = None
    position_type: str | None = None
    num_svs: int | None = None
    num_soln_svs: int | None = None
    diff_age_s: float | None = None
    leap_seconds: int | None = None
    resets: int = 0
    """Times the receiver was configured again after it fell silent or its time status fell back."""


@dataclass(eq=False)
class _Request:
    """A command queued by another thread for the I/O thread."""

    command: str
    deadline: float  # time.monotonic()
    done: threading.Event = field(default_factory=threading.Event)
    response: Response | None = None
    error: RigError | None = None
    cancelled: bool = False


class _RateMeter:
    """Messages per second by key over a sliding window of host time."""

    def __init__(self, window_ns: int) -> None:
        self._window_ns = window_ns
        self._times: dict[str, deque[int]] = {}
        self._first: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def add(self, key: str, t_ns: int) -> None:
        times = self._times.get(key)
        if times is None:
            times = self._times[key] = deque()
            self._first[key] = t_ns
            self.counts[key] = 0
        times.append(t_ns)
        self.counts[key] += 1
        cutoff = t_ns - self._window_ns
        while times and times[0] < cutoff:
            times.popleft()

    def rates(self, now_ns: int) -> dict[str, float]:
        """Per key: the intervals between the arrivals in the window over their span (a periodic stream's rate,
        not biased low by the time since its last message in a short run); one arrival: 1 / its age."""
        out = {}
        cutoff = now_ns - self._window_ns
        for key, times in self._times.items():
            recent = [t for t in times if t >= cutoff]
            if len(recent) >= 2 and recent[-1] > recent[0]:
                out[key] = (len(recent) - 1) / ((recent[-1] - recent[0]) / 1e9)
            else:
                span = min(self._window_ns, now_ns - self._first[key])
                out[key] = len(recent) / (span / 1e9) if span > 0 and recent else 0.0
        return out


def _message_key(frame: Frame) -> str:
    if frame.kind in LOG_KINDS:
        message = frame.message
        return message.name if isinstance(message, Log) else frame.kind.value
    if frame.kind is FrameKind.NMEA:
        return f"NMEA:{getattr(frame.message, 'sentence_type', '?')}"
    if frame.kind is FrameKind.RTCM3:
        return f"RTCM3:{getattr(frame.message, 'identity', '?')}"
    return frame.kind.name


class _StoppedError(Exception):
    """Internal: stop() was called during an exchange."""


class NovatelReceiver:
    """A NovAtel receiver on a serial port: configuration, streaming, health, reconnect.

    Args:
        settings: port, baud, commands and timing.
        on_data: called on the I/O thread with every :class:`ReceivedChunk` (keep it quick).
        on_event: called on the I/O thread with every :class:`ReceiverEvent`.
        clock: host clock for receive times and events (default: the wall clock).
        transport_factory: opens a port (url, baud, read_timeout_s); default :class:`SerialTransport`.
    """

    def __init__(
        self,
        settings: ReceiverSettings,
        *,
        on_data: Callable[[ReceivedChunk], None] | None = None,
        on_event: Callable[[ReceiverEvent], None] | None = None,
        clock: Clock | None = None,
        transport_factory: Callable[[str, int, float], SerialTransport] | None = None,
    ) -> None:
        self.settings = settings
        self._on_data = on_data
        self._on_event = on_event
        self._clock: Clock = clock if clock is not None else SystemClock()
        self._open_port = transport_factory or (lambda url, baud, t: SerialTransport(url, baud, read_timeout_s=t))
        self._framer = Framer(max_frame_len=settings.max_frame_len)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._requests: queue.Queue[_Request] = queue.Queue()
        self._inbox: deque[Response] = deque()
        self._exchanging = False
        self._state_lock = threading.Lock()
        self._transport: SerialTransport | None = None
        self._configured = threading.Event()
        self._config_done = threading.Event()
        self._config_errors: tuple[RigError, ...] = ()
        # health (written by the I/O thread under _state_lock)
        self._connection = 0
        self._connected = False
        self._baud: int | None = None
        self._good_baud: int | None = None
        self._disconnects = 0
        self._lost_at_ns: int | None = None
        self._last_gap_ns: int | None = None
        self._total_gap_ns = 0
        self._rates = _RateMeter(round(settings.rate_window_s * 1e9))
        self._command_failures = 0
        self._unsolicited = 0
        self._callback_failures = 0
        self._last_rx_ns: int | None = None
        self._last_bestpos: BestPos | None = None
        self._leap_seconds: int | None = None
        self._last_log_ns: int | None = None
        self._best_time_status: TimeStatus | None = None
        self._reset_why: str | None = None
        self._resets = 0
        self._last_config_ns = 0

    # --- public API -------------------------------------------------------------------------

    @property
    def name(self) -> str:
        return self.settings.name

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def configured(self) -> bool:
        """True once every configuration command of the current connection got ``<OK``."""
        return self._configured.is_set()

    def start(self) -> None:
        """Start the I/O thread (connects, configures, streams). Returns at once.

        Raises:
            DeviceError: already started.
        """
        if self._thread is not None:
            raise DeviceError(f"NovAtel receiver {self.name} on {self.settings.port}: already started")
        self._thread = threading.Thread(target=self._run, name=f"novatel-{self.name}", daemon=True)
        self._thread.start()

    def wait_configured(self, timeout_s: float) -> None:
        """Wait until the current connection's configuration pass has ended.

        Raises:
            CommandError: a command was rejected or not answered (names receiver, port, command).
            DeviceTimeoutError: no configuration pass ended within ``timeout_s`` (e.g. port absent).
        """
        if not self._config_done.wait(timeout_s):
            raise DeviceTimeoutError(
                f"NovAtel receiver {self.name} on {self.settings.port}: not connected and configured "
                f"within {timeout_s} s"
            )
        errors = self._config_errors
        if errors:
            if len(errors) == 1:
                raise errors[0]
            raise CommandError(
                f"NovAtel receiver {self.name} on {self.settings.port}: {len(errors)} configuration commands "
                f"failed: " + "; ".join(str(e) for e in errors)
            ) from errors[0]

    def command(self, text: str, timeout_s: float | None = None) -> Response:
        """Send one command through the I/O thread and wait for its ``<OK``.

        Safe from any thread except the session's own (its callbacks).

        Raises:
            CommandError: the receiver answered ``<ERROR`` (names receiver, port, command, reason).
            CommandTimeoutError: no answer in time (also when not connected meanwhile).
            DeviceError: the session is not running, the port was lost during the exchange, or called
                from a callback.
        """
        if "\r" in text or "\n" in text or not text.strip():
            raise CommandError(f"NovAtel receiver {self.name}: command {text!r} is empty or holds a line break")
        thread = self._thread
        if thread is None or not thread.is_alive() or self._stop.is_set():
            raise DeviceError(f"NovAtel receiver {self.name} on {self.settings.port}: session is not running")
        if threading.current_thread() is thread:
            raise DeviceError(
                f"NovAtel receiver {self.name}: command {text!r} called from a callback (it would wait on itself)"
            )
        timeout = self.settings.command_timeout_s if timeout_s is None else timeout_s
        request = _Request(text.strip(), time.monotonic() + timeout)
        self._requests.put(request)
        self._wake()
        if not request.done.wait(timeout + self.settings.read_timeout_s + 0.5):
            request.cancelled = True
            raise CommandTimeoutError(
                f"NovAtel receiver {self.name} on {self.settings.port}: command {request.command!r} "
                f"not answered within {timeout} s (connected: {self._connected})"
            )
        if request.error is not None:
            raise request.error
        assert request.response is not None
        return request.response

    def send_raw(self, data: bytes) -> None:
        """Write bytes as they are (e.g. RTCM corrections relayed to a rover).

        Raises:
            DeviceError: not connected, or the write failed.
        """
        with self._state_lock:
            transport = self._transport
        if transport is None:
            raise DeviceError(f"NovAtel receiver {self.name} on {self.settings.port}: not connected")
        transport.write(data)

    def health(self) -> ReceiverHealth:
        """A snapshot of the health figures (safe from any thread)."""
        now = self._clock.now_ns()
        with self._state_lock:
            stats = self._framer.stats.copy()
            pos = self._last_bestpos
            return ReceiverHealth(
                receiver=self.name,
                port=self.settings.port,
                connected=self._connected,
                configured=self._configured.is_set(),
                baud=self._baud,
                connection=self._connection,
                disconnects=self._disconnects,
                last_gap_ns=self._last_gap_ns,
                total_gap_ns=self._total_gap_ns,
                bytes_in=stats.bytes_in,
                rates_hz=self._rates.rates(now),
                message_counts=dict(self._rates.counts),
                framer=stats,
                crc_failures=sum(stats.crc_failures.values()),
                rejected_bytes=stats.total_skipped,
                command_failures=self._command_failures,
                unsolicited_responses=self._unsolicited,
                callback_failures=self._callback_failures,
                last_rx_ns=self._last_rx_ns,
                solution_status=pos.sol_status.name if pos else None,
                position_type=pos.pos_type.name if pos else None,
                num_svs=pos.num_svs if pos else None,
                num_soln_svs=pos.num_soln_svs if pos else None,
                diff_age_s=pos.diff_age_s if pos else None,
                leap_seconds=self._leap_seconds,
                resets=self._resets,
            )

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the session: wake the I/O thread (also in back-off), close the port, join the thread.

        Raises:
            DeviceTimeoutError: the thread did not end within ``timeout_s``.
        """
        self._stop.set()
        self._wake()
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
            if thread.is_alive():
                raise DeviceTimeoutError(
                    f"NovAtel receiver {self.name} on {self.settings.port}: I/O thread did not stop in {timeout_s} s"
                )

    def __enter__(self) -> NovatelReceiver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- I/O thread -------------------------------------------------------------------------

    def _wake(self) -> None:
        with self._state_lock:
            transport = self._transport
        if transport is not None:
            transport.cancel_read()

    def _run(self) -> None:
        delays = reconnect_delays(self.settings.reconnect_first_s, self.settings.reconnect_max_s)
        failed_before = False
        try:
            while not self._stop.is_set():
                try:
                    transport, early = self._connect()
                except DeviceError as exc:
                    if not failed_before:
                        self._event(ReceiverEventKind.CONNECT_FAILED, str(exc), error=exc)
                        failed_before = True
                    self._fail_requests("not connected")
                    if self._stop.wait(next(delays)):
                        break
                    continue
                failed_before = False
                delays = reconnect_delays(self.settings.reconnect_first_s, self.settings.reconnect_max_s)
                try:
                    self._session(transport, early)
                except DeviceError as exc:
                    self._lost(transport, exc)
                except _StoppedError:
                    pass
                finally:
                    self._close(transport)
        finally:
            self._fail_requests("session stopped")
            self._config_done.set()
            self._event(ReceiverEventKind.STOPPED, "session stopped")

    def _connect(self) -> tuple[SerialTransport, list[tuple[int, bytes]]]:
        """Open the port (detecting the baud rate if asked); returns it and bytes already read."""
        s = self.settings
        if not s.autobaud:
            transport = self._open_port(s.port, s.baud, s.read_timeout_s)
            self._connected_at(transport, s.baud)
            return transport, []
        candidates = list(dict.fromkeys([*(b for b in (self._good_baud, s.baud) if b), *s.autobaud_rates]))
        transport = self._open_port(s.port, candidates[0], s.read_timeout_s)
        try:
            for baud in candidates:
                if self._stop.is_set():
                    raise DeviceError(f"NovAtel receiver {self.name} on {s.port}: stopped during baud detection")
                early = self._probe(transport, baud)
                if early is not None:
                    self._good_baud = baud
                    self._connected_at(transport, baud)
                    self._event(ReceiverEventKind.BAUD_DETECTED, f"answers at {baud} Bd", baud=baud)
                    return transport, early
        except DeviceError:
            transport.close()
            raise
        transport.close()
        raise DeviceError(f"NovAtel receiver {self.name} on {s.port}: no NovAtel answer at any of {candidates} Bd")

    def _probe(self, transport: SerialTransport, baud: int) -> list[tuple[int, bytes]] | None:
        """Listen at one baud rate after a line break; the chunks read if a valid frame came."""
        transport.set_baud(baud)
        transport.reset_input()
        transport.write(b"\r\n")
        probe = Framer(max_frame_len=self.settings.max_frame_len)
        chunks: list[tuple[int, bytes]] = []
        deadline = time.monotonic() + self.settings.autobaud_probe_s
        while time.monotonic() < deadline and not self._stop.is_set():
            data = transport.read_available()
            if not data:
                continue
            chunks.append((self._clock.now_ns(), data))
            if any(f.kind in _PROOF_KINDS for f in probe.feed(data)):
                return chunks
        log.debug("NovAtel receiver %s: no answer at %d Bd", self.name, baud)
        return None

    def _connected_at(self, transport: SerialTransport, baud: int) -> None:
        now = self._clock.now_ns()
        gap = None
        with self._state_lock:
            self._transport = transport
            self._connection += 1
            self._connected = True
            self._baud = baud
            if self._lost_at_ns is not None:
                gap = now - self._lost_at_ns
                self._last_gap_ns = gap
                self._total_gap_ns += gap
                self._lost_at_ns = None
        self._configured.clear()
        self._config_done.clear()
        msg = f"connected at {baud} Bd" + (f" after a gap of {gap / 1e9:.3f} s" if gap is not None else "")
        self._event(ReceiverEventKind.CONNECTED, msg, gap_ns=gap, baud=baud, host_ns=now)

    def _session(self, transport: SerialTransport, early: list[tuple[int, bytes]]) -> None:
        for host_ns, data in early:
            self._deliver(host_ns, data, self._framer.feed(data))
        self._configure(transport)
        while not self._stop.is_set():
            self._serve_requests(transport)
            self._read_once(transport)
            why = self._reset_seen()
            if why is not None:
                self._resets += 1
                self._event(ReceiverEventKind.RESET, f"{why}: configuring it again")
                self._configure(transport)

    def _reset_seen(self) -> str | None:
        """Why the receiver looks reset behind an open port (None: it does not): a log's time status fell back
        from fine to coarse time, or no log came for ``silence_reconfigure_s`` since the last log or the
        last configuration pass (so a pass the resetting receiver did not answer is tried again)."""
        s = self.settings
        if not s.commands:
            return None
        with self._state_lock:
            why, self._reset_why = self._reset_why, None
            last = max(self._last_log_ns or 0, self._last_config_ns)
        if why is not None or s.silence_reconfigure_s is None:
            return why
        silent_ns = self._clock.now_ns() - last
        if silent_ns < s.silence_reconfigure_s * 1e9:
            return None
        return f"no log for {silent_ns / 1e9:.1f} s with the port open (a reset drops unsaved logs)"

    def _configure(self, transport: SerialTransport) -> None:
        with self._state_lock:
            self._last_config_ns = self._clock.now_ns()
            self._best_time_status = None
        errors: list[RigError] = []
        for command in self.settings.commands:
            try:
                self._exchange(transport, command, time.monotonic() + self.settings.command_timeout_s)
            except CommandTimeoutError as exc:
                errors.append(exc)
                break  # the receiver does not answer: sending the rest would only time out too
            except CommandError as exc:
                errors.append(exc)
        self._config_errors = tuple(errors)
        if errors:
            self._event(
                ReceiverEventKind.CONFIGURATION_FAILED,
                f"{len(errors)} of {len(self.settings.commands)} configuration commands failed",
                error=errors[0],
            )
        else:
            self._configured.set()
            self._event(ReceiverEventKind.CONFIGURED, f"{len(self.settings.commands)} commands answered <OK")
        self._config_done.set()

    def _exchange(self, transport: SerialTransport, command: str, deadline: float) -> Response:
        """Write one command and read (delivering everything) until its response or the deadline."""
        where = f"NovAtel receiver {self.name} on {self.settings.port}: command {command!r}"
        self._inbox.clear()
        self._exchanging = True
        try:
            transport.write(command.encode("ascii", errors="replace") + b"\r\n")
            while True:
                if self._inbox:
                    response = self._inbox.popleft()
                    break
                if self._stop.is_set():
                    raise _StoppedError
                if time.monotonic() >= deadline:
                    self._command_failures += 1
                    error = CommandTimeoutError(f"{where}: no <OK or <ERROR within {self.settings.command_timeout_s} s")
                    self._event(ReceiverEventKind.COMMAND_FAILED, str(error), command=command, error=error)
                    raise error
                self._read_once(transport)
        finally:
            self._exchanging = False
        if not response.ok:
            self._command_failures += 1
            rejected = CommandError(f"{where} answered <ERROR:{response.text}")
            self._event(ReceiverEventKind.COMMAND_FAILED, str(rejected), command=command, error=rejected)
            raise rejected
        return response

    def _serve_requests(self, transport: SerialTransport) -> None:
        while True:
            try:
                request = self._requests.get_nowait()
            except queue.Empty:
                return
            if request.cancelled:
                continue
            try:
                request.response = self._exchange(transport, request.command, request.deadline)
            except CommandError as exc:
                request.error = exc
            except DeviceError as exc:  # port lost: the session reconnects
                request.error = exc
                raise
            except _StoppedError:
                request.error = DeviceError(
                    f"NovAtel receiver {self.name} on {self.settings.port}: stopped during {request.command!r}"
                )
                raise
            finally:
                request.done.set()

    def _fail_requests(self, why: str) -> None:
        while True:
            try:
                request = self._requests.get_nowait()
            except queue.Empty:
                return
            request.error = DeviceError(
                f"NovAtel receiver {self.name} on {self.settings.port}: command {request.command!r} not sent: {why}"
            )
            request.done.set()

    def _read_once(self, transport: SerialTransport) -> None:
        data = transport.read_available()
        if data:
            host_ns = self._clock.now_ns()
            self._deliver(host_ns, data, self._framer.feed(data))
        else:
            frames = self._framer.flush()  # a read timeout ends a pending abbreviated log
            if frames:
                self._deliver(self._clock.now_ns(), b"", frames)

    def _deliver(self, host_ns: int, data: bytes, frames: tuple[Frame, ...]) -> None:
        with self._state_lock:
            if data:
                self._last_rx_ns = host_ns
            for frame in frames:
                self._rates.add(_message_key(frame), host_ns)
                if frame.kind not in _ANSWER_KINDS:  # the receiver's own output (logs, RTCM3, NMEA): alive
                    self._last_log_ns = host_ns
                message = frame.message
                if isinstance(message, Log):
                    status = getattr(message.header, "time_status", None)  # short headers carry none
                    if status is not None:
                        self._watch_time_status(status)
                    body = message.body
                    if isinstance(body, BestPos):
                        self._last_bestpos = body
                    elif isinstance(body, Time):
                        self._leap_seconds = body.leap_seconds
            connection = self._connection
        for frame in frames:
            if isinstance(frame.message, Response):
                if self._exchanging:
                    self._inbox.append(frame.message)
                else:
                    self._unsolicited += 1
        if self._on_data is not None:
            chunk = ReceivedChunk(self.name, host_ns, data, tuple(frames), connection)
            try:
                self._on_data(chunk)
            except Exception as exc:  # a consumer bug must not end the session: log it loudly, report it
                self._callback_failures += 1
                log.exception("NovAtel receiver %s: data consumer failed", self.name)
                self._event(
                    ReceiverEventKind.CALLBACK_FAILED,
                    f"data consumer raised {type(exc).__name__}: {exc}",
                    error=DeviceError(f"NovAtel receiver {self.name}: data consumer raised {exc!r}"),
                )

    def _watch_time_status(self, status: TimeStatus) -> None:
        """Called under ``_state_lock``: a fall from fine time (FINE or better) to coarse time is a reset."""
        best = self._best_time_status
        if best is None or status >= best:
            self._best_time_status = status
        elif best >= TimeStatus.FINE > status:
            self._reset_why = f"time status fell from {best.name} to {status.name}"
            self._best_time_status = status

    def _lost(self, transport: SerialTransport, exc: DeviceError) -> None:
        now = self._clock.now_ns()
        with self._state_lock:
            self._connected = False
            self._disconnects += 1
            self._lost_at_ns = now
            self._transport = None
        self._configured.clear()
        self._config_done.clear()
        self._fail_requests("port lost")
        self._event(ReceiverEventKind.DISCONNECTED, f"port lost: {exc}", error=exc, host_ns=now)

    def _close(self, transport: SerialTransport) -> None:
        with self._state_lock:
            if self._transport is transport:
                self._transport = None
            self._connected = False
        transport.close()
        frames = self._framer.finish()  # a frame cut by the loss is counted as truncated
        if frames:
            self._deliver(self._clock.now_ns(), b"", frames)

    def _event(
        self,
        kind: ReceiverEventKind,
        message: str,
        *,
        command: str | None = None,
        error: RigError | None = None,
        gap_ns: int | None = None,
        baud: int | None = None,
        host_ns: int | None = None,
    ) -> None:
        event = ReceiverEvent(
            kind=kind,
            receiver=self.name,
            port=self.settings.port,
            host_ns=self._clock.now_ns() if host_ns is None else host_ns,
            message=message,
            connection=self._connection,
            command=command,
            error=error,
            gap_ns=gap_ns,
            baud=baud,
        )
        level = logging.INFO if kind in (ReceiverEventKind.CONNECTED, ReceiverEventKind.CONFIGURED) else logging.WARNING
        if kind is ReceiverEventKind.STOPPED:
            level = logging.DEBUG
        log.log(level, "NovAtel receiver %s on %s: %s: %s", self.name, self.settings.port, kind.value, message)
        if self._on_event is not None:
            try:
                self._on_event(event)
            except Exception:  # same reasoning as the data consumer; nothing to report it to but the log
                log.exception("NovAtel receiver %s: event consumer failed", self.name)


def frames_of(chunks: Iterable[ReceivedChunk]) -> list[Frame]:
    """All frames of a sequence of chunks, in order (a helper for consumers and tests)."""
    return [frame for chunk in chunks for frame in chunk.frames]
