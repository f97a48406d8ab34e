"""Reading session parts: part naming, and a fast scanner that tolerates a truncated (crashed) part.

A session ``<dir>/<name>`` is stored as parts ``<name>.000.mcap``, ``<name>.001.mcap``, ... The
scanner walks a part's data section record by record, decompresses each chunk once and hands back
the messages grouped by topic. A part whose recorder was killed ends in the middle of a record; the
scanner stops at the last complete record and says so (:attr:`PartScan.truncation`), which is how
both :func:`rig.store.recover.recover` and :mod:`rig.data` read crashed recordings.

Damage is salvaged, not fatal: a chunk whose CRC, size, times or framing is wrong, or any record
that does not parse, is skipped as a :class:`DamagedRegion` and the scan goes on at the next record
(the following record when the damaged one's framing holds, else the next record found by a
search: a chunk whose CRC matches, a message index of exact shape, a metadata or attachment record
that round-trips, or the DataEnd). So every intact chunk before and after the damage is read. The
summary section is checked against the footer's CRC (a damaged summary is a region too) and, when
intact, names the time span and topics of a damaged chunk and the channels whose Channel record
was inside a damaged chunk. A damaged part's :attr:`PartScan.problem_kind` is ``CORRUPT``; each
region gives a ``/rig/events``-style warning (:meth:`DamagedRegion.event`).
"""

from __future__ import annotations

import mmap
import os
import re
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from io import BytesIO
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.records import Attachment, Channel, Metadata, Schema

from rig.core.topics import Event, EventKind, Severity
from rig.store.records import (
    CHUNK_HEAD,
    MCAP_MAGIC,
    MSG,
    OP_ATTACHMENT,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_SCHEMA,
    REC,
    CorruptChunkError,
    checked_summary,
    decompress_chunk,
    ends_with_footer,
)
from vsccore.errors import SessionFileError

__all__ = [
    "MCAP_MAGIC",
    "ChunkInfo",
    "DamagedRegion",
    "PartScan",
    "ProblemKind",
    "RecordRef",
    "TopicMessages",
    "find_parts",
    "part_index",
    "part_path",
    "scan_part",
    "session_base",
]

_PART_RE = re.compile(r"^(?P<name>.+)\.(?P<index>\d{3,})\.mcap$")

_DATA_OPS = frozenset(
    {OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX, OP_ATTACHMENT, OP_METADATA}
)
"""Records that may appear in the data section (custom opcodes >= 0x80 are skipped as well)."""
_MSG_INDEX_HEAD = struct.Struct("<HI")
_RESYNC_OPS = re.compile(rb"[\x06\x07\x09\x0c\x0f]")
"""Opcodes of the records a search after damage may land on (those that can be checked strongly)."""


def part_path(base: Path, index: int) -> Path:
    """The file of part ``index`` of the session whose base path is ``base`` (``<base>.NNN.mcap``)."""
    return base.with_name(f"{base.name}.{index:03d}.mcap")


def part_index(path: Path) -> int | None:
    """The part number of a part file name, or None if the name is not ``<name>.NNN.mcap``."""
    m = _PART_RE.match(path.name)
    return None if m is None else int(m.group("index"))


def session_base(path: Path) -> Path:
    """The base path of a session from its base, any of its part files, or ``<base>.mcap``."""
    m = _PART_RE.match(path.name)
    if m is not None:
        return path.with_name(m.group("name"))
    if path.suffix == ".mcap":
        return path.with_suffix("")
    return path


def find_parts(path: Path | str) -> list[Path]:
    """Every part of a session, in order.

    ``path`` is the session base (``dir/name``), one of its part files, a single ``.mcap`` file that
    is not a numbered part, or a directory holding exactly one session. Raises
    :class:`~vsccore.errors.SessionFileError` when nothing is found or a part in the sequence is
    missing (the message names it).
    """
    p = Path(path)
    if p.is_dir():
        bases = sorted({session_base(f) for f in p.glob("*.mcap") if part_index(f) is not None})
        if len(bases) != 1:
            found = ", ".join(b.name for b in bases) or "none"
            raise SessionFileError(f"{p}: expected one session in the directory, found {found}")
        p = bases[0]
    if p.is_file() and part_index(p) is None:
        return [p]
    base = session_base(p)
    parts: dict[int, Path] = {}
    for f in base.parent.glob(f"{glob_escape(base.name)}.*.mcap"):
        idx = part_index(f)
        if idx is not None and session_base(f) == base:
            parts[idx] = f
    if not parts:
        raise SessionFileError(f"{base}: no session parts ({part_path(base, 0).name}, ...) found")
    for i in range(max(parts) + 1):
        if i not in parts:
            raise SessionFileError(f"{part_path(base, i)}: part {i} of session {base.name} is missing")
    return [parts[i] for i in sorted(parts)]


