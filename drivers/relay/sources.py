"""Correction sources: serial port, NTRIP caster (v1/v2), TCP peer, capture file, in-process feed.

A :class:`Source` is driven by one thread (the relay's reader):

- ``open(stop)`` connects; it may wait, but returns early once ``stop`` is set;
- ``read(timeout_s)`` returns the bytes that arrived (as soon as any arrive) or ``b""`` after
  ``timeout_s``; it raises :class:`EndOfStream` when a finite source (a file) is exhausted and an
  ``OSError`` (:class:`~vsccore.errors.DeviceError`) when the connection is lost;
- ``close()`` releases it; the relay may ``open`` it again (reconnect).

Errors that retrying cannot cure (:class:`~vsccore.errors.NtripAuthError`,
:class:`~vsccore.errors.NtripMountpointError`, :class:`~vsccore.errors.ConfigError`) are listed
in :data:`FATAL_SOURCE_ERRORS`; the relay stops on them instead of retrying.

No source ever puts a password in a log record, an exception or its ``repr``.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import select
import socket
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from typing import IO

import serial

from drivers.relay.endpoints import (
    DEFAULT_NTRIP_PASSWORD_ENV,
    DEFAULT_NTRIP_USER_ENV,
    FileEndpoint,
    NtripEndpoint,
    RedactedEndpoint,
    SerialEndpoint,
    TcpEndpoint,
    parse_endpoint,
)
from drivers.relay.ntrip import (
    ChunkedDecoder,
    NtripResponse,
    ResponseKind,
    build_gga,
    build_request,
    parse_response_head,
    parse_sourcetable,
)
from vsccore import __version__
from vsccore.clock import Clock, SystemClock
from vsccore.errors import (
    ConfigError,
    DecodeError,
    DeviceError,
    DeviceTimeoutError,
    NtripAuthError,
    NtripError,
    NtripMountpointError,
)

__all__ = [
    "DEFAULT_BAUD",
    "FATAL_SOURCE_ERRORS",
    "EndOfStream",
    "FileSource",
    "GgaProvider",
    "NtripSource",
    "PushSource",
    "SerialSource",
    "Source",
    "TcpSource",
    "open_source",
]

log = logging.getLogger(__name__)

DEFAULT_BAUD = 115200
READ_SIZE = 65536
#: Errors on which the relay stops instead of reconnecting.
FATAL_SOURCE_ERRORS: tuple[type[BaseException], ...] = (NtripAuthError, NtripMountpointError, ConfigError)

#: A position for GGA upload: () -> (latitude deg, longitude deg, height m) or None when unknown.
GgaProvider = Callable[[], tuple[float, float, float] | None]


class EndOfStream(Exception):  # noqa: N818 - a signal, not an error
    """A finite source (a capture file) has no more data."""


class Source(ABC):
    """A byte source for the relay (see the module doc for the contract)."""

    finite = False
    """True for a source that ends (a capture read as fast as it goes): the relay then waits for
    the sinks instead of dropping (backpressure); a live source never waits for a sink."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._stop = threading.Event()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"

    @abstractmethod
    def open(self, stop: threading.Event | None = None) -> None:
        """Connect (``stop`` set → give up waiting)."""

    @abstractmethod
    def read(self, timeout_s: float) -> bytes:
        """The bytes that arrived, or ``b""`` after ``timeout_s``."""

    @abstractmethod
    def close(self) -> None:
        """Release the connection (idempotent)."""


def _wait_readable(fd: int, timeout_s: float) -> bool:
    readable, _, _ = select.select([fd], [], [], max(0.0, timeout_s))
    return bool(readable)


class SerialSource(Source):
    """A serial port (a base receiver or radio modem); raw reads, returned as soon as bytes arrive."""

    def __init__(self, endpoint: SerialEndpoint) -> None:
        super().__init__(endpoint.display)
        self.endpoint = endpoint
        self._port: serial.Serial | None = None

    def open(self, stop: threading.Event | None = None) -> None:
        self.close()
        try:
            self._port = serial.Serial(self.endpoint.path, self.endpoint.baud or DEFAULT_BAUD, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"relay source {self.name}: cannot open serial port: {exc}") from None

    def read(self, timeout_s: float) -> bytes:
        port = self._port
        if port is None:
            raise DeviceError(f"relay source {self.name}: serial port is not open")
        fd = port.fileno()
        try:
            if not _wait_readable(fd, timeout_s):
                return b""
            data = os.read(fd, READ_SIZE)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise DeviceError(f"relay source {self.name}: serial port lost: {exc}") from None
        if not data:
            raise DeviceError(f"relay source {self.name}: serial port lost (readable but no data: unplugged?)")
        return data

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, serial.SerialException):
                log.debug("relay source %s: error closing serial port", self.name, exc_info=True)


