"""A socketcand-protocol server on 127.0.0.1 that bridges TCP clients to in-process python-can buses.

There is no ``vcan`` on the rig's CI machines, so a simulated ECU on a python-can virtual bus is
made reachable from other processes the way a real remote CAN bus is: through socketcand's
ASCII protocol, which python-can's own ``socketcand`` interface speaks. Implemented (the subset a
raw-mode client uses; see socketcand's ``doc/protocol.md``)::

    server: < hi >                      on connect
    client: < open CHANNEL >            server: < ok >, or < error could not open bus > and hang up
    client: < rawmode >                 server: < ok >; then every bus frame as
    server: < frame ID SECS.USECS DATA >      ID 3 hex digits (base) or 8 (extended), DATA hex
    server: < error CLASS SECS.USECS >        error frames (SocketCAN error class)
    client: < send ID DLC B0 B1 ... >   a frame onto the bus (extended when ID has 8 digits)
    client: < echo >                    server: < echo >
    client: < bcmmode >                 server: < ok > (frames stop; BCM jobs are not implemented)

Each client gets its own bus instance from ``open_channel`` (as socketcand opens one raw socket
per client), so on a virtual bus every client sees the ECU's frames and each other's, and the
ECU sees the clients'.

A frame a client sends carries its arrival time as ``msg.timestamp``: on Linux the kernel's receive
stamp of the TCP segment that completed its ``< send >`` (``SO_TIMESTAMPNS``), elsewhere the time the
command thread read it. A virtual bus of :func:`virtual_channel_opener` keeps that stamp
(``preserve_timestamps``), so the other clients see the frame at the time it reached the server, as
socketcand's bus stamps a frame when the daemon writes it, and not later by however long this
process's command thread waited for the CPU and the interpreter lock (the other threads of the
process, e.g. a recorder reading from it, hold it; measured with a replay at 1x under load, see
``benchmarks/bench_replay.py``: a median spacing error of 33-93 µs with the thread's stamps against
7-25 µs with the arrival stamps, and more frames over 1 ms). When several commands arrive
before the thread reads them, they share the latest segment's stamp, which is still no later than
the read. A bus that stamps frames itself (SocketCAN) ignores the stamp.

Garbage between commands is skipped; malformed ``send`` commands are logged and ignored, as
socketcand does. ``stop()`` closes every socket and bus and joins every thread.
"""

from __future__ import annotations

import contextlib
import enum
import logging
import platform
import re
import select
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import can

from vsccore.errors import DeviceError, DeviceTimeoutError

__all__ = ["SocketcandServer", "format_frame", "parse_send", "virtual_channel_opener"]

log = logging.getLogger(__name__)

_MAX_COMMAND = 256
"""Longest command accepted (an FD ``send`` is < 220 characters); longer junk is dropped."""

_SO_TIMESTAMPNS = 35
"""Linux ``SO_TIMESTAMPNS`` (``SCM_TIMESTAMPNS``) with a 64-bit ``struct timespec``; Python's socket module
does not name it."""
_STAMPED = sys.platform == "linux" and platform.machine() in ("x86_64", "aarch64", "arm64", "riscv64")
"""Whether the kernel's receive stamps are asked for (architectures where the value above is this option)."""
_TIMESPEC = struct.Struct("qq")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) if _STAMPED else 0

_SEND = re.compile(r"^< send ([0-9A-Fa-f]{1,8}) ([0-9A-Fa-f]{1,2})((?: [0-9A-Fa-f]{1,2})*) >$")


def format_frame(msg: can.Message) -> str:
    """The server's line for one bus frame (``< frame … >``, ``< error … >`` or ``< rtr … >``)."""
    ts = max(float(msg.timestamp), 0.0)
    secs = int(ts)
    usecs = round((ts - secs) * 1e6)
    if usecs >= 1_000_000:
        secs, usecs = secs + 1, usecs - 1_000_000
    stamp = f"{secs}.{usecs:06d}"
    if msg.is_error_frame:
        return f"< error {msg.arbitration_id & 0x1FFFFFFF:03X} {stamp} >"
    ident = f"{msg.arbitration_id & 0x1FFFFFFF:08X}" if msg.is_extended_id else f"{msg.arbitration_id & 0x7FF:03X}"
    if msg.is_remote_frame:
        return f"< rtr {ident} {stamp} {msg.dlc} >"
    data = bytes(msg.data or b"").hex().upper()
    if msg.is_fd:
        flags = (0x01 if msg.bitrate_switch else 0) | (0x02 if msg.error_state_indicator else 0)
        return f"< fdframe {ident} {flags:02X} {stamp} {data} >"
    return f"< frame {ident} {stamp} {data} >"


