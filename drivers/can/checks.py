"""End-to-end protection of CAN frames: frame flags, checksum algorithms and counter checks.

A DBC names the ``COUNTER`` / ``CHECKSUM`` signals of a message but not how the checksum is
computed, so algorithms are chosen by name from a small registry (``"vw_mqb_crc8"``, ``"none"``,
more via :func:`register_checksum`). Every algorithm has a per-frame form (live decoding) and a
vectorised form over an ``(n, length)`` payload array (offline decoding); both give the same
numbers, and the tests hold them to each other and to hand-computed CRCs.

Counter checks follow AUTOSAR E2E: a frame is flagged when its counter did not advance by
1..``max_delta`` (modulo the counter range) since the last frame that passed its own checks; a
repeated counter (stale sender) is flagged too. Frames that fail length or checksum checks do
not advance the counter state, so the live and vectorised paths flag exactly the same frames.
"""

from __future__ import annotations

import difflib
import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from vsccore.errors import ConfigError, DecodeError

__all__ = [
    "CAN_EFF_FLAG",
    "CHECKSUM_NONE",
    "VW_MQB_DATA_IDS",
    "ChecksumAlgorithm",
    "CounterTracker",
    "FrameFlag",
    "NoChecksum",
    "VwMqbCrc8",
    "available_checksums",
    "counter_errors",
    "crc8_8h2f_table",
    "frame_key",
    "get_checksum",
    "register_checksum",
]


CAN_EFF_FLAG = 0x8000_0000
"""Marks a 29-bit (extended) identifier in a frame key, as SocketCAN's ``can_id`` does."""


def frame_key(arbitration_id: int, is_extended: bool = False) -> int:
    """The identifier key of a frame: 11- or 29-bit id, with :data:`CAN_EFF_FLAG` for extended frames.

    Base frame 0x101 and extended frame 0x00000101 are different messages; decoders and
    :class:`~drivers.can.vector_decode.FrameBatch` keep them apart by this key. An
    ``arbitration_id`` that already carries the flag keeps it.
    """
    extended = is_extended or bool(arbitration_id & CAN_EFF_FLAG)
    return (arbitration_id & 0x1FFF_FFFF) | (CAN_EFF_FLAG if extended else 0)


class FrameFlag(enum.IntFlag):
    """Why a frame (or one value from it) is not a plain good value.

    Frame-level flags (``WRONG_LENGTH``, ``CHECKSUM``, ``COUNTER``, ``DECODE_ERROR``) mean the
    frame yields no values at all. ``INVALID`` (the ECU's own quality bit says the value is a
    substitute) keeps the decoded value and only marks it. ``ABSENT`` marks a value that this
    frame does not carry (its multiplexer selects another page). ``UNKNOWN_ID`` marks a frame
    whose identifier is not in the DBC. Stored as ``uint16`` in the vectorised arrays.
    """

    OK = 0
    UNKNOWN_ID = 1
    WRONG_LENGTH = 2
    CHECKSUM = 4
    COUNTER = 8
    DECODE_ERROR = 16
    INVALID = 32
    ABSENT = 64

    @classmethod
    def frame_level(cls) -> FrameFlag:
        """Flags that suppress every value of a frame."""
        return cls.WRONG_LENGTH | cls.CHECKSUM | cls.COUNTER | cls.DECODE_ERROR | cls.UNKNOWN_ID

    def names(self) -> list[str]:
        """The set member names, e.g. ``["CHECKSUM", "COUNTER"]`` (empty for ``OK``)."""
        return [m.name for m in FrameFlag if m.value and (self & m) and m.name is not None]


@runtime_checkable
class ChecksumAlgorithm(Protocol):
    """A named checksum scheme for CAN payloads.

    ``compute`` takes the whole payload as sent (the checksum field's own bits are ignored by
    the algorithm) and returns the value the checksum signal must hold. ``compute_many`` does
    the same for ``n`` frames of one identifier at once.
    """

    @property
    def name(self) -> str:
        """The name configurations use (``algorithm = "..."``)."""
        ...

    def supports(self, arbitration_id: int) -> bool:
        """Whether the algorithm knows how to protect frames with this identifier."""
        ...

    def compute(self, arbitration_id: int, data: bytes) -> int:
        """Expected checksum value of one payload. Raises DecodeError for an unsupported id."""
        ...

    def compute_many(self, arbitration_id: int, data: NDArray[np.uint8]) -> NDArray[np.int64]:
        """Expected checksum values of an ``(n, length)`` payload array."""
        ...


