"""A small NTRIP caster on 127.0.0.1 for tests and the desk demo (NTRIP 1.0 and 2.0 answers).

- Basic authentication per caster (``users``); wrong or missing credentials get ``401``.
- ``GET /`` or an unknown mountpoint gets the source table (``SOURCETABLE 200 OK`` for an
  NTRIP 1 request, ``HTTP/1.1 200 OK`` with ``Content-Type: gnss/sourcetable`` for NTRIP 2).
- A known mountpoint gets ``ICY 200 OK`` and the raw stream (NTRIP 1) or ``HTTP/1.1 200 OK``,
  ``Ntrip-Version: Ntrip/2.0`` and the stream in chunked transfer coding (NTRIP 2).
- NMEA sentences a client sends (GGA for network RTK) and ``Ntrip-GGA`` request headers are
  kept in :attr:`NtripCaster.gga_received`.

Data reach a :class:`Mountpoint` through :meth:`Mountpoint.publish` (live: a test, or a
:class:`SerialFeeder` reading a simulated base's pty) or a :class:`FileFeeder` replaying a
capture at a line rate. Every thread (acceptor, one per client, feeders) stops on :meth:`stop`
and is joined.
"""

from __future__ import annotations

import base64
import binascii
import collections
import contextlib
import logging
import os
import select
import socket
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass

import serial

from drivers.relay.ntrip import encode_chunk
from vsccore.errors import ConfigError, DeviceError

__all__ = ["FileFeeder", "GgaRecord", "Mountpoint", "NtripCaster", "SerialFeeder"]

log = logging.getLogger(__name__)

_CLIENT_QUEUE = 1024  # chunks per client before the oldest are dropped
_POLL_S = 0.1


@dataclass(frozen=True, slots=True)
class GgaRecord:
    """An NMEA sentence a client sent."""

    mountpoint: str
    user: str | None
    sentence: str
    via_header: bool


class _Client:
    """One connected data client (its queue is filled by the mountpoint, drained by its thread)."""

    def __init__(self, chunked: bool) -> None:
        self.chunked = chunked
        self.queue: collections.deque[bytes] = collections.deque(maxlen=_CLIENT_QUEUE)
        self.wake_r, self.wake_w = socket.socketpair()
        self.wake_r.setblocking(False)
        self.wake_w.setblocking(False)

    def push(self, data: bytes) -> None:
        self.queue.append(data)
        with contextlib.suppress(OSError):  # BlockingIOError: already awake; OSError: closing
            self.wake_w.send(b"x")

    def close(self) -> None:
        self.wake_r.close()
        self.wake_w.close()


class Mountpoint:
    """A caster mountpoint: everything published is sent to every client connected to it."""

    def __init__(self, name: str, *, identifier: str = "", fmt: str = "RTCM 3.3", details: str = "") -> None:
        self.name = name
        self.identifier = identifier or name
        self.format = fmt
        self.details = details or "1005(10),1077(1),1087(1),1230(10)"
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._client_count_changed = threading.Condition(self._lock)
        self.bytes_published = 0

    def publish(self, data: bytes) -> None:
        """Send ``data`` to every connected client (never blocks; a slow client drops its oldest)."""
        if not data:
            return
        with self._lock:
            clients = list(self._clients)
            self.bytes_published += len(data)
        for client in clients:
            client.push(bytes(data))

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def wait_for_clients(self, n: int, timeout_s: float) -> bool:
        """Wait until at least ``n`` clients are connected."""
        with self._client_count_changed:
            return self._client_count_changed.wait_for(lambda: len(self._clients) >= n, timeout_s)

    def _add(self, client: _Client) -> None:
        with self._client_count_changed:
            self._clients.append(client)
            self._client_count_changed.notify_all()

    def _remove(self, client: _Client) -> None:
        with self._client_count_changed:
            if client in self._clients:
                self._clients.remove(client)
            self._client_count_changed.notify_all()

    def str_record(self) -> str:
        return (
            f"STR;{self.name};{self.identifier};{self.format};{self.details};2;GPS+GLO+GAL+BDS;SIM;DEU;"
            "52.00;13.00;0;0;vsc-rig sim;none;B;N;2400;"
        )


