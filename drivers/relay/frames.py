"""Whole-frame extraction for RTK correction streams: RTCM3, NovAtel RTCA and Trimble CMR.

Pure code, no I/O: :class:`CorrectionFramer` takes bytes in any chunking and returns the whole
frames whose check passed. A frame that fails its check is never returned; it is counted in
:class:`CorrectionFramerStats` and the search resumes one byte after its start, so a good frame
hidden inside a bad one's claimed length is still found.

Framings (the relay forwards ``raw`` unchanged):

- **RTCM3** (RTCM 10403.x): ``D3``, 6 reserved bits (0), 10-bit payload length, payload, CRC-24Q
  over header and payload. The message number is the first 12 bits of the payload.
- **RTCA** (NovAtel's RTCA / SCAT-I message block, RTCA DO-217, as sent by OEM receivers for the
  RTCA, RTCAOBS, RTCAOBS2, RTCAREF, RTCAEPHEM logs): message block identifier ``99`` (SCAT-I),
  24-bit ground station id, message type, message length (the whole block in bytes, header and
  CRC included), message, 24-bit CRC. The block is sent least significant bit first, so the CRC
  is CRC-24Q over the *bit-reversed* bytes: running CRC-24Q over the bit-reversed block, CRC
  included, leaves 0. Checked against the RTCA example in NovAtel's command reference
  (``$RTCA,9900000004475206…052DFB*20``, a 71-byte Type 1 block).
- **RTCA in NovAtel ASCII** (the ``RTCAA`` log): ``$RTCA,<hex of the block>*hh`` with the NMEA
  XOR checksum; a NovAtel rover takes it as a command. Both the XOR checksum and the block's own
  CRC must pass.
- **CMR / CMR+** (Trimble): ``02`` (STX), status, packet type (``93`` CMR, ``94`` CMR+,
  ``98`` CMR-W), data length N, N data bytes, checksum (sum of status, type, length and data
  modulo 256), ``03`` (ETX).

A candidate whose claimed end has not arrived yet is held. To keep a truncated frame (a source
cut mid-frame) from holding back the frames after it, a candidate is given up (counted as
truncated) when a complete CRC-24-checked frame (RTCM3 or RTCA) starts inside it and ends before
it. CMR's 8-bit checksum is too weak to be trusted for this. The decisions depend on the bytes
only, so every chunking of a stream gives the same frames, and the cost is linear in the bytes.

Counting: a candidate that fails its check is one rejected frame; the sync candidates inside
its claimed bytes are sync-search bytes (``skipped_bytes``), not more rejected frames.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum
from typing import Final

from drivers.novatel.crc import crc24q, xor_checksum

__all__ = [
    "CMR_PACKET_TYPES",
    "CorrectionFrame",
    "CorrectionFramer",
    "CorrectionFramerStats",
    "CorrectionKind",
    "bit_reverse_bytes",
    "cmr_checksum",
    "encode_cmr",
    "encode_rtca",
    "encode_rtca_ascii",
    "encode_rtcm3",
    "rtca_crc",
    "rtcm3_message_number",
]


class CorrectionKind(Enum):
    """Framing of a correction frame."""

    RTCM3 = "rtcm3"
    RTCA = "rtca"
    CMR = "cmr"


@dataclass(frozen=True, slots=True)
class CorrectionFrame:
    """One whole, checked correction frame.

    ``message_type`` is the RTCM3 message number, the RTCA message type, or the CMR packet
    type's sub-type (CMR ``93``: the CMR message type 0..4; CMR+ ``94``: the page number is not a
    type, so 0). ``label`` is what statistics are keyed by, e.g. ``"RTCM 1077"``, ``"RTCA 7"``,
    ``"CMR 0"``, ``"CMR+"``.
    """

    kind: CorrectionKind
    raw: bytes
    message_type: int
    label: str


@dataclass(slots=True)
class CorrectionFramerStats:
    """Running counts of a :class:`CorrectionFramer` (mutable; :meth:`copy` for a snapshot)."""

    bytes_in: int = 0
    bytes_in_frames: int = 0
    frames: dict[CorrectionKind, int] = field(default_factory=lambda: dict.fromkeys(CorrectionKind, 0))
    frames_by_label: dict[str, int] = field(default_factory=dict)
    rejected: dict[CorrectionKind, int] = field(default_factory=lambda: dict.fromkeys(CorrectionKind, 0))
    """Frames whose CRC, checksum or end marker failed (never returned)."""
    truncated: int = 0
    """Frames cut short: given up for a later good frame, at :meth:`CorrectionFramer.reset`, or at the end."""
    skipped_bytes: int = 0
    """Bytes not part of any returned frame (garbage, rejected and truncated frames)."""

    @property
    def total_frames(self) -> int:
        return sum(self.frames.values())

    @property
    def total_rejected(self) -> int:
        return sum(self.rejected.values())

    def copy(self) -> CorrectionFramerStats:
        return CorrectionFramerStats(
            self.bytes_in,
            self.bytes_in_frames,
            dict(self.frames),
            dict(self.frames_by_label),
            dict(self.rejected),
            self.truncated,
            self.skipped_bytes,
        )


RTCM3_PREAMBLE: Final = 0xD3
RTCA_BLOCK_ID: Final = 0x99  # SCAT-I message block identifier 1001 1001
RTCA_HEADER_LEN: Final = 6
RTCA_MIN_LEN: Final = RTCA_HEADER_LEN + 3
CMR_STX: Final = 0x02
CMR_ETX: Final = 0x03
#: Trimble packet types carried in the CMR envelope, with their statistics label prefix.
CMR_PACKET_TYPES: Final = {0x93: "CMR", 0x94: "CMR+", 0x98: "CMR-W"}
RTCM3_MAX_FRAME: Final = 1023 + 6
RTCA_ASCII_MAX: Final = 1 + 5 + 2 * 255 + 3  # "$RTCA," hex "*hh"

# Parser results: (status, end)
_OK: Final = 0
_NEED: Final = 1  # a plausible start whose end has not arrived
_NOT: Final = 2  # not a frame start: skip one byte
_BAD: Final = 3  # a complete candidate whose check failed
_NEVER: Final = 1 << 62


def _reverse_table() -> bytes:
    return bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))


_REVERSE: Final = _reverse_table()


def bit_reverse_bytes(data: bytes | bytearray | memoryview) -> bytes:
    """Each byte with its bit order reversed (MSB ↔ LSB)."""
    return bytes(data).translate(_REVERSE)


def rtca_crc(block_without_crc: bytes | bytearray | memoryview) -> bytes:
    """The 3 CRC bytes that end an RTCA block (CRC-24Q over the bit-reversed bytes, sent LSB first)."""
    crc = crc24q(bit_reverse_bytes(block_without_crc))
    return bit_reverse_bytes(crc.to_bytes(3, "big"))


def cmr_checksum(body: bytes | bytearray | memoryview) -> int:
    """CMR checksum: the sum modulo 256 of status, packet type, length and data bytes."""
    return sum(body) & 0xFF


def rtcm3_message_number(payload: bytes | bytearray | memoryview) -> int:
    """RTCM3 message number: the first 12 bits of the payload."""
    if len(payload) < 2:
        raise ValueError(f"RTCM3 payload of {len(payload)} bytes has no message number")
    return payload[0] << 4 | payload[1] >> 4


def encode_rtcm3(payload: bytes) -> bytes:
    """An RTCM3 frame around ``payload`` (at most 1023 bytes)."""
    if len(payload) > 1023:
        raise ValueError(f"RTCM3 payload of {len(payload)} bytes exceeds 1023")
    head = bytes((RTCM3_PREAMBLE, len(payload) >> 8, len(payload) & 0xFF)) + payload
    return head + crc24q(head).to_bytes(3, "big")


def encode_rtca(message_type: int, body: bytes, station_id: int = 0) -> bytes:
    """An RTCA (SCAT-I) message block: header, ``body`` and CRC."""
    total = RTCA_MIN_LEN + len(body)
    if total > 255:
        raise ValueError(f"RTCA block of {total} bytes exceeds 255")
    if not 0 <= message_type <= 255 or not 0 <= station_id < 1 << 24:
        raise ValueError(f"RTCA message type {message_type} or station id {station_id} out of range")
    block = bytes((RTCA_BLOCK_ID,)) + station_id.to_bytes(3, "big") + bytes((message_type, total)) + body
    return block + rtca_crc(block)


def encode_rtca_ascii(block: bytes) -> bytes:
    """NovAtel's ASCII wrapping of an RTCA block: ``$RTCA,<hex>*hh`` and CR LF."""
    text = b"RTCA," + block.hex().upper().encode("ascii")
    return b"$" + text + b"*" + f"{xor_checksum(text):02X}".encode("ascii") + b"\r\n"


