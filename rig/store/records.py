"""MCAP records at the byte level: opcodes, record heads, the summary section and a chunk's records.

The bottom of the one reader stack (bytes → records → chunks → messages): :mod:`rig.store.reader` scans a
part record by record, :mod:`rig.store.chunks` reads an indexed part chunk by chunk, and ``rig info``
reads a finalized part from its summary alone (:func:`read_summary`, parsed with :mod:`struct`: mcap's
reader builds every record through a Python stream, which takes most of a second for the thousands of
chunk indexes of a long session).
"""

from __future__ import annotations

import mmap
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

from mcap.records import AttachmentIndex, Channel, ChunkIndex, MetadataIndex, Schema, Statistics

__all__ = [
    "CHUNK_HEAD",
    "FOOTER_SIZE",
    "MCAP_MAGIC",
    "MSG",
    "REC",
    "CorruptChunkError",
    "Summary",
    "checked_summary",
    "chunk_records",
    "decompress_chunk",
    "ends_with_footer",
    "read_summary",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_MESSAGE_INDEX = 0x07
OP_CHUNK_INDEX = 0x08
OP_ATTACHMENT = 0x09
OP_ATTACHMENT_INDEX = 0x0A
OP_STATISTICS = 0x0B
OP_METADATA = 0x0C
OP_METADATA_INDEX = 0x0D
OP_DATA_END = 0x0F
REC = struct.Struct("<BQ")
"""Every record's head: opcode, body length."""
MSG = struct.Struct("<HIQQ")
"""A Message record's head: channel, sequence, log time, publish time."""
CHUNK_HEAD = struct.Struct("<QQQI")
"""A Chunk record's head: message start and end time, uncompressed size, uncompressed CRC."""
FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_CHUNK_INDEX_HEAD = struct.Struct("<QQQQI")
_CHUNK_INDEX_MID = struct.Struct("<QI")
_STATISTICS_HEAD = struct.Struct("<QHIIIIQQ")
_ATTACHMENT_INDEX_HEAD = struct.Struct("<QQQQQ")
_CHUNK_INDEX_HEAD_TAIL = struct.Struct("<QQ")


class CorruptChunkError(Exception):
    """A chunk or record that does not decode (the message says where)."""


def ends_with_footer(mm: bytes | mmap.mmap) -> bool:
    """The part ends with a Footer record and the closing magic (it was finalized)."""
    size = len(mm)
    if size < 2 * len(MCAP_MAGIC) + FOOTER_SIZE or mm[size - len(MCAP_MAGIC) :] != MCAP_MAGIC:
        return False
    op, ln = REC.unpack_from(mm, size - len(MCAP_MAGIC) - FOOTER_SIZE)
    return bool(op == OP_FOOTER and ln == FOOTER_SIZE - 9)


def decompress_chunk(compression: str, raw: bytes, usize: int, where: str) -> bytes:
    """Decompress one MCAP chunk; raises CorruptChunkError naming ``where`` on damaged or unknown data."""
    try:
        if compression == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize)
        if compression == "lz4":
            import lz4.frame

            out: bytes = lz4.frame.decompress(raw)
            return out
        if compression == "":
            return raw
    except Exception as exc:  # the libraries raise their own error types for damaged input
        raise CorruptChunkError(f"{where}: cannot decompress {compression} chunk: {exc}") from exc
    raise CorruptChunkError(f"{where}: unsupported chunk compression {compression!r}")


@dataclass(slots=True)
class Summary:
    """The summary section of a part (what ``mcap.reader.McapReader.get_summary`` gives, read faster)."""

    start: int = 0
    """Offset of the summary section (where the damage region of a bad summary begins)."""
    statistics: Statistics | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    attachment_indexes: list[AttachmentIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)




class _Body:
    """A cursor over one record's body that refuses to read past it (a damaged length or count)."""

    __slots__ = ("buf", "end", "pos")

    def __init__(self, buf: bytes | mmap.mmap, start: int, end: int) -> None:
        self.buf, self.pos, self.end = buf, start, end

    def take(self, st: struct.Struct) -> tuple[Any, ...]:
        if self.pos + st.size > self.end:
            raise ValueError(f"record at {self.pos} ends early")
        values = st.unpack_from(self.buf, self.pos)
        self.pos += st.size
        return values

    def span(self) -> tuple[int, int]:
        """A u32-length-prefixed field: its (start, end)."""
        (n,) = self.take(_U32)
        start = self.pos
        if start + n > self.end:
            raise ValueError(f"field at {start} of {n} bytes overruns its record")
        self.pos += n
        return start, start + n

    def text(self) -> str:
        a, b = self.span()
        return bytes(self.buf[a:b]).decode()

    def map_u16_u64(self) -> dict[int, int]:
        a, b = self.span()
        if (b - a) % 10:
            raise ValueError(f"map at {a}: {b - a} bytes is not a whole number of entries")
        return dict(struct.iter_unpack("<HQ", self.buf[a:b]))

    def map_text(self) -> dict[str, str]:
        a, b = self.span()
        inner = _Body(self.buf, a, b)
        out: dict[str, str] = {}
        while inner.pos < b:
            key = inner.text()
            out[key] = inner.text()
        return out