class NtripCaster:
    """NTRIP 1/2 caster on 127.0.0.1 (``port=0`` picks a free port; see :attr:`port`).

    Args:
        users: user → password; empty means no authentication.
        host: address to listen on (loopback only for tests).
        port: TCP port, 0 for a free one.
    """

    def __init__(self, *, users: Mapping[str, str] | None = None, host: str = "127.0.0.1", port: int = 0) -> None:
        self._users = dict(users or {})
        self._host = host
        self._port = port
        self._mounts: dict[str, Mountpoint] = {}
        self._sock: socket.socket | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._gga_cond = threading.Condition()
        self.gga_received: list[GgaRecord] = []
        self.requests: list[tuple[str, int, str]] = []  # (mountpoint, NTRIP version, answer)
        self.unauthorized = 0

    # --- set-up ---------------------------------------------------------------------------

    def add_mountpoint(self, name: str, **kwargs: str) -> Mountpoint:
        if not name or "/" in name:
            raise ConfigError(f"caster mountpoint name {name!r} is invalid")
        mount = Mountpoint(name, **kwargs)
        self._mounts[name] = mount
        return mount

    def mountpoint(self, name: str) -> Mountpoint:
        return self._mounts[name]

    @property
    def port(self) -> int:
        if self._sock is None:
            raise DeviceError("NTRIP caster is not started")
        return int(self._sock.getsockname()[1])

    @property
    def host(self) -> str:
        return self._host

    def url(self, mountpoint: str, user: str | None = None, password: str | None = None, version: int = 2) -> str:
        """``ntrip://user:password@127.0.0.1:PORT/MOUNT`` (with ``?version=1`` for NTRIP 1)."""
        cred = "" if user is None else f"{user}:{password}@" if password is not None else f"{user}@"
        suffix = "?version=1" if version == 1 else ""
        return f"ntrip://{cred}{self._host}:{self.port}/{mountpoint}{suffix}"

    def sourcetable(self) -> str:
        lines = [m.str_record() for m in self._mounts.values()]
        lines.append("NET;SIM;vsc-rig;B;N;none;none;none;none;")
        return "\r\n".join(lines) + "\r\nENDSOURCETABLE\r\n"

    # --- lifecycle ------------------------------------------------------------------------

    def start(self) -> None:
        if self._sock is not None:
            raise RuntimeError("NTRIP caster already started")
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((self._host, self._port))
        sock.listen(16)
        sock.setblocking(False)
        self._sock = sock
        self._stop.clear()
        self._spawn(self._accept_loop, "ntrip-caster-accept")

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        deadline = time.monotonic() + timeout_s
        while True:  # the acceptor may spawn a client thread until it sees the stop flag
            with self._lock:
                threads = [t for t in self._threads if t.is_alive()]
            if not threads or time.monotonic() > deadline:
                break
            for t in threads:
                t.join(max(0.0, deadline - time.monotonic()))
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def __enter__(self) -> NtripCaster:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait_for_gga(self, n: int = 1, timeout_s: float = 5.0) -> bool:
        """Wait until at least ``n`` GGA sentences have arrived."""
        with self._gga_cond:
            return self._gga_cond.wait_for(
                lambda: sum(1 for g in self.gga_received if "GGA" in g.sentence[:7]) >= n, timeout_s
            )

    def _spawn(self, target: object, name: str, *args: object) -> None:
        t = threading.Thread(target=target, name=name, args=args, daemon=True)  # type: ignore[arg-type]
        with self._lock:
            self._threads = [x for x in self._threads if x.is_alive()]
            self._threads.append(t)
        t.start()

    # --- serving --------------------------------------------------------------------------

    def _accept_loop(self) -> None:
        sock = self._sock
        assert sock is not None
        while not self._stop.is_set():
            readable, _, _ = select.select([sock], [], [], _POLL_S)
            if not readable:
                continue
            try:
                conn, _ = sock.accept()
            except (BlockingIOError, OSError):
                continue
            conn.setblocking(False)
            self._spawn(self._serve, "ntrip-caster-client", conn)

    def _read_request(self, conn: socket.socket) -> tuple[bytes, bytes] | None:
        buf = b""
        deadline = time.monotonic() + 5.0
        while b"\r\n\r\n" not in buf and not self._stop.is_set() and time.monotonic() < deadline:
            readable, _, _ = select.select([conn], [], [], _POLL_S)
            if not readable:
                continue
            data = conn.recv(4096)
            if not data:
                return None
            buf += data
            if len(buf) > 16384:
                return None
        if b"\r\n\r\n" not in buf:
            return None
        head, _, rest = buf.partition(b"\r\n\r\n")
        return head, rest

    def _authorized(self, headers: Mapping[str, str]) -> str | bool | None:
        """The user name if the credentials are good, None if no auth is needed, False if refused."""
        if not self._users:
            return None
        value = headers.get("authorization", "")
        scheme, _, token = value.partition(" ")
        if scheme.lower() != "basic":
            return False
        try:
            user, _, password = base64.b64decode(token, validate=True).decode("utf-8").partition(":")
        except (binascii.Error, UnicodeDecodeError, ValueError):
            return False
        return user if self._users.get(user) == password else False

    def _serve(self, conn: socket.socket) -> None:
        try:
            self._serve_client(conn)
        except OSError as exc:
            log.debug("NTRIP caster: client connection ended: %s", exc)
        finally:
            conn.close()

    def _send_all(self, conn: socket.socket, data: bytes) -> bool:
        view = memoryview(data)
        while view:
            if self._stop.is_set():
                return False
            _, writable, _ = select.select([], [conn], [], _POLL_S)
            if not writable:
                continue
            try:
                n = conn.send(view)
            except BlockingIOError:
                continue
            view = view[n:]
        return True

    def _serve_client(self, conn: socket.socket) -> None:
        got = self._read_request(conn)
        if got is None:
            return
        head, rest = got
        lines = head.decode("latin-1").split("\r\n")
        parts = lines[0].split()
        if len(parts) < 3 or parts[0] != "GET":
            self._send_all(conn, b"HTTP/1.1 400 Bad Request\r\nConnection: close\r\n\r\n")
            return
        headers: dict[str, str] = {}
        for line in lines[1:]:
            name, sep, value = line.partition(":")
            if sep:
                headers[name.strip().lower()] = value.strip()
        v2 = headers.get("ntrip-version", "").lower().startswith("ntrip/2")
        mount_name = parts[1].lstrip("/")
        version = 2 if v2 else 1
        mount = self._mounts.get(mount_name)
        if mount is None:
            self.requests.append((mount_name, version, "sourcetable"))
            self._send_sourcetable(conn, v2)
            return
        user = self._authorized(headers)
        if user is False:
            self.unauthorized += 1
            self.requests.append((mount_name, version, "401"))
            if v2:
                answer = (
                    "HTTP/1.1 401 Unauthorized\r\nNtrip-Version: Ntrip/2.0\r\n"
                    f'WWW-Authenticate: Basic realm="/{mount_name}"\r\nContent-Length: 0\r\nConnection: close\r\n\r\n'
                )
            else:
                answer = f'HTTP/1.0 401 Unauthorized\r\nWWW-Authenticate: Basic realm="/{mount_name}"\r\n\r\n'
            self._send_all(conn, answer.encode("latin-1"))
            return
        user_name = user if isinstance(user, str) else None
        if "ntrip-gga" in headers:
            self._note_nmea(mount_name, user_name, headers["ntrip-gga"], via_header=True)
        self.requests.append((mount_name, version, "data"))
        if v2:
            answer = (
                "HTTP/1.1 200 OK\r\nNtrip-Version: Ntrip/2.0\r\nServer: NTRIP vsc-rig sim caster\r\n"
                "Content-Type: gnss/data\r\nTransfer-Encoding: chunked\r\nCache-Control: no-store\r\n"
                "Connection: close\r\n\r\n"
            )
        else:
            answer = "ICY 200 OK\r\n"
        if not self._send_all(conn, answer.encode("latin-1")):
            return
        client = _Client(chunked=v2)
        mount._add(client)
        try:
            self._stream(conn, client, mount_name, user_name, rest)
        finally:
            mount._remove(client)
            client.close()

    def _stream(self, conn: socket.socket, client: _Client, mount: str, user: str | None, pending: bytes) -> None:
        inbox = pending
        inbox = self._take_nmea(inbox, mount, user)
        while not self._stop.is_set():
            readable, _, _ = select.select([conn, client.wake_r], [], [], _POLL_S)
            if conn in readable:
                data = conn.recv(4096)
                if not data:
                    return  # the client hung up
                inbox = self._take_nmea(inbox + data, mount, user)
            if client.wake_r in readable:
                with contextlib.suppress(BlockingIOError):
                    client.wake_r.recv(4096)
            while client.queue:
                chunk = client.queue.popleft()
                out = encode_chunk(chunk) if client.chunked else chunk
                if not self._send_all(conn, out):
                    return

    def _take_nmea(self, inbox: bytes, mount: str, user: str | None) -> bytes:
        while b"\n" in inbox:
            line, _, inbox = inbox.partition(b"\n")
            text = line.strip().decode("latin-1")
            if text.startswith("$"):
                self._note_nmea(mount, user, text, via_header=False)
        return inbox[-4096:]

    def _note_nmea(self, mount: str, user: str | None, sentence: str, *, via_header: bool) -> None:
        with self._gga_cond:
            self.gga_received.append(GgaRecord(mount, user, sentence, via_header))
            self._gga_cond.notify_all()

    def _send_sourcetable(self, conn: socket.socket, v2: bool) -> None:
        table = self.sourcetable().encode("latin-1")
        if v2:
            head = (
                "HTTP/1.1 200 OK\r\nNtrip-Version: Ntrip/2.0\r\nServer: NTRIP vsc-rig sim caster\r\n"
                f"Content-Type: gnss/sourcetable\r\nContent-Length: {len(table)}\r\nConnection: close\r\n\r\n"
            )
        else:
            head = (
                "SOURCETABLE 200 OK\r\nServer: NTRIP vsc-rig sim caster\r\nContent-Type: text/plain\r\n"
                f"Content-Length: {len(table)}\r\n\r\n"
            )
        self._send_all(conn, head.encode("latin-1") + table)


