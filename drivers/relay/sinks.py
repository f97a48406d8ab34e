"""Correction sinks: each with its own worker thread and bounded queue of whole frames.

:meth:`Sink.offer` never blocks the caller (the relay's reader): it appends the frame to the
sink's queue and, when the queue is full, drops the *oldest* queued frame and counts it. The
worker writes one frame at a time and never interleaves two, so a frame written in parts still
arrives whole. A slow, full or unplugged sink therefore only loses its own (oldest) frames and
never delays another sink. On a write error the worker closes the port, counts the frame it was
writing as dropped, and reopens with back-off (waiting on its stop event); frames that waited
longer than ``max_age_s`` are dropped as stale instead of being written late.

Transports: :class:`SerialSink` (``os.write`` on the non-blocking fd with ``select``, so a rover
that stops reading only stalls this worker), :class:`TcpSink`, :class:`FileSink` (append) and
:class:`CallbackSink` (a port owned by someone else, e.g. a receiver session).
"""

from __future__ import annotations

import collections
import logging
import os
import select
import socket
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import IO

import serial

from drivers.relay.endpoints import FileEndpoint, NtripEndpoint, SerialEndpoint, TcpEndpoint, parse_endpoint
from drivers.relay.sources import DEFAULT_BAUD
from vsccore.errors import ConfigError, DeviceError, RigError

__all__ = [
    "Backoff",
    "CallbackSink",
    "FileSink",
    "SerialSink",
    "Sink",
    "SinkStats",
    "TcpSink",
    "open_sink",
]

log = logging.getLogger(__name__)

WRITE_WAIT_S = 0.1  # longest a worker waits in one write, so stop() is prompt
_NEVER_STALE = -1  # queue time of a frame from a finite source (never dropped as stale)


@dataclass(frozen=True, slots=True)
class Backoff:
    """Reconnect back-off: ``initial_s``, times ``factor`` after each failure, at most ``max_s``."""

    initial_s: float = 0.5
    max_s: float = 10.0
    factor: float = 2.0

    def delays(self) -> collections.abc.Iterator[float]:
        delay = self.initial_s
        while True:
            yield delay
            delay = min(self.max_s, delay * self.factor)


@dataclass(frozen=True, slots=True)
class SinkStats:
    """Counters of one sink (frames unless said otherwise)."""

    name: str
    connected: bool
    queue_depth: int
    queue_max: int
    frames_out: int
    bytes_out: int
    dropped: int
    """Dropped because the queue was full (the oldest go first)."""
    dropped_stale: int
    """Dropped because they waited longer than ``max_age_s``."""
    dropped_disconnect: int
    """Frames being written when the port failed."""
    reconnects: int
    last_error: str | None
    dropped_at_stop: int = 0
    """Frames still queued when the sink was stopped (never written)."""

    @property
    def dropped_total(self) -> int:
        return self.dropped + self.dropped_stale + self.dropped_disconnect + self.dropped_at_stop


