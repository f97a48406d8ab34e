"""RTCM 3 encoders for the simulated base (RTCM 10403.3 field layouts), and header readers for rovers.

Messages: 1005/1006 (station antenna reference point), 1033 (antenna and receiver descriptors),
1230 (GLONASS code-phase biases) and MSM4/MSM7 observations of GPS (1074/1077) and GLONASS
(1084/1087). Payloads are written with a small bit writer, framed with the 0xD3 preamble, 10-bit
length and CRC-24Q (the codec's :func:`drivers.novatel.crc24q`); the tests decode every frame with
pyrtcm, an independent implementation.

The readers (:func:`frame_message_number`, :func:`frame_station_id`, :func:`frame_gps_epoch_ms`)
take a complete, CRC-checked frame, as the codec's framer returns it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.novatel.crc import crc24q
from sim_devices.gnss.constellation import SPEED_OF_LIGHT, GnssSystem
from vsccore.errors import EncodeError
from vsccore.gpstime import NS_PER_S, SECONDS_PER_WEEK

__all__ = [
    "BitReader",
    "BitWriter",
    "MsmSatellite",
    "MsmSignal",
    "encode_1005",
    "encode_1006",
    "encode_1033",
    "encode_1230",
    "encode_msm",
    "frame",
    "frame_gps_epoch_ms",
    "frame_message_number",
    "frame_station_id",
    "glonass_epoch",
    "lock_indicator_msm4",
    "lock_indicator_msm7",
]

_LIGHT_MS = SPEED_OF_LIGHT * 1e-3  # metres per millisecond of light travel


class BitWriter:
    """Big-endian (MSB-first) bit packer."""

    def __init__(self) -> None:
        self._value = 0
        self._bits = 0

    def put(self, value: int, nbits: int, *, signed: bool = False, name: str = "field") -> None:
        """Append ``value`` in ``nbits`` bits (two's complement when ``signed``).

        Raises:
            EncodeError: the value does not fit.
        """
        if signed:
            lo, hi = -(1 << (nbits - 1)), (1 << (nbits - 1)) - 1
        else:
            lo, hi = 0, (1 << nbits) - 1
        if not lo <= value <= hi:
            raise EncodeError(f"RTCM3 {name}: value {value} does not fit {nbits} bits")
        self._value = (self._value << nbits) | (value & ((1 << nbits) - 1))
        self._bits += nbits

    @property
    def bits(self) -> int:
        return self._bits

    def to_bytes(self) -> bytes:
        """The bits, zero-padded to a whole byte."""
        pad = (-self._bits) % 8
        return (self._value << pad).to_bytes((self._bits + pad) // 8, "big")


class BitReader:
    """Big-endian bit reader over bytes."""

    def __init__(self, data: bytes, offset_bits: int = 0) -> None:
        self._value = int.from_bytes(data, "big")
        self._total = len(data) * 8
        self.pos = offset_bits

    def get(self, nbits: int, *, signed: bool = False) -> int:
        if self.pos + nbits > self._total:
            raise ValueError(f"RTCM3 reader: {nbits} bits at {self.pos} run past {self._total}")
        v = (self._value >> (self._total - self.pos - nbits)) & ((1 << nbits) - 1)
        self.pos += nbits
        if signed and v >> (nbits - 1):
            v -= 1 << nbits
        return v


def frame(payload: bytes) -> bytes:
    """RTCM3 transport frame: D3, 6 zero bits + 10-bit length, payload, CRC-24Q."""
    if len(payload) > 1023:
        raise EncodeError(f"RTCM3 payload of {len(payload)} bytes exceeds 1023")
    head = bytes((0xD3, len(payload) >> 8, len(payload) & 0xFF)) + payload
    return head + crc24q(head).to_bytes(3, "big")


def frame_message_number(raw: bytes) -> int:
    """Message number (DF002) of a frame."""
    return raw[3] << 4 | raw[4] >> 4


def frame_station_id(raw: bytes) -> int:
    """Reference station ID (DF003) of a frame (every standard message has it after DF002)."""
    return (raw[4] & 0x0F) << 8 | raw[5]


def frame_gps_epoch_ms(raw: bytes) -> int:
    """GPS epoch time of week in ms (DF004) of a GPS observation message (1001-1004, 1071-1077)."""
    return BitReader(raw[3:-3], 24).get(30)


def _ecef_field(w: BitWriter, value_m: float, name: str) -> None:
    w.put(round(value_m * 1e4), 38, signed=True, name=name)


def _station_payload(number: int, station_id: int, ecef_m: Sequence[float], height_m: float | None) -> bytes:
    w = BitWriter()
    w.put(number, 12, name="DF002")
    w.put(station_id, 12, name="DF003")
    w.put(0, 6, name="DF021")  # ITRF realization year: not given
    w.put(1, 1)  # GPS
    w.put(1, 1)  # GLONASS
    w.put(0, 1)  # Galileo
    w.put(0, 1)  # DF141: physical reference station
    _ecef_field(w, ecef_m[0], "DF025")
    w.put(0, 1)  # DF142: single receiver oscillator
    w.put(0, 1)  # reserved
    _ecef_field(w, ecef_m[1], "DF026")
    w.put(0, 2)  # DF364: quarter cycle indicator
    _ecef_field(w, ecef_m[2], "DF027")
    if height_m is not None:
        w.put(round(height_m * 1e4), 16, name="DF028")
    return w.to_bytes()


def encode_1005(station_id: int, ecef_m: Sequence[float]) -> bytes:
    """Payload of 1005: station ARP (ECEF, m) of a GPS + GLONASS reference station."""
    return _station_payload(1005, station_id, ecef_m, None)


def encode_1006(station_id: int, ecef_m: Sequence[float], antenna_height_m: float = 0.0) -> bytes:
    """Payload of 1006: 1005 plus the antenna height above the marker (m)."""
    return _station_payload(1006, station_id, ecef_m, antenna_height_m)


def _text(w: BitWriter, text: str, name: str) -> None:
    data = text.encode("latin-1")
    w.put(len(data), 8, name=f"{name} counter")
    for b in data:
        w.put(b, 8)


def encode_1033(
    station_id: int,
    *,
    antenna_descriptor: str = "NOV850          NONE",
    antenna_setup_id: int = 0,
    antenna_serial: str = "",
    receiver_type: str = "NOVATEL OEM729",
    firmware: str = "OM7MR0810RN0000",
    receiver_serial: str = "",
) -> bytes:
    """Payload of 1033: antenna and receiver descriptors."""
    w = BitWriter()
    w.put(1033, 12)
    w.put(station_id, 12, name="DF003")
    _text(w, antenna_descriptor, "DF030")
    w.put(antenna_setup_id, 8, name="DF031")
    _text(w, antenna_serial, "DF033")
    _text(w, receiver_type, "DF228")
    _text(w, firmware, "DF230")
    _text(w, receiver_serial, "DF232")
    return w.to_bytes()


def encode_1230(
    station_id: int,
    biases_m: tuple[float | None, float | None, float | None, float | None] = (0.0, 0.0, 0.0, 0.0),
    *,
    aligned: bool = False,
) -> bytes:
    """Payload of 1230: GLONASS L1 C/A, L1 P, L2 C/A, L2 P code-phase biases (m; None = not sent)."""
    w = BitWriter()
    w.put(1230, 12)
    w.put(station_id, 12, name="DF003")
    w.put(1 if aligned else 0, 1)
    w.put(0, 3)
    for b in biases_m:
        w.put(0 if b is None else 1, 1)
    for i, b in enumerate(biases_m):
        if b is not None:
            w.put(round(b / 0.02), 16, signed=True, name=f"DF{423 + i}")
    return w.to_bytes()


@dataclass(frozen=True, slots=True)
class MsmSignal:
    """One signal (cell) of an MSM satellite: RINEX-style signal ID as in the MSM signal mask."""

    signal_id: int
    pseudorange_m: float
    phaserange_m: float
    phaserange_rate_mps: float
    cnr_dbhz: float
    lock_time_s: float


@dataclass(frozen=True, slots=True)
class MsmSatellite:
    """One satellite of an MSM message (ID 1..64: GPS PRN or GLONASS slot)."""

    sat_id: int
    signals: tuple[MsmSignal, ...]
    range_m: float
    range_rate_mps: float
    glonass_fcn: int = 0


def lock_indicator_msm4(lock_ms: float) -> int:
    """DF402 (4 bits): 0 below 32 ms, then k for 2^(k+4) ≤ t < 2^(k+5) ms, 15 at ≥ 524288 ms."""
    if lock_ms < 32:
        return 0
    return min(15, int(math.floor(math.log2(lock_ms))) - 4)


def lock_indicator_msm7(lock_ms: float) -> int:
    """DF407 (10 bits): the largest indicator whose minimum lock time ≤ ``lock_ms`` (max 704)."""
    t = int(lock_ms)
    if t < 64:
        return max(t, 0)
    c = 0
    for n in range(1, 21):
        lo_i, hi_i = 32 * (n + 1), 32 * (n + 2)
        c += (1 << (n - 1)) * 32 * (n + 1)
        for_i = (t + c) >> n
        if for_i < hi_i:
            return max(lo_i, for_i)
    return 704


def glonass_epoch(gps_ns: int, leap_seconds: int) -> tuple[int, int]:
    """(day of week 0 = Sunday, ms of day) of GLONASS time (UTC + 3 h) at GPS time ``gps_ns``."""
    # The GPS epoch (1980-01-06) was a Sunday 00:00 UTC.
    glo_ms = (gps_ns // 1_000_000) - leap_seconds * 1000 + 3 * 3600 * 1000
    day, ms = divmod(glo_ms, 86_400_000)
    return day % 7, ms


def encode_msm(
    msm: int,
    system: GnssSystem,
    station_id: int,
    epoch_gps_ns: int,
    satellites: Sequence[MsmSatellite],
    *,
    leap_seconds: int = 18,
    multiple_message: bool = False,
    iods: int = 0,
) -> bytes:
    """Payload of an MSM4 or MSM7 message of GPS (107x) or GLONASS (108x).

    Raises:
        EncodeError: unsupported MSM type, too many cells (> 64), or a value out of range.
    """
    if msm not in (4, 7):
        raise EncodeError(f"RTCM3 MSM{msm} is not supported (4 or 7)")
    number = (1070 if system is GnssSystem.GPS else 1080) + msm
    sats = sorted(satellites, key=lambda s: s.sat_id)
    sig_ids = sorted({sig.signal_id for s in sats for sig in s.signals})
    if len(sats) * len(sig_ids) > 64:
        raise EncodeError(f"RTCM3 {number}: {len(sats)} satellites x {len(sig_ids)} signals exceed 64 cells")
    w = BitWriter()
    w.put(number, 12)
    w.put(station_id, 12, name="DF003")
    if system is GnssSystem.GPS:
        tow_ms = (epoch_gps_ns // 1_000_000) % (SECONDS_PER_WEEK * 1000)
        w.put(tow_ms, 30, name="DF004")
    else:
        dow, ms = glonass_epoch(epoch_gps_ns, leap_seconds)
        w.put(dow, 3, name="DF416")
        w.put(ms, 27, name="DF034")
    w.put(1 if multiple_message else 0, 1)
    w.put(iods, 3, name="DF409")
    w.put(0, 7)
    w.put(0, 2)  # clock steering: unknown
    w.put(0, 2)  # external clock: internal
    w.put(0, 1)  # divergence-free smoothing: no
    w.put(0, 3)  # smoothing interval: none
    sat_mask = 0
    for s in sats:
        if not 1 <= s.sat_id <= 64:
            raise EncodeError(f"RTCM3 {number}: satellite ID {s.sat_id} out of 1..64")
        sat_mask |= 1 << (64 - s.sat_id)
    w.put(sat_mask, 64)
    sig_mask = 0
    for sid in sig_ids:
        sig_mask |= 1 << (32 - sid)
    w.put(sig_mask, 32)
    cells: list[MsmSignal] = []
    rough_ms: list[float] = []
    for s in sats:
        have = {sig.signal_id: sig for sig in s.signals}
        for sid in sig_ids:
            w.put(1 if sid in have else 0, 1)
    for s in sats:
        r = round(s.range_m / _LIGHT_MS * 1024) / 1024
        rough_ms.append(r)
    # Satellite data.
    for r in rough_ms:
        w.put(int(math.floor(r)), 8, name="DF397")
    if msm == 7:
        for s in sats:
            w.put((s.glonass_fcn + 7) if system is GnssSystem.GLONASS else 0, 4, name="ext sat info")
    for r in rough_ms:
        w.put(round((r - math.floor(r)) * 1024), 10, name="DF398")
    if msm == 7:
        for s in sats:
            w.put(round(s.range_rate_mps), 14, signed=True, name="DF399")
    # Signal data, satellite-major.
    rough_of_cell: list[tuple[float, float]] = []
    for s, r in zip(sats, rough_ms, strict=True):
        have = {sig.signal_id: sig for sig in s.signals}
        for sid in sig_ids:
            if sid in have:
                cells.append(have[sid])
                rough_of_cell.append((r, float(round(s.range_rate_mps))))
    if msm == 4:
        for c, (r, _) in zip(cells, rough_of_cell, strict=True):
            w.put(round((c.pseudorange_m / _LIGHT_MS - r) * 2**24), 15, signed=True, name="DF400")
        for c, (r, _) in zip(cells, rough_of_cell, strict=True):
            w.put(round((c.phaserange_m / _LIGHT_MS - r) * 2**29), 22, signed=True, name="DF401")
        for c in cells:
            w.put(lock_indicator_msm4(c.lock_time_s * 1000), 4, name="DF402")
        for _ in cells:
            w.put(0, 1)  # DF420 half-cycle ambiguity
        for c in cells:
            w.put(min(63, max(0, round(c.cnr_dbhz))), 6, name="DF403")
    else:
        for c, (r, _) in zip(cells, rough_of_cell, strict=True):
            w.put(round((c.pseudorange_m / _LIGHT_MS - r) * 2**29), 20, signed=True, name="DF405")
        for c, (r, _) in zip(cells, rough_of_cell, strict=True):
            w.put(round((c.phaserange_m / _LIGHT_MS - r) * 2**31), 24, signed=True, name="DF406")
        for c in cells:
            w.put(lock_indicator_msm7(c.lock_time_s * 1000), 10, name="DF407")
        for _ in cells:
            w.put(0, 1)
        for c in cells:
            w.put(min(1023, max(0, round(c.cnr_dbhz * 16))), 10, name="DF408")
        for c, (_, rr) in zip(cells, rough_of_cell, strict=True):
            w.put(round((c.phaserange_rate_mps - rr) / 1e-4), 15, signed=True, name="DF404")
    return w.to_bytes()


def gps_epoch_from_tow_ms(tow_ms: int, near_gps_ns: int) -> int:
    """Full GPS time (ns) of a time-of-week in ms, taking the week that puts it nearest ``near_gps_ns``."""
    week_ns = SECONDS_PER_WEEK * NS_PER_S
    base = (near_gps_ns // week_ns) * week_ns + tow_ms * 1_000_000
    candidates = (base - week_ns, base, base + week_ns)
    return min(candidates, key=lambda c: abs(c - near_gps_ns))