@dataclass(frozen=True, slots=True)
class NoChecksum:
    """The ``"none"`` algorithm: nothing to check (``supports`` is always true)."""

    name: str = "none"

    def supports(self, arbitration_id: int) -> bool:
        return True

    def compute(self, arbitration_id: int, data: bytes) -> int:
        return 0

    def compute_many(self, arbitration_id: int, data: NDArray[np.uint8]) -> NDArray[np.int64]:
        return np.zeros(data.shape[0], dtype=np.int64)


def crc8_8h2f_table() -> NDArray[np.uint8]:
    """Lookup table of the AUTOSAR CRC-8H2F (polynomial 0x2F, MSB first)."""
    table = np.zeros(256, dtype=np.uint8)
    for i in range(256):
        crc = i
        for _ in range(8):
            crc = ((crc << 1) ^ 0x2F) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[i] = crc
    return table


def _repeat16(value: int) -> tuple[int, ...]:
    return (value,) * 16


def _hex(text: str) -> tuple[int, ...]:
    return tuple(bytes.fromhex(text))


# Per-message "data ID" bytes of the VW MQB E2E profile (AUTOSAR E2E P2), indexed by the
# 4-bit counter. Public knowledge collected by the opendbc project (MIT); many messages use
# one constant for all counter values, others a table.
VW_MQB_DATA_IDS: Mapping[int, tuple[int, ...]] = {
    0x040: _repeat16(0x40),  # Airbag_01
    0x086: _repeat16(0x86),  # LWI_01
    0x09F: _repeat16(0xF5),  # LH_EPS_03
    0x0AD: _hex("3F 69 39 DC 94 F9 14 64 D8 6A 34 CE A2 55 B5 2C"),  # Getriebe_11
    0x0FD: _hex("B4 EF F8 49 1E E5 C2 C0 97 19 3C C9 F1 98 D6 61"),  # ESP_21
    0x101: _repeat16(0xAA),  # ESP_02
    0x106: _repeat16(0x07),  # ESP_05
    0x116: _repeat16(0xAC),  # ESP_10
    0x117: _repeat16(0x16),  # ACC_10
    0x120: _hex("C4 E2 4F E4 F8 2F 56 81 9F E5 83 44 05 3F 97 DF"),  # TSK_06
    0x121: _hex("E9 65 AE 6B 7B 35 E5 5F 4E C7 86 A2 BB DD EB B4"),  # Motor_20
    0x122: _hex("37 7D F3 A9 18 46 6D 4D 3D 71 92 9C E5 32 10 B9"),  # ACC_06
    0x126: _repeat16(0xDA),  # HCA_01
    0x12B: _hex("6A 38 B4 27 22 EF E1 BB F8 80 84 49 C7 9E 1E 2B"),  # GRA_ACC_01
    0x12E: _hex("F8 E5 97 C9 D6 07 47 21 66 DD CF 6F A1 94 74 63"),  # ACC_07
    0x187: _hex("7F ED 17 C2 7C EB 44 21 01 FA DB 15 4A 6B 23 05"),  # Motor_EV_01
    0x1AB: _hex("13 21 9B 6A 9A 62 D4 65 18 F1 AB 16 32 89 E7 26"),  # ESP_33
    0x30C: _repeat16(0x0F),  # ACC_02
    0x30F: _repeat16(0x0C),  # SWA_01
    0x324: _repeat16(0x27),  # ACC_04
    0x3C0: _repeat16(0xC3),  # Klemmen_Status_01
    0x3D5: _hex("C5 39 C7 F9 92 D8 24 CE F1 B5 7A C4 BC 60 E3 D1"),  # Licht_Anf_01
    0x65D: _hex("AC B3 AB EB 7A E1 3B F7 73 BA 7C 9E 06 5F 02 D9"),  # ESP_20
}


