"""Serial transport: one pyserial port (device path or pyserial URL) behind a small, typed interface.

Device sessions (NovAtel receiver, correction relay) read and write through :class:`SerialTransport`
and never see pyserial's exceptions: every failure becomes :class:`vsccore.errors.DeviceError`
naming the port, so "the port went away" (USB adapter unplugged, pseudo-terminal master closed)
is one exception type that a session answers by reconnecting.

- :meth:`SerialTransport.read_available` waits up to the read timeout for the first byte and then
  takes whatever else is already buffered, so chunks are delivered with low latency.
- :meth:`SerialTransport.cancel_read` wakes a blocked read from another thread (used by ``stop()``).
- :func:`reconnect_delays` gives the exponential back-off of a reconnect loop.

Opening works on anything pyserial opens: ``/dev/ttyUSB0``, ``COM3``, a pseudo-terminal path,
``socket://host:port``, ``loop://``. No threads here.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator

import serial

from vsccore.errors import DeviceError

log = logging.getLogger(__name__)

__all__ = ["SerialTransport", "reconnect_delays"]


class SerialTransport:
    """An open serial port.

    Args:
        url: device path or pyserial URL.
        baud: baud rate.
        read_timeout_s: longest a read waits for the first byte.
        write_timeout_s: longest a write may block (None: no limit).

    Raises:
        DeviceError: the port cannot be opened (the message names it).
    """

    def __init__(
        self, url: str, baud: int, *, read_timeout_s: float = 0.05, write_timeout_s: float | None = 2.0
    ) -> None:
        self.url = url
        self._write_lock = threading.Lock()
        try:
            self._port = serial.serial_for_url(
                url, baudrate=baud, timeout=read_timeout_s, write_timeout=write_timeout_s, exclusive=None
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"serial port {url}: cannot open at {baud} Bd: {exc}") from exc
        log.debug("serial port %s open at %d Bd", url, baud)

    @property
    def baud(self) -> int:
        return int(self._port.baudrate)

    @property
    def is_open(self) -> bool:
        return bool(self._port.is_open)

    def set_baud(self, baud: int) -> None:
        """Change the host side's baud rate.

        Raises:
            DeviceError: the port refused the rate or is gone.
        """
        try:
            self._port.baudrate = baud
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"serial port {self.url}: cannot set {baud} Bd: {exc}") from exc

    def read_available(self, max_bytes: int = 65536) -> bytes:
        """Bytes received: waits up to the read timeout for the first, then takes what is buffered.

        Returns b"" on timeout (or after :meth:`cancel_read`).

        Raises:
            DeviceError: the port is gone (device unplugged, pseudo-terminal closed).
        """
        port = self._port
        try:
            waiting = port.in_waiting
            data: bytes = port.read(min(max(waiting, 1), max_bytes))
            if data:
                more = port.in_waiting
                if more:
                    data += port.read(min(more, max_bytes - len(data)))
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            # pyserial raises TypeError/AttributeError when the port is closed under a read
            raise DeviceError(f"serial port {self.url}: read failed (port lost?): {exc}") from exc
        return data

    def write(self, data: bytes) -> None:
        """Write all of ``data`` (thread-safe: writes from several threads do not interleave).

        Raises:
            DeviceError: the write failed or timed out (port lost or blocked).
        """
        with self._write_lock:
            try:
                written = self._port.write(data)
                self._port.flush()
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                raise DeviceError(f"serial port {self.url}: write failed (port lost?): {exc}") from exc
        if written is not None and written != len(data):
            raise DeviceError(f"serial port {self.url}: wrote {written} of {len(data)} bytes")

    def reset_input(self) -> None:
        """Drop bytes received but not read yet.

        Raises:
            DeviceError: the port is gone.
        """
        try:
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError, TypeError) as exc:
            raise DeviceError(f"serial port {self.url}: cannot reset input: {exc}") from exc

    def cancel_read(self) -> None:
        """Wake a read blocked in another thread (it returns what it has, maybe b"")."""
        cancel = getattr(self._port, "cancel_read", None)
        if cancel is not None:
            with contextlib.suppress(serial.SerialException, OSError):  # closing anyway
                cancel()

    def close(self) -> None:
        """Close the port (idempotent; never raises)."""
        try:
            self._port.close()
        except (serial.SerialException, OSError) as exc:
            log.debug("serial port %s: error on close ignored: %s", self.url, exc)

    def __enter__(self) -> SerialTransport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def reconnect_delays(first_s: float, max_s: float, factor: float = 2.0) -> Iterator[float]:
    """Back-off delays for reconnect attempts: first_s, first_s*factor, … capped at max_s."""
    if first_s <= 0 or max_s < first_s or factor < 1:
        raise ValueError(f"bad back-off: first {first_s} s, max {max_s} s, factor {factor}")
    delay = first_s
    while True:
        yield delay
        delay = min(delay * factor, max_s)