def glob_escape(name: str) -> str:
    """``name`` with glob metacharacters escaped."""
    return re.sub(r"([*?\[])", r"[\1]", name)


class ProblemKind(StrEnum):
    """What is wrong with a part."""

    TRUNCATED = "truncated"
    """The part ends inside a record (a killed recorder, a copy cut short)."""
    CORRUPT = "corrupt"
    """A record, chunk or the summary is damaged (bad CRC, undecodable, impossible length); skipped."""


class DamageKind(StrEnum):
    """What a damaged region was."""

    CHUNK = "chunk"
    """A chunk (its messages are lost; the span and topics say which)."""
    RECORD = "record"
    """Another data-section record, or bytes where no record parses."""
    SUMMARY = "summary"
    """The summary section or footer (no message lost; the index is rebuilt by ``rig recover``)."""
    MAGIC = "magic"
    """The leading magic bytes."""
    CHANNEL = "channel"
    """Messages of intact chunks on a channel whose Channel record was lost in a damaged chunk."""
    DATA = "data section"
    """Bytes of the data section changed that no record's own CRC covers (DataEnd's CRC of the whole data
    section says so): a bit of a chunk's compressed stream that decodes to the same records. No message is
    lost or changed; ``rig recover`` writes a clean copy."""


_NS = 1_000_000_000


@dataclass(frozen=True, slots=True)
class DamagedRegion:
    """A damaged part of a file that the scanner skipped."""

    offset: int
    length: int
    """Bytes skipped."""
    kind: DamageKind
    reason: str
    chunks: tuple[int, ...] = ()
    """Ordinals (0-based, in file order) of the chunks lost in the region."""
    start_ns: int | None = None
    """Log time of the first message lost (or the last intact message before the region)."""
    end_ns: int | None = None
    """Log time of the last message lost (or the first intact message after the region)."""
    topics: tuple[str, ...] = ()
    """Topics with messages in the region ('channel N' when the channel is unknown); empty if unknown."""
    messages: int | None = None
    """Messages lost (None: unknown)."""
    span_exact: bool = False
    """``start_ns``/``end_ns`` are the lost messages' own times (else the intact neighbours')."""

    @property
    def duration_s(self) -> float:
        """Seconds of data the region covers (0 when unknown)."""
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return max(0, self.end_ns - self.start_ns) / _NS

    def describe(self) -> str:
        """One line: what, where, why, what was lost."""
        if self.kind is DamageKind.CHUNK:
            which = "chunk" + ("s " if len(self.chunks) > 1 else " ") + ", ".join(map(str, self.chunks))
            what = f"{which} at offset {self.offset} ({self.length} bytes)"
        elif self.kind is DamageKind.CHANNEL:
            what = f"{self.messages} messages on {', '.join(self.topics)} (Channel record lost)"
        else:
            what = f"{self.kind.value} at offset {self.offset} ({self.length} bytes)"
        text = f"damaged {what}: {self.reason}"
        if self.kind in (DamageKind.CHUNK, DamageKind.RECORD) and self.start_ns is not None:
            span = "" if self.span_exact else "between intact data "
            text += f"; {self.duration_s:.3f} s of data lost {span}({self.start_ns} .. {self.end_ns} ns)"
            if self.messages is not None:
                text += f", {self.messages} messages"
            if self.topics:
                text += f" on {', '.join(self.topics)}"
        if self.kind is DamageKind.SUMMARY:
            text += "; no data lost (the index is rebuilt by `rig recover`)"
        elif self.kind is DamageKind.DATA:
            text += "; no message lost or changed (every record checks; `rig recover` writes a clean copy)"
        return text

    def event(self, path: Path) -> Event:
        """The region as a ``/rig/events``-style warning (not written anywhere: for reports)."""
        return Event(
            EventKind.WARNING,
            "reader",
            f"{path.name}: {self.describe()}",
            Severity.WARNING,
            self.start_ns,
            self.end_ns,
            {
                "file": path.name,
                "damage": self.kind.value,
                "offset": self.offset,
                "length": self.length,
                "chunks": list(self.chunks),
                "topics": list(self.topics),
                "messages": self.messages,
                "duration_s": self.duration_s,
            },
        )


