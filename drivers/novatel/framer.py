"""Framer: finds and validates frames in a raw byte stream from a NovAtel port, in any mix.

Recognised frames (:class:`FrameKind`):

- NovAtel ASCII logs ``#…;…*xxxxxxxx`` and short ASCII ``%…;…*xxxxxxxx`` (CRC-32),
- NovAtel binary logs, long header ``AA 44 12`` and short header ``AA 44 13`` (CRC-32),
- abbreviated ASCII: responses ``<OK`` / ``<ERROR:…``, logs ``<NAME port …`` plus their
  ``<     …`` continuation lines, and port prompts ``[COM1]``, ``[USB1]``, ``[ICOM1]``,
- NMEA 0183 sentences ``$…*hh`` (XOR checksum; fields decoded by pynmea2),
- RTCM3 frames ``D3``, 10-bit length, CRC-24Q (decoded by pyrtcm).

The framer is incremental: :meth:`Framer.feed` takes any chunk and returns the frames it completes,
as a tuple (a frame split across chunks is reassembled; when none completes, one shared empty tuple:
the common small read allocates nothing); :meth:`Framer.finish` ends the stream.
:class:`FrameReader` drives it from any object with ``read(n)``. Sync candidates are found with
one compiled regular expression (a C-level scan), CRCs run in C (zlib) for NovAtel frames. The
common case, a standard long-header binary log, is handled inline in the scan loop and decoded by
a generated whole-frame decoder (:func:`drivers.novatel.binary.compile_long_frame_decoders`);
everything else, and anything that decoder declines, goes through the per-kind parsers with the
same result.

A frame whose CRC fails is never returned. Every byte that is not part of a returned frame is
counted in :class:`FramerStats` by reason (garbage, CRC failure, truncated, oversize), and CR/LF
line ends between text frames are counted apart. After a rejection the framer resumes the
search one byte after the rejected start, so a good frame hidden inside a bad one's claimed
length is still found. ``Frame.raw`` is the exact frame bytes, without the CR LF that follows
text frames.

An abbreviated-ASCII log has no end marker: it is complete when the next byte after a
continuation line is not another continuation line. At the end of a chunk the framer therefore
waits for the next byte (or :meth:`Framer.finish`; a receiver session may call
:meth:`Framer.flush` after a read timeout).

The cost is linear in the bytes fed, however they are chunked (a serial port at 460 800 baud
delivers 1–64 bytes per read). When a scan stops inside an incomplete frame, the parser says what
could change its verdict: the buffer reaching a length (the rest of a binary or RTCM3 frame, the
CRC digits of a text frame) and/or a byte from a small set arriving (the ``*`` or line break a text
frame waits for, a non-hex digit in its CRC field). :meth:`Framer.feed` only appends the bytes and
returns until then, so a partial frame is rescanned a bounded number of times, not once per chunk;
an abbreviated log resumes at its last complete line. Between frames the same holds: after a frame
the next bytes wait until they could hold a complete frame (10 bytes, or a byte that ends one of
the few frames shorter than that), and bytes that start no frame wait for a sync byte (at most
512 of them), so a binary log fed one byte at a time is looked at twice: at its header and at its
end (neither needs a scan). A look at a frame that waits at the start of the held bytes (its sync
byte, a text log's header, its ``*`` or CRC digits, an RTCM3 header) asks only that frame's parser,
which is what a scan would do first; a scan runs once the parser has a verdict, and takes it from
there, so a text or RTCM3 frame fed one byte at a time is scanned once. Frames and counts are the
same for any chunking, and a frame is returned by the very ``feed`` that completes it; bytes that
are still held (:attr:`Framer.pending_bytes`) are counted in the stats once a scan has classified
them.

A 1-byte feed that changes no verdict appends the byte, compares the buffer's length with the end of
the frame in progress (the rest of a binary log or RTCM3 frame) or, when a byte may end the wait (a
text frame's ``*`` or CRC digits, the bytes after a frame, garbage), with the wait's length and makes
one set lookup, and returns the shared empty tuple. That entry is written in C
(``drivers/novatel/_feed.c``, the base class of :class:`Framer`, built by ``setup.py`` where a C compiler
is found; :data:`FEED_IMPLEMENTATION` says which one runs): in Python it costs a Python call and a few
attribute loads per read, which was most of a 1-byte-at-a-time feed's cost. Everything after the entry
(a look at the held bytes) is Python, the same for both. ``benchmarks/bench_framer_chunking.py``, 1 MB of a
receiver's stream fed one byte at a time, idle 2-CPU machine, medians of 9 rounds: 2.14x one 1 MB call
with the C entry (goal 3x), 3.67x with the pure-Python twin. Streams that one call passes over at C speed
cost more in ratio (the benchmark's ``worst`` stream, 5.0x with the C entry: its 400-line abbreviated
logs wake a Python look at each line end), still linear in the bytes.
"""

from __future__ import annotations

import logging
import re
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any, Protocol

import pynmea2
from pyrtcm import RTCMReader

from drivers.novatel.ascii import decode_abbreviated_lines, decode_ascii_text
from drivers.novatel.binary import compile_long_frame_decoders, decode_verified
from drivers.novatel.crc import crc24q, xor_checksum
from drivers.novatel.messages import Log, Prompt, Response, fast_constructor
from vsccore.errors import DecodeError

_log = logging.getLogger(__name__)

DEFAULT_MAX_FRAME_LEN = 32768
#: NMEA 0183 allows 82 characters; NovAtel's proprietary sentences are longer, so allow some room.
MAX_NMEA_LEN = 1024


