"""Test helpers: RTCM3 messages built field by field and framed by pyrtcm, CMR envelopes built by
hand from the published layout, and pseudo-terminal peers that record what they receive."""

from __future__ import annotations

import os
import queue
import select
import threading
import time
import tty
from dataclasses import dataclass

from pyrtcm import RTCMMessage, RTCMReader


class BitWriter:
    """MSB-first bit packer (RTCM3 field layout)."""

    def __init__(self) -> None:
        self._value = 0
        self._nbits = 0

    def u(self, nbits: int, value: int) -> BitWriter:
        assert 0 <= value < 1 << nbits, (nbits, value)
        self._value = (self._value << nbits) | value
        self._nbits += nbits
        return self

    def s(self, nbits: int, value: int) -> BitWriter:
        assert -(1 << (nbits - 1)) <= value < 1 << (nbits - 1)
        return self.u(nbits, value & ((1 << nbits) - 1))

    def text(self, value: str) -> BitWriter:
        self.u(8, len(value))
        for ch in value.encode("ascii"):
            self.u(8, ch)
        return self

    def bytes(self) -> bytes:
        pad = (-self._nbits) % 8
        return (self._value << pad).to_bytes((self._nbits + pad) // 8, "big")


def payload_1005(station: int = 7, xyz_m: tuple[float, float, float] = (3_800_000.0, 880_000.0, 5_030_000.0)) -> bytes:
    w = BitWriter().u(12, 1005).u(12, station).u(6, 0).u(1, 1).u(1, 1).u(1, 1).u(1, 0)
    w.s(38, round(xyz_m[0] * 1e4)).u(1, 0).u(1, 0).s(38, round(xyz_m[1] * 1e4)).u(2, 0).s(38, round(xyz_m[2] * 1e4))
    return w.bytes()


def payload_1006(station: int = 7) -> bytes:
    w = BitWriter().u(12, 1006).u(12, station).u(6, 0).u(1, 1).u(1, 1).u(1, 1).u(1, 0)
    w.s(38, 38_000_000_000).u(1, 0).u(1, 0).s(38, 8_800_000_000).u(2, 0).s(38, 50_300_000_000).u(16, 15_000)
    return w.bytes()


def payload_1033(station: int = 7) -> bytes:
    w = BitWriter().u(12, 1033).u(12, station).text("NOV850").u(8, 0).text("")
    return w.text("NOV OEM729").text("7.08.10").text("BX1234").bytes()


def payload_msm7(number: int, station: int = 7, epoch_ms: int = 345_600_000, sats: int = 6, sigs: int = 2) -> bytes:
    """An MSM7 message (1077 GPS, 1087 GLONASS, ...) with ``sats`` satellites and ``sigs`` signals."""
    w = BitWriter().u(12, number).u(12, station).u(30, epoch_ms % (1 << 30)).u(1, 0).u(3, 0).u(7, 0)
    w.u(2, 0).u(2, 0).u(1, 0).u(3, 0)
    sat_mask = sum(1 << (63 - i) for i in range(1, 1 + 2 * sats, 2))
    sig_mask = (1 << 31) | (1 << 23) if sigs == 2 else 1 << 31
    w.u(64, sat_mask).u(32, sig_mask)
    ncell = sats * sigs
    w.u(ncell, (1 << ncell) - 1)
    for i in range(sats):
        w.u(8, 70 + i)
    for _ in range(sats):
        w.u(4, 0)
    for i in range(sats):
        w.u(10, 100 * i)
    for i in range(sats):
        w.s(14, -300 + 50 * i)
    for c in range(ncell):
        w.s(20, 1000 * c - 5000)
    for c in range(ncell):
        w.s(24, 3000 * c - 9000)
    for _ in range(ncell):
        w.u(10, 500)
    for _ in range(ncell):
        w.u(1, 0)
    for _ in range(ncell):
        w.u(10, 45 * 16)
    for c in range(ncell):
        w.s(15, 20 * c)
    return w.bytes()


def payload_1230(station: int = 7) -> bytes:
    return (
        BitWriter()
        .u(12, 1230)
        .u(12, station)
        .u(1, 1)
        .u(3, 0)
        .u(4, 0b1111)
        .s(16, 10)
        .s(16, -10)
        .s(16, 5)
        .s(16, -5)
        .bytes()
    )


def rtcm_frame(payload: bytes) -> bytes:
    """Frame ``payload`` with pyrtcm (its own CRC-24Q), and check pyrtcm parses it back."""
    raw = RTCMMessage(payload=payload).serialize()
    parsed = RTCMReader.parse(raw)
    assert int(parsed.identity) == payload[0] << 4 | payload[1] >> 4
    return raw


def base_epoch(epoch_ms: int = 345_600_000, station: int = 7) -> list[bytes]:
    """One second of a base's stream: 1005, 1006, 1033, 1077, 1087, 1230."""
    return [
        rtcm_frame(payload_1005(station)),
        rtcm_frame(payload_1006(station)),
        rtcm_frame(payload_1033(station)),
        rtcm_frame(payload_msm7(1077, station, epoch_ms)),
        rtcm_frame(payload_msm7(1087, station, epoch_ms, sats=5)),
        rtcm_frame(payload_1230(station)),
    ]


def cmr_by_hand(packet_type: int, data: bytes, status: int = 0) -> bytes:
    """CMR envelope per Talbot (1996) / RTKLIB cmr.c: checksum = sum(status..data) mod 256."""
    body = [status, packet_type, len(data), *data]
    return bytes([0x02, *body, sum(body) % 256, 0x03])


# NovAtel's example RTCAA log (MiLLennium command reference, "RTCA" log): a 71-byte SCAT-I block.
NOVATEL_RTCAA_EXAMPLE = (
    b"$RTCA,990000000447520607BE7C92FA0B82423E9FE507DF5F3FC9FD071AFC7FA0"
    b"D207D090808C0E045BACC055E9075271FFB0200413F43FF810049C9DFF8FFD074F"
    b"CF3C940504052DFB*20\r\n"
)
NOVATEL_RTCA_BLOCK = bytes.fromhex(NOVATEL_RTCAA_EXAMPLE[6:-5].decode())


@dataclass
class Received:
    t_ns: int
    data: bytes


class PtyPeer:
    """A pseudo-terminal: the code under test opens :attr:`path`; the test holds the master.

    Closing it (:meth:`close`) is an unplug: the code under test then gets EIO on its fd.

    ``start_reader()`` records every chunk arriving at the master with ``time.monotonic_ns``.
    """

    def __init__(self) -> None:
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        # The test keeps a slave fd open so the master reads EAGAIN (not EIO) while the code under
        # test has not opened the path yet.
        self.chunks: queue.Queue[Received] = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            n = os.write(self.master, view)
            view = view[n:]
        return time.monotonic_ns()

    def start_reader(self) -> PtyPeer:
        self._thread = threading.Thread(target=self._read_loop, name="pty-peer-reader", daemon=True)
        self._thread.start()
        return self

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.05)
            if not r:
                continue
            try:
                data = os.read(self.master, 65536)
            except OSError:
                return  # the slave side is closed (no one has it open)
            if not data:
                return
            self.chunks.put(Received(time.monotonic_ns(), data))

    def read_exactly(self, n: int, timeout_s: float) -> bytes:
        """Bytes received by the reader thread until ``n`` have come (or the timeout)."""
        out = b""
        deadline = time.monotonic() + timeout_s
        while len(out) < n:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                out += self.chunks.get(timeout=left).data
            except queue.Empty:
                break
        return out

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if not self._closed:
            os.close(self.master)
            os.close(self._slave)
            self._closed = True