@dataclass(frozen=True, slots=True)
class VwMqbCrc8:
    """VW MQB checksum: AUTOSAR E2E profile 2, CRC-8H2F with a per-message data ID.

    The CRC (init 0xFF, final XOR 0xFF) runs over payload bytes 1..length-1 (byte 0 holds the
    checksum, the low nibble of byte 1 the counter) and then over one data-ID byte chosen by
    the frame identifier and the counter. ``data_ids`` maps identifiers to their 16 data IDs;
    pass your own table for messages the default table does not know.
    """

    data_ids: Mapping[int, tuple[int, ...]] = field(default_factory=lambda: dict(VW_MQB_DATA_IDS))
    name: str = "vw_mqb_crc8"
    _table: NDArray[np.uint8] = field(default_factory=crc8_8h2f_table, repr=False, compare=False)

    def supports(self, arbitration_id: int) -> bool:
        return arbitration_id in self.data_ids

    def _ids(self, arbitration_id: int) -> NDArray[np.uint8]:
        try:
            return np.asarray(self.data_ids[arbitration_id], dtype=np.uint8)
        except KeyError:
            raise DecodeError(
                f"vw_mqb_crc8: no data-ID table for CAN id 0x{arbitration_id:X}; "
                "the MQB checksum cannot be verified for this message"
            ) from None

    def compute(self, arbitration_id: int, data: bytes) -> int:
        ids = self._ids(arbitration_id)
        if len(data) < 2:
            raise DecodeError(f"vw_mqb_crc8: CAN id 0x{arbitration_id:X} payload of {len(data)} bytes is too short")
        table = self._table
        crc = 0xFF
        for byte in data[1:]:
            crc = int(table[crc ^ byte])
        crc = int(table[crc ^ int(ids[data[1] & 0x0F])])
        return crc ^ 0xFF

    def compute_many(self, arbitration_id: int, data: NDArray[np.uint8]) -> NDArray[np.int64]:
        ids = self._ids(arbitration_id)
        if data.ndim != 2 or data.shape[1] < 2:
            raise DecodeError(
                f"vw_mqb_crc8: CAN id 0x{arbitration_id:X} payload array of shape {data.shape} is too short"
            )
        table = self._table
        crc = np.full(data.shape[0], 0xFF, dtype=np.uint8)
        for col in range(1, data.shape[1]):
            crc = table[crc ^ data[:, col]]
        crc = table[crc ^ ids[data[:, 1] & 0x0F]]
        return (crc ^ np.uint8(0xFF)).astype(np.int64)


CHECKSUM_NONE = "none"

_REGISTRY: dict[str, ChecksumAlgorithm] = {
    CHECKSUM_NONE: NoChecksum(),
    "vw_mqb_crc8": VwMqbCrc8(),
}


def register_checksum(algorithm: ChecksumAlgorithm, *, replace: bool = False) -> None:
    """Make a checksum algorithm available by its ``name`` to role configurations.

    Raises:
        ConfigError: the name is taken and ``replace`` is false.
    """
    if algorithm.name in _REGISTRY and not replace:
        raise ConfigError(f"checksum algorithm {algorithm.name!r} is already registered")
    _REGISTRY[algorithm.name] = algorithm


def available_checksums() -> tuple[str, ...]:
    """Names accepted by :func:`get_checksum`, sorted."""
    return tuple(sorted(_REGISTRY))


def get_checksum(name: str, *, where: str = "checksum") -> ChecksumAlgorithm:
    """Look a checksum algorithm up by name.

    Raises:
        ConfigError: unknown name; the message names ``where`` (the config key) and suggests
            close matches.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        close = difflib.get_close_matches(name, list(_REGISTRY), n=3)
        hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        raise ConfigError(
            f"{where}: unknown checksum algorithm {name!r} (known: {', '.join(available_checksums())}){hint}"
        ) from None


def counter_errors(counters: NDArray[np.integer], modulus: int, max_delta: int = 1) -> NDArray[np.bool_]:
    """Flag counter jumps in a sequence of consecutive frames of one message.

    Frame ``i > 0`` is flagged when ``(c[i] - c[i-1]) mod modulus`` is 0 (repeated, stale) or
    larger than ``max_delta`` (frames lost). The first frame is never flagged. The caller passes
    only frames that passed their length and checksum checks.
    """
    c = np.asarray(counters, dtype=np.int64)
    bad = np.zeros(c.shape[0], dtype=bool)
    if c.shape[0] > 1:
        delta = np.mod(c[1:] - c[:-1], modulus)
        bad[1:] = (delta == 0) | (delta > max_delta)
    return bad


@dataclass(slots=True)
class CounterTracker:
    """Live form of :func:`counter_errors` for one message: feed counters one frame at a time."""

    modulus: int
    max_delta: int = 1
    _last: int | None = None

    def check(self, counter: int) -> bool:
        """Record ``counter``; return True when it is a jump or a repeat (the frame is flagged)."""
        last, self._last = self._last, counter
        if last is None:
            return False
        delta = (counter - last) % self.modulus
        return delta == 0 or delta > self.max_delta

    def reset(self) -> None:
        """Forget the last counter (e.g. after the bus was reopened)."""
        self._last = None