def encode_cmr(packet_type: int, data: bytes, status: int = 0) -> bytes:
    """A CMR envelope: STX, status, packet type, length, data, checksum, ETX."""
    if len(data) > 255:
        raise ValueError(f"CMR data of {len(data)} bytes exceeds 255")
    body = bytes((status & 0xFF, packet_type & 0xFF, len(data))) + data
    return bytes((CMR_STX,)) + body + bytes((cmr_checksum(body), CMR_ETX))


_HEX_DIGITS: Final = frozenset(b"0123456789ABCDEFabcdef")


class CorrectionFramer:
    """Incremental framer for RTCM3, RTCA and CMR correction streams.

    The frames returned depend only on the byte stream, never on how it was cut into chunks, and
    the cost is linear in the bytes for any chunking: while a frame is incomplete the framer knows
    the buffer length at which anything could change (the frame's end, or the header of a frame
    that may complete inside it) and only appends until then.

    A candidate frame is given up (counted as truncated) when a complete CRC-24-checked frame
    (RTCM3 or RTCA) starts inside it and ends before it; of several, the one that ends first wins
    (what a byte-at-a-time reader sees first). A candidate that fails its check counts as one
    rejected frame; sync candidates inside a rejected frame's bytes are not counted again (their
    bytes are skipped bytes).

    Args:
        kinds: the framings to look for (all by default). Bytes of other framings are skipped.
    """

    def __init__(self, kinds: Iterable[CorrectionKind] = tuple(CorrectionKind)) -> None:
        self.kinds = frozenset(kinds)
        if not self.kinds:
            raise ValueError("CorrectionFramer needs at least one correction kind")
        sync = b""
        if CorrectionKind.RTCM3 in self.kinds:
            sync += rb"\xd3"
        if CorrectionKind.RTCA in self.kinds:
            sync += rb"\x99\$"
        if CorrectionKind.CMR in self.kinds:
            sync += rb"\x02"
        self._sync = re.compile(b"[" + sync + b"]")
        inner = bytes(b for b in (RTCM3_PREAMBLE, RTCA_BLOCK_ID) if _KIND_OF_SYNC[b] in self.kinds)
        # a frame that may start inside a held one (matches nothing when only CMR is framed)
        self._inner_re = re.compile(b"[" + re.escape(inner) + b"]" if inner else b"(?!)")
        self._watch = (inner[0], inner[-1]) if inner else (CMR_STX, CMR_STX)
        self._inner_key = -1  # stream offset of the held candidate that _inner_* belong to
        self._inner_live: list[int] = []  # undecided candidates inside it (offsets from it)
        self._inner_next = 1  # offset from it up to which candidates have been listed
        self._stats = CorrectionFramerStats()
        self._buf = bytearray()
        self._base = 0  # stream offset of _buf[0]
        self._need = 1  # buffer length at which scanning again can make progress
        self._hex_from = 0  # pending "$RTCA," log at _buf[0]: _buf[6:_hex_from] are hex digits, no '*'
        self._bad_end = 0  # stream offset where the last rejected frame's claimed bytes end

    # --- public API ---------------------------------------------------------------------

    @property
    def stats(self) -> CorrectionFramerStats:
        """Running counts (mutable; :meth:`CorrectionFramerStats.copy` for a snapshot)."""
        self._stats.bytes_in = self._base + len(self._buf)
        return self._stats

    def feed(self, data: bytes | bytearray | memoryview) -> list[CorrectionFrame]:
        """Add bytes; return the frames they complete, in stream order."""
        buf = self._buf
        buf += data
        # Below the decisive length only a new frame start inside the held one can change anything.
        if len(buf) < self._need and self._watch[0] not in data and self._watch[1] not in data:
            return []
        return self._scan(False)

    def reset(self) -> None:
        """Drop a partial frame (the source was reconnected): it counts as truncated."""
        if self._buf:
            self._give_up(len(self._buf))
        self._base += len(self._buf)
        self._buf = bytearray()
        self._need = 1
        self._hex_from = 0

    def finish(self) -> list[CorrectionFrame]:
        """End of stream: nothing more will complete the held bytes.

        A candidate still incomplete is given up (one truncated frame) and the bytes after its
        start are searched again, so a whole frame behind a truncated one is still returned.
        """
        frames = self._scan(True)
        self.reset()
        return frames

    @property
    def pending_bytes(self) -> int:
        """Bytes held while waiting for the rest of a frame."""
        return len(self._buf)

    # --- scanning -----------------------------------------------------------------------

    def _give_up(self, nbytes: int) -> None:
        # Bytes held for a candidate that never completed.
        self._stats.truncated += 1
        self._stats.skipped_bytes += nbytes

    def _scan(self, final: bool) -> list[CorrectionFrame]:
        buf = self._buf
        n = len(buf)
        out: list[CorrectionFrame] = []
        # A pending RTCAA log only changes with a '*', a non-hex byte or at its longest length.
        if self._hex_from and not final and n < RTCA_ASCII_MAX and _HEX_DIGITS.issuperset(buf[self._hex_from :]):
            self._hex_from = n
            self._need = n + 1
            return out
        self._hex_from = 0
        pos = 0
        need = 1
        stats = self._stats
        search = self._sync.search
        inner_search = self._inner_re.search
        truncated_at_end = False
        while pos < n:
            m = search(buf, pos)
            if m is None:
                stats.skipped_bytes += n - pos
                pos = n
                break
            start = m.start()
            stats.skipped_bytes += start - pos
            status, end, frame = self._parse(buf, start, n)
            if status == _NOT:
                stats.skipped_bytes += 1
                pos = start + 1
                continue
            # OK and BAD: complete, ends at ``end``; NEED: ``end`` is the length that decides it.
            if status != _NEED and self._inner_key != self._base + start and not inner_search(buf, start + 1, end):
                inner, inner_need = None, _NEVER  # nothing inside a complete frame could start a frame
            else:
                inner, inner_need = self._look_past(buf, start, n + 1 if status == _NEED else end, n)
            if inner is not None:
                q, q_end, q_frame = inner
                self._give_up(q - start)
                self._emit(out, q_frame, q_end - q)
                pos = q_end
            elif status == _OK and frame is not None:
                self._emit(out, frame, end - start)
                pos = end
            elif status == _BAD:
                if self._base + start >= self._bad_end:
                    stats.rejected[_KIND_OF_SYNC[buf[start]]] += 1
                    self._bad_end = self._base + end
                stats.skipped_bytes += 1
                pos = start + 1
            elif final:
                # End of stream: the candidate at ``start`` never completes; every later
                # candidate lies inside its claimed bytes, so it counts as one truncated frame.
                if not truncated_at_end:
                    stats.truncated += 1
                    truncated_at_end = True
                stats.skipped_bytes += 1
                pos = start + 1
            else:
                pos = start
                need = min(end, inner_need) - start
                if buf[start] == 0x24 and n - start > len(_RTCA_ASCII_HEAD) and buf.find(b"*", start) < 0:
                    self._hex_from = n - start
                break
        del buf[:pos]
        self._base += pos
        self._need = need
        return out

    def _emit(self, out: list[CorrectionFrame], frame: CorrectionFrame, length: int) -> None:
        stats = self._stats
        out.append(frame)
        stats.frames[frame.kind] += 1
        stats.frames_by_label[frame.label] = stats.frames_by_label.get(frame.label, 0) + 1
        stats.bytes_in_frames += length

    def _look_past(
        self, buf: bytearray, start: int, limit: int, n: int
    ) -> tuple[tuple[int, int, CorrectionFrame] | None, int]:
        """The complete CRC-24-checked frame after ``start`` that ends first, before ``limit``;
        and the least buffer length at which an incomplete one there could be decided.

        The candidates inside the one at ``start`` are kept between calls (as offsets from it), so
        a held frame's bytes are searched once, not on every feed.
        """
        key = self._base + start
        if self._inner_key != key:
            self._inner_key = key
            self._inner_live = []
            self._inner_next = 1
        live = self._inner_live
        stop = min(n, limit)
        if start + self._inner_next < stop:
            live.extend(m.start() - start for m in self._inner_re.finditer(buf, start + self._inner_next, stop))
            self._inner_next = stop - start
        best: tuple[int, int, CorrectionFrame] | None = None
        need = _NEVER
        keep: list[int] = []
        parse = self._parse
        for d in live:
            q = start + d
            if q >= stop:
                keep.append(d)
                continue
            status, end, frame = parse(buf, q, n)
            if status == _OK and frame is not None:
                keep.append(d)
                if end < limit and (best is None or end < best[1]):
                    best = (q, end, frame)
            elif status == _NEED:
                keep.append(d)
                need = min(need, end)
        self._inner_live = keep
        return best, need

    def _parse(self, buf: bytearray, start: int, n: int) -> tuple[int, int, CorrectionFrame | None]:
        b0 = buf[start]
        if b0 == RTCM3_PREAMBLE:
            return _parse_rtcm3(buf, start, n)
        if b0 == RTCA_BLOCK_ID:
            return _parse_rtca(buf, start, n)
        if b0 == 0x24:  # '$'
            return _parse_rtca_ascii(buf, start, n)
        return _parse_cmr(buf, start, n)