def damaged_chunk_count(damage: Iterable[DamagedRegion]) -> int:
    """Chunks lost to ``damage`` (a damaged region that names no chunk counts as one)."""
    return sum(max(1, len(d.chunks)) for d in damage if d.kind is DamageKind.CHUNK)


def damaged_seconds(damage: Iterable[DamagedRegion]) -> float:
    """Seconds of data in the damaged chunks and records of ``damage``."""
    return sum(d.duration_s for d in damage if d.kind in (DamageKind.CHUNK, DamageKind.RECORD))


@dataclass(frozen=True, slots=True)
class ChunkInfo:
    """Where a complete chunk lies in a part (enough to index it)."""

    offset: int
    length: int
    """Whole record, opcode and length prefix included."""
    message_start_time: int
    message_end_time: int
    compression: str
    compressed_size: int
    uncompressed_size: int


@dataclass(frozen=True, slots=True)
class RecordRef:
    """A top-level record's position (metadata and attachments, for indexes)."""

    offset: int
    length: int


@dataclass(slots=True)
class TopicMessages:
    """The messages of one topic in one part, in file order."""

    topic: str
    schema_name: str
    message_encoding: str
    log_time: list[int] = field(default_factory=list)
    publish_time: list[int] = field(default_factory=list)
    sequence: list[int] = field(default_factory=list)
    data: list[bytes] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.log_time)


