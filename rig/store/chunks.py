"""Reading an indexed MCAP part chunk by chunk: the chunk index from the summary, each chunk CRC-checked and
decompressed, the wanted channels' messages through their MessageIndex records.

``wanted`` maps a channel id to the byte offset of a little-endian u32 row count in each of its messages
(a CAN or DAQ block says how many frames or samples it holds), or None for one row per message."""

from __future__ import annotations

import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rig.store.reader import PartScan, scan_part
from rig.store.records import MSG, OP_CHUNK, OP_MESSAGE, REC, CorruptChunkError, checked_summary, decompress_chunk
from vsccore.errors import SessionFileError

_CHUNK_HEAD_CLEN = struct.Struct("<QQQII")






@dataclass(frozen=True, slots=True)
class ChunkRef:
    """Where a chunk lies in a part, and what its index (or the scan that found it) says it holds."""

    offset: int
    length: int
    compression: str
    uncompressed_size: int
    start_ns: int
    end_ns: int
    message_index: Mapping[int, int] = field(default_factory=dict)
    """Channel id → file offset of the chunk's MessageIndex record for it (from the summary's chunk index)."""
    message_index_length: int = 0


@dataclass(slots=True)
class PartPlan:
    topics: dict[int, str]
    """Channel id → topic."""
    chunks: list[ChunkRef]
    scan: PartScan | None
    """The scanner's result when the part's summary was not usable (an unfinished or damaged part)."""