class FileFeeder:
    """Replays a capture file into a mountpoint at a line rate (10 bits a byte), optionally looping."""

    def __init__(self, mount: Mountpoint, path: str | os.PathLike[str], *, baud: int = 115200, loop: bool = True):
        self._mount = mount
        self._path = os.fspath(path)
        self._bytes_per_s = baud / 10.0
        self._loop = loop
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.done = threading.Event()

    def start(self) -> None:
        with open(self._path, "rb") as f:
            self._data = f.read()
        if not self._data:
            raise ConfigError(f"caster capture file {self._path} is empty")
        self._thread = threading.Thread(target=self._run, name="ntrip-caster-file", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    def _run(self) -> None:
        step = max(1, int(self._bytes_per_s * 0.05))
        t0 = time.monotonic()
        sent = 0
        data = self._data
        try:
            while not self._stop.is_set():
                offset = sent % len(data)
                if not self._loop and sent >= len(data):
                    return
                chunk = data[offset : offset + step]
                due = t0 + sent / self._bytes_per_s
                if self._stop.wait(max(0.0, due - time.monotonic())):
                    return
                self._mount.publish(chunk)
                sent += len(chunk)
        finally:
            self.done.set()


class SerialFeeder:
    """Publishes what a serial port delivers (e.g. a simulated base's RTCM pty) to a mountpoint."""

    def __init__(self, mount: Mountpoint, port: str, *, baud: int = 115200) -> None:
        self._mount = mount
        self._port_name = port
        self._baud = baud
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        try:
            self._port = serial.Serial(self._port_name, self._baud, timeout=_POLL_S)
        except serial.SerialException as exc:
            raise DeviceError(f"caster feeder: cannot open serial port {self._port_name}: {exc}") from None
        self._thread = threading.Thread(target=self._run, name="ntrip-caster-serial", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    data = self._port.read(max(1, self._port.in_waiting))
                except (serial.SerialException, OSError) as exc:
                    log.warning("caster feeder %s: %s", self._port_name, exc)
                    return
                if data:
                    self._mount.publish(data)
        finally:
            self._port.close()