class Sink(ABC):
    """A correction sink with its own worker thread and bounded queue.

    Args:
        name: shown in statistics, logs and errors (no credentials).
        queue_frames: queue bound (frames).
        max_age_s: frames older than this when their turn comes are dropped (None: never).
        backoff: reconnect delays.
    """

    def __init__(
        self,
        name: str,
        *,
        queue_frames: int = 256,
        max_age_s: float | None = 10.0,
        backoff: Backoff | None = None,
    ) -> None:
        if queue_frames < 1:
            raise ConfigError(f"relay sink {name}: queue_frames must be >= 1, got {queue_frames}")
        self.name = name
        self._max = queue_frames
        self._max_age_ns = None if max_age_s is None else int(max_age_s * 1e9)
        self._backoff = backoff or Backoff()
        self._queue: collections.deque[tuple[int, bytes]] = collections.deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._idle = threading.Event()  # queue empty and no frame in the writer's hands
        self._idle.set()
        self.connected = threading.Event()
        """Set while the transport is open."""
        self._state_cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._frames_out = 0
        self._bytes_out = 0
        self._dropped = 0
        self._dropped_stale = 0
        self._dropped_disconnect = 0
        self._dropped_at_stop = 0
        self._reconnects = 0
        self._opened_once = False
        self._last_error: str | None = None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    # --- transport hooks (called from the worker thread only) ----------------------------

    @abstractmethod
    def _open(self) -> None:
        """Open the transport; raise OSError/RigError when it is not there."""

    @abstractmethod
    def _write(self, data: memoryview, timeout_s: float) -> int:
        """Write some of ``data``; return the count (0 if not writable within ``timeout_s``).

        Raise OSError when the transport is gone.
        """

    @abstractmethod
    def _close(self) -> None:
        """Close the transport (idempotent)."""

    # --- public API -----------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError(f"relay sink {self.name} already started")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"relay-sink-{self.name}", daemon=True)
        self._thread.start()

    def offer(self, frame: bytes, t_ns: int | None = None) -> None:
        """Queue a whole frame (never blocks; drops the oldest queued frame when full)."""
        item = (time.monotonic_ns() if t_ns is None else t_ns, frame)
        with self._cond:
            if len(self._queue) >= self._max:
                self._queue.popleft()
                self._dropped += 1
            self._queue.append(item)
            self._idle.clear()
            self._cond.notify_all()

    def put(self, frame: bytes, stop: threading.Event | None = None) -> bool:
        """Queue a whole frame, waiting while the queue is full (backpressure for a finite source,
        which must lose nothing). The frame is never dropped as stale. False (frame not queued) if
        ``stop`` or the sink's own stop is set while waiting."""
        with self._cond:
            while len(self._queue) >= self._max:
                if self._stop.is_set() or (stop is not None and stop.is_set()):
                    return False
                self._cond.wait(0.1)
            self._queue.append((_NEVER_STALE, frame))
            self._idle.clear()
            self._cond.notify_all()
        return True

    def wait_connected(self, connected: bool = True, timeout_s: float = 5.0) -> bool:
        """Wait until the transport is open (``connected``) or closed; True if it happened in time."""
        with self._state_cond:
            return self._state_cond.wait_for(lambda: self.connected.is_set() == connected, timeout_s)

    def _set_connected(self, connected: bool) -> None:
        with self._state_cond:
            if connected:
                self.connected.set()
            else:
                self.connected.clear()
            self._state_cond.notify_all()

    def drain(self, timeout_s: float) -> bool:
        """Wait until every queued frame is written or dropped; True if it happened in time."""
        return self._idle.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0, *, drain_s: float = 0.0) -> None:
        """Stop the worker (after writing what is queued, for up to ``drain_s``) and close the port."""
        if drain_s > 0 and self._thread is not None and self._thread.is_alive():
            self.drain(drain_s)
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("relay sink %s: worker did not stop within %.1f s", self.name, timeout_s)

    def stats(self) -> SinkStats:
        with self._cond:
            return SinkStats(
                self.name,
                self.connected.is_set(),
                len(self._queue),
                self._max,
                self._frames_out,
                self._bytes_out,
                self._dropped,
                self._dropped_stale,
                self._dropped_disconnect,
                self._reconnects,
                self._last_error,
                self._dropped_at_stop,
            )

    # --- worker ---------------------------------------------------------------------------

    def _note_error(self, what: str, exc: BaseException) -> None:
        text = f"{what}: {exc}"
        if text != self._last_error:
            log.warning("relay sink %s: %s", self.name, text)
        self._last_error = text

    def _next(self) -> tuple[int, bytes] | None:
        with self._cond:
            if not self._queue:
                self._idle.set()
                self._cond.wait(0.5)
            if not self._queue:
                return None
            item = self._queue.popleft()
            self._cond.notify_all()  # a producer waiting for room (put)
            return item

    def _run(self) -> None:
        delays = self._backoff.delays()
        is_open = False
        try:
            while not self._stop.is_set():
                if not is_open:
                    try:
                        self._open()
                    except (OSError, RigError, ValueError) as exc:
                        self._note_error("cannot open", exc)
                        self._stop.wait(next(delays))
                        continue
                    is_open = True
                    delays = self._backoff.delays()
                    if self._opened_once:
                        self._reconnects += 1
                        log.info("relay sink %s: reconnected", self.name)
                    self._opened_once = True
                    self._set_connected(True)
                item = self._next()
                if item is None:
                    continue
                t_ns, frame = item
                stale = self._max_age_ns is not None and time.monotonic_ns() - t_ns > self._max_age_ns
                if stale and t_ns != _NEVER_STALE:
                    with self._cond:
                        self._dropped_stale += 1
                    continue
                if not self._write_frame(frame):
                    is_open = False
                    self._close()
                    self._set_connected(False)
        finally:
            self._close()
            self._set_connected(False)
            with self._cond:
                self._dropped_at_stop += len(self._queue)
                self._queue.clear()
                self._cond.notify_all()
            self._idle.set()

    def _write_frame(self, frame: bytes) -> bool:
        """Write one whole frame; False if the transport failed (the frame is then dropped)."""
        view = memoryview(frame)
        done = 0
        total = len(frame)
        while done < total:
            if self._stop.is_set():
                with self._cond:
                    self._dropped += 1
                return True
            try:
                done += self._write(view[done:], WRITE_WAIT_S)
            except (OSError, RigError) as exc:
                self._note_error("write failed", exc)
                with self._cond:
                    self._dropped_disconnect += 1
                return False
        with self._cond:
            self._frames_out += 1
            self._bytes_out += total
        return True