class _SocketSource(Source):
    """Common socket handling of the TCP and NTRIP sources."""

    connect_timeout_s = 5.0

    def __init__(self, name: str, host: str, port: int) -> None:
        super().__init__(name)
        self._host = host
        self._port_no = port
        self._sock: socket.socket | None = None

    def _connect(self) -> socket.socket:
        self.close()
        try:
            sock = socket.create_connection((self._host, self._port_no), timeout=self.connect_timeout_s)
        except OSError as exc:
            raise DeviceError(f"relay source {self.name}: cannot connect: {exc}") from None
        sock.setblocking(False)
        self._sock = sock
        return sock

    def _recv(self, timeout_s: float) -> bytes:
        sock = self._sock
        if sock is None:
            raise DeviceError(f"relay source {self.name}: not connected")
        try:
            if not _wait_readable(sock.fileno(), timeout_s):
                return b""
            data = sock.recv(READ_SIZE)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise DeviceError(f"relay source {self.name}: connection lost: {exc}") from None
        if not data:
            raise DeviceError(f"relay source {self.name}: connection closed by the peer")
        return data

    def _send(self, data: bytes, timeout_s: float = 2.0) -> None:
        sock = self._sock
        if sock is None:
            raise DeviceError(f"relay source {self.name}: not connected")
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        try:
            while view:
                _, writable, _ = select.select([], [sock.fileno()], [], max(0.0, deadline - time.monotonic()))
                if not writable:
                    raise DeviceTimeoutError(f"relay source {self.name}: send timed out")
                n = sock.send(view)
                view = view[n:]
        except BlockingIOError:
            raise DeviceTimeoutError(f"relay source {self.name}: send would block") from None
        except OSError as exc:
            if isinstance(exc, DeviceTimeoutError):
                raise
            raise DeviceError(f"relay source {self.name}: connection lost while sending: {exc}") from None

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                log.debug("relay source %s: error closing socket", self.name, exc_info=True)


class TcpSource(_SocketSource):
    """A raw TCP stream (e.g. a radio bridge or ``str2str`` TCP server)."""

    def __init__(self, endpoint: TcpEndpoint) -> None:
        super().__init__(endpoint.display, endpoint.host, endpoint.port)
        self.endpoint = endpoint

    def open(self, stop: threading.Event | None = None) -> None:
        self._connect()

    def read(self, timeout_s: float) -> bytes:
        return self._recv(timeout_s)