_KIND_OF_SYNC: Final = {
    RTCM3_PREAMBLE: CorrectionKind.RTCM3,
    RTCA_BLOCK_ID: CorrectionKind.RTCA,
    0x24: CorrectionKind.RTCA,
    CMR_STX: CorrectionKind.CMR,
}

_Result = tuple[int, int, CorrectionFrame | None]


def _parse_rtcm3(buf: bytearray, start: int, n: int) -> _Result:
    avail = n - start
    if avail < 2:
        return _NEED, start + 2, None
    if buf[start + 1] & 0xFC:
        return _NOT, 0, None
    if avail < 5:
        return _NEED, start + 5, None
    length = (buf[start + 1] & 0x03) << 8 | buf[start + 2]
    if length < 2:
        return _NOT, 0, None
    end = start + length + 6
    if end > n:
        return _NEED, end, None
    raw = bytes(buf[start:end])
    if crc24q(raw) != 0:
        return _BAD, end, None
    number = buf[start + 3] << 4 | buf[start + 4] >> 4
    return _OK, end, CorrectionFrame(CorrectionKind.RTCM3, raw, number, f"RTCM {number}")


def _parse_rtca(buf: bytearray, start: int, n: int) -> _Result:
    if n - start < RTCA_HEADER_LEN:
        return _NEED, start + RTCA_HEADER_LEN, None
    length = buf[start + 5]
    if length < RTCA_MIN_LEN:
        return _NOT, 0, None
    end = start + length
    if end > n:
        return _NEED, end, None
    raw = bytes(buf[start:end])
    if crc24q(raw.translate(_REVERSE)) != 0:
        return _BAD, end, None
    mtype = buf[start + 4]
    return _OK, end, CorrectionFrame(CorrectionKind.RTCA, raw, mtype, f"RTCA {mtype}")