def _write_fd(fd: int, data: memoryview, timeout_s: float) -> int:
    _, writable, _ = select.select([], [fd], [], timeout_s)
    if not writable:
        return 0
    try:
        return os.write(fd, data)
    except BlockingIOError:
        return 0


class SerialSink(Sink):
    """A rover's correction port (non-blocking writes: a rover that stops reading stalls only this sink)."""

    def __init__(
        self,
        endpoint: SerialEndpoint,
        *,
        queue_frames: int = 256,
        max_age_s: float | None = 10.0,
        backoff: Backoff | None = None,
    ) -> None:
        super().__init__(endpoint.display, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
        self.endpoint = endpoint
        self._port: serial.Serial | None = None

    def _open(self) -> None:
        self._close()
        try:
            self._port = serial.Serial(self.endpoint.path, self.endpoint.baud or DEFAULT_BAUD, timeout=0)
        except (serial.SerialException, ValueError) as exc:
            raise DeviceError(f"cannot open serial port {self.endpoint.path}: {exc}") from None

    def _write(self, data: memoryview, timeout_s: float) -> int:
        if self._port is None:
            raise DeviceError(f"serial port {self.endpoint.path} is not open")
        return _write_fd(self._port.fileno(), data, timeout_s)

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, serial.SerialException):
                log.debug("relay sink %s: error closing port", self.name, exc_info=True)


class TcpSink(Sink):
    """A TCP peer the relay connects to (e.g. a rover's Ethernet correction port)."""

    def __init__(
        self,
        endpoint: TcpEndpoint,
        *,
        connect_timeout_s: float = 5.0,
        queue_frames: int = 256,
        max_age_s: float | None = 10.0,
        backoff: Backoff | None = None,
    ) -> None:
        super().__init__(endpoint.display, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
        self.endpoint = endpoint
        self._connect_timeout_s = connect_timeout_s
        self._sock: socket.socket | None = None

    def _open(self) -> None:
        self._close()
        sock = socket.create_connection((self.endpoint.host, self.endpoint.port), timeout=self._connect_timeout_s)
        sock.setblocking(False)
        self._sock = sock

    def _write(self, data: memoryview, timeout_s: float) -> int:
        if self._sock is None:
            raise DeviceError(f"{self.name} is not connected")
        return _write_fd(self._sock.fileno(), data, timeout_s)

    def _close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()


class FileSink(Sink):
    """Appends the relayed frames to a file."""

    def __init__(
        self,
        endpoint: FileEndpoint,
        *,
        queue_frames: int = 256,
        max_age_s: float | None = 10.0,
        backoff: Backoff | None = None,
    ) -> None:
        super().__init__(endpoint.display, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
        self.endpoint = endpoint
        self._file: IO[bytes] | None = None

    def _open(self) -> None:
        self._close()
        self._file = open(self.endpoint.path, "ab", buffering=0)  # noqa: SIM115 - closed by _close()

    def _write(self, data: memoryview, timeout_s: float) -> int:
        if self._file is None:
            raise DeviceError(f"file {self.endpoint.path} is not open")
        return self._file.write(data) or 0

    def _close(self) -> None:
        f, self._file = self._file, None
        if f is not None:
            f.close()


class CallbackSink(Sink):
    """Hands each frame to ``write`` (a port owned by someone else, e.g. a receiver session).

    ``write`` is called from this sink's worker thread; it should raise OSError when its port
    is gone, so the frame is counted and the sink retries with back-off.
    """

    def __init__(
        self,
        name: str,
        write: Callable[[bytes], object],
        *,
        queue_frames: int = 256,
        max_age_s: float | None = 10.0,
        backoff: Backoff | None = None,
    ) -> None:
        super().__init__(name, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
        self._write_cb = write

    def _open(self) -> None:
        return None

    def _write(self, data: memoryview, timeout_s: float) -> int:
        self._write_cb(bytes(data))
        return len(data)

    def _close(self) -> None:
        return None


def open_sink(
    text: str,
    *,
    queue_frames: int = 256,
    max_age_s: float | None = 10.0,
    backoff: Backoff | None = None,
) -> Sink:
    """A sink from an endpoint string (serial port, ``tcp://host:port`` or ``file:PATH``).

    Raises:
        ConfigError: not a valid sink (an ``ntrip://`` URL is a source only).
    """
    ep = parse_endpoint(text, env={})
    if isinstance(ep, SerialEndpoint):
        return SerialSink(ep, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
    if isinstance(ep, TcpEndpoint):
        return TcpSink(ep, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
    if isinstance(ep, FileEndpoint):
        return FileSink(ep, queue_frames=queue_frames, max_age_s=max_age_s, backoff=backoff)
    assert isinstance(ep, NtripEndpoint)
    raise ConfigError(f"relay sink {ep.display!r}: an NTRIP caster can only be a source")