def read_summary(mm: bytes | mmap.mmap, out: Summary | None = None) -> Summary | None:
    """The summary section, parsed with :mod:`struct` (mcap's reader builds every record through a
    Python stream and takes most of a second for the thousands of chunk indexes of a long session).

    None when the footer says there is no summary. Raises ``ValueError``/``struct.error`` for a damaged
    one, as mcap's reader raises its errors; like it, the summary CRC is not checked (``--verify`` does).
    """
    footer = len(mm) - len(MCAP_MAGIC) - FOOTER_SIZE
    (summary_start,) = _U64.unpack_from(mm, footer + 9)
    if summary_start == 0:
        return None
    if not len(MCAP_MAGIC) <= summary_start <= footer:
        raise ValueError(f"summary start {summary_start} outside the file")
    if out is None:
        out = Summary()
    out.start = summary_start
    pos = summary_start
    while pos < footer:
        op, ln = REC.unpack_from(mm, pos)
        body_end = pos + 9 + ln
        if body_end > footer:
            raise ValueError(f"summary record at {pos} ({ln} bytes) runs into the footer")
        b = _Body(mm, pos + 9, body_end)
        if op == OP_CHUNK_INDEX:  # thousands of them: parsed inline
            p = pos + 9
            if p + 36 > body_end:
                raise ValueError(f"chunk index at {pos} ends early")
            t0, t1, chunk_start, chunk_len, map_len = _CHUNK_INDEX_HEAD.unpack_from(mm, p)
            p += 36
            if map_len % 10 or p + map_len + 12 > body_end:
                raise ValueError(f"chunk index at {pos}: message index map of {map_len} bytes overruns it")
            offsets = dict(struct.iter_unpack("<HQ", mm[p : p + map_len]))
            p += map_len
            mi_len, text_len = _CHUNK_INDEX_MID.unpack_from(mm, p)
            p += 12
            if p + text_len + 16 > body_end:
                raise ValueError(f"chunk index at {pos}: compression name overruns it")
            compression = mm[p : p + text_len].decode()
            csize, usize = _CHUNK_INDEX_HEAD_TAIL.unpack_from(mm, p + text_len)
            out.chunk_indexes.append(ChunkIndex(message_start_time=t0, message_end_time=t1,
                                                chunk_start_offset=chunk_start, chunk_length=chunk_len,
                                                message_index_offsets=offsets, message_index_length=mi_len,
                                                compression=compression, compressed_size=csize,
                                                uncompressed_size=usize))
        elif op == OP_CHANNEL:
            (cid,) = b.take(_U16)
            (sid,) = b.take(_U16)
            topic = b.text()
            enc = b.text()
            out.channels[cid] = Channel(id=cid, schema_id=sid, topic=topic, message_encoding=enc,
                                        metadata=b.map_text())
        elif op == OP_SCHEMA:
            (sid,) = b.take(_U16)
            name = b.text()
            enc = b.text()
            a, e = b.span()
            out.schemas[sid] = Schema(id=sid, name=name, encoding=enc, data=bytes(mm[a:e]))
        elif op == OP_STATISTICS:
            n, n_schemas, n_channels, n_att, n_meta, n_chunks, t0, t1 = b.take(_STATISTICS_HEAD)
            out.statistics = Statistics(message_count=n, schema_count=n_schemas, channel_count=n_channels,
                                        attachment_count=n_att, metadata_count=n_meta, chunk_count=n_chunks,
                                        message_start_time=t0, message_end_time=t1,
                                        channel_message_counts=b.map_u16_u64())
        elif op == OP_METADATA_INDEX:
            off, length = b.take(_CHUNK_INDEX_HEAD_TAIL)
            out.metadata_indexes.append(MetadataIndex(offset=off, length=length, name=b.text()))
        elif op == OP_ATTACHMENT_INDEX:
            off, length, log_time, create_time, data_size = b.take(_ATTACHMENT_INDEX_HEAD)
            name = b.text()
            out.attachment_indexes.append(AttachmentIndex(offset=off, length=length, log_time=log_time,
                                                          create_time=create_time, data_size=data_size, name=name,
                                                          media_type=b.text()))
        pos = body_end  # other records (summary offsets) are not needed
    return out



def chunk_records(mm: mmap.mmap, ci: Any) -> bytes:
    """The decompressed records of the chunk that ``ci`` (a ChunkIndex) points at."""
    pos = ci.chunk_start_offset
    op, _ln = REC.unpack_from(mm, pos)
    if op != OP_CHUNK:
        raise CorruptChunkError(f"no chunk at offset {pos}")
    body = pos + 9
    _t0, _t1, usize, _crc = CHUNK_HEAD.unpack_from(mm, body)
    (clen,) = struct.unpack_from("<I", mm, body + 28)
    comp = bytes(mm[body + 32 : body + 32 + clen]).decode()
    (rlen,) = struct.unpack_from("<Q", mm, body + 32 + clen)
    start = body + 40 + clen
    return decompress_chunk(comp, bytes(mm[start : start + rlen]), usize, f"chunk at offset {pos}")


def checked_summary(mm: bytes | mmap.mmap, validate_crcs: bool) -> tuple[Summary | None, str | None]:
    """The intact summary, or why it is unusable (None, None: there is none); ``validate_crcs``: the summary CRC
    of the footer is checked."""
    if not ends_with_footer(mm):
        return None, None
    fpos = len(mm) - len(MCAP_MAGIC) - FOOTER_SIZE
    sstart, soff, crc = struct.unpack_from("<QQI", mm, fpos + 9)
    if sstart == 0:
        return None, None
    if not (len(MCAP_MAGIC) < sstart <= fpos) or (soff and not sstart <= soff <= fpos):
        return Summary(start=min(max(sstart, 0), fpos)), f"footer points outside the file (summary at {sstart})"
    out = Summary(start=sstart)
    if validate_crcs and crc:
        c = zlib.crc32(mm[sstart:fpos])
        if zlib.crc32(mm[fpos : fpos + 25], c) != crc:
            return out, "summary CRC mismatch"
    try:
        read_summary(mm, out)
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        return out, f"summary damaged: {exc}"
    out.chunk_indexes.sort(key=lambda c: c.chunk_start_offset)
    return out, None
