"""A simulated serial port on a pseudo-terminal, reachable through a stable symlink.

The simulated device holds the pty master; whoever opens :attr:`PtyPort.path` (pyserial in the real
driver) gets the slave side, exactly like a USB serial adapter's ``/dev/ttyUSB0``. The slave is put
in raw mode at creation (no echo, no CR/LF translation), so nothing the device writes comes back
before the driver opens the port.

:meth:`PtyPort.unplug` closes the master and removes the symlink: an open slave sees the hang-up
and a new open fails. :meth:`PtyPort.replug` makes a new pty and points the same symlink at it, so a
driver that reconnects to the same path finds the device again. The object is not thread-safe:
the owning device's thread does all I/O (see :class:`sim_devices.gnss.receiver.SimReceiver`).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import logging
import os
import struct
import sys
import termios
import tty
from pathlib import Path

from vsccore.errors import DeviceError

__all__ = ["PtyPort"]

log = logging.getLogger(__name__)


class PtyPort:
    """One pty pair with a stable symlink ``path`` → ``/dev/pts/N``.

    Args:
        name: the port's name on the simulated device (``COM1``, ``COM2`` …), for messages.
        path: where the symlink lives (its directory must exist).
    """

    def __init__(self, name: str, path: Path) -> None:
        self.name = name
        self.path = path
        self.device_path: str | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self.bytes_written = 0
        self.bytes_dropped = 0
        self.bytes_lost = 0
        """The part of ``bytes_dropped`` dropped while someone had the port open (or it could not be
        told): bytes a reader was there to get and never will (its side of the pty was full)."""
        self.bytes_read = 0
        self._watch: _OpenWatch | None = None

    @property
    def connected(self) -> bool:
        """True while plugged in (the pty exists)."""
        return self._master is not None

    @property
    def master_fd(self) -> int | None:
        return self._master

    def plug(self) -> None:
        """Create the pty and point the symlink at its slave.

        Raises:
            DeviceError: the pty or the symlink could not be made.
        """
        if self._master is not None:
            return
        try:
            master, slave = os.openpty()
        except OSError as exc:
            raise DeviceError(f"sim port {self.name}: cannot open a pseudo-terminal: {exc}") from exc
        try:
            tty.setraw(slave, termios.TCSANOW)
            flags = fcntl.fcntl(master, fcntl.F_GETFL)
            fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
            device = os.ttyname(slave)
            tmp = self.path.with_name(self.path.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            os.symlink(device, tmp)
            os.replace(tmp, self.path)
        except OSError as exc:
            os.close(master)
            os.close(slave)
            raise DeviceError(f"sim port {self.name}: cannot link {self.path}: {exc}") from exc
        self._master, self._slave, self.device_path = master, slave, device
        self._watch = _OpenWatch.of(device)
        log.debug("sim port %s plugged: %s -> %s", self.name, self.path, device)

    def unplug(self) -> None:
        """Close the pty and remove the symlink (an open slave sees a hang-up)."""
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        if self._master is not None:
            log.debug("sim port %s unplugged (%s)", self.name, self.device_path)
        self._master = self._slave = None
        if self._watch is not None:
            self._watch.close()
            self._watch = None

    def readers(self) -> int | None:
        """How many times the other side (a driver, any process) has the port open now: 0 when nobody
        does (never opened, or closed again), None when it cannot be told (not on Linux)."""
        if self._master is None:
            return 0
        return self._watch.count() if self._watch is not None else None

    def write(self, data: bytes) -> int:
        """Write without blocking; bytes that do not fit (nobody reading, or the reader behind) are
        dropped and counted in :attr:`bytes_dropped`, and in :attr:`bytes_lost` when a reader has the
        port open."""
        if self._master is None:
            self.bytes_dropped += len(data)
            return 0
        try:
            n = os.write(self._master, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EAGAIN):
                raise
            n = 0
        self.bytes_written += n
        if n < len(data):
            self.bytes_dropped += len(data) - n
            if self.readers() != 0:
                self.bytes_lost += len(data) - n
        return n

    def unread(self) -> int:
        """Bytes written here that the other side has not read yet (0 when unplugged)."""
        if self._slave is None:
            return 0
        buf = bytearray(4)
        try:
            fcntl.ioctl(self._slave, termios.FIONREAD, buf)
        except OSError:
            return 0
        return int.from_bytes(buf, sys.byteorder)

    def read(self, n: int = 65536) -> bytes:
        """Bytes the other side wrote, without blocking (b"" when none)."""
        if self._master is None:
            return b""
        try:
            data = os.read(self._master, n)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:  # no slave open: nothing to read
                return b""
            raise
        self.bytes_read += len(data)
        return data

    def slave_baud(self) -> int | None:
        """Baud rate the slave side is set to (by the driver), or None when unknown."""
        if self._slave is None:
            return None
        try:
            speed = termios.tcgetattr(self._slave)[5]
        except termios.error:
            return None
        for name in dir(termios):
            if name.startswith("B") and name[1:].isdigit() and getattr(termios, name) == speed:
                return int(name[1:])
        return None


_IN_OPEN = 0x20
_IN_CLOSE = 0x08 | 0x10  # IN_CLOSE_WRITE | IN_CLOSE_NOWRITE
_IN_Q_OVERFLOW = 0x4000
_EVENT = struct.Struct("iIII")


class _OpenWatch:
    """Opens minus closes of a device node by anyone since the watch started (Linux inotify): a
    close event comes with the last close of an open file description, also when its process dies."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._open = 0
        self._lost = False

    @classmethod
    def of(cls, path: str) -> _OpenWatch | None:
        """A watch of ``path``, None where inotify is not available."""
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            init, add = libc.inotify_init1, libc.inotify_add_watch
        except (OSError, AttributeError):
            return None
        fd = int(init(os.O_NONBLOCK | os.O_CLOEXEC))
        if fd < 0:
            log.info("sim port %s: no inotify (%s): cannot tell whether a reader has it open",
                     path, os.strerror(ctypes.get_errno()))
            return None
        if int(add(fd, path.encode(), _IN_OPEN | _IN_CLOSE)) < 0:
            log.info("sim port %s: cannot watch it (%s)", path, os.strerror(ctypes.get_errno()))
            os.close(fd)
            return None
        return cls(fd)

    def count(self) -> int | None:
        """Open file descriptions of the node now (None: events were lost, it cannot be told)."""
        while self._fd >= 0:
            try:
                data = os.read(self._fd, 4096)
            except (BlockingIOError, OSError):
                break
            i = 0
            while i + _EVENT.size <= len(data):
                _wd, mask, _cookie, length = _EVENT.unpack_from(data, i)
                i += _EVENT.size + length
                if mask & _IN_Q_OVERFLOW:
                    self._lost = True
                elif mask & _IN_OPEN:
                    self._open += 1
                elif mask & _IN_CLOSE:
                    self._open -= 1
        return None if self._lost else max(0, self._open)

    def close(self) -> None:
        if self._fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = -1