class FrameKind(Enum):
    """Kind of a frame found in the stream."""

    # Members are singletons compared by identity; hashing by identity (in C) instead of Enum's
    # Python-level hash of the name keeps per-frame counting off the profile.
    __hash__ = object.__hash__

    NOVATEL_ASCII = "novatel_ascii"
    NOVATEL_SHORT_ASCII = "novatel_short_ascii"
    NOVATEL_ABBREV = "novatel_abbrev"
    NOVATEL_BINARY = "novatel_binary"
    NOVATEL_SHORT_BINARY = "novatel_short_binary"
    RESPONSE = "response"
    PROMPT = "prompt"
    NMEA = "nmea"
    RTCM3 = "rtcm3"


#: Kinds whose message is a NovAtel :class:`Log`.
LOG_KINDS = frozenset(
    {
        FrameKind.NOVATEL_ASCII,
        FrameKind.NOVATEL_SHORT_ASCII,
        FrameKind.NOVATEL_ABBREV,
        FrameKind.NOVATEL_BINARY,
        FrameKind.NOVATEL_SHORT_BINARY,
    }
)


class SkipReason(Enum):
    """Why bytes were not returned as part of a frame."""

    __hash__ = object.__hash__

    GARBAGE = "garbage"  # no frame starts there
    CRC_FAILURE = "crc_failure"  # inside a frame candidate whose CRC/checksum failed
    TRUNCATED = "truncated"  # a frame cut short (line break before its CRC, or end of stream)
    OVERSIZE = "oversize"  # a frame candidate longer than the framer's bound


@dataclass(frozen=True, slots=True)
class Frame:
    """One validated frame: its kind, exact bytes and decoded message.

    ``message`` is a :class:`Log` for NovAtel logs, a :class:`Response` or :class:`Prompt`, a
    pynmea2 sentence for NMEA, a pyrtcm ``RTCMMessage`` for RTCM3, or None when decoding was
    switched off or failed; ``error`` then says why (the frame itself is valid: its CRC checked).
    """

    kind: FrameKind
    raw: bytes
    message: Any = None
    error: str | None = None

    @property
    def log(self) -> Log | None:
        """The NovAtel log, if this frame carries one."""
        return self.message if isinstance(self.message, Log) else None


_new_frame = fast_constructor(Frame)
#: What feed() returns when no frame completes: one shared (immutable) empty tuple, no allocation.
_NO_FRAMES: tuple[Frame, ...] = ()
_BINARY = FrameKind.NOVATEL_BINARY
_crc32 = zlib.crc32
# Generated decoders that turn a verified standard long-header binary frame straight into a Frame.
_FAST_FRAMES, _fast_raw_frame = compile_long_frame_decoders((Frame, _BINARY))
_FAST_FRAMES_GET = _FAST_FRAMES.get


def _zero_counts(keys: type[Enum]) -> dict[Any, int]:
    return dict.fromkeys(keys, 0)


