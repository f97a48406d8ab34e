"""One session part read for ``rig info``: from its summary and message indexes when it was finalized (no
chunk decompressed but those holding events and time-base records), else record by record."""

from __future__ import annotations

import mmap
import os
import struct
from dataclasses import dataclass, field
from enum import StrEnum
from io import BytesIO
from pathlib import Path

import numpy as np
import numpy.typing as npt
from mcap.data_stream import ReadDataStream
from mcap.records import Metadata

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.store.reader import (
    DamagedRegion,
    ProblemKind,
    scan_part,
)
from rig.store.records import (
    FOOTER_SIZE,
    MCAP_MAGIC,
    MSG,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    REC,
    CorruptChunkError,
    Summary,
    chunk_records,
    ends_with_footer,
    read_summary,
)
from vsccore.errors import SessionFileError

PAYLOAD_TOPICS = frozenset({T.TOPIC_EVENTS, T.TOPIC_TIMEBASE})
"""Topics whose messages ``rig info`` decodes (small, JSON)."""




_MSG_INDEXREC = struct.Struct("<BQHI")
















class ReadVia(StrEnum):
    """How a part was read."""

    SUMMARY = "summary"
    """Summary section and message indexes (finalized part; fast)."""
    SCAN = "scan"
    """Record by record, every chunk decompressed (crashed part, recovered copy without message index)."""


@dataclass(frozen=True, slots=True)
class AttachmentInfo:
    name: str
    media_type: str
    size_bytes: int


@dataclass(slots=True)
class PartRead:
    """What one part contributed (internal; times and payloads by topic)."""

    path: Path
    size: int
    via: ReadVia
    finalized: bool
    problem: str | None = None
    problem_kind: ProblemKind | None = None
    start_ns: int | None = None
    end_ns: int | None = None
    damage: tuple[DamagedRegion, ...] = ()
    verified: bool = False
    topics: dict[str, tuple[str, str]] = field(default_factory=dict)
    """topic → (schema name, message encoding)."""
    counts: dict[str, int] = field(default_factory=dict)
    times: dict[str, list[npt.NDArray[np.int64]]] = field(default_factory=dict)
    payloads: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    attachments: list[AttachmentInfo] = field(default_factory=list)

    @property
    def messages(self) -> int:
        return sum(self.counts.values())


class NoIndexError(Exception):
    """The part has no usable summary or message index (it is scanned instead)."""