def parse_send(command: str) -> can.Message | None:
    """The frame of a ``< send ID DLC B… >`` command, or None when it is malformed."""
    match = _SEND.match(" ".join(command.split()))
    if match is None:
        return None
    ident_text, dlc_text, data_text = match.groups()
    dlc = int(dlc_text, 16)
    data = [int(b, 16) for b in data_text.split()]
    ident = int(ident_text, 16)
    extended = len(ident_text) == 8
    if dlc > 8 or len(data) != dlc or ident > (0x1FFFFFFF if extended else 0x7FF):
        return None
    return can.Message(arbitration_id=ident, is_extended_id=extended, data=bytes(data), dlc=dlc)


def virtual_channel_opener(
    channels: Mapping[str, str] | None = None, **bus_options: Any
) -> Callable[[str], can.BusABC]:
    """An ``open_channel`` for :class:`SocketcandServer` that opens python-can virtual buses.

    ``channels`` maps socketcand bus names (what clients ``open``) to virtual channel names;
    without it every name is served as the virtual channel of the same name.

    ``bus_options`` go to ``can.Bus``; ``preserve_timestamps`` defaults to True, so a frame a client sends
    keeps its arrival stamp (module docstring).
    """
    options = {"preserve_timestamps": True, **bus_options}

    def open_channel(name: str) -> can.BusABC:
        if channels is not None and name not in channels:
            raise DeviceError(f"socketcand: no bus named {name!r} (serving {', '.join(sorted(channels))})")
        target = channels[name] if channels is not None else name
        return can.Bus(interface="virtual", channel=target, **options)

    return open_channel


class _Mode(enum.Enum):
    NO_BUS = "no_bus"
    BCM = "bcm"
    RAW = "raw"


