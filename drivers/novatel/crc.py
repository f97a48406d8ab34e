"""Checksums of the streams a NovAtel port carries: NovAtel CRC-32, RTCM3 CRC-24Q, NMEA XOR.

NovAtel's CRC-32 is the reflected polynomial 0xEDB88320 with initial value 0 and no final XOR.
zlib's CRC-32 is the same polynomial with initial value 0xFFFFFFFF and a final XOR with
0xFFFFFFFF, and ``zlib.crc32(data, value)`` starts its register at ``value ^ 0xFFFFFFFF``. So
passing ``value = 0xFFFFFFFF`` starts the register at 0 and only the final XOR remains to undo:

    novatel_crc32(data) == zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF

which runs in C. Because there is no final XOR, running the register over a binary frame
*including* its little-endian CRC leaves 0 (``zlib.crc32(frame, 0xFFFFFFFF) == 0xFFFFFFFF``); the
framer uses that to check a frame in one call without slicing it.
"""

from __future__ import annotations

import zlib

_MASK32 = 0xFFFFFFFF


def novatel_crc32(data: bytes | bytearray | memoryview) -> int:
    """NovAtel CRC-32 (poly 0xEDB88320 reflected, init 0, no final XOR) of ``data``."""
    return zlib.crc32(data, _MASK32) ^ _MASK32


def novatel_crc32_residue_ok(frame: bytes | bytearray | memoryview) -> bool:
    """True when a binary frame (header + body + little-endian CRC) checks."""
    return zlib.crc32(frame, _MASK32) == _MASK32


def _crc24q_table() -> tuple[int, ...]:
    poly = 0x1864CFB
    table = []
    for byte in range(256):
        crc = byte << 16
        for _ in range(8):
            crc <<= 1
            if crc & 0x1000000:
                crc ^= poly
        table.append(crc & 0xFFFFFF)
    return tuple(table)


_CRC24Q_TABLE = _crc24q_table()


def crc24q(data: bytes | bytearray | memoryview) -> int:
    """RTCM3 CRC-24Q (poly 0x1864CFB, init 0, MSB first) of ``data``.

    Over a whole RTCM3 frame including its 3 CRC bytes the result is 0.
    """
    table = _CRC24Q_TABLE
    crc = 0
    for octet in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ table[(crc >> 16) ^ octet]
    return crc


def xor_checksum(data: bytes | bytearray) -> int:
    """NMEA 0183 checksum: XOR of all bytes (between ``$`` and ``*``).

    Folds the bytes as one big integer, halving its width each step, so the work is done by a few
    C-level integer operations instead of a per-byte Python loop.
    """
    n = len(data)
    if n == 0:
        return 0
    value = int.from_bytes(data, "little")
    width = n  # in bytes
    while width > 1:
        half = (width + 1) // 2
        shift = half * 8
        value = (value >> shift) ^ (value & ((1 << shift) - 1))
        width = half
    return value