def plan_part(part: Path) -> PartPlan:
    """The part's channels and chunks from its summary when that is intact (its CRC checked against the footer),
    else from a scan of the whole part (:func:`rig.store.reader.scan_part`, which skips damaged chunks)."""
    import mmap

    try:
        with open(part, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            summary: Any = None
            problem: str | None = "empty part"
            if size:
                with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                    summary, problem = checked_summary(mm, True)
    except OSError as exc:
        raise SessionFileError(f"{part}: cannot open session part: {exc}") from exc
    if summary is not None and problem is None and (summary.chunk_indexes or summary.channels):
        chunks = [ChunkRef(ci.chunk_start_offset, ci.chunk_length, ci.compression, ci.uncompressed_size,
                            ci.message_start_time, ci.message_end_time, dict(ci.message_index_offsets),
                            ci.message_index_length) for ci in summary.chunk_indexes]
        return PartPlan({cid: ch.topic for cid, ch in summary.channels.items()}, chunks, None)
    scan = scan_part(part, collect=False)
    chunks = [ChunkRef(c.offset, c.length, c.compression, c.uncompressed_size, c.message_start_time,
                        c.message_end_time) for c in scan.chunks]
    return PartPlan({cid: ch.topic for cid, ch in scan.channels.items()}, chunks, scan)


class BadChunkError(Exception):
    """A chunk that cannot be read as its index says (damage): skipped, and the part is scanned to describe it."""


def read_chunk(fd: int, ref: ChunkRef) -> tuple[tuple[int, int], bytes]:
    """The chunk's header times and records, decompressed and checked (framing, sizes, CRC); raises
    BadChunkError."""
    import zlib

    where = f"chunk at offset {ref.offset}"
    raw = os.pread(fd, ref.length, ref.offset)
    try:
        op, ln = REC.unpack_from(raw, 0)
        if op != OP_CHUNK or len(raw) != ref.length or 9 + ln != ref.length:
            raise BadChunkError(f"{where}: not the chunk record its index points at")
        t0, t1, usize, ucrc, clen = _CHUNK_HEAD_CLEN.unpack_from(raw, 9)
        comp = raw[41 : 41 + clen].decode()
        (rlen,) = struct.unpack_from("<Q", raw, 41 + clen)
        rstart = 49 + clen
        if rstart + rlen != len(raw) or usize != ref.uncompressed_size or comp != ref.compression:
            raise BadChunkError(f"{where}: header disagrees with its index")
        data = decompress_chunk(comp, raw[rstart:], usize, where)
    except (struct.error, UnicodeDecodeError, CorruptChunkError) as exc:
        raise BadChunkError(f"{where}: {exc}") from exc
    if len(data) != usize or (ucrc and zlib.crc32(data) != ucrc):
        raise BadChunkError(f"{where}: CRC or size mismatch (damaged data)")
    return (int(t0), int(t1)), data


@dataclass(slots=True)
class ChunkMessages:
    """One channel's messages in one chunk, in file order."""

    log_time: npt.NDArray[np.int64]
    publish_time: npt.NDArray[np.int64]
    data: list[bytes]
    rows: npt.NDArray[np.int64]
    """Rows each message makes (a block's frames or samples; else 1)."""


def chunk_messages(data: bytes, chunk_head: tuple[int, int], wanted: Mapping[int, int | None]
                    ) -> dict[int, ChunkMessages]:
    """The chunk's messages on ``wanted`` channels, record by record; the chunk's header times must match its
    messages' (as the scanner checks). Raises BadChunkError."""
    got: dict[int, tuple[list[int], list[int], list[bytes]]] = {}
    end = len(data)
    q = 0
    lo: int | None = None
    hi: int | None = None
    unpack_rec = REC.unpack_from
    unpack_msg = MSG.unpack_from
    try:
        while q < end:
            op, ln = unpack_rec(data, q)
            nxt = q + 9 + ln
            if nxt > end:
                raise BadChunkError(f"record of {ln} bytes at {q} runs past the end of the chunk")
            if op == OP_MESSAGE:
                cid, _seq, lt, pt = unpack_msg(data, q + 9)
                if lo is None or lt < lo:
                    lo = lt
                if hi is None or lt > hi:
                    hi = lt
                if cid in wanted:
                    g = got.get(cid)
                    if g is None:
                        g = got[cid] = ([], [], [])
                    g[0].append(lt)
                    g[1].append(pt)
                    g[2].append(data[q + 31 : nxt])
            q = nxt
    except struct.error as exc:
        raise BadChunkError(f"records do not parse: {exc}") from exc
    if ((lo, hi) if lo is not None else (0, 0)) != chunk_head:
        raise BadChunkError(f"header times {chunk_head} disagree with its messages' {lo}..{hi}")
    return {cid: ChunkMessages(np.asarray(lt, dtype=np.int64), np.asarray(pt, dtype=np.int64), d,
                           np.asarray([_rows(x, wanted[cid]) for x in d], dtype=np.int64))
            for cid, (lt, pt, d) in got.items()}


def _rows(payload: bytes, at: int | None) -> int:
    """Rows a message makes: the u32 count at ``at`` when the payload holds it, else 1."""
    if at is not None and len(payload) >= at + 4:
        return max(1, int.from_bytes(payload[at : at + 4], "little"))
    return 1


def _gather(buf: npt.NDArray[np.uint8], pos: npt.NDArray[np.int64], dtype: str) -> npt.NDArray[Any]:
    """The little-endian ``dtype`` value at each byte offset ``pos`` of ``buf``."""
    size = np.dtype(dtype).itemsize
    return np.ascontiguousarray(buf[pos[:, None] + np.arange(size)]).view(dtype).reshape(-1)


def indexed_messages(fd: int, ref: ChunkRef, data: bytes, chunk_head: tuple[int, int],
                      wanted: Mapping[int, int | None]) -> dict[int, ChunkMessages] | None:
    """The chunk's messages on ``wanted`` channels found through its MessageIndex records (no walk over the
    other channels' messages), each checked against the record it points at; None when the index is missing
    or does not fit the chunk (then the chunk is walked record by record)."""
    if not ref.message_index or chunk_head != (ref.start_ns, ref.end_ns):
        return None
    base = min(ref.message_index.values())
    region = os.pread(fd, ref.message_index_length, base)
    buf = np.frombuffer(data, dtype=np.uint8)
    out: dict[int, ChunkMessages] = {}
    for cid, hdr in wanted.items():
        at = ref.message_index.get(cid)
        if at is None:
            continue
        p = at - base
        try:
            op, ln = REC.unpack_from(region, p)
            cid2, alen = struct.unpack_from("<HI", region, p + 9)
        except struct.error:
            return None
        if op != 0x07 or cid2 != cid or ln != 6 + alen or alen % 16:
            return None
        pairs = np.frombuffer(region, dtype="<u8", count=alen // 8, offset=p + 15).reshape(-1, 2).astype(np.int64)
        if not pairs.shape[0]:
            continue
        pairs = pairs[np.argsort(pairs[:, 1], kind="stable")]  # file order (receive order for CAN counters)
        off = pairs[:, 1]
        if int(off[0]) < 0 or int(off[-1]) + 31 > len(data):
            return None
        ln_rec = _gather(buf, off + 1, "<u8").astype(np.int64)
        ends = off + 9 + ln_rec
        if (np.any(buf[off] != OP_MESSAGE) or np.any(ln_rec < 22) or np.any(ends > len(data))
                or np.any(_gather(buf, off + 9, "<u2") != cid) or np.any(_gather(buf, off + 15, "<u8") != pairs[:, 0])):
            return None
        starts = off + 31
        rows = np.ones(off.shape[0], dtype=np.int64)
        if hdr is not None:
            fits = ends - starts >= hdr + 4
            if np.any(fits):
                rows[fits] = np.maximum(_gather(buf, starts[fits] + hdr, "<u4").astype(np.int64), 1)
        out[cid] = ChunkMessages(pairs[:, 0], _gather(buf, off + 23, "<u8").astype(np.int64),
                             [data[a:b] for a, b in zip(starts.tolist(), ends.tolist(), strict=True)], rows)
    return out