@dataclass(slots=True)
class FramerStats:
    """Running counts of a framer (mutable; take :meth:`copy` for a snapshot)."""

    frames: dict[FrameKind, int] = field(default_factory=lambda: _zero_counts(FrameKind))
    crc_failures: dict[FrameKind, int] = field(default_factory=lambda: _zero_counts(FrameKind))
    decode_errors: dict[FrameKind, int] = field(default_factory=lambda: _zero_counts(FrameKind))
    oversize: dict[FrameKind, int] = field(default_factory=lambda: _zero_counts(FrameKind))
    bytes_skipped: dict[SkipReason, int] = field(default_factory=lambda: _zero_counts(SkipReason))
    truncated: int = 0
    line_end_bytes: int = 0
    bytes_in: int = 0
    bytes_in_frames: int = 0

    @property
    def total_frames(self) -> int:
        return sum(self.frames.values())

    @property
    def total_skipped(self) -> int:
        return sum(self.bytes_skipped.values())

    def copy(self) -> FramerStats:
        return FramerStats(
            dict(self.frames),
            dict(self.crc_failures),
            dict(self.decode_errors),
            dict(self.oversize),
            dict(self.bytes_skipped),
            self.truncated,
            self.line_end_bytes,
            self.bytes_in,
            self.bytes_in_frames,
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able view (zero counts left out of the per-kind maps)."""
        return {
            "frames": {k.value: v for k, v in self.frames.items() if v},
            "crc_failures": {k.value: v for k, v in self.crc_failures.items() if v},
            "decode_errors": {k.value: v for k, v in self.decode_errors.items() if v},
            "oversize": {k.value: v for k, v in self.oversize.items() if v},
            "bytes_skipped": {k.value: v for k, v in self.bytes_skipped.items() if v},
            "truncated": self.truncated,
            "line_end_bytes": self.line_end_bytes,
            "bytes_in": self.bytes_in,
            "bytes_in_frames": self.bytes_in_frames,
        }


# Parser results: (status, end, payload).
_OK = 0  # payload: Frame; end: frame end
_NEED = 1  # payload: kind once the sync is complete, else None; end: buffer length worth a rescan
_NOT_FRAME = 2  # skip one byte as garbage
_CRC_FAIL = 3  # payload: kind; end: end of the candidate
_TRUNC = 4  # payload: kind; end: where the frame was cut
_OVERSIZE = 5  # payload: kind

_Result = tuple[int, int, Any]

_SYNC = re.compile(rb"[#%<\[$\xaa\xd3]")
_SYNC_BYTES = b"#%<[$\xaa\xd3"
#: Sync and header length of a standard long-header binary log.
_LONG_SYNC_28 = b"\xaa\x44\x12\x1c"
_HEX_DIGITS = b"0123456789ABCDEFabcdef"
_HEX2 = re.compile(rb"[0-9A-Fa-f]{2}")
_LINE_BREAK = re.compile(rb"[\r\n]")
_PROMPT = re.compile(rb"\[([A-Z][A-Z0-9_]{0,15})\]")
_PROMPT_PARTIAL = re.compile(rb"\[(?:[A-Z][A-Z0-9_]{0,15})?")
_ABBREV_HEADER = re.compile(
    rb"<[A-Z][A-Z0-9]*(?:_\d+)? +[A-Z][A-Z0-9_]* +\d+ +[\d.]+ +[A-Z0-9_]+ +\d+ +[\d.]+"
    rb" +[0-9A-Fa-f]+ +[0-9A-Fa-f]+ +\d+ *\r?$"
)
_NMEA_ADDRESS = re.compile(rb"\$[A-Z][A-Z0-9]{1,9},")
#: After a scan that ended at a frame's end, new bytes are held until there are this many, or one of
#: _WAKE_AFTER_FRAME arrives: a frame that completes within 10 bytes is a prompt (ends in ']'), a
#: response (its line end), an NMEA sentence (has a '$') or an RTCM3 frame (has its 0xD3); text logs
#: take 11 bytes at least and binary logs 16. So the header of the next binary log is scanned once.
_AFTER_FRAME_LEN = 10
#: Bytes without a sync byte held before they are counted as skipped (they can start no frame).
_GARBAGE_HOLD = 512

_WakeSearch = Callable[[bytes | bytearray | memoryview], Any]
_Wake = tuple[frozenset[bytes], _WakeSearch]


def _wake_on(pattern: bytes) -> _Wake:
    """Bytes that end a wait early: as a set of 1-byte strings (a 1-byte feed is a hash lookup,
    not a regex call) and as a regex search (for longer chunks)."""
    compiled = re.compile(pattern)
    return frozenset(bytes([c]) for c in range(256) if compiled.match(bytes([c]))), compiled.search


# Bytes that end the wait of an incomplete frame before it reaches its expected length.
_WAKE_TEXT_END = _wake_on(rb"[*\r\n]")  # a text frame waiting for its '*' (or a line break)
_WAKE_LINE_END = _wake_on(rb"\n")  # an abbreviated-ASCII line waiting for its end
_WAKE_NOT_HEX = _wake_on(rb"[^0-9A-Fa-f]")  # a CRC field that would stop being hex digits
_WAKE_NOT_44 = _wake_on(rb"[^\x44]")  # a binary sync's second byte that is not 0x44
_WAKE_NOT_LT = _wake_on(rb"[^<]")  # after an abbreviated log's line: anything but a continuation's '<'
_WAKE_SYNC = _wake_on(_SYNC.pattern)  # garbage held: only a sync byte can start a frame
_WAKE_AFTER_FRAME = _wake_on(rb"[\]\n$\xd3]")  # see _AFTER_FRAME_LEN

_ALL_BYTES = frozenset(bytes([c]) for c in range(256))
#: The 1-byte chunks that :meth:`Framer.feed` keeps without a look, per wake set (None: any byte).
_QUIET: dict[frozenset[bytes] | None, frozenset[bytes]] = {None: _ALL_BYTES} | {
    wake[0]: _ALL_BYTES - wake[0]
    for wake in (_WAKE_TEXT_END, _WAKE_LINE_END, _WAKE_NOT_HEX, _WAKE_NOT_44, _WAKE_NOT_LT, _WAKE_SYNC,
                 _WAKE_AFTER_FRAME)
}
_QUIET_AFTER_FRAME = _QUIET[_WAKE_AFTER_FRAME[0]]


def _rtcm_number_plausible(number: int) -> bool:
    # Standard messages 1001-1300s and proprietary 4001-4095; anything else is not RTCM3 data.
    return 1001 <= number <= 1399 or 4001 <= number <= 4095


class _PyFeedGate:
    """The pure-Python twin of :class:`drivers.novatel._feed.FeedGate` (the C entry of :meth:`Framer.feed`),
    used when that extension is not built: the same decision, per chunk, on the same attributes."""

    _acc: bytearray
    _quiet_len: int
    _wake_len: int
    _wake_set: frozenset[bytes] | None
    _wake_search: _WakeSearch
    _quiet: frozenset[bytes]
    _look: Callable[[], tuple[Frame, ...]]
    """Framer's look at the held bytes (called when a fed chunk may change a verdict)."""

    def feed(self, data: bytes | bytearray | memoryview) -> tuple[Frame, ...]:
        """Add bytes; return the frames completed by them (in stream order; ``()`` for none)."""
        acc = self._acc
        acc += data
        n = len(acc)
        if n < self._quiet_len:  # a frame's known rest: no byte can end the wait before its end
            return _NO_FRAMES
        if n < self._wake_len:
            # No frame can complete, or be rejected, before the wake condition: keep the bytes only.
            if self._wake_set is None:
                return _NO_FRAMES
            try:
                if data in self._quiet:  # a serial port's typical read, one byte: a hash lookup
                    return _NO_FRAMES
            except (TypeError, ValueError):  # a bytearray or writable memoryview: unhashable
                pass
            if self._wake_search(data) is None:  # a longer chunk (never in the set of 1-byte ones)
                return _NO_FRAMES
        return self._look()


#: Which :meth:`Framer.feed` this install runs: ``"c"`` (drivers/novatel/_feed.c, built by setup.py where a
#: C compiler is found) or ``"python"`` (:class:`_PyFeedGate`). The frames and counts are the same.
FEED_IMPLEMENTATION: str
if TYPE_CHECKING:
    _FeedGate = _PyFeedGate
else:
    try:
        from drivers.novatel._feed import FeedGate as _FeedGate
    except ImportError:  # not built: the pure-Python twin
        _FeedGate = _PyFeedGate
        FEED_IMPLEMENTATION = "python"
    else:
        FEED_IMPLEMENTATION = "c"


class Framer(_FeedGate):
    """Incremental multi-protocol framer for NovAtel receiver ports.

    Args:
        max_frame_len: longest frame accepted (bytes). A frame claiming more, or a text frame with
            no end within this many bytes, is rejected; the buffer never holds much more.
        decode_logs: decode NovAtel logs into :class:`Log` (else ``message`` is None).
        decode_nmea: parse NMEA sentences with pynmea2.
        decode_rtcm: parse RTCM3 frames with pyrtcm.
    """

    def __init__(
        self,
        *,
        max_frame_len: int = DEFAULT_MAX_FRAME_LEN,
        decode_logs: bool = True,
        decode_nmea: bool = True,
        decode_rtcm: bool = True,
    ) -> None:
        if max_frame_len < 64:
            raise ValueError(f"max_frame_len must be >= 64, got {max_frame_len}")
        self.max_frame_len = max_frame_len
        self._decode_logs = decode_logs
        self._decode_nmea = decode_nmea
        self._decode_rtcm = decode_rtcm
        self._stats = FramerStats()
        # Bytes held: those the last scan left (the start of an incomplete frame) + those fed since.
        self._acc = bytearray()
        # Rescan when len(_acc) reaches _wake_len, or when a fed chunk holds a byte of _wake_set
        # (found by _wake_search in a longer chunk); None: no byte ends the wait (module docstring).
        self._wake_len = _AFTER_FRAME_LEN
        self._wake_set: frozenset[bytes] | None
        self._wake_search: _WakeSearch
        self._wake_set, self._wake_search = _WAKE_AFTER_FRAME
        # The 1-byte chunks that are not of _wake_set (a 1-byte feed's test is one set lookup).
        self._quiet = _QUIET[self._wake_set]
        # _wake_len when no byte ends the wait (_wake_set None), else 0: below it, feed() keeps the
        # bytes after one comparison (the rest of a binary log or an RTCM3 frame).
        self._quiet_len = 0
        self._abbrev_resume: tuple[int, int, int] | None = None  # stream offsets (start, next line, end)
        self._base = 0  # stream offset of self._acc[0]
        self._span_end = 0  # stream offset where the current rejected span ends
        self._span_reason = SkipReason.GARBAGE
        self._flush = False
        parsers: dict[int, Callable[[bytes, int, int, bool], _Result]] = {
            0x23: self._parse_ascii,  # '#'
            0x25: self._parse_ascii,  # '%'
            0x3C: self._parse_abbreviated,  # '<'
            0x5B: self._parse_prompt,  # '['
            0x24: self._parse_nmea,  # '$'
            0xAA: self._parse_binary,
            0xD3: self._parse_rtcm,
        }
        self._parsers = parsers

    # --- public API ---------------------------------------------------------------------

    @property
    def stats(self) -> FramerStats:
        """Running counts (the live object: take :meth:`FramerStats.copy` for a snapshot)."""
        stats = self._stats
        stats.bytes_in = self._base + len(self._acc)  # kept here, not per feed: feed(1 byte) stays cheap
        return stats

    def _look(self) -> tuple[Frame, ...]:
        """Look at the bytes held now that a fed chunk could change a verdict."""
        acc = self._acc
        n = len(acc)
        if n >= 10 and acc[0] == 0xAA and acc.startswith(_LONG_SYNC_28):
            # A standard long binary log at the start: the usual wake-ups when frames are fed in small
            # pieces (its header, then its last byte), taken here without a scan. The same decisions
            # as the scan's inline path.
            total = 32 + (acc[8] | acc[9] << 8)
            if total <= self.max_frame_len:
                if n < total:  # wait for the rest (as _parse_binary would say)
                    self._wake_len = self._quiet_len = total
                    self._wake_set = None
                    return _NO_FRAMES
                if n == total and self._decode_logs:
                    # The buffer is one such log: taken as the scan's inline path takes it, if its CRC is
                    # good and a generated decoder takes it (else the scan decides, with the same result).
                    raw = bytes(acc)
                    if _crc32(raw, 0xFFFFFFFF) == 0xFFFFFFFF:
                        try:
                            frame = _FAST_FRAMES_GET(raw[4] | raw[5] << 8, _fast_raw_frame)(raw)
                        except KeyError:
                            frame = None
                        if frame is not None:
                            base = self._base
                            if self._span_end > base:  # an accepted frame ends the rejected span
                                self._span_end = base
                            stats = self._stats
                            stats.frames[_BINARY] += 1
                            stats.bytes_in_frames += n
                            self._base = base + n
                            acc.clear()
                            self._wake_len = _AFTER_FRAME_LEN
                            self._wake_set, self._wake_search = _WAKE_AFTER_FRAME
                            self._quiet = _QUIET_AFTER_FRAME
                            self._quiet_len = 0
                            return (frame,)
        resume = self._abbrev_resume
        if resume is not None and resume[0] == self._base:
            # An abbreviated log at the start, waiting for its next line: walk the new lines in the
            # buffer itself, without a scan (its many short lines would each cost one). Only its end
            # takes the scan, which resumes where this walk stopped.
            self._wake_set = None  # as in a scan: the walk sets another when it waits for a byte
            status, end, _ = self._abbreviated_extent(acc, 0, n, False)
            if status == _NEED:
                self._wake_len = end
                self._settle()
                return _NO_FRAMES
            self._abbrev_resume = resume
        first = acc[0]
        if first in _SYNC_BYTES and (first != 0xAA or n < 10):
            # A frame candidate at the start (where the last scan stopped, or the sync byte that woke
            # an after-frame wait): its parser is what a scan would call first. While it still needs
            # bytes, that is all a scan would do; otherwise the scan takes its verdict from here. (A
            # binary log's header is left to the scan, whose inline path decodes a standard one.)
            buf = bytes(acc)
            self._wake_set = None  # as in a scan: a parser that stops at a NEED may set another
            result = self._parsers[first](buf, 0, n, False)
            if result[0] == _NEED:
                self._wake_len = result[1]
                self._settle()
                return _NO_FRAMES
            frames = self._scan(False, (buf, result))
        elif n == 2 and acc == b"\r\n":  # a text frame's line end (the scan would count it so)
            self._skip(acc, 0, 2)
            self._base += 2
            acc.clear()
            self._wake_len = _AFTER_FRAME_LEN
            self._wake_set, self._wake_search = _WAKE_AFTER_FRAME
            frames = _NO_FRAMES
        else:
            frames = self._scan(False)
        self._settle()
        return frames

    def _settle(self) -> None:
        """After a look at the bytes: the 1-byte chunks that feed() may keep without the next look."""
        wake_set = self._wake_set
        self._quiet = _QUIET[wake_set]
        self._quiet_len = self._wake_len if wake_set is None else 0

    def flush(self) -> tuple[Frame, ...]:
        """Complete a pending abbreviated-ASCII log without waiting for the next byte.

        An abbreviated log has no end marker; call this after a read timeout. Every other frame
        still waits for its bytes.
        """
        self._flush = True
        try:
            return self._scan(final=False)
        finally:
            self._flush = False
            self._settle()

    def finish(self) -> tuple[Frame, ...]:
        """End of stream: complete what can be completed, count the rest as truncated or garbage."""
        frames = self._scan(final=True)
        self._acc.clear()
        self._wake_len = _AFTER_FRAME_LEN
        self._wake_set, self._wake_search = _WAKE_AFTER_FRAME
        self._settle()
        return frames

    @property
    def pending_bytes(self) -> int:
        """Bytes held and not yet classified: the start of an incomplete frame, or bytes waiting for
        enough of them to decide anything (a few after a frame, up to 512 of garbage)."""
        return len(self._acc)

    # --- scanning -----------------------------------------------------------------------

    def _scan(self, final: bool, first: tuple[bytes, _Result] | None = None) -> tuple[Frame, ...]:
        """Frame the held bytes; ``first``: the held bytes (as bytes) and the verdict of the parser of
        the sync byte at their start, already called (:meth:`_look`)."""
        acc = self._acc
        n = len(acc)
        if first is None:
            buf = bytes(acc)
        else:
            buf, result = first
        self._wake_set = None  # a parser that stops at a NEED may set another
        pos = 0
        out: list[Frame] = []
        append = out.append
        stats = self._stats
        search = _SYNC.search
        parsers = self._parsers
        fast_binary = self._decode_logs
        max_len = self.max_frame_len
        fast_count = 0  # frames taken by the inline binary path; added to the stats at the end
        fast_bytes = 0
        line_ends = 0
        span_rel = self._span_end - self._base  # the current rejected span ends at buf[span_rel]
        while pos < n:
            if first is not None:  # the verdict at buf[0], given
                first = None
                start = 0
                status, end, payload = result
            else:
                if buf[pos] in _SYNC_BYTES:  # back-to-back frames: no search needed
                    start = pos
                else:
                    m = search(buf, pos)
                    if m is None:
                        if final:
                            pass
                        elif buf[pos:].strip(b"\r\n"):
                            # Until a sync byte arrives, held bytes can complete nothing; count them then.
                            self._wake_len = _GARBAGE_HOLD
                            self._wake_set, self._wake_search = _WAKE_SYNC
                        else:  # only the line end of a text frame
                            self._wake_len = _AFTER_FRAME_LEN
                            self._wake_set, self._wake_search = _WAKE_AFTER_FRAME
                        self._skip(buf, pos, n)
                        pos = n
                        break
                    start = m.start()
                    self._skip(buf, pos, start)
                # Inline path for the common case, a complete long-header binary log with the standard
                # header length and a good CRC: the same checks and result as _parse_binary, without
                # its dispatch, result tuple and wrapper calls. Anything else takes the general path.
                if fast_binary and start + 10 <= n and buf.startswith(_LONG_SYNC_28, start):
                    total = 32 + (buf[start + 8] | buf[start + 9] << 8)
                    end = start + total
                    if end <= n and total <= max_len:
                        raw = buf[start:end]
                        if _crc32(raw, 0xFFFFFFFF) == 0xFFFFFFFF:
                            try:
                                frame = _FAST_FRAMES_GET(buf[start + 4] | buf[start + 5] << 8, _fast_raw_frame)(raw)
                            except KeyError:
                                frame = None
                            if frame is not None:
                                if start < span_rel:  # an accepted frame ends the rejected span
                                    self._span_end = self._base + start
                                    span_rel = start
                                append(frame)
                                fast_count += 1
                                fast_bytes += total
                                pos = end
                                continue
                status, end, payload = parsers[buf[start]](buf, start, n, final)
            if status == _OK:
                if self._base + start < self._span_end:
                    self._span_end = self._base + start
                append(payload)
                stats.frames[payload.kind] += 1
                stats.bytes_in_frames += end - start
                if payload.error is not None:
                    stats.decode_errors[payload.kind] += 1
                    _log.debug("NovAtel framer: %s frame decode error: %s", payload.kind.value, payload.error)
                pos = end
                # The CR LF after a text frame: counted here instead of by a search and _skip (an
                # accepted frame ends any rejected span, so these bytes are never in one).
                if buf[end : end + 2] == b"\r\n":
                    line_ends += 2
                    pos = end + 2
            elif status == _NEED:
                if not final:
                    pos = start
                    self._wake_len = end - start  # relative to the new buffer start; _wake_set by the parser
                    break
                if payload is not None:
                    # The stream ended inside a frame: count it once, then look inside it.
                    if not self._in_span(start, SkipReason.TRUNCATED):
                        stats.truncated += 1
                    self._reject(start, n, SkipReason.TRUNCATED)
                self._skip(buf, start, start + 1)
                pos = start + 1
            elif status == _NOT_FRAME:
                self._skip(buf, start, start + 1)
                pos = start + 1
            elif status == _CRC_FAIL:
                stats.crc_failures[payload] += 1
                _log.debug("NovAtel framer: %s CRC failure at stream offset %d", payload.value, self._base + start)
                self._reject(start, end, SkipReason.CRC_FAILURE)
                self._skip(buf, start, start + 1)
                pos = start + 1
            elif status == _TRUNC:
                if not self._in_span(start, SkipReason.TRUNCATED):
                    stats.truncated += 1
                self._reject(start, end, SkipReason.TRUNCATED)
                self._skip(buf, start, start + 1)
                pos = start + 1
            else:  # _OVERSIZE
                stats.oversize[payload] += 1
                self._reject(start, start + 1, SkipReason.OVERSIZE)
                self._skip(buf, start, start + 1)
                pos = start + 1
            span_rel = self._span_end - self._base
        else:  # ended at a frame's end (or a rejected byte)
            self._wake_len = _AFTER_FRAME_LEN
            self._wake_set, self._wake_search = _WAKE_AFTER_FRAME
        if fast_count:
            stats.frames[_BINARY] += fast_count
            stats.bytes_in_frames += fast_bytes
        if line_ends:
            stats.line_end_bytes += line_ends
        self._base += pos
        if pos == n:
            acc.clear()
        elif pos:
            del acc[:pos]
        return tuple(out)

    def _in_span(self, start: int, reason: SkipReason) -> bool:
        return self._base + start < self._span_end and self._span_reason is reason

    def _reject(self, start: int, end: int, reason: SkipReason) -> None:
        a = self._base + start
        b = self._base + end
        if a < self._span_end:
            self._span_end = max(self._span_end, b)  # inside an earlier rejected span: keep its reason
        else:
            self._span_end = b
            self._span_reason = reason

    def _skip(self, buf: bytes | bytearray, start: int, end: int) -> None:
        """Count buf[start:end] as skipped: by the rejected span's reason, else garbage/line ends."""
        a = self._base + start
        b = self._base + end
        skipped = self._stats.bytes_skipped
        if a < self._span_end:
            cut = min(b, self._span_end)
            skipped[self._span_reason] += cut - a
            if cut >= b:
                return
            start = cut - self._base
        line_ends = buf.count(b"\n", start, end) + buf.count(b"\r", start, end)
        self._stats.line_end_bytes += line_ends
        skipped[SkipReason.GARBAGE] += end - start - line_ends

    # --- parsers: (buf, start, n, final) -> (status, end, payload) ----------------------

    def _parse_binary(self, buf: bytes, start: int, n: int, final: bool) -> _Result:
        avail = n - start
        if avail < 3:
            if avail == 2 and buf[start + 1] != 0x44:
                return _NOT_FRAME, 0, None
            if avail == 1:  # only a second byte other than 0x44 decides before the third arrives
                self._wake_set, self._wake_search = _WAKE_NOT_44
            return _NEED, start + 3, None
        b2 = buf[start + 2]
        if buf[start + 1] != 0x44 or (b2 != 0x12 and b2 != 0x13):
            return _NOT_FRAME, 0, None
        if b2 == 0x12:
            kind = FrameKind.NOVATEL_BINARY
            if avail < 10:
                return _NEED, start + 10, kind
            hdr_len = buf[start + 3]
            if hdr_len < 28:
                return _NOT_FRAME, 0, None
            total = hdr_len + (buf[start + 8] | buf[start + 9] << 8) + 4
        else:
            kind = FrameKind.NOVATEL_SHORT_BINARY
            if avail < 4:
                return _NEED, start + 4, kind
            total = 16 + buf[start + 3]
        if total > self.max_frame_len:
            return _OVERSIZE, 0, kind
        end = start + total
        if end > n:
            return _NEED, end, kind
        raw = buf[start:end]
        if zlib.crc32(raw, 0xFFFFFFFF) != 0xFFFFFFFF:
            return _CRC_FAIL, end, kind
        if not self._decode_logs:
            return _OK, end, _new_frame(kind, raw, None, None)
        log, error = decode_verified(raw, kind is FrameKind.NOVATEL_SHORT_BINARY)
        return _OK, end, _new_frame(kind, raw, log, error)

    def _parse_ascii(self, buf: bytes, start: int, n: int, final: bool) -> _Result:
        if n - start < 2:
            return _NEED, start + 2, None
        if not 0x41 <= buf[start + 1] <= 0x5A:  # a log name starts with an upper-case letter
            return _NOT_FRAME, 0, None
        kind = FrameKind.NOVATEL_ASCII if buf[start] == 0x23 else FrameKind.NOVATEL_SHORT_ASCII
        limit = min(n, start + self.max_frame_len)
        star = buf.find(b"*", start + 2, limit)
        if star < 0:
            brk = _LINE_BREAK.search(buf, start + 2, limit)
            if brk is not None:
                return self._text_cut(buf, start, brk.start(), kind)
            if limit - start >= self.max_frame_len:
                return _OVERSIZE, 0, kind
            self._wake_set, self._wake_search = _WAKE_TEXT_END
            return _NEED, start + self.max_frame_len, kind
        nl = buf.find(b"\n", start + 2, star)
        cr = buf.find(b"\r", start + 2, star)
        if nl >= 0 or cr >= 0:
            return self._text_cut(buf, start, min(nl, cr) if nl >= 0 and cr >= 0 else max(nl, cr), kind)
        end = star + 9
        if end > n:
            if n > star + 1 and not _is_hex_prefix(buf, star + 1, n):
                return self._text_cut(buf, start, star + 1, kind)
            self._wake_set, self._wake_search = _WAKE_NOT_HEX
            return _NEED, end, kind
        crc_text = buf[star + 1 : end]
        if crc_text.strip(_HEX_DIGITS):  # something other than 8 hex digits
            return self._text_cut(buf, start, star + 1, kind)
        inner = buf[start + 1 : star]
        if _crc32(inner, 0xFFFFFFFF) ^ 0xFFFFFFFF != int(crc_text, 16):
            # A header has commas (its ';' may be the very byte that was corrupted): without one this
            # was never a log, with one it is a log that failed its CRC.
            if buf.find(b",", start, star) < 0:
                return _NOT_FRAME, 0, None
            # A new log starting before this one's CRC means this one was cut short.
            inner_start = buf.find(buf[start : start + 1], start + 1, star)
            if inner_start >= 0:
                return _TRUNC, inner_start, kind
            return _CRC_FAIL, end, kind
        raw = buf[start:end]
        if not self._decode_logs:
            return _OK, end, _new_frame(kind, raw, None, None)
        try:
            log, error = decode_ascii_text(buf[start], inner.decode("latin-1"))
        except DecodeError as exc:
            return _OK, end, Frame(kind, raw, None, str(exc))
        return _OK, end, _new_frame(kind, raw, log, error)

    @staticmethod
    def _text_cut(buf: bytes, start: int, cut: int, kind: FrameKind) -> _Result:
        # A text frame that ends (line break / bad CRC field) before a valid CRC: truncated if it
        # got as far as its first header field (',' seen), otherwise it was never a frame.
        if buf.find(b",", start, cut) < 0:
            return _NOT_FRAME, 0, None
        return _TRUNC, cut, kind

    def _parse_abbreviated(self, buf: bytes, start: int, n: int, final: bool) -> _Result:
        status, end, payload = self._abbreviated_extent(buf, start, n, final)
        if status != _OK or payload is not None:  # not complete, or a response
            return status, end, payload
        kind = FrameKind.NOVATEL_ABBREV
        raw = buf[start:end]
        if not self._decode_logs:
            return _OK, end, _new_frame(kind, raw, None, None)
        try:
            log, error = decode_abbreviated_lines(raw)
        except DecodeError as exc:
            return _OK, end, Frame(kind, raw, None, str(exc))
        return _OK, end, _new_frame(kind, raw, log, error)

    def _abbreviated_extent(self, buf: bytes | bytearray, start: int, n: int, final: bool) -> _Result:
        """Where the abbreviated log or response at ``buf[start]`` ends: (_OK, end, None) for a
        complete log, a whole result for a response, or the verdict of a parser (_NEED etc.)."""
        limit = min(n, start + self.max_frame_len)
        kind = FrameKind.NOVATEL_ABBREV
        resume = self._abbrev_resume
        self._abbrev_resume = None
        base = self._base
        if resume is not None and resume[0] == base + start:
            # The header and the complete lines were checked by the scan that stopped here.
            p = resume[1] - base
            last_end = resume[2] - base
        else:
            nl = buf.find(b"\n", start + 1, limit)
            if nl < 0:
                if limit - start >= self.max_frame_len:
                    return _NOT_FRAME, 0, None
                if not final:
                    self._wake_set, self._wake_search = _WAKE_LINE_END
                    return _NEED, start + self.max_frame_len, None
                line_end = n
            else:
                line_end = nl
            line = bytes(buf[start:line_end]).rstrip(b"\r")  # bytes(): no copy of a bytes slice
            if line == b"<OK":
                return _OK, start + len(line), Frame(FrameKind.RESPONSE, line, Response(True, "OK"))
            if line.startswith(b"<ERROR:"):
                message = line[7:].decode("latin-1")
                return _OK, start + len(line), Frame(FrameKind.RESPONSE, line, Response(False, message))
            if _ABBREV_HEADER.match(line) is None:
                return _NOT_FRAME, 0, None
            last_end = start + len(line)
            p = line_end + 1
        complete_at_end = final or self._flush
        while True:
            if p >= n:
                if complete_at_end:
                    break
                self._abbrev_resume = (base + start, base + p, base + last_end)
                # A '<' next changes nothing until the byte after it; anything else completes the log.
                self._wake_set, self._wake_search = _WAKE_NOT_LT
                return _NEED, p + 2, kind
            if buf[p] != 0x3C:  # not '<': the log is complete
                break
            if p + 1 >= n:
                if complete_at_end:
                    break
                self._abbrev_resume = (base + start, base + p, base + last_end)
                return _NEED, p + 2, kind
            if buf[p + 1] != 0x20 and buf[p + 1] != 0x09:  # '<' not followed by blank: next frame
                break
            q = buf.find(b"\n", p, limit)
            if q < 0:
                if limit - start >= self.max_frame_len:
                    return _OVERSIZE, 0, kind
                if not final:
                    self._abbrev_resume = (base + start, base + p, base + last_end)
                    self._wake_set, self._wake_search = _WAKE_LINE_END
                    return _NEED, start + self.max_frame_len, kind
                q = n
            last_end = q - 1 if q > p and buf[q - 1] == 0x0D else q
            p = q + 1
        return _OK, last_end, None

    def _parse_prompt(self, buf: bytes, start: int, n: int, final: bool) -> _Result:
        m = _PROMPT.match(buf, start)
        if m is not None:
            end = m.end()
            return _OK, end, Frame(FrameKind.PROMPT, buf[start:end], Prompt(m.group(1).decode("ascii")))
        if not final and n - start < 18 and _PROMPT_PARTIAL.fullmatch(buf, start, n) is not None:
            return _NEED, n + 1, None
        return _NOT_FRAME, 0, None

    def _parse_nmea(self, buf: bytes, start: int, n: int, final: bool) -> _Result:
        if n - start < 2:
            return _NEED, start + 2, None
        if not 0x41 <= buf[start + 1] <= 0x5A:
            return _NOT_FRAME, 0, None
        kind = FrameKind.NMEA
        limit = min(n, start + MAX_NMEA_LEN, start + self.max_frame_len)
        star = buf.find(b"*", start + 2, limit)
        if star < 0:
            brk = _LINE_BREAK.search(buf, start + 2, limit)
            if brk is not None:
                return self._nmea_cut(buf, start, brk.start())
            if limit - start >= min(MAX_NMEA_LEN, self.max_frame_len):
                return _NOT_FRAME, 0, None
            self._wake_set, self._wake_search = _WAKE_TEXT_END
            return _NEED, start + min(MAX_NMEA_LEN, self.max_frame_len), kind
        brk = _LINE_BREAK.search(buf, start + 2, star)
        if brk is not None:
            return self._nmea_cut(buf, start, brk.start())
        end = star + 3
        if end > n:
            if n > star + 1 and not _is_hex_prefix(buf, star + 1, n):
                return self._nmea_cut(buf, start, star + 1)
            self._wake_set, self._wake_search = _WAKE_NOT_HEX
            return _NEED, end, kind
        if _HEX2.fullmatch(buf, star + 1, end) is None:
            return self._nmea_cut(buf, start, star + 1)
        if _NMEA_ADDRESS.match(buf, start, star) is None:
            return _NOT_FRAME, 0, None
        if xor_checksum(buf[start + 1 : star]) != int(buf[star + 1 : end], 16):
            inner = buf.find(b"$", start + 1, star)
            if inner >= 0:
                return _TRUNC, inner, kind
            return _CRC_FAIL, end, kind
        raw = buf[start:end]
        if not self._decode_nmea:
            return _OK, end, _new_frame(kind, raw, None, None)
        message, error = _parse_nmea_sentence(raw)
        return _OK, end, _new_frame(kind, raw, message, error)

    @staticmethod
    def _nmea_cut(buf: bytes, start: int, cut: int) -> _Result:
        # Looked like a sentence (valid address field) but ended before a checksum: truncated.
        if _NMEA_ADDRESS.match(buf, start, cut) is None:
            return _NOT_FRAME, 0, None
        return _TRUNC, cut, FrameKind.NMEA

    def _parse_rtcm(self, buf: bytes, start: int, n: int, final: bool) -> _Result:
        avail = n - start
        if avail >= 2 and buf[start + 1] & 0xFC:
            return _NOT_FRAME, 0, None
        if avail < 5:
            return _NEED, start + (2 if avail < 2 else 5), None
        length = (buf[start + 1] & 0x03) << 8 | buf[start + 2]
        if length < 2 or not _rtcm_number_plausible(buf[start + 3] << 4 | buf[start + 4] >> 4):
            return _NOT_FRAME, 0, None
        kind = FrameKind.RTCM3
        end = start + length + 6
        if end - start > self.max_frame_len:
            return _OVERSIZE, 0, kind
        if end > n:
            return _NEED, end, kind
        raw = buf[start:end]
        if crc24q(raw) != 0:
            return _CRC_FAIL, end, kind
        if not self._decode_rtcm:
            return _OK, end, _new_frame(kind, raw, None, None)
        message, error = _parse_rtcm_frame(raw)
        return _OK, end, _new_frame(kind, raw, message, error)


def _is_hex_prefix(buf: bytes, start: int, end: int) -> bool:
    return all(c in b"0123456789ABCDEFabcdef" for c in buf[start:end])


def _parse_nmea_sentence(raw: bytes) -> tuple[Any, str | None]:
    try:
        return pynmea2.parse(raw.decode("ascii")), None
    except (pynmea2.ParseError, UnicodeDecodeError, ValueError, AttributeError, TypeError) as exc:
        return None, f"pynmea2 cannot parse NMEA sentence: {exc}"


def _parse_rtcm_frame(raw: bytes) -> tuple[Any, str | None]:
    try:
        return RTCMReader.parse(raw, validate=0), None
    except Exception as exc:  # pyrtcm raises its own errors and also bare ones on odd payloads
        return None, f"pyrtcm cannot parse RTCM3 frame: {type(exc).__name__}: {exc}"


class SupportsRead(Protocol):
    """Anything with ``read(n) -> bytes`` (file, BytesIO, serial port, socket file)."""

    def read(self, n: int, /) -> bytes: ...


class FrameReader:
    """Frames from a byte source with ``read(n)``; stops at the first empty read (end of stream).

    For a serial port whose ``read`` returns ``b""`` on timeout, feed a :class:`Framer` directly
    instead (a receiver session does).
    """

    def __init__(self, stream: SupportsRead, *, framer: Framer | None = None, chunk_size: int = 65536) -> None:
        self._stream = stream
        self.framer = framer if framer is not None else Framer()
        self._chunk_size = chunk_size

    @property
    def stats(self) -> FramerStats:
        return self.framer.stats

    def __iter__(self) -> Iterator[Frame]:
        read = self._stream.read
        feed = self.framer.feed
        while True:
            data = read(self._chunk_size)
            if not data:
                break
            yield from feed(data)
        yield from self.framer.finish()


def iter_frames(stream: SupportsRead, **framer_options: Any) -> Iterator[Frame]:
    """Frames of a whole stream (see :class:`Framer` for the options)."""
    return iter(FrameReader(stream, framer=Framer(**framer_options)))
