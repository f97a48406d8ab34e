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
import errno
import fcntl
import logging
import os
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
        self.bytes_read = 0

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

    def write(self, data: bytes) -> int:
        """Write without blocking; bytes that do not fit (nobody reading) are dropped and counted."""
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
        self.bytes_dropped += len(data) - n
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