class NtripSource(_SocketSource):
    """NTRIP 1.0/2.0 client for one mountpoint, with periodic GGA upload for network (VRS) casters.

    Args:
        endpoint: caster, mountpoint, credentials (the password is a Secret), version.
        gga: position for GGA upload, or None to send none (single-base casters don't need it).
        gga_period_s: how often the GGA is sent (the first one right after connecting).
        clock: host clock, for the GGA time of day.
        head_timeout_s: how long to wait for the caster's answer.
    """

    def __init__(
        self,
        endpoint: NtripEndpoint,
        *,
        gga: GgaProvider | None = None,
        gga_period_s: float = 10.0,
        clock: Clock | None = None,
        head_timeout_s: float = 10.0,
    ) -> None:
        super().__init__(endpoint.display, endpoint.host, endpoint.port)
        if gga_period_s <= 0:
            raise ConfigError(f"relay source {endpoint.display}: gga_period_s must be > 0")
        self.endpoint = endpoint
        self._gga = gga
        self._gga_period_ns = int(gga_period_s * 1e9)
        self._clock = clock or SystemClock()
        self._head_timeout_s = head_timeout_s
        self._pending = b""
        self._chunked: ChunkedDecoder | None = None
        self._next_gga_ns = 0
        self.gga_sent = 0
        self.response_version: int | None = None

    @property
    def _where(self) -> str:
        e = self.endpoint
        return f"NTRIP caster {e.host}:{e.port} mountpoint {e.mountpoint!r}"

    def _gga_sentence(self) -> str | None:
        if self._gga is None:
            return None
        pos = self._gga()
        if pos is None:
            return None
        sod = (self._clock.now_ns() // 1_000_000) % 86_400_000 / 1000.0
        try:
            return build_gga(pos[0], pos[1], pos[2], utc_seconds_of_day=sod)
        except ValueError as exc:
            log.warning("relay source %s: no GGA sent: %s", self.name, exc)
            return None

    def _request(self, mountpoint: str, gga: str | None) -> bytes:
        e = self.endpoint
        return build_request(
            e.host,
            e.port,
            mountpoint,
            user=e.user,
            password=e.password.reveal() if e.password is not None else None,
            version=e.version,
            gga=gga,
            agent_version=__version__,
        )

    def _read_head(self, stop: threading.Event | None) -> tuple[bytes, NtripResponse]:
        deadline = time.monotonic() + self._head_timeout_s
        buf = b""
        while True:
            if stop is not None and stop.is_set():
                raise DeviceError(f"relay source {self.name}: stopped while waiting for the caster")
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeoutError(f"{self._where}: no answer within {self._head_timeout_s:g} s")
            eof = False
            try:
                buf += self._recv(min(left, 0.2))
            except DeviceError:
                if not buf:
                    raise
                eof = True  # e.g. str2str: a bare "HTTP/1.0 401 Unauthorized" line, then close
            try:
                head = parse_response_head(buf, eof=eof)
            except DecodeError as exc:
                raise NtripError(f"{self._where}: {exc}") from None
            if head is not None:
                return buf, head
            if eof:
                raise NtripError(f"{self._where}: the caster closed the connection in its answer's head")

    def _read_until_close(self, buf: bytes, stop: threading.Event | None, limit: int = 1 << 20) -> bytes:
        deadline = time.monotonic() + self._head_timeout_s
        while b"ENDSOURCETABLE" not in buf and len(buf) < limit and time.monotonic() < deadline:
            if stop is not None and stop.is_set():
                break
            try:
                buf += self._recv(0.2)
            except DeviceError:
                break  # the caster closes after the table
        return buf

    def _sourcetable_names(self, stop: threading.Event | None) -> list[str]:
        """Mountpoints the caster lists (a separate request for the table)."""
        try:
            self._connect()
            self._send(self._request("", None))
            buf, head = self._read_head(stop)
            text = self._table_text(buf, head, stop)
        except OSError:
            return []
        finally:
            self.close()
        return [entry.mountpoint for entry in parse_sourcetable(text)]

    def _table_text(self, buf: bytes, head: NtripResponse, stop: threading.Event | None) -> str:
        try:
            body = self._read_until_close(buf[head.body_start :], stop)
        finally:
            self.close()
        if head.chunked:
            with contextlib.suppress(DecodeError):
                body = ChunkedDecoder().feed(body)
        return body.decode("latin-1", "replace")

    def open(self, stop: threading.Event | None = None) -> None:
        e = self.endpoint
        gga = self._gga_sentence()
        self._connect()
        self._pending = b""
        self._chunked = None
        try:
            self._send(self._request(e.mountpoint, gga))
            buf, head = self._read_head(stop)
        except BaseException:
            self.close()
            raise
        if head.kind is ResponseKind.DATA:
            self.response_version = head.version
            body = buf[head.body_start :]
            if head.chunked:
                self._chunked = ChunkedDecoder()
                body = self._chunked.feed(body)
            self._pending = body
            log.info("relay source %s: connected (NTRIP %d answer)", self.name, head.version)
            self._next_gga_ns = time.monotonic_ns()
            if gga is not None and e.version == 2:
                self._next_gga_ns += self._gga_period_ns  # the request header carried the first one
                self.gga_sent += 1
            self._maybe_send_gga()
            return
        user = "no user" if e.user is None else f"user {e.user!r}"
        if head.kind in (ResponseKind.UNAUTHORIZED, ResponseKind.FORBIDDEN):
            self.close()
            raise NtripAuthError(
                f"{self._where}: credentials refused for {user} ({head.status_line[:80]!r}); "
                f"check the user name and the password (in the URL or {DEFAULT_NTRIP_PASSWORD_ENV})"
            )
        if head.kind is ResponseKind.SOURCETABLE:
            names = [m.mountpoint for m in parse_sourcetable(self._table_text(buf, head, stop))]
        elif head.kind is ResponseKind.NOT_FOUND:
            self.close()
            names = self._sourcetable_names(stop)
        else:
            self.close()
            raise NtripError(f"{self._where}: caster answered {head.status_line[:80]!r}")
        listed = ", ".join(names) if names else "none"
        raise NtripMountpointError(f"{self._where}: no such mountpoint; the caster's source table lists: {listed}")

    def _maybe_send_gga(self) -> None:
        if self._gga is None or time.monotonic_ns() < self._next_gga_ns:
            return
        self._next_gga_ns = time.monotonic_ns() + self._gga_period_ns
        sentence = self._gga_sentence()
        if sentence is None:
            return
        self._send((sentence + "\r\n").encode("ascii"))
        self.gga_sent += 1
        log.debug("relay source %s: GGA sent", self.name)

    def read(self, timeout_s: float) -> bytes:
        if self._pending:
            data, self._pending = self._pending, b""
            return data
        self._maybe_send_gga()
        if self._gga is not None:
            timeout_s = min(timeout_s, max(0.0, (self._next_gga_ns - time.monotonic_ns()) / 1e9))
        data = self._recv(timeout_s)
        if data and self._chunked is not None:
            try:
                data = self._chunked.feed(data)
            except DecodeError as exc:
                raise NtripError(f"{self._where}: {exc}") from None
            if self._chunked.done:
                raise DeviceError(f"{self._where}: the caster ended the stream")
        return data


class FileSource(Source):
    """A capture file, read as fast as it goes or paced at a line rate (``file:PATH@BAUD``).

    Args:
        endpoint: path and optional baud (10 bits a byte, as an 8N1 serial line).
        clock: the clock that paces the replay (inject a fast one in tests).
        chunk_size: bytes per read when not paced.
    """

    def __init__(self, endpoint: FileEndpoint, *, clock: Clock | None = None, chunk_size: int = 4096) -> None:
        super().__init__(endpoint.display)
        self.endpoint = endpoint
        self.finite = endpoint.baud is None  # a paced replay stands in for a live port
        self._clock = clock or SystemClock()
        self._chunk_size = chunk_size
        self._file: IO[bytes] | None = None
        self._sent = 0
        self._t0_ns = 0
        self._stop_event: threading.Event | None = None

    def open(self, stop: threading.Event | None = None) -> None:
        self.close()
        try:
            self._file = open(self.endpoint.path, "rb")  # noqa: SIM115 - closed by close()
        except OSError as exc:
            raise ConfigError(f"relay source {self.name}: cannot open capture file: {exc.strerror}") from None
        self._sent = 0
        self._t0_ns = self._clock.now_ns()
        self._stop_event = stop

    def read(self, timeout_s: float) -> bytes:
        f = self._file
        if f is None:
            raise DeviceError(f"relay source {self.name}: file is not open")
        baud = self.endpoint.baud
        if baud is None:
            data = f.read(self._chunk_size)
        else:
            bytes_per_s = baud / 10.0
            size = max(1, min(self._chunk_size, int(bytes_per_s * 0.01)))  # about 10 ms of data
            due = self._t0_ns + int(self._sent / bytes_per_s * 1e9)
            now = self._clock.now_ns()
            if due > now:
                limit = now + int(timeout_s * 1e9)
                if due > limit:
                    self._clock.sleep_until_ns(limit, self._stop_event)
                    return b""
                if not self._clock.sleep_until_ns(due, self._stop_event):
                    return b""
            data = f.read(size)
        if not data:
            raise EndOfStream(self.name)
        self._sent += len(data)
        return data

    def close(self) -> None:
        f, self._file = self._file, None
        if f is not None:
            f.close()


class PushSource(Source):
    """Bytes handed over in-process (e.g. by the receiver session that owns the base's port).

    :meth:`feed` never blocks; beyond ``max_chunks`` waiting chunks the oldest are dropped and
    counted in ``dropped_chunks``. :meth:`end` makes the relay finish after the queued bytes.
    """

    def __init__(self, name: str, *, max_chunks: int = 4096) -> None:
        super().__init__(name)
        self._queue: collections.deque[bytes | None] = collections.deque()
        self._cond = threading.Condition()
        self._max = max_chunks
        self.dropped_chunks = 0

    def feed(self, data: bytes) -> None:
        if not data:
            return
        with self._cond:
            if len(self._queue) >= self._max:
                self._queue.popleft()
                self.dropped_chunks += 1
            self._queue.append(bytes(data))
            self._cond.notify()

    def end(self) -> None:
        with self._cond:
            self._queue.append(None)
            self._cond.notify()

    def open(self, stop: threading.Event | None = None) -> None:
        return None

    def read(self, timeout_s: float) -> bytes:
        with self._cond:
            if not self._queue and not self._cond.wait(timeout_s):
                return b""
            if not self._queue:
                return b""
            first = self._queue.popleft()
            if first is None:
                raise EndOfStream(self.name)
            parts = [first]
            while self._queue and self._queue[0] is not None:
                item = self._queue.popleft()
                assert item is not None
                parts.append(item)
        return b"".join(parts)

    def close(self) -> None:
        return None


def open_source(
    text: str | RedactedEndpoint,
    *,
    env: Mapping[str, str] | None = None,
    user_env: str = DEFAULT_NTRIP_USER_ENV,
    password_env: str = DEFAULT_NTRIP_PASSWORD_ENV,
    gga: GgaProvider | None = None,
    gga_period_s: float = 10.0,
    clock: Clock | None = None,
) -> Source:
    """A source from an endpoint string (``/dev/ttyUSB0@115200``, ``ntrip://…``, ``tcp://…``, ``file:…``).

    Raises:
        ConfigError: the string is not a valid source (password masked in the message).
    """
    ep = parse_endpoint(text, env=env, user_env=user_env, password_env=password_env)
    if isinstance(ep, SerialEndpoint):
        return SerialSource(ep)
    if isinstance(ep, TcpEndpoint):
        return TcpSource(ep)
    if isinstance(ep, FileEndpoint):
        return FileSource(ep, clock=clock)
    return NtripSource(ep, gga=gga, gga_period_s=gga_period_s, clock=clock)