class _Client:
    """One TCP connection: a command thread (socket → bus) and, once open, a frame thread (bus → socket)."""

    def __init__(
        self,
        server: SocketcandServer,
        sock: socket.socket,
        peer: tuple[str, int],
    ) -> None:
        self.server = server
        self.sock = sock
        self.peer = f"{peer[0]}:{peer[1]}"
        self.bus: can.BusABC | None = None
        self.mode = _Mode.NO_BUS
        self.raw_since: float | None = None
        self.closed = threading.Event()
        self._send_lock = threading.Lock()
        self._buffer = ""
        self._cmd_thread = threading.Thread(target=self._command_loop, name=f"socketcand-cmd-{self.peer}")
        self._rx_thread: threading.Thread | None = None
        self.frames_out = 0
        self.frames_in = 0
        self.stamped = False  # the kernel stamps what the client sends (module docstring)
        if _STAMPED:
            try:
                sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
                self.stamped = True
            except OSError as exc:
                log.info("socketcand: client %s: no kernel receive stamps (%s); stamping on read", self.peer, exc)

    def start(self) -> None:
        self._send("< hi >")
        self._cmd_thread.start()

    def close(self) -> None:
        if self.closed.is_set():
            return
        self.closed.set()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        self.server._notify()

    def join(self, timeout_s: float) -> bool:
        """Join both threads; True when they finished."""
        for thread in (self._cmd_thread, self._rx_thread):
            if thread is not None and thread is not threading.current_thread() and thread.ident is not None:
                thread.join(timeout_s)
                if thread.is_alive():
                    return False
        return True

    def _send(self, line: str) -> bool:
        try:
            with self._send_lock:
                self.sock.sendall(line.encode("ascii"))
        except OSError as exc:
            if not self.closed.is_set():
                log.info("socketcand: client %s gone while sending: %s", self.peer, exc)
            self.close()
            return False
        return True

    # -- socket → bus --

    def _command_loop(self) -> None:
        stop = self.server._stop
        try:
            while not stop.is_set() and not self.closed.is_set():
                try:
                    readable, _, _ = select.select([self.sock], [], [], self.server.poll_s)
                except (OSError, ValueError):
                    break  # socket closed under us
                if not readable:
                    continue
                try:
                    chunk, arrived_s = self._read()
                except OSError:
                    break
                if not chunk:
                    log.info("socketcand: client %s disconnected", self.peer)
                    break
                self._buffer += chunk.decode("ascii", errors="replace")
                for command in self._commands():
                    self._handle(command, arrived_s)
                    if self.closed.is_set():
                        break
        finally:
            if stop.is_set() and self._rx_thread is not None and self._rx_thread.ident is not None:
                # the server is stopping: let the frame thread send what the bus still holds first
                self._rx_thread.join(self.server.join_timeout_s)
            self.close()
            if self._rx_thread is not None and self._rx_thread.ident is not None:
                self._rx_thread.join(self.server.join_timeout_s)
            bus, self.bus = self.bus, None
            if bus is not None:
                bus.shutdown()

    def _read(self) -> tuple[bytes, float]:
        """The next bytes from the client and their arrival time (s, Unix epoch; see the module docstring)."""
        if self.stamped:
            data, ancillary, _flags, _addr = self.sock.recvmsg(4096, _ANCILLARY)
            for level, kind, payload in ancillary:
                if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(payload) >= _TIMESPEC.size:
                    secs, nsecs = _TIMESPEC.unpack_from(payload)
                    return data, secs + nsecs * 1e-9
            return data, time.time()
        return self.sock.recv(4096), time.time()

    def _commands(self) -> list[str]:
        out: list[str] = []
        buf = self._buffer
        while True:
            start = buf.find("<")
            if start < 0:
                buf = ""  # nothing that can start a command: drop the junk
                break
            end = buf.find(">", start)
            if end < 0:
                buf = buf[start:]
                if len(buf) > _MAX_COMMAND:
                    log.warning("socketcand: client %s sent %d bytes without '>'; dropped", self.peer, len(buf))
                    buf = ""
                break
            out.append(" ".join(buf[start : end + 1].split()))
            buf = buf[end + 1 :]
        self._buffer = buf
        return out

    def _handle(self, command: str, arrived_s: float) -> None:
        if command == "< echo >":
            self._send("< echo >")
            return
        if self.mode is _Mode.NO_BUS:
            if command.startswith("< open ") and command.endswith(" >"):
                self._open(command[7:-2].strip())
            else:
                log.warning("socketcand: client %s: %r before < open >", self.peer, command)
                self._send("< error no bus opened >")
            return
        if command == "< rawmode >":
            # python-can's client reads its '< ok >' with one recv(); frames sent right behind it
            # would land in the same read and fail its handshake, so frames start a moment later.
            self.raw_since = self.server.settle_deadline()
            self.mode = _Mode.RAW
            self._send("< ok >")
            return
        if command == "< bcmmode >":
            self.mode = _Mode.BCM
            self._send("< ok >")
            return
        if command.startswith("< send "):
            msg = parse_send(command)
            if msg is None:
                log.warning("socketcand: client %s: malformed send command %r ignored", self.peer, command)
                return
            msg.timestamp = arrived_s
            bus = self.bus
            if bus is not None:
                try:
                    bus.send(msg)
                    self.frames_in += 1
                except can.CanError as exc:
                    log.warning("socketcand: client %s: bus send failed: %s", self.peer, exc)
            return
        log.warning("socketcand: client %s: unknown command %r", self.peer, command)
        self._send("< error unknown command >")

    def _open(self, name: str) -> None:
        try:
            self.bus = self.server.open_channel(name)
        except (DeviceError, can.CanError, OSError, ValueError) as exc:
            log.warning("socketcand: client %s: cannot open bus %r: %s", self.peer, name, exc)
            self._send("< error could not open bus >")
            self.close()
            return
        self.mode = _Mode.BCM
        self._rx_thread = threading.Thread(target=self._frame_loop, name=f"socketcand-rx-{self.peer}")
        self._rx_thread.start()
        self._send("< ok >")

    # -- bus → socket --

    def _frame_loop(self) -> None:
        stop = self.server._stop
        bus = self.bus
        while bus is not None and not stop.is_set() and not self.closed.is_set():
            try:
                msg = bus.recv(timeout=self.server.poll_s)
            except can.CanError as exc:
                log.warning("socketcand: client %s: bus receive failed: %s", self.peer, exc)
                self.close()
                return
            if msg is None or self.mode is not _Mode.RAW:
                continue
            if self.raw_since is not None and time.monotonic() < self.raw_since:
                continue
            if not self._send(format_frame(msg)):
                return
            self.frames_out += 1
        if bus is not None and stop.is_set() and not self.closed.is_set() and self.mode is _Mode.RAW:
            # a stopping server still delivers the frames its bus had queued: none are lost at the end
            while (msg := bus.recv(timeout=0.0)) is not None:
                if not self._send(format_frame(msg)):
                    return
                self.frames_out += 1