_RTCA_ASCII_HEAD: Final = b"$RTCA,"


def _parse_rtca_ascii(buf: bytearray, start: int, n: int) -> _Result:
    head = buf[start : start + len(_RTCA_ASCII_HEAD)]
    if not _RTCA_ASCII_HEAD.startswith(head):
        return _NOT, 0, None
    if len(head) < len(_RTCA_ASCII_HEAD):
        return _NEED, n + 1, None
    star = buf.find(b"*", start + len(_RTCA_ASCII_HEAD), min(n, start + RTCA_ASCII_MAX))
    if star < 0:
        # Hex digits only until the '*'; anything else means this is not an RTCAA log.
        stop = min(n, start + RTCA_ASCII_MAX)
        body = buf[start + len(_RTCA_ASCII_HEAD) : stop]
        if not _HEX_DIGITS.issuperset(body):
            return _NOT, 0, None
        return (_NEED, n + 1, None) if stop < start + RTCA_ASCII_MAX else (_NOT, 0, None)
    end = star + 3
    if end > n:
        return _NEED, end, None
    hex_body = buf[start + len(_RTCA_ASCII_HEAD) : star]
    if not hex_body or len(hex_body) % 2 or not _HEX_DIGITS.issuperset(hex_body):
        return _NOT, 0, None
    try:
        expected = int(buf[star + 1 : end], 16)
    except ValueError:
        return _NOT, 0, None
    if xor_checksum(buf[start + 1 : star]) != expected:
        return _BAD, end, None
    block = bytes.fromhex(hex_body.decode("ascii"))
    if len(block) < RTCA_MIN_LEN or block[0] != RTCA_BLOCK_ID or block[5] != len(block):
        return _BAD, end, None
    if crc24q(block.translate(_REVERSE)) != 0:
        return _BAD, end, None
    # The rover parses the log as a command line, so the frame always ends with CR LF; the CR LF
    # that follows in the stream is taken with it when it has arrived (not waited for).
    raw = bytes(buf[start:end]) + b"\r\n"
    if buf[end : end + 2] == b"\r\n":
        end += 2
    mtype = block[4]
    return _OK, end, CorrectionFrame(CorrectionKind.RTCA, raw, mtype, f"RTCA {mtype}")


def _parse_cmr(buf: bytearray, start: int, n: int) -> _Result:
    avail = n - start
    if avail < 3:
        return _NEED, start + 3, None
    if buf[start + 2] not in CMR_PACKET_TYPES:
        return _NOT, 0, None
    if avail < 4:
        return _NEED, start + 4, None
    length = buf[start + 3]
    end = start + length + 6
    if end > n:
        return _NEED, end, None
    if buf[end - 1] != CMR_ETX or cmr_checksum(buf[start + 1 : end - 2]) != buf[end - 2]:
        return _BAD, end, None
    raw = bytes(buf[start:end])
    ptype = buf[start + 2]
    prefix = CMR_PACKET_TYPES[ptype]
    if ptype == 0x93 and length >= 2:
        mtype = buf[start + 5] >> 5  # CMR header: version(3) station(5) | type(3) nsv(5)
        return _OK, end, CorrectionFrame(CorrectionKind.CMR, raw, mtype, f"{prefix} {mtype}")
    return _OK, end, CorrectionFrame(CorrectionKind.CMR, raw, 0, prefix)
