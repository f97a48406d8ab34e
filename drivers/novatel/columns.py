"""Bulk columnar decoder: every NovAtel log in a byte buffer → numpy columns per log (struct of arrays).

For post-processing, where a capture or a session's raw GNSS stream holds ~200k logs an hour and
the consumer wants arrays, not one dataclass per log::

    batch = decode_columns(data)                  # any mix of ASCII and binary, garbage between
    pos = batch.log("BESTPOS")                     # LogColumns (empty when the buffer has none)
    pos.header["gps_ns"], pos.body["lat_deg"], pos.body["sol_status"]   # int64, float64, int64
    batch.rejected[RejectReason.CRC_FAILURE]

It finds the same frames as :class:`drivers.novatel.Framer` on the whole buffer (ASCII ``#…*CRC``
and long-header binary ``AA 44 12`` logs are decoded; short-header ``%`` / ``AA 44 13`` frames
are framed, so their bytes hide nothing, and counted in :attr:`ColumnBatch.other`) and gives
the same values field for field, with the same names as the per-message dataclasses
(:mod:`drivers.novatel.messages`, :mod:`drivers.novatel.jsonview`): header fields in
:attr:`LogColumns.header` (``port``, ``sequence``, ``idle_time_pct``, ``time_status``, ``week``,
``seconds``, ``receiver_status``, ``reserved``, ``sw_version``, ``source`` and ``gps_ns``),
body fields in :attr:`LogColumns.body` (plus ``event_gps_ns`` for MARKTIME/MARK1TIME/MARK2TIME and
``leap_seconds`` for TIME, as the dataclass properties). Floats are float64 (a float32 wire value
widens exactly), integers, hex fields and enums int64 (an enum as its value; an unknown value
stays a number, as the per-message ``UNKNOWN_<n>`` member does), strings numpy ``str``, PSRDOP's
PRN lists an object column of tuples. A derived time that has no int64 value (negative or
far-future week, non-finite seconds) is :data:`MISSING_INT`.

The logs the stream decoders keep raw for post-processing are decoded too, to the values of their
:mod:`drivers.novatel.rawobs` decoders: GPSEPHEM and GLOEPHEMERIS (body columns named as the
dataclass fields), and RANGECMP, whose body holds ``num_obs`` and whose observations are in
:attr:`LogColumns.records` (one row per record, the :class:`~drivers.novatel.rawobs.RangeCmpRecord`
fields; log i holds ``record_start[i]:record_start[i + 1]``)::

    rc = batch.log("RANGECMP")
    rc.records["pseudorange_m"], rc.records["adr_cycles"], rc.record_rows()   # per observation

How it stays fast: frame starts, ``*``, separators and line breaks are located with numpy over
the whole buffer and every candidate is classified in bulk as the framer would; only the CRC is a
per-frame call (zlib, in C). Binary frames are located first: a ``#`` or ``%`` inside a good binary
frame is never looked at by the framer once that frame is accepted, so the text scans run only for
the candidates outside them (in a binary stream, none), and again over all of them in the rare case
that such a frame was not accepted. Binary logs of one message ID are copied out as one array and
viewed through a structured dtype built from the layout tables of :mod:`drivers.novatel.layouts`
(header and body in one view); RANGECMP records are copied out in one gather and their bit fields
cut out of 32-bit words with shifts and masks, the ADR roll-over resolved with the per-record
decoder's own double-precision operations. ASCII logs of one name are split at the separator positions (no joined
copy); each token is read right-aligned as 64-bit words, and numbers are parsed with SWAR
arithmetic, eight digits per word operation (a decimal of at most 15 digits is ``mantissa /
10**k``, one correctly rounded IEEE division, so it equals ``float(token)``); hex, enum and
string columns are hashed and converted once per distinct token with the per-message decoder's
own conversion. A run of columns that is the same in every row of the batch (port, time status,
week, datum, … in a typical capture) is recognised by comparing its byte span, and parsed once.
No Python code runs per field per log. A row that does not fit these shapes (wrong field count, a
quoted comma, an exponent or 16+ digits, an enum given as a number, a non-standard binary header
length, PSRDOP's variable PRN list, a RANGECMP whose length is not its count of records, ASCII
RANGECMP, the ephemerides) is decoded by the per-message decoder instead, so the result is always
that decoder's; a frame that decoder cannot decode either is counted as :attr:`RejectReason.MALFORMED`.

Known differences from the per-message path: numpy ``str`` columns drop trailing NUL characters,
and an ASCII integer too large for int64 (which no wire field can carry) makes its log malformed.
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import Any

import numpy as np
import numpy.typing as npt

from drivers.novatel.ascii import decode_ascii_text
from drivers.novatel.binary import LONG_HEADER, LONG_HEADER_LEN, decode_verified
from drivers.novatel.enums import TimeStatus, _OpenIntEnum, port_name_from_byte
from drivers.novatel.framer import DEFAULT_MAX_FRAME_LEN
from drivers.novatel.layouts import CODECS_BY_ID, CODECS_BY_NAME, BodyCodec, Kind
from drivers.novatel.messages import Header, Log, RawBody, log_name_for_id
from drivers.novatel.rawobs import (
    ADR_MAX_VALUE,
    PSR_STD_M,
    RECORD_LEN,
    GloEphemeris,
    GpsEphem,
    RangeCmp,
    RangeCmpRecord,
    decode_gloephemeris,
    decode_gpsephem,
    decode_rangecmp,
    gloephemeris_codec,
    gpsephem_codec,
    signal_wavelength_m,
)
from vsccore.errors import ConfigError, DecodeError
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK, gps_to_ns

__all__ = ["MISSING_INT", "ColumnBatch", "LogColumns", "RejectReason", "decode_columns", "empty_columns"]

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
U8Array = npt.NDArray[np.uint8]
Column = npt.NDArray[Any]

#: Value of an int64 time column that has no value (see the module docstring).
MISSING_INT = int(np.iinfo(np.int64).min)

#: Header columns of every log, in order (``gps_ns`` derived from week and seconds).
HEADER_COLUMNS: tuple[str, ...] = (
    "port",
    "sequence",
    "idle_time_pct",
    "time_status",
    "week",
    "seconds",
    "receiver_status",
    "reserved",
    "sw_version",
    "source",
    "gps_ns",
)
_HEADER_KINDS: dict[str, Kind] = {
    "port": Kind.STR,
    "sequence": Kind.INT,
    "idle_time_pct": Kind.FLOAT,
    "time_status": Kind.ENUM,
    "week": Kind.INT,
    "seconds": Kind.FLOAT,
    "receiver_status": Kind.HEX,
    "reserved": Kind.HEX,
    "sw_version": Kind.INT,
    "source": Kind.INT,
    "gps_ns": Kind.INT,
}


class RejectReason(Enum):
    """Why a frame candidate gave no log (counted as the framer counts them)."""

    CRC_FAILURE = "crc_failure"  # complete candidate whose CRC does not check
    TRUNCATED = "truncated"  # cut short (line break before its CRC, a new frame inside it, end of buffer)
    OVERSIZE = "oversize"  # claims more than the frame bound
    MALFORMED = "malformed"  # CRC good, but the log does not decode (the framer's decode errors)


@dataclass(frozen=True, slots=True)
class LogColumns:
    """Every decoded log of one name, in buffer order, as columns of equal length."""

    name: str
    message_id: int
    offset: IntArray
    """Byte offset of each frame in the buffer."""
    length: IntArray
    """Frame length in bytes (binary: header, body and CRC; ASCII: ``#`` to the last CRC digit)."""
    binary: BoolArray
    """True for a binary frame, False for ASCII."""
    header: Mapping[str, Column]
    body: Mapping[str, Column]
    records: Mapping[str, Column] = field(default_factory=dict)
    """Columns of a log's repeated records (RANGECMP: one row per observation), all logs' records in
    log order; empty for logs without a record list."""
    record_start: IntArray | None = None
    """Index into :attr:`records` of each log's first record, then the number of records (``len(self) + 1``
    entries: log i holds records ``record_start[i]:record_start[i + 1]``); None for logs without records."""

    def __len__(self) -> int:
        return int(self.offset.shape[0])

    @property
    def end(self) -> IntArray:
        """Offset one past each frame's last byte."""
        return self.offset + self.length

    def record_rows(self) -> IntArray:
        """The row (log) of each record (empty for logs without records)."""
        if self.record_start is None:
            return np.zeros(0, dtype=np.int64)
        return np.repeat(np.arange(len(self), dtype=np.int64), np.diff(self.record_start))

    def __getitem__(self, name: str) -> Column:
        """A body column, else a header column, else a record column."""
        if name in self.body:
            return self.body[name]
        if name in self.header:
            return self.header[name]
        if name in self.records:
            return self.records[name]
        raise KeyError(
            f"NovAtel {self.name} columns: no {name!r}; body: {list(self.body)}, header: {list(self.header)}, "
            f"records: {list(self.records)}"
        )


@dataclass(frozen=True, slots=True)
class ColumnBatch:
    """Result of :func:`decode_columns`."""

    logs: Mapping[str, LogColumns]
    """Columns by log name (``BESTPOS``), for the logs found."""
    rejected: Mapping[RejectReason, int]
    """Frame candidates that gave no log, by reason."""
    other: Mapping[str, int] = field(default_factory=dict)
    """Valid frames not decoded into columns, by log name: logs the columns do not decode (no typed
    layout, not RANGECMP, GPSEPHEM or GLOEPHEMERIS), short-header logs, binary responses and logs left
    out by the ``logs`` argument."""
    bytes_in: int = 0

    def log(self, name: str) -> LogColumns:
        """Columns of ``name`` (empty columns of the right types when the buffer had none).

        Raises:
            ConfigError: ``name`` is not a log the columns decode.
        """
        found = self.logs.get(name)
        return found if found is not None else empty_columns(name)

    @property
    def total_logs(self) -> int:
        return sum(len(c) for c in self.logs.values())


# ---------------------------------------------------------------------------------------------
# Column tables derived from the layouts
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Layout:
    """The columns of one log: body columns, record columns (a log with a list of records), and for a
    log the stream decoders keep raw, the :mod:`drivers.novatel.rawobs` decoder of its body."""

    name: str
    message_id: int
    body: tuple[tuple[str, Kind], ...]
    records: tuple[tuple[str, Kind], ...] = ()
    prns: bool = False  # PSRDOP's variable PRN list, an object column of tuples
    raw: Callable[[RawBody], Any] | None = None


def _kinds(cls: type[Any]) -> tuple[tuple[str, Kind], ...]:
    return tuple((f.name, Kind.FLOAT if f.type in ("float", float) else Kind.INT) for f in fields(cls))


def _layouts() -> dict[str, _Layout]:
    out = {
        name: _Layout(name, c.cls.MESSAGE_ID, tuple((s.name, s.kind) for s in c.specs), prns=not c.fixed_layout)
        for name, c in CODECS_BY_NAME.items()
    }
    raw = (
        _Layout("RANGECMP", RangeCmp.MESSAGE_ID, (("num_obs", Kind.INT),), _kinds(RangeCmpRecord), raw=decode_rangecmp),
        _Layout("GPSEPHEM", GpsEphem.MESSAGE_ID, tuple((s.name, s.kind) for s in gpsephem_codec().specs),
                raw=decode_gpsephem),
        _Layout("GLOEPHEMERIS", GloEphemeris.MESSAGE_ID, tuple((s.name, s.kind) for s in gloephemeris_codec().specs),
                raw=decode_gloephemeris),
    )
    for lay in raw:
        out.setdefault(lay.name, lay)  # a typed layout of the same log (none today) would take over
    return out


_LAYOUTS = _layouts()
_LAYOUTS_BY_ID = {lay.message_id: lay for lay in _LAYOUTS.values()}


def _layout(name: str) -> _Layout:
    found = _LAYOUTS.get(name)
    if found is None:
        raise ConfigError(f"NovAtel columns: no column layout for log {name!r}; known: {sorted(_LAYOUTS)}")
    return found


def _empty(kind: Kind) -> Column:
    if kind is Kind.FLOAT:
        return np.zeros(0, dtype=np.float64)
    if kind is Kind.STR:
        return np.zeros(0, dtype=str)
    return np.zeros(0, dtype=np.int64)


_EVENT_TIME_LOGS = frozenset({"MARKTIME", "MARK1TIME", "MARK2TIME"})
"""Logs of an event input's GPS time: their columns get ``event_gps_ns``."""


def _derived_names(name: str) -> tuple[str, ...]:
    if name in _EVENT_TIME_LOGS:
        return ("event_gps_ns",)
    if name == "TIME":
        return ("leap_seconds",)
    return ()


def empty_columns(name: str) -> LogColumns:
    """Columns of log ``name`` with no rows (the dtypes a decoded batch has).

    Raises:
        ConfigError: ``name`` is not a log the columns decode.
    """
    layout = _layout(name)
    body: dict[str, Column] = {n: _empty(k) for n, k in layout.body}
    if layout.prns:
        body["prns"] = np.zeros(0, dtype=object)
    for d in _derived_names(name):
        body[d] = np.zeros(0, dtype=np.int64)
    header = {h: _empty(_HEADER_KINDS[h]) for h in HEADER_COLUMNS}
    z = np.zeros(0, dtype=np.int64)
    records = {n: _empty(k) for n, k in layout.records}
    return LogColumns(name, layout.message_id, z, z.copy(), np.zeros(0, dtype=bool), header, body, records,
                      np.zeros(1, dtype=np.int64) if layout.records else None)


_STRUCT_TO_NUMPY = {"B": "u1", "H": "<u2", "I": "<u4", "i": "<i4", "d": "<f8", "f": "<f4", "s": "S"}
_STRUCT_CODE = re.compile(r"(\d*)([A-Za-z?])")

#: Names of the long binary header's fields after the 3 sync bytes (:data:`binary.LONG_HEADER`).
_LONG_HEADER_FIELDS = (
    "h_header_length",
    "h_message_id",
    "h_message_type",
    "h_port",
    "h_message_length",
    "h_sequence",
    "h_idle",
    "h_time_status",
    "h_week",
    "h_milliseconds",
    "h_receiver_status",
    "h_reserved",
    "h_sw_version",
)


def _struct_fields(fmt: str, names: Sequence[str], offset: int = 0) -> tuple[list[tuple[str, str, int]], int]:
    """(name, numpy type, offset) of each field of a little-endian ``struct`` format, and its size."""
    out: list[tuple[str, str, int]] = []
    pos = offset
    it = iter(names)
    for count_text, code in _STRUCT_CODE.findall(fmt.lstrip("<")):
        count = int(count_text) if count_text else 1
        if code == "x":
            pos += count
            continue
        if code == "s":
            out.append((next(it), f"S{count}", pos))
            pos += count
            continue
        np_code = _STRUCT_TO_NUMPY[code]
        size = np.dtype(np_code).itemsize
        for _ in range(count):
            out.append((next(it), np_code, pos))
            pos += size
    if next(it, None) is not None:
        raise TypeError(f"struct format {fmt!r} has fewer fields than names")
    return out, pos


def _frame_dtype(codec: BodyCodec) -> np.dtype[Any]:
    """Structured dtype of a whole standard long-header frame of ``codec`` (without the CRC)."""
    head, size = _struct_fields(LONG_HEADER.format, _LONG_HEADER_FIELDS, offset=3)
    if size != LONG_HEADER_LEN:
        raise TypeError(f"long header layout is {size} bytes, expected {LONG_HEADER_LEN}")
    body, total = _struct_fields(codec.struct.format, [f"b_{n}" for n in codec.names], offset=size)
    fields_ = head + body
    return np.dtype({
        "names": [f[0] for f in fields_],
        "formats": [f[1] for f in fields_],
        "offsets": [f[2] for f in fields_],
        "itemsize": total,
    })


_FRAME_DTYPES: dict[int, np.dtype[Any]] = {mid: _frame_dtype(c) for mid, c in CODECS_BY_ID.items() if c.fixed_layout}

# ---------------------------------------------------------------------------------------------
# Locating frames (vectorised version of the framer's scan)
# ---------------------------------------------------------------------------------------------

_OK, _NOT_FRAME, _CRC_FAIL, _TRUNC, _OVERSIZE = 0, 1, 2, 3, 4
_K_ASCII, _K_SHORT_ASCII, _K_BINARY, _K_SHORT_BINARY = 0, 1, 2, 3

_HEX_LUT = np.full(256, 255, dtype=np.uint8)
for _i, _c in enumerate(b"0123456789"):
    _HEX_LUT[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX_LUT[_c] = 10 + _i
    _HEX_LUT[_c - 32] = 10 + _i
_POW16 = 16 ** np.arange(16, dtype=np.int64)
_POW10F = 10.0 ** np.arange(23, dtype=np.float64)
_MASK32 = 0xFFFFFFFF


@dataclass(slots=True)
class _Candidates:
    start: list[IntArray] = field(default_factory=list)
    end: list[IntArray] = field(default_factory=list)
    status: list[IntArray] = field(default_factory=list)
    kind: list[IntArray] = field(default_factory=list)
    star: list[IntArray] = field(default_factory=list)

    def add(
        self, start: IntArray, end: IntArray, status: int | IntArray, kind: int, star: IntArray | None = None
    ) -> None:
        if start.size == 0:
            return
        self.start.append(start.astype(np.int64))
        self.end.append(np.asarray(end, dtype=np.int64))
        self.status.append(np.broadcast_to(np.asarray(status, dtype=np.int64), start.shape).copy())
        self.kind.append(np.full(start.shape, kind, dtype=np.int64))
        self.star.append(np.full(start.shape, -1, dtype=np.int64) if star is None else star.astype(np.int64))

    def arrays(self) -> tuple[IntArray, IntArray, IntArray, IntArray, IntArray]:
        if not self.start:
            z = np.zeros(0, dtype=np.int64)
            return z, z, z, z, z
        start = np.concatenate(self.start)
        order = np.argsort(start, kind="stable")
        return (start[order], np.concatenate(self.end)[order], np.concatenate(self.status)[order],
                np.concatenate(self.kind)[order], np.concatenate(self.star)[order])


def _next_at(sorted_pos: IntArray, at: IntArray, none: int) -> IntArray:
    """The first element of ``sorted_pos`` >= each ``at`` (``none`` where there is none)."""
    i = np.searchsorted(sorted_pos, at)
    if sorted_pos.shape[0] == 0:
        return np.full(at.shape, none, dtype=np.int64)
    return np.where(i < sorted_pos.shape[0], sorted_pos.take(i, mode="clip"), none)


class _Scan:
    """Positions of the bytes that structure text frames, found with one numpy pass each, on first use."""

    def __init__(self, buf: bytes, arr: U8Array) -> None:
        self.buf = buf
        self.arr = arr
        self._cache: dict[str, IntArray] = {}

    def _get(self, key: str, make: Callable[[], IntArray]) -> IntArray:
        found = self._cache.get(key)
        if found is None:
            found = self._cache[key] = make()
        return found

    def of(self, byte: int) -> IntArray:
        """Positions of ``byte`` (none without a C-level search finding one first)."""
        if self.buf.find(bytes((byte,))) < 0:
            return np.zeros(0, dtype=np.int64)
        return self._get(f"b{byte}", lambda: np.flatnonzero(self.arr == byte))

    @property
    def breaks(self) -> IntArray:
        """Every CR and LF (found among the bytes <= 13: one comparison over the buffer)."""

        def make() -> IntArray:
            low = np.flatnonzero(self.arr <= 0x0D)
            v = self.arr[low]
            return low[(v == 0x0D) | (v == 0x0A)]

        return self._get("breaks", make)

    @property
    def seps(self) -> IntArray:
        """Every ',' and ';'."""
        return self._get("seps", lambda: np.flatnonzero((self.arr == 0x2C) | (self.arr == 0x3B)))

    @property
    def semis(self) -> IntArray:
        return self._get("semis", lambda: self.seps[self.arr[self.seps] == 0x3B])


def _first_comma(scan: _Scan, pos: IntArray, none: int) -> IntArray:
    """The first ',' at or after each position: the first separator, unless that is a ';' (then searched)."""
    sep = _next_at(scan.seps, pos, none)
    semi = np.flatnonzero(scan.arr.take(sep, mode="clip") == 0x3B) if sep.size else sep
    for i in semi.tolist():
        if sep[i] < none:
            found = scan.buf.find(b",", int(pos[i]))
            sep[i] = found if found >= 0 else none
    return sep


def _inside(pos: IntArray, starts: IntArray, ends: IntArray) -> BoolArray:
    """Which positions lie inside one of the spans ``[start, end)`` that start before them (spans sorted by start)."""
    if starts.size == 0:
        return np.zeros(pos.shape, dtype=bool)
    j = np.searchsorted(starts, pos, side="left") - 1  # the last span starting before each position
    reach = np.maximum.accumulate(ends)  # overlapping spans: the furthest end so far
    return (j >= 0) & (pos < reach.take(j, mode="clip"))


def _locate_ascii(
    scan: _Scan, sync: int, kind: int, max_len: int, out: _Candidates, skip: tuple[IntArray, IntArray] | None = None
) -> IntArray:
    """Classify every ``#`` (or ``%``) as :meth:`Framer._parse_ascii` does at the end of a stream.

    Candidates inside the spans ``skip`` (starts, ends: the good binary frames) are left out and returned:
    the framer never looks at them once those frames are accepted, which the caller checks. In a binary
    stream they are all there are, and leaving them out spares the scans for '*', separators and line
    breaks over the whole buffer.
    """
    buf, arr = scan.buf, scan.arr
    n = arr.shape[0]
    syncs = scan.of(sync)
    pos = syncs[syncs + 1 < n]
    nxt = arr[pos + 1]
    pos = pos[(nxt >= 0x41) & (nxt <= 0x5A)]
    skipped = np.zeros(0, dtype=np.int64)
    if skip is not None and pos.size:
        inside = _inside(pos, *skip)
        skipped, pos = pos[inside], pos[~inside]
    if pos.size == 0:
        return skipped
    big = n + max_len + 16
    limit = np.minimum(n, pos + max_len)
    star = _next_at(scan.of(0x2A), pos + 2, big)
    brk = _next_at(scan.breaks, pos + 2, big)
    comma = _first_comma(scan, pos, big)
    inner = _next_at(syncs, pos + 1, big)
    status = np.full(pos.shape, _NOT_FRAME, dtype=np.int64)
    end = np.full(pos.shape, n, dtype=np.int64)
    cut = np.full(pos.shape, -1, dtype=np.int64)
    star_in = star < limit
    # no '*' within the bound: a line break cuts it, else oversize, else the buffer ended inside it
    a = ~star_in
    cut[a & (brk < limit)] = brk[a & (brk < limit)]
    status[a & (brk >= limit) & (limit - pos >= max_len)] = _OVERSIZE
    status[a & (brk >= limit) & (limit - pos < max_len)] = _TRUNC
    b = star_in & (brk < star)
    cut[b] = brk[b]
    c = star_in & (brk > star)
    tail = c & (star + 9 > n)
    for i in np.flatnonzero(tail).tolist():  # at most one: the end of the buffer
        s = int(star[i])
        if n > s + 1 and buf[s + 1 : n].strip(b"0123456789ABCDEFabcdef"):
            cut[i] = s + 1
        else:
            status[i] = _TRUNC
    idx = np.flatnonzero(c & ~tail)
    crc_want = np.zeros(0, dtype=np.int64)
    if idx.size:
        digits = _HEX_LUT[arr[star[idx, None] + np.arange(1, 9)]]
        hex_ok = np.all(digits < 16, axis=1)
        bad_hex = idx[~hex_ok]
        cut[bad_hex] = star[bad_hex] + 1
        idx = idx[hex_ok]
        crc_want = digits[hex_ok].astype(np.int64) @ _POW16[7::-1]
    # text cut: truncated once it got as far as a ',' (else it was never a frame)
    has_cut = cut >= 0
    status[has_cut & (comma < cut)] = _TRUNC
    end[has_cut] = cut[has_cut]
    if idx.size:
        # NovAtel CRC-32 = zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF (see drivers.novatel.crc); zlib is
        # called directly, one call per frame, as the framer does
        crc32 = zlib.crc32
        got = [crc32(buf[p + 1 : s], _MASK32) for p, s in zip(pos[idx].tolist(), star[idx].tolist(), strict=True)]
        good = (np.asarray(got, dtype=np.int64) ^ _MASK32) == crc_want
        status[idx[good]] = _OK
        end[idx[good]] = star[idx[good]] + 9
        fail = idx[~good]
        # a failed CRC: not a log without a header comma; cut short by a new log starting inside it
        with_comma = fail[comma[fail] < star[fail]]
        nested = with_comma[inner[with_comma] < star[with_comma]]
        status[nested] = _TRUNC
        end[nested] = inner[nested]
        crc_fail = with_comma[inner[with_comma] >= star[with_comma]]
        status[crc_fail] = _CRC_FAIL
        end[crc_fail] = star[crc_fail] + 9
    keep = status != _NOT_FRAME
    out.add(pos[keep], end[keep], status[keep], kind, star[keep])
    return skipped


def _locate_binary(scan: _Scan, max_len: int, out: _Candidates) -> tuple[IntArray, IntArray]:
    """Classify every ``AA 44 12`` / ``AA 44 13`` as :meth:`Framer._parse_binary` does at the end of a stream;
    returns the spans (starts, ends) of the good frames, in order."""
    buf, arr = scan.buf, scan.arr
    n = arr.shape[0]
    pos = scan.of(0xAA)
    pos = pos[pos + 2 < n]
    pos = pos[(arr[pos + 1] == 0x44) & ((arr[pos + 2] == 0x12) | (arr[pos + 2] == 0x13))]
    if pos.size == 0:
        return pos, pos
    long_ = arr[pos + 2] == 0x12
    total = np.zeros(pos.shape, dtype=np.int64)
    status = np.full(pos.shape, _NOT_FRAME, dtype=np.int64)
    lp = pos[long_]
    head_ok = lp + 10 <= n
    safe = np.minimum(lp, max(n - 10, 0))
    hdr_len = arr[np.minimum(safe + 3, n - 1)].astype(np.int64)
    msg_len = arr[np.minimum(safe + 8, n - 1)].astype(np.int64) | arr[np.minimum(safe + 9, n - 1)].astype(np.int64) << 8
    total[long_] = np.where(head_ok, hdr_len + msg_len + 4, 0)
    status[long_] = np.where(~head_ok, _TRUNC, np.where(hdr_len < LONG_HEADER_LEN, _NOT_FRAME, _OK))
    sp = pos[~long_]
    head_ok_s = sp + 4 <= n
    total[~long_] = np.where(head_ok_s, 16 + arr[np.minimum(sp + 3, n - 1)].astype(np.int64), 0)
    status[~long_] = np.where(head_ok_s, _OK, _TRUNC)
    maybe = status == _OK
    status[maybe & (total > max_len)] = _OVERSIZE
    maybe &= total <= max_len
    status[maybe & (pos + total > n)] = _TRUNC
    maybe &= pos + total <= n
    end = np.where(status == _TRUNC, n, pos + total)
    idx = np.flatnonzero(maybe)
    if idx.size:
        # over a whole frame including its CRC the NovAtel CRC register ends at 0 (drivers.novatel.crc)
        crc32 = zlib.crc32
        got = [crc32(buf[p:e], _MASK32) for p, e in zip(pos[idx].tolist(), end[idx].tolist(), strict=True)]
        status[idx[np.asarray(got, dtype=np.int64) != _MASK32]] = _CRC_FAIL
    keep = status != _NOT_FRAME
    kinds = np.where(long_, _K_BINARY, _K_SHORT_BINARY)[keep]
    for k in (_K_BINARY, _K_SHORT_BINARY):
        m = kinds == k
        out.add(pos[keep][m], end[keep][m], status[keep][m], k)
    good = status == _OK
    return pos[good], end[good]


def _walk(start: IntArray, end: IntArray, status: IntArray) -> tuple[BoolArray, dict[RejectReason, int]]:
    """Accepted candidates and rejection counts, applying the framer's order: a candidate inside an
    accepted frame is never looked at, and a truncation inside a truncated span is counted once."""
    counts = dict.fromkeys(RejectReason, 0)
    ok = status == _OK
    acc_start, acc_end = start[ok], end[ok]
    if not bool(np.all(acc_start[1:] >= acc_end[:-1])):
        return _walk_all(start, end, status, counts)
    # the good frames do not overlap, so all are accepted; a rejection inside one is never seen, and one
    # after an accepted frame starts a new rejected span
    rej = np.flatnonzero(~ok)
    if rej.size == 0:
        return ok, counts
    j = np.searchsorted(acc_start, start[rej], side="right") - 1
    inside = (j >= 0) & (start[rej] < np.append(acc_end, 0)[j])  # j = -1: before every accepted frame
    rej = rej[~inside]
    j = j[~inside]
    new_span = np.ones(rej.shape, dtype=bool)
    new_span[1:] = j[1:] != j[:-1]
    span_end = -1
    span_reason = -1
    for s, e, st, fresh in zip(start[rej].tolist(), end[rej].tolist(), status[rej].tolist(), new_span.tolist(),
                               strict=True):
        if fresh:
            span_end = -1
        span_end, span_reason = _reject(counts, s, e, st, span_end, span_reason)
    return ok, counts


def _reject(
    counts: dict[RejectReason, int], s: int, e: int, st: int, span_end: int, span_reason: int
) -> tuple[int, int]:
    """Count one rejected candidate and update the rejected span (the framer's ``_reject``)."""
    if st == _CRC_FAIL:
        counts[RejectReason.CRC_FAILURE] += 1
    elif st == _TRUNC:
        if not (s < span_end and span_reason == _TRUNC):
            counts[RejectReason.TRUNCATED] += 1
    else:
        counts[RejectReason.OVERSIZE] += 1
        e = s + 1
    if s < span_end:
        return max(span_end, e), span_reason
    return e, st


def _walk_all(
    start: IntArray, end: IntArray, status: IntArray, counts: dict[RejectReason, int]
) -> tuple[BoolArray, dict[RejectReason, int]]:
    """:func:`_walk` one candidate at a time (good frames overlap: only the first of them is taken)."""
    accepted = np.zeros(start.shape[0], dtype=bool)
    acc_end = -1
    span_end = -1
    span_reason = -1
    for i, (s, e, st) in enumerate(zip(start.tolist(), end.tolist(), status.tolist(), strict=True)):
        if s < acc_end:
            continue
        if st == _OK:
            accepted[i] = True
            acc_end = e
            span_end = min(span_end, s)
            continue
        span_end, span_reason = _reject(counts, s, e, st, span_end, span_reason)
    return accepted, counts


# ---------------------------------------------------------------------------------------------
# Vectorised token parsers: a column of tokens (start, end in the buffer) → values, plus the rows
# they cannot take (those go to the per-message decoder). Each token is copied right-aligned into
# 8, 16 or 24 bytes (one row-window copy) and handled as 64-bit words: numbers are parsed with
# SWAR arithmetic (all 8 digits of a word at once), so the work is a few 1-D operations over the
# rows; hex, enum and string columns are hashed and converted once per distinct token, in Python,
# with exactly the per-message decoder's conversion.
# ---------------------------------------------------------------------------------------------

_TOKEN_CAP = 24  # longest token the parsers take; longer ones go to the per-message path
_NUMBER_CAP = 16  # longest number token (15 digits, sign, point: "-114.03066788586" is 16)
_PAD = _TOKEN_CAP  # zero bytes in front of the buffer, so every right-aligned window starts inside it
_MAX_DIGITS = 15  # a mantissa below 10**15 < 2**53 is exact in float64

_U64 = np.uint64
_ALL = 0xFFFF_FFFF_FFFF_FFFF
#: Word mask keeping its top 8 - o bytes (a right-aligned token leaves o bytes of the word outside).
_KEEP = np.array([_ALL & ~((1 << (8 * o)) - 1) for o in range(9)], dtype=np.uint64)
_HI_NIBBLES = _U64(0xF0F0_F0F0_F0F0_F0F0)
_ZEROS = _U64(0x3030_3030_3030_3030)
_SIXES = _U64(0x0606_0606_0606_0606)
_ONES = _U64(0x0101_0101_0101_0101)
_HIGH_BITS = _U64(0x8080_8080_8080_8080)
_DOTS = _U64(0x2E2E_2E2E_2E2E_2E2E)
_POW10_U = np.array([10**k for k in range(20)], dtype=np.uint64)


class _Tokens:
    """Tokens as right-aligned little-endian 64-bit words.

    Byte ``c`` of the ``width``-byte window is byte ``c % 8`` of word ``c // 8``; token i fills the last
    ``length[i]`` bytes, the bytes before it are ``fill`` (0, or '0' for numbers: leading zeros).
    ``begin`` and ``end`` are the tokens' positions in the buffer (``text``).
    """

    __slots__ = ("bad", "begin", "end", "length", "text", "width", "words")

    def __init__(self, text: _Text, begin: IntArray, end: IntArray, width: int, fill: int = 0) -> None:
        self.text = text
        self.begin = begin
        self.end = end
        self.width = width
        self.length = length = end - begin
        self.bad: BoolArray = length > width
        n_words = width // 8
        self.words = words = np.empty((length.shape[0], n_words), dtype=np.uint64)
        at = end + (_PAD - width)
        outside = width - length
        fill_word = _U64(fill * 0x0101_0101_0101_0101)
        for j in range(n_words):
            keep = _KEEP.take(np.clip(outside - 8 * j, 0, 8))  # 0..8 bytes of the word outside the token
            x = text.words[at + 8 * j]
            words[:, j] = (x & keep) if not fill else ((x ^ fill_word) & keep) ^ fill_word

    def byte(self, pos: IntArray) -> U8Array:
        """The buffer's byte at each position (0 before the buffer's start)."""
        return self.text.padded[pos + _PAD]

    def subset(self, rows: IntArray) -> _Tokens:
        out = object.__new__(_Tokens)
        out.text, out.width = self.text, self.width
        out.begin, out.end, out.length = self.begin[rows], self.end[rows], self.length[rows]
        out.bad, out.words = self.bad[rows], self.words[rows]
        return out

    def xor_byte(self, rows: IntArray, col: IntArray, xor: int) -> None:
        """XOR byte ``col`` (window column) of each of ``rows`` with ``xor``."""
        masks = np.left_shift(_U64(xor), (8 * (col % 8)).astype(np.uint64))
        word = col // 8
        for j in range(self.words.shape[1]):
            here = word == j
            self.words[rows[here], j] ^= masks[here]

    def token(self, i: int) -> bytes:
        n = min(int(self.length[i]), self.width)
        return self.words[i].tobytes()[self.width - n :]


@dataclass(frozen=True, slots=True)
class _Text:
    """The buffer behind :data:`_PAD` zero bytes, and the same bytes seen as a little-endian 64-bit word
    starting at every byte (an unaligned strided view: ``words[i]`` = bytes ``i … i+7``)."""

    padded: U8Array
    words: npt.NDArray[np.uint64]

    @classmethod
    def of(cls, arr: U8Array) -> _Text:
        padded = np.concatenate([np.zeros(_PAD, dtype=np.uint8), arr, np.zeros(8, dtype=np.uint8)])
        words = np.ndarray(shape=(padded.shape[0] - 7,), dtype="<u8", buffer=padded, strides=(1,))
        return cls(padded, words)

    def byte(self, pos: IntArray) -> U8Array:
        return self.padded[pos + _PAD]


def _width(longest: int, cap: int = _TOKEN_CAP) -> int:
    """Window width (8, 16 or 24 bytes, at most ``cap``) for tokens of up to ``longest`` bytes."""
    return min(cap, 8 if longest <= 8 else 16 if longest <= 16 else 24)


def _swar8(v: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    """Eight digit values (byte 0 the most significant, 0..9 each) → the 8-digit number."""
    v = v * _U64(10) + (v >> _U64(8))
    v &= _U64(0x00FF_00FF_00FF_00FF)
    v = v * _U64(100) + (v >> _U64(16))
    v &= _U64(0x0000_FFFF_0000_FFFF)
    v = v * _U64(10000) + (v >> _U64(32))
    v &= _U64(0xFFFF_FFFF)
    return v


def _digits(t: _Tokens) -> tuple[npt.NDArray[np.uint64], BoolArray]:
    """Each token (filled with '0' in front) read as one decimal number, and the rows with a non-digit."""
    raw = np.zeros(t.words.shape[0], dtype=np.uint64)
    bad = t.bad.copy()
    for j in range(t.words.shape[1]):
        x = t.words[:, j]
        # a byte is a digit when its high nibble is 3 and its low nibble plus 6 stays below 16 (a carry
        # out of a byte comes only from a non-digit byte >= 0xFA, whose row is bad anyway)
        bad |= (((x & _HI_NIBBLES) ^ _ZEROS) | (((x + _SIXES) & _HI_NIBBLES) ^ _ZEROS)) != 0
        v = _swar8(x - _ZEROS)
        raw = v if j == 0 else raw * _U64(10**8) + v
    return raw, bad


def _number_tokens(text: _Text, begin: IntArray, end: IntArray, width: int) -> tuple[_Tokens, BoolArray]:
    """Number tokens without their leading '-' (returned apart), '0'-filled in front."""
    neg = (text.byte(begin) == 0x2D) & (end > begin)
    return _Tokens(text, begin + neg, end, width, fill=0x30), neg


def _parse_int(t: _Tokens, neg: BoolArray, _dec: IntArray) -> tuple[IntArray, BoolArray]:
    """Decimal integers ``[-]digits`` of up to 15 digits (the per-message path takes any other form)."""
    raw, bad = _digits(t)
    bad |= (t.length < 1) | (t.length > _MAX_DIGITS)
    v = np.where(bad, _U64(0), raw).astype(np.int64)
    return np.where(neg, -v, v), bad


def _dot_col(t: _Tokens, rows: IntArray) -> IntArray:
    """Window column of the first '.' of each of ``rows`` (-1: none), by the zero-byte test on
    word ^ '........' (its lowest flagged byte is exact), the bit found by an exact float conversion."""
    col = np.full(rows.shape[0], -1, dtype=np.int64)
    for j in reversed(range(t.words.shape[1])):  # the lowest word with a point wins
        y = t.words[rows, j] ^ _DOTS
        z = (y - _ONES) & ~y & _HIGH_BITS
        found = z != 0
        if found.any():
            _m, exp = np.frexp((z & (~z + _U64(1))).astype(np.float64))
            col = np.where(found, 8 * j + (exp - 1) // 8, col)
    return col


def _parse_float(t: _Tokens, neg: BoolArray, dec: IntArray) -> tuple[FloatArray, BoolArray]:
    """Decimals ``[-]digits[.digits]`` of up to 15 digits; ``dec``: each row's usual number of digits
    after the point (-1: usually none), checked per row, and the point searched for where it is not.

    Exact: the mantissa m (< 2**53) and 10**k are exact doubles, so m / 10**k is the correctly rounded
    value of the decimal, as ``float(token)`` is. Anything else (an exponent, ``nan``, a second point,
    a '+' …) has a byte that is neither digit, sign nor point, and its row goes to the per-message path.
    """
    w = t.width
    has_dot = (dec >= 0) & (dec < t.length) & ~t.bad & (t.byte(t.end - 1 - dec) == 0x2E)
    col = w - 1 - dec
    odd = np.flatnonzero(~has_dot & ~t.bad)
    if odd.size:  # the point elsewhere, or none: find it in those rows
        found = _dot_col(t, odd)
        col[odd] = found
        has_dot[odd] = found >= 0
    dotted = np.flatnonzero(has_dot)
    t.xor_byte(dotted, col[dotted], 0x2E ^ 0x30)  # the point read as a 0 digit
    raw, bad = _digits(t)
    digits = t.length - has_dot
    bad |= (digits < 1) | (digits > _MAX_DIGITS)
    raw = np.where(bad, _U64(0), raw)
    # raw = int_part * 10**(f+1) + frac_part, with f digits after the point
    f = np.where(has_dot, w - 1 - col, 0)
    frac = raw % _POW10_U[f]
    mant = np.where(has_dot, (raw - frac) // _U64(10) + frac, raw)
    v = mant.astype(np.float64) / _POW10F[f]
    return np.where(neg, -v, v), bad


def _parse_numbers(
    parse: Callable[[_Tokens, BoolArray, IntArray], tuple[Column, BoolArray]],
    text: _Text, begin: IntArray, end: IntArray, width: int, dec: IntArray, segments: int,
) -> tuple[Column, BoolArray]:
    """``parse`` over ``segments`` columns of equal length; a column whose tokens are all the same
    (common in a capture: week, ages, sigmas, counts …) is parsed from its first row only."""
    t, neg = _number_tokens(text, begin, end, width)
    n = t.length.shape[0]
    rows = n // segments
    first = np.arange(segments) * rows
    rep = np.repeat(first, rows)  # each row's column's first row
    differ = (t.length != t.length[rep]) | (neg != neg[rep])
    for j in range(t.words.shape[1]):
        differ |= t.words[:, j] != t.words[rep, j]
    varying = differ.reshape(segments, rows).any(axis=1)
    if varying.all():
        return parse(t, neg, dec)
    # parse the first row of every column and all rows of the varying ones, then spread
    take = np.concatenate([first, *(np.arange(k * rows, (k + 1) * rows) for k in np.flatnonzero(varying))])
    values_sub, bad_sub = parse(t.subset(take), neg[take], dec[take])
    where = rep.copy()  # constant columns: their first row's value
    vary_rows = take[segments:]
    where[vary_rows] = vary_rows
    position = np.empty(n, dtype=np.int64)
    position[take] = np.arange(take.shape[0])
    return values_sub[position[where]], bad_sub[position[where]]


_HASH_MULT = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9], dtype=np.uint64)


def _categories(t: _Tokens, segments: int = 1) -> tuple[list[bytes], IntArray]:
    """Distinct tokens and each row's index into them. The rows are ``segments`` columns of equal
    length; a column whose tokens are all the same (common: port, status, datum …) is settled from its
    first row, only the others are hashed and sorted. A token longer than the width is cut (its row is
    bad already)."""
    n, k = t.words.shape
    if n == 0:
        return [], np.zeros(0, dtype=np.int64)
    rows = n // segments
    words, length = t.words, np.minimum(t.length, t.width)
    inverse = np.zeros(n, dtype=np.int64)
    tokens: list[bytes] = []
    index: dict[bytes, int] = {}

    def number(tok: bytes) -> int:
        i = index.get(tok)
        if i is None:
            i = index[tok] = len(tokens)
            tokens.append(tok)
        return i

    varying: list[int] = []
    for s in range(segments):
        sl = slice(s * rows, (s + 1) * rows)
        seg_words, seg_len = words[sl], length[sl]
        differ = seg_len != seg_len[0]
        for j in range(k):
            differ |= seg_words[:, j] != seg_words[0, j]
        if differ.any():
            varying.append(s)
        else:
            inverse[sl] = number(t.token(s * rows))
    if varying:
        rows_v = np.concatenate([np.arange(s * rows, (s + 1) * rows) for s in varying])
        vw, vl = words[rows_v], length[rows_v]
        key = vl.astype(np.uint64)
        for j in range(k):
            key = key * _HASH_MULT[j] + vw[:, j]
        _u, first, inv = np.unique(key, return_index=True, return_inverse=True)
        inv = inv.reshape(-1)
        rep = first[inv]
        differ = vl != vl[rep]
        for j in range(k):
            differ |= vw[:, j] != vw[rep, j]
        if differ.any():  # a hash collision: the exact (slower) way
            both = np.concatenate([vw, vl.astype(np.uint64)[:, None]], axis=1)
            _u2, first, inv = np.unique(both, axis=0, return_index=True, return_inverse=True)
            inv = inv.reshape(-1)
        ids = np.asarray([number(t.token(int(rows_v[i]))) for i in first.tolist()], dtype=np.int64)
        inverse[rows_v] = ids[inv]
    return tokens, inverse


def _str_token(raw: bytes) -> str | None:
    """The per-message fast path's string token (None: it would take the generic path)."""
    if b'"' not in raw:
        return raw.decode("latin-1")
    if len(raw) >= 2 and raw[:1] == b'"' and raw[-1:] == b'"' and b'"' not in raw[1:-1]:
        return raw[1:-1].decode("latin-1")
    return None


def _hex_value(raw: bytes) -> int | None:
    v = int(raw.decode("latin-1"), 16)
    return v if _INT64_MIN <= v <= _INT64_MAX else None


def _enum_converter(enum: type[_OpenIntEnum]) -> Callable[[bytes], int | None]:
    members = enum._member_map_

    def convert(raw: bytes) -> int | None:
        member = members.get(raw.decode("latin-1"))
        return None if member is None else member.value  # other forms: the per-message path

    return convert


def _port_token(raw: bytes) -> str:
    return raw.decode("latin-1")


_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1


# ---------------------------------------------------------------------------------------------
# Derived columns
# ---------------------------------------------------------------------------------------------


def _fits(v: int) -> bool:
    return -(2**63) <= v < 2**63 and v != MISSING_INT


def gps_ns_columns(week: IntArray, seconds: FloatArray) -> IntArray:
    """``vsccore.gpstime.gps_to_ns`` over arrays: :data:`MISSING_INT` where it raises (negative week,
    non-finite seconds) or its value does not fit an int64."""
    week = np.asarray(week, dtype=np.int64)
    with np.errstate(over="ignore", invalid="ignore"):  # out-of-range seconds: decided below
        x = np.asarray(seconds, dtype=np.float64) * float(NS_PER_S)  # the same double product as gps_to_ns
    fast = (week >= 0) & (week < 2**63 // NS_PER_WEEK) & np.isfinite(x) & (np.abs(x) <= 2.0**62)
    whole = np.where(fast, week, 0) * NS_PER_WEEK  # no overflow: week < 2**63 / NS_PER_WEEK
    sub = np.rint(np.where(fast, x, 0.0)).astype(np.int64)  # round half to even, as round()
    total = whole + sub
    fast &= ~((sub > 0) & (total < whole))  # the sum wrapped past 2**63
    out = np.where(fast, total, MISSING_INT)
    for i in np.flatnonzero(~fast).tolist():  # rare: decide exactly with Python integers
        try:
            v = gps_to_ns(int(week[i]), float(seconds[i]))
        except (ValueError, OverflowError):
            continue
        if _fits(v):
            out[i] = v
    return out


def _leap_seconds(utc_offset_s: FloatArray) -> IntArray:
    """``Time.leap_seconds`` (-round(utc_offset_s)) over arrays; :data:`MISSING_INT` where it has no int64 value."""
    x = np.asarray(utc_offset_s, dtype=np.float64)
    fast = np.isfinite(x) & (np.abs(x) <= 2.0**62)
    out = np.where(fast, -np.rint(np.where(fast, x, 0.0)).astype(np.int64), MISSING_INT)
    for i in np.flatnonzero(~fast).tolist():
        try:
            v = -round(float(x[i]))
        except (ValueError, OverflowError):
            continue
        if _fits(v):
            out[i] = v
    return out


def _add_derived(name: str, header: dict[str, Column], body: dict[str, Column]) -> None:
    header["gps_ns"] = gps_ns_columns(header["week"], header["seconds"])
    if name in _EVENT_TIME_LOGS:
        body["event_gps_ns"] = gps_ns_columns(body["week"], body["seconds"])
    elif name == "TIME":
        body["leap_seconds"] = _leap_seconds(body["utc_offset_s"])


# ---------------------------------------------------------------------------------------------
# Building columns
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True)
class _Part:
    """Rows of one log from one path (binary, ASCII or per-message), columns before concatenation."""

    offset: IntArray
    length: IntArray
    binary: BoolArray
    header: dict[str, Column]
    body: dict[str, Column]
    counts: IntArray | None = None  # records of each row, for a log with records
    records: dict[str, Column] | None = None


def _binary_header(rec: npt.NDArray[Any]) -> dict[str, Column]:
    """Header columns of long-header frames seen through a structured dtype with the ``h_`` fields."""
    ports, port_inv = np.unique(rec["h_port"], return_inverse=True)
    return {
        "port": np.asarray([port_name_from_byte(int(p)) for p in ports.tolist()], dtype=str)[port_inv.reshape(-1)],
        "sequence": rec["h_sequence"].astype(np.int64),
        "idle_time_pct": rec["h_idle"].astype(np.float64) * 0.5,
        "time_status": rec["h_time_status"].astype(np.int64),
        "week": rec["h_week"].astype(np.int64),
        "seconds": rec["h_milliseconds"].astype(np.float64) / 1000,
        "receiver_status": rec["h_receiver_status"].astype(np.int64),
        "reserved": rec["h_reserved"].astype(np.int64),
        "sw_version": rec["h_sw_version"].astype(np.int64),
        "source": (rec["h_message_type"] & 0x1F).astype(np.int64),
    }


def _rows(arr: U8Array, size: int) -> npt.NDArray[np.void]:
    """The buffer as ``size``-byte items starting at every byte (an overlapping view: indexing it with
    positions copies those rows, one memory copy each)."""
    return np.ndarray((max(arr.shape[0] - size + 1, 0),), dtype=f"V{size}", buffer=arr, strides=(1,))


def _frames(arr: U8Array, start: IntArray, dtype: np.dtype[Any]) -> npt.NDArray[Any]:
    """The first ``dtype.itemsize`` bytes of each frame, one row copy each, viewed through ``dtype``."""
    return _rows(arr, dtype.itemsize)[start].view(dtype)


def _binary_part(codec: BodyCodec, arr: U8Array, start: IntArray, length: IntArray) -> _Part:
    rec = _frames(arr, start, _FRAME_DTYPES[codec.cls.MESSAGE_ID])  # header and body in one view
    header = _binary_header(rec)
    body: dict[str, Column] = {}
    for spec in codec.specs:
        col = rec[f"b_{spec.name}"]
        if spec.kind is Kind.FLOAT:
            body[spec.name] = col.astype(np.float64)
        elif spec.kind is Kind.STR:
            uniq, inv = np.unique(col, return_inverse=True)
            texts = np.asarray([u.decode("latin-1") for u in uniq.tolist()], dtype=str)
            body[spec.name] = texts[inv.reshape(-1)]
        else:
            body[spec.name] = col.astype(np.int64)
    return _Part(start.astype(np.int64), length.astype(np.int64), np.ones(start.shape, dtype=bool), header, body)


def _rangecmp_head() -> np.dtype[Any]:
    """A RANGECMP frame's long header and observation count."""
    head = [*_struct_fields(LONG_HEADER.format, _LONG_HEADER_FIELDS, offset=3)[0], ("b_count", "<u4", LONG_HEADER_LEN)]
    return np.dtype({"names": [f[0] for f in head], "formats": [f[1] for f in head], "offsets": [f[2] for f in head],
                     "itemsize": LONG_HEADER_LEN + 4})


_RANGECMP_HEAD = _rangecmp_head()


def _rangecmp_part(arr: U8Array, start: IntArray, length: IntArray) -> _Part:
    """Standard long-header binary RANGECMP frames whose length holds exactly their count of records."""
    head = _frames(arr, start, _RANGECMP_HEAD)
    counts = head["b_count"].astype(np.int64)
    records = _rangecmp_records(arr, start + LONG_HEADER_LEN + 4, counts)
    return _Part(start.astype(np.int64), length.astype(np.int64), np.ones(start.shape, dtype=bool),
                 _binary_header(head), {"num_obs": counts}, counts, records)


#: A RANGECMP record as little-endian 32-bit words (bit fields of the OEM7 reference): tracking status;
#: Doppler (28 bits) and the pseudorange's low 4 bits; the pseudorange's high 32 bits; ADR; σ indices,
#: PRN and lock time's low 16 bits; lock time's high 5 bits, C/N0 and GLONASS channel.
_RECORD = np.dtype({
    "names": ["status", "doppler_psr", "psr", "adr", "w4", "w5"],
    "formats": ["<u4", "<u4", "<u4", "<i4", "<u4", "<u4"],
    "offsets": [0, 4, 8, 12, 16, 20],
    "itemsize": RECORD_LEN,
})


_RECORD_CHUNK = 65536  # records unpacked together (bounded temporaries for long captures)


def _rangecmp_records(arr: U8Array, first: IntArray, counts: IntArray) -> dict[str, Column]:
    """RANGECMP records as columns, the values of :func:`drivers.novatel.rawobs.decode_rangecmp`: ``counts[i]``
    records of 24 bytes from ``arr[first[i]]``, all in order.

    The records are copied out (one gather per chunk of records) and their bit fields cut out of 32-bit
    words with shifts and masks; every value is computed exactly (integers, and sums and quotients that
    a double holds exactly), and the ADR roll-over is resolved with the same double-precision operations
    as the per-record decoder, the wavelength of each distinct (system, signal, GLONASS channel) taken
    from :func:`drivers.novatel.rawobs.signal_wavelength_m`: bit for bit the per-record decoder's values.
    """
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    # record j (over all frames) starts at first[i] + 24 * (j - records before frame i)
    pos = np.repeat(np.asarray(first, dtype=np.int64) - RECORD_LEN * (np.cumsum(counts) - counts), counts)
    pos += RECORD_LEN * np.arange(total, dtype=np.int64)
    if total and not 0 <= int(pos.min()) <= int(pos.max()) <= arr.shape[0] - RECORD_LEN:
        raise ValueError(f"RANGECMP records run past the buffer's {arr.shape[0]} bytes")
    rows = _rows(arr, RECORD_LEN)
    ints = ("tracking_status", "prn", "cn0_dbhz", "glonass_fcn")
    out: dict[str, Column] = {
        name: np.empty(total, dtype=np.int64 if name in ints else np.float64) for name in _RANGECMP_COLUMNS
    }
    psr_std = np.asarray(PSR_STD_M, dtype=np.float64)
    lam_table = np.full(1 << 14, np.nan)  # wavelength by key, NaN: unknown (or not looked up yet)
    looked_up = np.zeros(1 << 14, dtype=bool)
    for a in range(0, total, _RECORD_CHUNK):
        b = min(total, a + _RECORD_CHUNK)
        rec = rows[pos[a:b]].view(_RECORD)
        status, dop_psr, w4, w5 = rec["status"], rec["doppler_psr"], rec["w4"], rec["w5"]
        out["tracking_status"][a:b] = status
        psr = out["pseudorange_m"][a:b]
        np.multiply(rec["psr"], 16.0, out=psr)
        psr += dop_psr >> 28
        psr /= 128.0  # 36 bits over 2**7: exact
        adr_raw = np.divide(rec["adr"], 256.0, out=out["adr_raw_cycles"][a:b])
        fcn = (w5 >> 10) & 0x3F
        out["glonass_fcn"][a:b] = fcn
        # the wavelength per (system, signal type, GLONASS channel): the per-record function, once per key
        key = ((status >> 16) & 0x7) | ((status >> 18) & 0xF8) | (fcn << 8)
        new = np.flatnonzero(np.bincount(key, minlength=1 << 14).astype(bool) & ~looked_up)
        for k in new.tolist():
            lam_k = signal_wavelength_m(((k & 0x7) << 16) | (((k >> 3) & 0x1F) << 21), k >> 8)
            if lam_k is not None:
                lam_table[k] = lam_k
        looked_up[new] = True
        lam = lam_table[key]
        unknown = np.isnan(lam)
        # the 32-bit ADR wraps; the pseudorange tells which wrap (decode_rangecmp: round half away from
        # zero, rolls - 0.5 below zero and rolls + 0.5 above, both truncated); computed in place
        adr = np.divide(psr, lam, out=out["adr_cycles"][a:b])
        adr += adr_raw
        adr /= ADR_MAX_VALUE  # the rolls
        adr += np.copysign(0.5, adr, out=lam)  # (into lam's memory: lam is not needed any more)
        np.trunc(adr, out=adr)
        adr *= -ADR_MAX_VALUE
        adr += adr_raw
        np.copyto(adr, adr_raw, where=unknown)  # no known wavelength: the wire value
        np.divide((dop_psr << 4).view(np.int32) >> 4, 256.0, out=out["doppler_hz"][a:b])  # 28-bit two's complement
        np.take(psr_std, w4 & 0xF, out=out["psr_std_m"][a:b])
        np.divide(((w4 >> 4) & 0xF) + 1, 512.0, out=out["adr_std_cycles"][a:b])
        out["prn"][a:b] = (w4 >> 8) & 0xFF
        np.divide((w4 >> 16) | ((w5 & 0x1F) << 16), 32.0, out=out["lock_time_s"][a:b])
        out["cn0_dbhz"][a:b] = ((w5 >> 5) & 0x1F) + 20
    return out


#: Record columns of RANGECMP, in the order of :class:`drivers.novatel.rawobs.RangeCmpRecord`'s fields.
_RANGECMP_COLUMNS = tuple(f.name for f in fields(RangeCmpRecord))


_ASCII_HEADER: tuple[tuple[str, Kind, type[_OpenIntEnum] | None], ...] = (
    ("port", Kind.STR, None),
    ("sequence", Kind.INT, None),
    ("idle_time_pct", Kind.FLOAT, None),
    ("time_status", Kind.ENUM, TimeStatus),
    ("week", Kind.INT, None),
    ("seconds", Kind.FLOAT, None),
    ("receiver_status", Kind.HEX, None),
    ("reserved", Kind.HEX, None),
    ("sw_version", Kind.INT, None),
)


def _category_converter(kind: Kind, enum: type[_OpenIntEnum] | None, quoted: bool) -> tuple[
    Callable[[bytes], Any], Any
]:
    if kind is Kind.HEX:
        return _hex_value, np.int64
    if kind is Kind.ENUM:
        assert enum is not None
        return _enum_converter(enum), np.int64
    return (_str_token if quoted else _port_token), str


def _ascii_part(
    codec: BodyCodec, text: _Text, seps: IntArray, semis: IntArray, start: IntArray, star: IntArray, source: int
) -> tuple[_Part | None, IntArray]:
    """Columns of the ASCII logs ``#…*`` at ``start`` (``*`` at ``star``) of one name token.

    ``seps`` holds the positions of every ',' and ';' in the buffer, ``semis`` of every ';'. Rows
    with the layout's field count (and the header's ';' in its place) are parsed column by column in
    groups: float columns, integer columns, and hex / enum / string columns (through one table of
    distinct tokens), each group split by token width. Returns the part for the rows the vectorised
    parsers take and the positions (into ``start``) of the rows that must take the per-message path.
    """
    n_tokens = 10 + len(codec.specs)
    first = np.searchsorted(seps, start)
    count = np.searchsorted(seps, star) - first
    semi_count = np.searchsorted(semis, star) - np.searchsorted(semis, start)
    ok = (count == n_tokens - 1) & (semi_count == 1)
    # the header's ';' must be the 10th separator (else the header has the wrong field count)
    ok[ok] = seps[first[ok] + 9] == semis[np.searchsorted(semis, start[ok])]
    good = np.flatnonzero(ok)
    if good.size == 0:
        return None, np.arange(start.shape[0])
    rows = good.size
    base = first[good]
    row_star = star[good]
    # (destination, name, token index, kind, enum, quoted): the header's port is any token, quotes and
    # all; the body's strings drop their quotes as the per-message decoder does
    cols = [("h", name, k, kind, enum, False) for k, (name, kind, enum) in enumerate(_ASCII_HEADER, 1)]
    cols += [("b", spec.name, 10 + j, spec.kind, spec.enum, True) for j, spec in enumerate(codec.specs)]
    out: dict[str, dict[str, Column]] = {"h": {}, "b": {}}
    bad = np.zeros(rows, dtype=bool)
    # each column's tokens, then the columns grouped by how they parse and by token width, so that one
    # parser call takes many columns and no token is gathered wider than its group needs
    at = seps.take(base[None, :] + np.arange(n_tokens - 1)[:, None])  # separator k of each row: row k
    begins = [at[c[2] - 1] + 1 for c in cols]
    ends = [at[c[2]] if c[2] < n_tokens - 1 else row_star for c in cols]
    buf = text.padded[_PAD : text.padded.shape[0] - 8]
    constant = _constant_columns(text, buf, begins, ends)
    if constant.any():  # parsed from the first row, below, as a batch of one row
        begins = [b[:1] if constant[i] else b for i, b in enumerate(begins)]
        ends = [e[:1] if constant[i] else e for i, e in enumerate(ends)]
    groups: dict[tuple[str, int, bool], list[int]] = {}
    for i, c in enumerate(cols):
        parse = "float" if c[3] is Kind.FLOAT else "int" if c[3] is Kind.INT else "table"
        width = _width(int((ends[i] - begins[i]).max()), _NUMBER_CAP if parse != "table" else _TOKEN_CAP)
        groups.setdefault((parse, width, bool(constant[i])), []).append(i)
    for (parse, width, one_row), members in groups.items():
        n = 1 if one_row else rows
        begin = np.concatenate([begins[i] for i in members])
        end = np.concatenate([ends[i] for i in members])
        values, group_bad = _parse_group([cols[i] for i in members], parse, width, text, buf, begin, end, n)
        bad |= group_bad.any() if one_row else group_bad.any(axis=0)
        for i, v in zip(members, values, strict=True):
            out[cols[i][0]][cols[i][1]] = np.repeat(v, rows) if one_row else v
    header, body = out["h"], {spec.name: out["b"][spec.name] for spec in codec.specs}
    header = {name: header[name] for name, _kind, _enum in _ASCII_HEADER}
    header["source"] = np.full(rows, source, dtype=np.int64)
    keep = ~bad
    fallback = np.concatenate([np.flatnonzero(~ok), good[bad]])
    if not keep.any():
        return None, fallback
    row_start = start[good][keep]
    part = _Part(
        row_start.astype(np.int64),
        (row_star[keep] + 9 - row_start).astype(np.int64),
        np.zeros(row_start.shape, dtype=bool),
        {k: v[keep] for k, v in header.items()},
        {k: v[keep] for k, v in body.items()},
    )
    return part, fallback


_Col = tuple[str, str, int, Kind, "type[_OpenIntEnum] | None", bool]


def _parse_group(
    cols: Sequence[_Col], parse: str, width: int, text: _Text, buf: U8Array, begin: IntArray, end: IntArray,
    rows: int,
) -> tuple[list[Column], BoolArray]:
    """Values of columns that parse alike (their tokens: ``rows`` each, one column after the other in
    ``begin``/``end``), and the bad tokens as a (columns, rows) matrix."""
    if parse == "table":
        t = _Tokens(text, begin, end, width)
        tokens, inverse = _categories(t, len(cols))
        bad = t.bad.reshape(len(cols), rows).copy()
        values: list[Column] = []
        for m, (_dest, _name, _k, kind, enum, quoted) in enumerate(cols):
            inv = inverse[m * rows : (m + 1) * rows]
            convert, dtype = _category_converter(kind, enum, quoted)
            table, refused = _convert_tokens(tokens, np.flatnonzero(np.bincount(inv, minlength=len(tokens))),
                                             convert, dtype)
            values.append(table[inv])
            bad[m] |= refused[inv]
        return values, bad
    if parse == "float":
        # each column's usual number of decimals, from its first row (a fixed-decimals field keeps it)
        firsts = [buf[int(begin[m * rows]) : int(end[m * rows])].tobytes() for m in range(len(cols))]
        decimals = [len(tok) - 1 - tok.find(b".") if b"." in tok else -1 for tok in firsts]
        dec = np.repeat(np.asarray(decimals, dtype=np.int64), rows)
        flat, flat_bad = _parse_numbers(_parse_float, text, begin, end, width, dec, len(cols))
    else:
        flat, flat_bad = _parse_numbers(_parse_int, text, begin, end, width, np.zeros(begin.shape, np.int64), len(cols))
    return [flat[m * rows : (m + 1) * rows] for m in range(len(cols))], flat_bad.reshape(len(cols), rows)


_SPAN_CAP = 512  # longest run of columns checked as one span


def _constant_columns(text: _Text, buf: U8Array, begins: Sequence[IntArray], ends: Sequence[IntArray]) -> BoolArray:
    """Columns (in token order) whose token is the same in every row, found run by run: a column whose
    first, middle and last tokens agree (and whose length never changes) is a candidate, and a run of
    consecutive candidates is confirmed by comparing its whole byte span in every row with the first
    row's, a 64-bit word at a time (stopping at the first word that differs)."""
    n_cols = len(begins)
    rows = begins[0].shape[0]
    out = np.zeros(n_cols, dtype=bool)
    if rows < 8:
        return out
    samples = (0, rows // 2, rows - 1)
    cand = []
    for b, e in zip(begins, ends, strict=True):
        length = e - b
        ok = bool((length == length[0]).all())
        if ok:
            first = buf[int(b[0]) : int(e[0])].tobytes()
            ok = all(buf[int(b[r]) : int(e[r])].tobytes() == first for r in samples[1:])
        cand.append(ok)
    i = 0
    while i < n_cols:
        if not cand[i]:
            i += 1
            continue
        j = i
        while j + 1 < n_cols and cand[j + 1]:
            j += 1
        begin, end = begins[i], ends[j]
        span = int(end[0] - begin[0])
        if bool((end - begin == span).all()) and 0 < span <= _SPAN_CAP:
            width = -(-span // 8) * 8
            at = end + (_PAD - width)
            keep0 = _KEEP[width - span]
            same = True
            for w in range(width // 8):
                x = text.words[at + 8 * w]
                if w == 0:
                    x = x & keep0
                if not bool((x == x[0]).all()):
                    same = False
                    break
            out[i : j + 1] = same
        i = j + 1
    return out


def _convert_tokens(
    tokens: Sequence[bytes], used: IntArray, convert: Callable[[bytes], Any], dtype: Any
) -> tuple[Column, BoolArray]:
    """``convert`` applied to the ``used`` tokens (a table over all tokens) and which it refused
    (raised ValueError/KeyError or gave None)."""
    fill: Any = "" if dtype is str else 0
    values: list[Any] = [fill] * len(tokens)
    refused = np.zeros(len(tokens), dtype=bool)
    for i in used.tolist():
        try:
            v = convert(tokens[i])
        except (ValueError, KeyError):
            v = None
        if v is None:
            refused[i] = True
        else:
            values[i] = v
    return np.asarray(values, dtype=dtype), refused


def _fits_int64(header: Header, body: Any) -> bool:
    """Every integer of the log fits an int64 column (ASCII can print any integer; no wire field is wider)."""
    values = [getattr(header, n) for n in HEADER_COLUMNS[:-1]]
    values += [getattr(body, f.name) for f in fields(body) if f.name not in ("prns", "records")]
    return all(_INT64_MIN <= v <= _INT64_MAX for v in values if isinstance(v, int))


def _value(v: Any) -> Any:
    return v.value if isinstance(v, Enum) else v


def _column(values: list[Any], kind: Kind) -> Column:
    return np.asarray(values, dtype=str if kind is Kind.STR else np.float64 if kind is Kind.FLOAT else np.int64)


_Decoded = tuple[Header, Any, int, int, bool]  # header, body, offset, length, binary


def _logs_part(layout: _Layout, items: Sequence[_Decoded]) -> _Part:
    """Columns of logs decoded by the per-message path."""
    headers = [h for h, *_ in items]
    header = {name: _column([_value(getattr(h, name)) for h in headers], _HEADER_KINDS[name])
              for name in HEADER_COLUMNS[:-1]}
    bodies = [b for _h, b, *_ in items]
    body: dict[str, Column] = {}
    counts = records = None
    if layout.records:  # RANGECMP: the count, and the records flattened in order
        counts = np.asarray([len(b.records) for b in bodies], dtype=np.int64)
        body["num_obs"] = counts
        recs = [r for b in bodies for r in b.records]
        records = {name: _column([getattr(r, name) for r in recs], kind) for name, kind in layout.records}
    else:
        for name, kind in layout.body:
            body[name] = _column([_value(getattr(b, name)) for b in bodies], kind)
    if layout.prns:
        prns = np.empty(len(bodies), dtype=object)
        prns[:] = [tuple(b.prns) for b in bodies]
        body["prns"] = prns
    return _Part(
        np.asarray([o for _h, _b, o, _n, _bin in items], dtype=np.int64),
        np.asarray([n for _h, _b, _o, n, _bin in items], dtype=np.int64),
        np.asarray([bin_ for *_x, bin_ in items], dtype=bool),
        header,
        body,
        counts,
        records,
    )


def _concat(name: str, parts: Sequence[_Part]) -> LogColumns:
    """One log's parts (vectorised binary, vectorised ASCII, per message) as columns in buffer order."""
    layout = _LAYOUTS[name]
    if layout.prns and any("prns" not in p.body for p in parts):
        raise TypeError(f"NovAtel {name}: PRN lists missing from a part")
    if layout.records and any(p.counts is None or p.records is None for p in parts):
        raise TypeError(f"NovAtel {name}: records missing from a part")
    counts: IntArray | None
    records: dict[str, Column]
    if len(parts) == 1 and bool(np.all(np.diff(parts[0].offset) > 0)):
        p = parts[0]
        offset, length, binary, header, body = p.offset, p.length, p.binary, dict(p.header), dict(p.body)
        counts, records = p.counts, dict(p.records or {})
    else:
        offset = np.concatenate([p.offset for p in parts])
        order = np.argsort(offset, kind="stable")
        offset = offset[order]
        length = np.concatenate([p.length for p in parts])[order]
        binary = np.concatenate([p.binary for p in parts])[order]
        header = {k: np.concatenate([p.header[k] for p in parts])[order] for k in parts[0].header}
        body = {k: np.concatenate([p.body[k] for p in parts])[order] for k in parts[0].body}
        counts, records = None, {}
        if layout.records:
            all_counts = np.concatenate([p.counts for p in parts if p.counts is not None])
            all_first = np.cumsum(all_counts) - all_counts
            counts = all_counts[order]
            # record k of the reordered rows: the row's first record in the parts' order, plus its rank
            take = np.repeat(all_first[order] - (np.cumsum(counts) - counts), counts)
            take += np.arange(take.shape[0], dtype=np.int64)
            records = {k: np.concatenate([p.records[k] for p in parts if p.records is not None])[take]
                       for k, _kind in layout.records}
    _add_derived(name, header, body)
    record_start = None
    if counts is not None:
        record_start = np.zeros(counts.shape[0] + 1, dtype=np.int64)
        np.cumsum(counts, out=record_start[1:])
    return LogColumns(name, layout.message_id, offset, length, binary, header, body, records, record_start)


# ---------------------------------------------------------------------------------------------
# The decoder
# ---------------------------------------------------------------------------------------------


_ASCII_NAME = re.compile(rb"([A-Z][A-Z0-9]*?)A(?:_(\d+))?")


#: Key of :attr:`ColumnBatch.other` counting short-header logs (framed, not decoded).
SHORT_HEADER_LOGS = "(short header)"


def decode_columns(
    data: bytes | bytearray | memoryview,
    logs: Collection[str] | None = None,
    *,
    max_frame_len: int = DEFAULT_MAX_FRAME_LEN,
) -> ColumnBatch:
    """Every NovAtel log in ``data`` (a complete buffer: a cut-off tail counts as truncated) as columns.

    ``logs``: names to decode (``BESTPOS``, ``RANGECMP`` …; default every log the columns decode); other
    valid frames are only counted in :attr:`ColumnBatch.other`. See the module docstring for the columns.

    Raises:
        ConfigError: a name in ``logs`` is not a log the columns decode.
    """
    wanted = None
    if logs is not None:
        wanted = set(logs)
        for name in wanted:
            _layout(name)  # raises for a name the columns do not decode
    buf = bytes(data)
    n = len(buf)
    arr = np.frombuffer(buf, dtype=np.uint8)
    scan = _Scan(buf, arr)
    cands, skipped = _locate(scan, max_frame_len, skip_inside_binary=True)
    start, end, status, kind, star = cands.arrays()
    accepted, rejected = _walk(start, end, status)
    if skipped.size and not _inside(skipped, start[accepted], end[accepted]).all():
        # a good binary frame was not accepted (a frame overlapping it came first): the text frame
        # candidates inside it count after all
        cands, _ = _locate(scan, max_frame_len, skip_inside_binary=False)
        start, end, status, kind, star = cands.arrays()
        accepted, rejected = _walk(start, end, status)
    start, end, kind, star = start[accepted], end[accepted], kind[accepted], star[accepted]
    other: dict[str, int] = {}
    parts: dict[str, list[_Part]] = {}
    slow: dict[str, list[_Decoded]] = {}

    def per_message(log: Log | None, error: str | None, offset: int, length: int, binary: bool) -> None:
        if log is None or error is not None or not isinstance(log.header, Header):
            if log is not None and error is None:
                other[log.name] = other.get(log.name, 0) + 1
            else:
                rejected[RejectReason.MALFORMED] += 1
            return
        body: Any = log.body
        if isinstance(body, RawBody):
            layout = _LAYOUTS.get(log.name)
            if layout is None or layout.raw is None or log.header.response or (
                wanted is not None and log.name not in wanted
            ):
                other[log.name] = other.get(log.name, 0) + 1
                return
            try:  # a log the stream decoders keep raw: its rawobs decoder, as a caller of the Framer would
                body = layout.raw(body)
            except DecodeError:
                rejected[RejectReason.MALFORMED] += 1
                return
        elif wanted is not None and log.name not in wanted:
            other[log.name] = other.get(log.name, 0) + 1
            return
        if not _fits_int64(log.header, body):
            rejected[RejectReason.MALFORMED] += 1
            return
        slow.setdefault(log.name, []).append((log.header, body, offset, length, binary))

    n_short = int(np.count_nonzero((kind == _K_SHORT_BINARY) | (kind == _K_SHORT_ASCII)))
    if n_short:
        other[SHORT_HEADER_LOGS] = n_short
    _decode_binary(buf, arr, start[kind == _K_BINARY], end[kind == _K_BINARY], wanted, parts, other, per_message)
    _decode_ascii(scan, start[kind == _K_ASCII], star[kind == _K_ASCII], wanted, parts, other, per_message)
    for name, items in slow.items():
        parts.setdefault(name, []).append(_logs_part(_LAYOUTS[name], items))
    columns = {name: _concat(name, ps) for name, ps in sorted(parts.items())}
    return ColumnBatch(columns, rejected, other, n)


def _locate(scan: _Scan, max_frame_len: int, *, skip_inside_binary: bool) -> tuple[_Candidates, IntArray]:
    """Every frame candidate of the buffer, and (``skip_inside_binary``) the text frame starts left out
    because they lie inside good binary frames."""
    cands = _Candidates()
    if not scan.arr.shape[0]:
        return cands, np.zeros(0, dtype=np.int64)
    spans = _locate_binary(scan, max_frame_len, cands)
    skip = spans if skip_inside_binary else None
    skipped = [_locate_ascii(scan, sync, k, max_frame_len, cands, skip)
               for sync, k in ((0x23, _K_ASCII), (0x25, _K_SHORT_ASCII))]
    return cands, np.concatenate(skipped)


_PerMessage = Callable[[Log | None, str | None, int, int, bool], None]


def _decode_binary(
    buf: bytes, arr: U8Array, start: IntArray, end: IntArray, wanted: set[str] | None,
    parts: dict[str, list[_Part]], other: dict[str, int], per_message: _PerMessage,
) -> None:
    if start.size == 0:
        return
    mid = arr[start + 4].astype(np.int64) | arr[start + 5].astype(np.int64) << 8
    hdr_len = arr[start + 3].astype(np.int64)
    mtype = arr[start + 6]
    msg_len = arr[start + 8].astype(np.int64) | arr[start + 9].astype(np.int64) << 8
    length = end - start
    for m in np.unique(mid).tolist():
        rows = mid == m
        layout = _LAYOUTS_BY_ID.get(m)
        name = layout.name if layout is not None else log_name_for_id(m)
        if layout is None or (wanted is not None and name not in wanted):
            other[name] = other.get(name, 0) + int(rows.sum())
            continue
        codec = CODECS_BY_ID.get(m)
        fast = rows & (hdr_len == LONG_HEADER_LEN) & (mtype < 0x80)
        if codec is not None and codec.fixed_layout:
            fast &= msg_len >= codec.size
            if fast.any():
                parts.setdefault(name, []).append(_binary_part(codec, arr, start[fast], length[fast]))
        elif m == RangeCmp.MESSAGE_ID and codec is None:
            # records in bulk where the body holds exactly its count of them (else the per-message
            # path, whose decoder says what is wrong)
            fast &= msg_len >= 4
            at = start[fast] + LONG_HEADER_LEN
            count = np.zeros(start.shape, dtype=np.int64)
            count[fast] = arr[at].astype(np.int64) | arr[at + 1].astype(np.int64) << 8 | (
                arr[at + 2].astype(np.int64) << 16) | arr[at + 3].astype(np.int64) << 24
            fast &= msg_len == 4 + RECORD_LEN * count
            if fast.any():
                parts.setdefault(name, []).append(_rangecmp_part(arr, start[fast], length[fast]))
        else:  # PSRDOP's variable list, the ephemerides (decoded with their checks): per message
            fast = np.zeros_like(rows)
        for i in np.flatnonzero(rows & ~fast).tolist():
            s, e = int(start[i]), int(end[i])
            log, error = decode_verified(buf[s:e], False)
            per_message(log, error, s, e - s, True)


_ASCII_CHUNK = 32768  # ASCII logs of one name parsed together


def _decode_ascii(
    scan: _Scan, start: IntArray, star: IntArray, wanted: set[str] | None,
    parts: dict[str, list[_Part]], other: dict[str, int], per_message: _PerMessage,
) -> None:
    if start.size == 0:
        return
    buf = scan.buf
    seps = scan.seps
    text = _Text.of(scan.arr)
    # group by the name token (``BESTPOSA``, ``BESTPOSA_1`` …: after '#', to the first separator)
    name_end = np.minimum(_next_at(seps, start, len(buf)), star)
    names, inverse = _categories(_Tokens(text, start + 1, name_end, _width(int((name_end - start).max()))))
    name_len = name_end - start - 1
    for g, token in enumerate(names):
        rows = np.flatnonzero(inverse == g)
        match = _ASCII_NAME.fullmatch(token) if int(name_len[rows[0]]) == len(token) else None
        name = match.group(1).decode("ascii") if match is not None else ""
        codec = CODECS_BY_NAME.get(name)
        if match is None or codec is None or not codec.fixed_layout:
            for i in rows.tolist():  # other logs, PSRDOP's variable list, odd names: per message
                _ascii_per_message(buf, int(start[i]), int(star[i]), per_message)
            continue
        if wanted is not None and name not in wanted:
            other[name] = other.get(name, 0) + rows.size
            continue
        source = int(match.group(2)) if match.group(2) is not None else 0
        for at in range(0, rows.size, _ASCII_CHUNK):  # bounded memory (and cache-sized arrays) for long captures
            chunk = rows[at : at + _ASCII_CHUNK]
            part, fallback = _ascii_part(codec, text, seps, scan.semis, start[chunk], star[chunk], source)
            if part is not None:
                parts.setdefault(name, []).append(part)
            for i in chunk[fallback].tolist():
                _ascii_per_message(buf, int(start[i]), int(star[i]), per_message)


def _ascii_per_message(buf: bytes, start: int, star: int, per_message: _PerMessage) -> None:
    try:
        log, error = decode_ascii_text(buf[start], buf[start + 1 : star].decode("latin-1"))
    except DecodeError as exc:
        log, error = None, str(exc)
    per_message(log, error, start, star + 9 - start, False)