class SocketcandServer:
    """Serve in-process python-can buses to socketcand clients on ``host:port`` (0: any free port).

    ``open_channel(name)`` returns a new bus for a client's ``< open name >`` and raises
    :class:`~vsccore.errors.DeviceError` (or ``can.CanError``) for names it does not serve.
    """

    def __init__(
        self,
        open_channel: Callable[[str], can.BusABC],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        poll_s: float = 0.05,
        rawmode_settle_s: float = 0.05,
        join_timeout_s: float = 2.0,
    ) -> None:
        self.open_channel = open_channel
        self.host = host
        self.port = port
        self.poll_s = poll_s
        self.rawmode_settle_s = rawmode_settle_s
        self.join_timeout_s = join_timeout_s
        self._stop = threading.Event()
        self._listener: socket.socket | None = None
        self._accept_thread: threading.Thread | None = None
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)

    def settle_deadline(self) -> float:
        """Monotonic time after which a client that just entered raw mode gets frames."""
        return time.monotonic() + self.rawmode_settle_s

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound (the port is known after :meth:`start`)."""
        return self.host, self.port

    @property
    def client_count(self) -> int:
        """Clients currently connected."""
        with self._lock:
            return sum(1 for c in self._clients if not c.closed.is_set())

    def wait_for_clients(self, count: int, timeout_s: float) -> bool:
        """Wait until exactly ``count`` clients are connected; False on timeout."""
        with self._changed:
            return self._changed.wait_for(
                lambda: sum(1 for c in self._clients if not c.closed.is_set()) == count, timeout_s
            )

    def _notify(self) -> None:
        with self._changed:
            self._changed.notify_all()

    def start(self) -> None:
        """Bind, listen and start accepting.

        Raises:
            DeviceError: the address cannot be bound (the message names it).
        """
        if self._accept_thread is not None:
            raise RuntimeError("socketcand server already started")
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            listener.bind((self.host, self.port))
            listener.listen(8)
        except OSError as exc:
            listener.close()
            raise DeviceError(f"socketcand server: cannot listen on {self.host}:{self.port}: {exc}") from exc
        self.port = int(listener.getsockname()[1])
        self._listener = listener
        self._accept_thread = threading.Thread(target=self._accept_loop, name=f"socketcand-{self.port}")
        self._accept_thread.start()
        log.info("socketcand server listening on %s:%d", self.host, self.port)

    def stop(self) -> None:
        """Close the listener and every client (socket and bus) and join all threads.

        Raises:
            DeviceTimeoutError: a thread did not finish within ``join_timeout_s``.
        """
        self._stop.set()
        thread = self._accept_thread
        if thread is not None:
            thread.join(self.join_timeout_s)
        listener, self._listener = self._listener, None
        if listener is not None:
            listener.close()
        with self._lock:
            clients = list(self._clients)
        # threads see the stop event, send what their bus still holds, then close their socket
        stuck = [c.peer for c in clients if not c.join(self.join_timeout_s)]
        for client in clients:
            client.close()
        if thread is not None and thread.is_alive():
            stuck.append("accept")
        if stuck:
            raise DeviceTimeoutError(f"socketcand server {self.host}:{self.port}: threads did not stop: {stuck}")

    def __enter__(self) -> SocketcandServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _accept_loop(self) -> None:
        listener = self._listener
        assert listener is not None
        while not self._stop.is_set():
            try:
                readable, _, _ = select.select([listener], [], [], self.poll_s)
            except (OSError, ValueError):
                return
            if not readable:
                self._reap()
                continue
            try:
                sock, peer = listener.accept()
            except OSError:
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(self, sock, peer)
            with self._changed:
                self._clients.append(client)
                self._changed.notify_all()
            log.info("socketcand: client %s connected", client.peer)
            client.start()

    def _reap(self) -> None:
        """Forget clients whose threads have finished."""
        with self._lock:
            done = [c for c in self._clients if c.closed.is_set() and c.join(0.0)]
            for c in done:
                self._clients.remove(c)