def _read_indexed(path: Path) -> PartRead:
    """Read a finalized part from its summary and message indexes (raises NoIndexError otherwise)."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size < 2 * len(MCAP_MAGIC) + FOOTER_SIZE:
            raise NoIndexError("too short to be finalized")
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            if mm[: len(MCAP_MAGIC)] != MCAP_MAGIC or not ends_with_footer(mm):
                raise NoIndexError("no footer")
            try:
                summary = read_summary(mm)
            except (struct.error, ValueError, UnicodeDecodeError) as exc:
                raise NoIndexError(f"unreadable summary: {exc}") from exc
            if summary is None or summary.statistics is None:
                raise NoIndexError("no summary statistics")
            try:
                return _from_summary(path, size, mm, summary)
            except (struct.error, ValueError, IndexError, KeyError, CorruptChunkError) as exc:  # damaged index: scan
                raise NoIndexError(f"unusable index: {exc}") from exc
        finally:
            mm.close()


def _from_summary(path: Path, size: int, mm: mmap.mmap, summary: Summary) -> PartRead:
    stats = summary.statistics
    assert stats is not None  # checked by the caller
    part = PartRead(path=path, size=size, via=ReadVia.SUMMARY, finalized=True)
    channels = summary.channels
    for ch in channels.values():
        schema = summary.schemas.get(ch.schema_id)
        part.topics[ch.topic] = (schema.name if schema is not None else "", ch.message_encoding)
    blocks: dict[int, list[bytes]] = {}
    """channel → its message index entries ((log time, offset) u64 pairs), chunk after chunk."""
    wanted = {cid for cid, ch in channels.items() if ch.topic in PAYLOAD_TOPICS}
    for ci in summary.chunk_indexes:
        payload_entries: list[tuple[int, int, int]] = []  # (channel, log time, offset in chunk)
        for cid, off in ci.message_index_offsets.items():
            if cid not in channels or off + 15 > size:
                raise NoIndexError(f"message index at {off} names unknown channel {cid} or lies outside the file")
            op, ln, rcid, rlen = _MSG_INDEXREC.unpack_from(mm, off)
            if op != OP_MESSAGE_INDEX or rcid != cid or rlen % 16 or off + 15 + rlen > size or 6 + rlen > ln:
                raise NoIndexError(f"bad message index record at offset {off}")
            block = mm[off + 15 : off + 15 + rlen]
            blocks.setdefault(cid, []).append(block)
            if cid in wanted:
                pairs = struct.unpack(f"<{rlen // 8}Q", block)
                payload_entries.extend((cid, t, o) for t, o in zip(pairs[0::2], pairs[1::2], strict=True))
        if payload_entries:
            data = chunk_records(mm, ci)
            for cid, log_t_i, off in payload_entries:
                if off + 9 + 22 > len(data):
                    raise NoIndexError(f"chunk at {ci.chunk_start_offset}: message offset {off} outside the chunk")
                op, ln = REC.unpack_from(data, off)
                mcid, _seq, _lt, _pt = MSG.unpack_from(data, off + 9)
                if op != OP_MESSAGE or mcid != cid:
                    raise NoIndexError(f"chunk at {ci.chunk_start_offset}: no message of channel {cid} at {off}")
                topic = channels[cid].topic
                part.payloads.setdefault(topic, []).append((log_t_i, bytes(data[off + 9 + 22 : off + 9 + ln])))
    for cid, n in stats.channel_message_counts.items():
        got = sum(len(b) for b in blocks.get(cid, [])) // 16
        if got != n:
            raise NoIndexError(f"channel {cid}: message index has {got} entries, statistics say {n}")
    for cid, chunks in blocks.items():  # one array per channel: its log times in file order
        log_t = np.frombuffer(b"".join(chunks), dtype="<u8")[0::2].astype(np.int64)
        topic = channels[cid].topic
        part.times.setdefault(topic, []).append(log_t)
        part.counts[topic] = part.counts.get(topic, 0) + int(log_t.size)
    if stats.message_count:
        part.start_ns, part.end_ns = int(stats.message_start_time), int(stats.message_end_time)
    for mi in summary.metadata_indexes:
        body = bytes(mm[mi.offset + 9 : mi.offset + mi.length])
        md = Metadata.read(ReadDataStream(BytesIO(body)))
        part.metadata.append((md.name, dict(md.metadata)))
    for ai in summary.attachment_indexes:
        part.attachments.append(AttachmentInfo(ai.name, ai.media_type, int(ai.data_size)))
    return part


def _read_scanned(path: Path) -> PartRead:
    """Read a part record by record (tolerates a truncated or damaged part)."""
    scan = scan_part(path)
    part = PartRead(
        path=path,
        size=scan.size,
        via=ReadVia.SCAN,
        finalized=scan.finalized and scan.problem is None,
        problem=scan.problem,
        problem_kind=scan.problem_kind,
        start_ns=scan.message_start_time,
        end_ns=scan.message_end_time,
        damage=tuple(scan.damage),
        verified=True,
    )
    for cid, ch in scan.channels.items():
        schema = scan.schemas.get(ch.schema_id)
        part.topics[ch.topic] = (schema.name if schema is not None else "", ch.message_encoding)
        n = scan.channel_counts.get(cid, 0)
        if n:
            part.counts[ch.topic] = part.counts.get(ch.topic, 0) + n
    for topic, tm in scan.topics.items():
        if len(tm):
            part.times.setdefault(topic, []).append(np.asarray(tm.log_time, dtype=np.int64))
        if topic in PAYLOAD_TOPICS:
            part.payloads.setdefault(topic, []).extend(zip(tm.log_time, tm.data, strict=True))
    for md, _ref in scan.metadata:
        part.metadata.append((md.name, dict(md.metadata)))
    for att, _ref in scan.attachments:
        part.attachments.append(AttachmentInfo(att.name, att.media_type, len(att.data)))
    return part


def read_part(path: Path, verify: bool = False) -> PartRead:
    try:
        if verify:
            return _read_scanned(path)
        return _read_indexed(path)
    except NoIndexError:
        return _read_scanned(path)
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot read session part: {exc}") from exc