@dataclass(slots=True)
class PartScan:
    """What :func:`scan_part` found in one part."""

    path: Path
    size: int
    library: str = ""
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: list[tuple[Metadata, RecordRef]] = field(default_factory=list)
    attachments: list[tuple[Attachment, RecordRef]] = field(default_factory=list)
    chunks: list[ChunkInfo] = field(default_factory=list)
    """The intact chunks."""
    topics: dict[str, TopicMessages] = field(default_factory=dict)
    """Collected messages by topic (only the topics asked for)."""
    channel_counts: dict[int, int] = field(default_factory=dict)
    """Messages per channel id (all channels, collected or not)."""
    message_start_time: int | None = None
    message_end_time: int | None = None
    data_end: int = 0
    """Offset just past the last complete data-section record (where an in-place finalize cuts)."""
    data_end_found: bool = False
    """The data section ends with its DataEnd record (the writer finished it)."""
    finalized: bool = False
    """DataEnd, summary, footer and closing magic are all there."""
    header_ok: bool = False
    """The MCAP header record is intact."""
    damage: list[DamagedRegion] = field(default_factory=list)
    """Damaged regions skipped, in file order (channel-loss entries last)."""
    truncation: str | None = None
    """Why the part ends early (a killed recorder), or None."""
    orphans: dict[int, int] = field(default_factory=dict)
    """Messages per unknown channel id (its Channel record was lost with a damaged chunk, no usable summary)."""
    channels_from_summary: set[int] = field(default_factory=set)
    """Channels known only from the summary (their Channel record was inside a damaged chunk)."""
    problem: str | None = None
    """One line: the damage (first) and/or the truncation; None for a sound, complete part."""
    problem_kind: ProblemKind | None = None
    """CORRUPT when anything is damaged, else TRUNCATED when the part ends early."""

    @property
    def message_count(self) -> int:
        return sum(self.channel_counts.values())

    @property
    def damaged(self) -> bool:
        return bool(self.damage)

    @property
    def damaged_chunks(self) -> int:
        """Chunks lost to damage."""
        return damaged_chunk_count(self.damage)

    @property
    def damaged_s(self) -> float:
        """Seconds of data in the damaged chunks and records."""
        return damaged_seconds(self.damage)

    def damage_events(self) -> list[Event]:
        """Every damaged region as a ``/rig/events``-style warning."""
        return [d.event(self.path) for d in self.damage]

    def metadata_dict(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (a later record of the same name wins)."""
        return {m.name: dict(m.metadata) for m, _ in self.metadata}

    def check(self, *, allow_truncated: bool, allow_damaged: bool = False) -> None:
        """Raise :class:`SessionFileError` for a problem (a truncation or damage only if not allowed)."""
        if self.damage and not allow_damaged:
            raise SessionFileError(f"{self.path}: {self.problem}")
        if self.truncation is not None and not allow_truncated:
            raise SessionFileError(f"{self.path}: {self.truncation}")




class _TruncatedError(Exception):
    pass


def _read_record(stream_bytes: bytes, cls: type[Schema] | type[Channel] | type[Metadata] | type[Attachment]) -> object:
    return cls.read(ReadDataStream(BytesIO(stream_bytes)))


def _read_exact(mm: bytes | mmap.mmap, pos: int, nxt: int, cls: type[Any]) -> Any:
    """The record at ``mm[pos:nxt]``, which must write back to exactly the same bytes (else CorruptChunkError)."""
    try:
        rec = cls.read(ReadDataStream(BytesIO(mm[pos + 9 : nxt])))
        b = RecordBuilder()
        rec.write(b)
        same = b.end() == mm[pos:nxt]
    except Exception as exc:  # mcap raises assorted errors for garbage
        raise CorruptChunkError(f"{cls.__name__} record at offset {pos} does not parse: {exc}") from exc
    if not same:
        raise CorruptChunkError(f"{cls.__name__} record at offset {pos} is damaged (fields disagree with its length)")
    return rec


def scan_part(
    path: Path | str,
    *,
    want: Callable[[str], bool] | None = None,
    collect: bool = True,
    validate_crcs: bool = True,
) -> PartScan:
    """Walk one part's data section; never raises for damage, which is skipped and reported in the result.

    ``want(topic)`` chooses the topics whose messages are collected (default: all); with
    ``collect=False`` nothing is collected (counts and chunk positions only). Raises
    :class:`SessionFileError` only when the file cannot be opened or is not MCAP at all.
    """
    p = Path(path)
    try:
        f = open(p, "rb")  # noqa: SIM115 - closed by the with statement below
    except OSError as exc:
        raise SessionFileError(f"{p}: cannot open session part: {exc}") from exc
    with f:
        size = os.fstat(f.fileno()).st_size
        scan = PartScan(path=p, size=size)
        if size < len(MCAP_MAGIC):
            if size and not MCAP_MAGIC.startswith(f.read()):
                raise SessionFileError(f"{p}: not an MCAP file (bad magic)")
            scan.truncation = f"{size} bytes: too short for an MCAP file"
            _set_problem(scan)
            return scan
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            if mm[: len(MCAP_MAGIC)] != MCAP_MAGIC:
                # a damaged magic in front of a recognisable MCAP file is salvaged; anything else is refused
                if size >= 17 and (mm[8] == OP_HEADER or mm[size - len(MCAP_MAGIC) :] == MCAP_MAGIC):
                    scan.damage.append(DamagedRegion(0, 8, DamageKind.MAGIC, "leading magic bytes damaged"))
                else:
                    raise SessionFileError(f"{p}: not an MCAP file (bad magic)")
            _Scanner(mm, scan, want, collect, validate_crcs).run()
        finally:
            mm.close()
    _set_problem(scan)
    return scan


def _set_problem(scan: PartScan) -> None:
    if scan.damage:
        n = len(scan.damage)
        first = scan.damage[0].describe()
        more = f" (and {n - 1} more damaged region{'s' if n > 2 else ''})" if n > 1 else ""
        tail = f"; and {scan.truncation}" if scan.truncation else ""
        scan.problem = f"{first}{more}{tail}"
        scan.problem_kind = ProblemKind.CORRUPT
    elif scan.truncation is not None:
        scan.problem = scan.truncation
        scan.problem_kind = ProblemKind.TRUNCATED




def _next_strong(mm: mmap.mmap, start: int) -> int | None:
    """The first offset >= ``start`` holding a record that checks out strongly (see the module docstring)."""
    for m in _RESYNC_OPS.finditer(mm, start):
        if _strong(mm, m.start()):
            return int(m.start())
    return None


def _strong(mm: mmap.mmap, p: int) -> bool:
    """A record at ``p`` whose content proves it is one: a chunk with matching CRC, an exact message index, ..."""
    size = len(mm)
    if p + 9 > size:
        return False
    op, ln = REC.unpack_from(mm, p)
    nxt = p + 9 + ln
    if nxt > size:
        return False
    body = p + 9
    try:
        if op == OP_MESSAGE_INDEX:
            if ln < 6:
                return False
            _cid, rl = _MSG_INDEX_HEAD.unpack_from(mm, body)
            return ln == 6 + rl and rl % 16 == 0
        if op == OP_DATA_END:
            return ln == 4 and (nxt == size or ends_with_footer(mm))
        if op == OP_CHUNK:
            if ln < 40:
                return False
            _t0, _t1, usize, ucrc = CHUNK_HEAD.unpack_from(mm, body)
            (clen,) = struct.unpack_from("<I", mm, body + 28)
            if clen > 8 or ucrc == 0:
                return False
            comp = mm[body + 32 : body + 32 + clen].decode()
            (rlen,) = struct.unpack_from("<Q", mm, body + 32 + clen)
            rstart = body + 40 + clen
            if rstart + rlen != nxt:
                return False
            data = decompress_chunk(comp, mm[rstart:nxt], usize, "")
            return len(data) == usize and zlib.crc32(data) == ucrc
        if op == OP_METADATA:
            _read_exact(mm, p, nxt, Metadata)
            return True
        if op == OP_ATTACHMENT:
            _read_exact(mm, p, nxt, Attachment)
            (acrc,) = struct.unpack_from("<I", mm, nxt - 4)
            return acrc != 0 and zlib.crc32(mm[body : nxt - 4]) == acrc
    except (CorruptChunkError, struct.error, UnicodeDecodeError, ValueError):
        return False
    return False


class _Scanner:
    """One pass over a part's data section (state of :func:`scan_part`)."""

    def __init__(
        self,
        mm: mmap.mmap,
        scan: PartScan,
        want: Callable[[str], bool] | None,
        collect: bool,
        validate_crcs: bool,
    ) -> None:
        self.mm = mm
        self.scan = scan
        self.want = want
        self.collect = collect
        self.validate_crcs = validate_crcs
        self.targets: dict[int, TopicMessages | None] = {}
        """channel id -> TopicMessages to collect into, or None (counted only)."""
        self.summary, self.summary_problem = checked_summary(mm, validate_crcs)
        self.chunk_no = 0
        self.orphans: dict[int, list[int]] = {}
        """Unknown channel id -> [count, first log time, last log time]."""
        self.pending: list[dict[str, Any]] = []

    # --- channels and messages --------------------------------------------------------------------

    def add_channel(self, ch: Channel) -> None:
        scan = self.scan
        scan.channels[ch.id] = ch
        target: TopicMessages | None = None
        if self.collect and (self.want is None or self.want(ch.topic)):
            target = scan.topics.get(ch.topic)
            if target is None:
                schema = scan.schemas.get(ch.schema_id)
                target = TopicMessages(ch.topic, schema.name if schema else "", ch.message_encoding)
                scan.topics[ch.topic] = target
        self.targets[ch.id] = target

    def channel_from_summary(self, cid: int) -> bool:
        s = self.summary
        if s is None or self.summary_problem is not None or cid not in s.channels:
            return False
        ch = s.channels[cid]
        if ch.schema_id and ch.schema_id not in self.scan.schemas:
            sc = s.schemas.get(ch.schema_id)
            if sc is None:
                return False
            self.scan.schemas[sc.id] = sc
        self.add_channel(ch)
        self.scan.channels_from_summary.add(cid)
        return True

    def on_messages(self, buf: bytes, start: int, end: int, where: str) -> tuple[int | None, int | None]:
        """Parse the records of ``buf[start:end]``; returns the first and last log time among its messages."""
        scan = self.scan
        targets = self.targets
        q = start
        counts = scan.channel_counts
        t_min: int | None = None
        t_max: int | None = None
        while q < end:
            if q + 9 > end:
                raise CorruptChunkError(f"{where}: record header runs past the end at {q}")
            op, ln = REC.unpack_from(buf, q)
            body = q + 9
            nxt = body + ln
            if nxt > end:
                raise CorruptChunkError(f"{where}: record of {ln} bytes runs past the end")
            if op == OP_MESSAGE:
                if ln < 22:
                    raise CorruptChunkError(f"{where}: message record of {ln} bytes is too short")
                cid, seq, log_t, pub_t = MSG.unpack_from(buf, body)
                if t_min is None or log_t < t_min:
                    t_min = log_t
                if t_max is None or log_t > t_max:
                    t_max = log_t
                if cid not in targets and not self.channel_from_summary(cid):
                    o = self.orphans.setdefault(cid, [0, log_t, log_t])
                    o[0] += 1
                    o[1] = min(o[1], log_t)
                    o[2] = max(o[2], log_t)
                    q = nxt
                    continue
                counts[cid] = counts.get(cid, 0) + 1
                tgt = targets[cid]
                if tgt is not None:
                    tgt.log_time.append(log_t)
                    tgt.publish_time.append(pub_t)
                    tgt.sequence.append(seq)
                    tgt.data.append(buf[body + 22 : nxt])
            elif op == OP_SCHEMA:
                sc = _read_exact(buf, q, nxt, Schema)
                scan.schemas[sc.id] = sc
            elif op == OP_CHANNEL:
                ch = _read_exact(buf, q, nxt, Channel)
                if ch.schema_id and ch.schema_id not in scan.schemas:
                    # its Schema record was in a damaged chunk: from the summary, else the channel stays
                    # without one (its messages are still read; ``rig recover`` declares a placeholder)
                    sc = self.summary.schemas.get(ch.schema_id) if self.summary is not None else None
                    if sc is not None and self.summary_problem is None:
                        scan.schemas[sc.id] = sc
                self.add_channel(ch)
            q = nxt
        return t_min, t_max

    def messages_atomically(self, buf: bytes, where: str, t0: int | None, t1: int | None) -> None:
        """Take a chunk's (or a record's) messages, all or none; the chunk's header times must match them.

        (A chunk without messages has header times 0, 0; the MCAP specification says so.)
        """
        scan = self.scan
        before = {id(tm): len(tm) for tm in scan.topics.values()}
        counts = dict(scan.channel_counts)
        orphans = {k: list(v) for k, v in self.orphans.items()}
        try:
            lo, hi = self.on_messages(buf, 0, len(buf), where)
            if t0 is not None and ((lo, hi) if lo is not None else (0, 0)) != (t0, t1):
                raise CorruptChunkError(f"{where}: header times {t0}..{t1} disagree with its messages' {lo}..{hi}")
        except Exception:
            for tm in scan.topics.values():
                n = before.get(id(tm), 0)
                del tm.log_time[n:], tm.publish_time[n:], tm.sequence[n:], tm.data[n:]
            scan.channel_counts.clear()
            scan.channel_counts.update(counts)
            self.orphans = orphans
            raise
        if lo is not None and hi is not None:
            if scan.message_start_time is None or lo < scan.message_start_time:
                scan.message_start_time = lo
            if scan.message_end_time is None or hi > scan.message_end_time:
                scan.message_end_time = hi

    # --- records ------------------------------------------------------------------------------------

    def record(self, op: int, pos: int, nxt: int) -> None:
        """Take one complete top-level record (raises CorruptChunkError when it is damaged)."""
        mm = self.mm
        scan = self.scan
        body = pos + 9
        where = f"record at offset {pos}"
        try:
            if op == OP_HEADER:
                (plen,) = struct.unpack_from("<I", mm, body)
                (llen,) = struct.unpack_from("<I", mm, body + 4 + plen)
                if body + 8 + plen + llen != nxt:
                    raise CorruptChunkError(f"header record at offset {pos} is damaged (string lengths)")
                scan.library = mm[body + 8 + plen : body + 8 + plen + llen].decode("utf-8")
                mm[body + 4 : body + 4 + plen].decode("utf-8")
                scan.header_ok = True
            elif op == OP_CHUNK:
                where = f"chunk at offset {pos}"
                t0, t1, usize, ucrc = CHUNK_HEAD.unpack_from(mm, body)
                (clen,) = struct.unpack_from("<I", mm, body + 28)
                if clen > 8:
                    raise CorruptChunkError(f"{where}: compression name of {clen} bytes (damaged header)")
                comp = mm[body + 32 : body + 32 + clen].decode()
                (rlen,) = struct.unpack_from("<Q", mm, body + 32 + clen)
                rstart = body + 40 + clen
                if rstart + rlen != nxt:
                    raise CorruptChunkError(f"{where}: length fields disagree (damaged header)")
                data = decompress_chunk(comp, mm[rstart:nxt], usize, where)
                if len(data) != usize:
                    raise CorruptChunkError(f"{where}: {len(data)} bytes decompressed, header says {usize}")
                if self.validate_crcs and ucrc and zlib.crc32(data) != ucrc:
                    raise CorruptChunkError(f"{where}: CRC mismatch (damaged data)")
                self.messages_atomically(data, where, t0, t1)
                scan.chunks.append(ChunkInfo(pos, nxt - pos, t0, t1, comp, int(rlen), usize))
                self.chunk_no += 1
            elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE):
                self.messages_atomically(mm[pos:nxt], where, None, None)
            elif op == OP_MESSAGE_INDEX:
                if not _strong(mm, pos):
                    raise CorruptChunkError(f"message index at offset {pos} is damaged")
            elif op == OP_METADATA:
                md = _read_exact(mm, pos, nxt, Metadata)
                scan.metadata.append((md, RecordRef(pos, nxt - pos)))
            elif op == OP_ATTACHMENT:
                att = _read_exact(mm, pos, nxt, Attachment)
                (acrc,) = struct.unpack_from("<I", mm, nxt - 4)
                if self.validate_crcs and acrc and zlib.crc32(mm[body : nxt - 4]) != acrc:
                    raise CorruptChunkError(f"attachment {att.name!r} at offset {pos}: CRC mismatch")
                scan.attachments.append((att, RecordRef(pos, nxt - pos)))
            elif op == OP_DATA_END and nxt - pos != 13:
                raise CorruptChunkError(f"DataEnd record at offset {pos} has length {nxt - pos - 9}")
        except (struct.error, UnicodeDecodeError, ValueError, IndexError) as exc:
            raise CorruptChunkError(f"{where} (opcode 0x{op:02x}) is damaged: {exc}") from exc

    # --- the pass -----------------------------------------------------------------------------------

    def run(self) -> None:
        mm = self.mm
        scan = self.scan
        size = len(mm)
        pos = len(MCAP_MAGIC)
        scan.data_end = pos
        header_seen = False
        while True:
            if pos == size:
                scan.truncation = "the part ends without a DataEnd record (recording not finished)"
                break
            if pos + 9 > size:
                scan.truncation = f"the part ends inside a record header at offset {pos}"
                break
            op, ln = REC.unpack_from(mm, pos)
            if op == 0 and ln == 0 and not any(mm[pos : min(size, pos + 4096)]):
                scan.truncation = f"zero-filled tail from offset {pos} (unwritten file blocks)"
                break
            nxt = pos + 9 + ln
            try:
                if not header_seen and op != OP_HEADER:
                    raise CorruptChunkError(f"expected the MCAP header at offset {pos}, found opcode 0x{op:02x}")
                if header_seen and op != OP_DATA_END and op not in _DATA_OPS:
                    raise CorruptChunkError(f"unexpected record opcode 0x{op:02x} at offset {pos} in the data section")
                if nxt > size:
                    raise _TruncatedError(f"the part ends inside a record (opcode 0x{op:02x}) at offset {pos}")
                self.record(op, pos, nxt)
            except _TruncatedError as exc:
                r = _next_strong(mm, pos + 1)
                if r is None:  # nothing intact follows: a cut, not damage
                    scan.truncation = str(exc)
                    break
                self.damaged(pos, r, f"record length runs past the end of the file ({exc})")
                pos = scan.data_end = r
                header_seen = True
                continue
            except CorruptChunkError as exc:
                r = nxt if op == OP_CHUNK and nxt <= size and _strong(mm, nxt) else _next_strong(mm, pos + 1)
                self.damaged(pos, size if r is None else r, str(exc))
                if r is None:
                    break
                pos = scan.data_end = r
                header_seen = True
                continue
            header_seen = True
            pos = nxt
            if op == OP_DATA_END:
                scan.data_end_found = True
                self.check_data_section(pos - 13)  # the DataEnd record: 9-byte header + its CRC
                scan.finalized = ends_with_footer(mm)
                if not scan.finalized:
                    scan.truncation = "the part ends inside its summary (all data is there; no index)"
                elif self.summary_problem is not None:
                    start = self.summary.start if self.summary is not None else pos
                    start = max(pos, start)
                    scan.damage.append(DamagedRegion(start, size - start, DamageKind.SUMMARY, self.summary_problem))
                break
            scan.data_end = pos
        self.finish()

    def check_data_section(self, data_end: int) -> None:
        """Compare DataEnd's CRC of the data section (``[0, data_end)``, when the writer computed one) when
        no record was found damaged: a compressed chunk can take a flipped bit and still decode to the same
        records (about 1 in 800 single-bit flips of zstd data, measured), which no chunk CRC sees."""
        if not self.validate_crcs or self.pending:
            return
        (crc,) = struct.unpack_from("<I", self.mm, data_end + 9)
        if not crc:  # 0: not computed (files of older recorders, `rig recover`'s copies)
            return
        with memoryview(self.mm) as whole, whole[:data_end] as data:
            actual = zlib.crc32(data)
        if actual != crc:
            self.scan.damage.append(DamagedRegion(
                0, data_end, DamageKind.DATA,
                "the data section's CRC (its DataEnd record) does not match, though every record in it checks"))

    def damaged(self, start: int, end: int, reason: str) -> None:
        """Note the region ``[start, end)`` as damaged (described in :meth:`finish`)."""
        self.pending.append({"start": start, "end": end, "reason": reason, "after_chunk": len(self.scan.chunks),
                             "prev_t": self.scan.message_end_time, "first_chunk_no": self.chunk_no,
                             "looks_chunk": self.mm[start] == OP_CHUNK})
        self.chunk_no += 1

    def finish(self) -> None:
        scan = self.scan
        regions: list[DamagedRegion] = []
        for d in self.pending:
            regions.append(self.describe(d))
        summary_damage = [r for r in scan.damage if r.kind in (DamageKind.DATA, DamageKind.SUMMARY)]
        lead = [r for r in scan.damage if r.kind is DamageKind.MAGIC]
        scan.damage = lead + regions + summary_damage
        scan.orphans = {cid: v[0] for cid, v in sorted(self.orphans.items())}
        for cid, (n, t0, t1) in sorted(self.orphans.items()):
            scan.damage.append(DamagedRegion(0, 0, DamageKind.CHANNEL,
                                             f"channel {cid} is not defined in any intact record", (),
                                             t0, t1, (f"channel {cid}",), n, True))

    def topic_of(self, cid: int) -> str:
        ch = self.scan.channels.get(cid)
        if ch is None and self.summary is not None and self.summary_problem is None:
            ch = self.summary.channels.get(cid)
        return ch.topic if ch is not None else f"channel {cid}"

    def describe(self, d: dict[str, Any]) -> DamagedRegion:
        mm = self.mm
        scan = self.scan
        start, end = int(d["start"]), int(d["end"])
        chunks: list[int] = []
        cids: set[int] = set()
        t_lo: int | None = None
        t_hi: int | None = None
        n_msgs: int | None = None
        s = self.summary
        if s is not None and self.summary_problem is None:
            for i, ci in enumerate(s.chunk_indexes):
                if start <= ci.chunk_start_offset < end:
                    chunks.append(i)
                    t_lo = ci.message_start_time if t_lo is None else min(t_lo, ci.message_start_time)
                    t_hi = ci.message_end_time if t_hi is None else max(t_hi, ci.message_end_time)
                    cids.update(ci.message_index_offsets)
                    for off in ci.message_index_offsets.values():
                        if _strong(mm, off) and mm[off] == OP_MESSAGE_INDEX:
                            n_msgs = (n_msgs or 0) + _MSG_INDEX_HEAD.unpack_from(mm, off + 9)[1] // 16
        if not chunks and (d["looks_chunk"] or (end < len(mm) and mm[end] == OP_MESSAGE_INDEX)):
            chunks.append(int(d["first_chunk_no"]))
            # the message index records right after the region belong to the chunk that was lost
            q = end
            while q + 15 <= len(mm) and mm[q] == OP_MESSAGE_INDEX and _strong(mm, q):
                cid, rl = _MSG_INDEX_HEAD.unpack_from(mm, q + 9)
                if rl:
                    cids.add(cid)
                    pairs = struct.unpack_from(f"<{rl // 8}Q", mm, q + 15)
                    times = pairs[0::2]
                    t_lo = min(times) if t_lo is None else min(t_lo, *times)
                    t_hi = max(times) if t_hi is None else max(t_hi, *times)
                    n_msgs = (n_msgs or 0) + rl // 16
                (_op, ln) = REC.unpack_from(mm, q)
                q += 9 + ln
        exact = t_lo is not None
        if not exact:
            t_lo = d["prev_t"]
            after = int(d["after_chunk"])
            t_hi = scan.chunks[after].message_start_time if after < len(scan.chunks) else scan.message_end_time
        kind = DamageKind.CHUNK if chunks else DamageKind.RECORD
        topics = tuple(sorted({self.topic_of(c) for c in cids}))
        return DamagedRegion(start, end - start, kind, str(d["reason"]), tuple(chunks), t_lo, t_hi, topics,
                             n_msgs, exact)





def iter_topic_messages(scans: list[PartScan], topic: str) -> Iterator[tuple[int, int, int, bytes]]:
    """(log_time, publish_time, sequence, data) of ``topic`` across scanned parts, in file order."""
    for s in scans:
        tm = s.topics.get(topic)
        if tm is not None:
            yield from zip(tm.log_time, tm.publish_time, tm.sequence, tm.data, strict=True)
