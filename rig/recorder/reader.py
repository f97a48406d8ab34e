"""Reading session parts: part naming, and a fast scanner that tolerates a truncated (crashed) part.

A session ``<dir>/<name>`` is stored as parts ``<name>.000.mcap``, ``<name>.001.mcap``, ... The
scanner walks a part's data section record by record (it never needs the summary), decompresses
each chunk once and hands back the messages grouped by topic. A part whose recorder was killed ends
in the middle of a record; the scanner stops at the last complete record and says so
(:attr:`PartScan.problem`), which is how both :func:`rig.recorder.recover.recover` and
:mod:`rig.dataset` read crashed recordings. Corruption in the middle (bad CRC, undecodable chunk,
impossible record) is reported as such, not as a truncation.
"""

from __future__ import annotations

import mmap
import os
import re
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.records import Attachment, Channel, Metadata, Schema

from vsccore.errors import SessionFileError

__all__ = [
    "MCAP_MAGIC",
    "ChunkInfo",
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

MCAP_MAGIC = b"\x89MCAP0\r\n"
_PART_RE = re.compile(r"^(?P<name>.+)\.(?P<index>\d{3,})\.mcap$")

_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_MESSAGE_INDEX = 0x07
_OP_ATTACHMENT = 0x09
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F
_DATA_OPS = frozenset(
    {_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX, _OP_ATTACHMENT, _OP_METADATA}
)
"""Records that may appear in the data section (custom opcodes >= 0x80 are skipped as well)."""
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQI")
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4


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
    """Why a scan stopped before the end of the data section."""

    TRUNCATED = "truncated"
    """The part ends inside a record (a killed recorder, a copy cut short)."""
    CORRUPT = "corrupt"
    """A record or chunk is damaged (bad CRC, undecodable, impossible length)."""


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
    topics: dict[str, TopicMessages] = field(default_factory=dict)
    """Collected messages by topic (only the topics asked for)."""
    channel_counts: dict[int, int] = field(default_factory=dict)
    """Messages per channel id (all channels, collected or not)."""
    message_start_time: int | None = None
    message_end_time: int | None = None
    data_end: int = 0
    """Offset just past the last complete data-section record (where a recovery cuts)."""
    data_end_found: bool = False
    """The data section ends with its DataEnd record (the writer finished it)."""
    finalized: bool = False
    """DataEnd, summary, footer and closing magic are all there."""
    problem: str | None = None
    problem_kind: ProblemKind | None = None

    @property
    def message_count(self) -> int:
        return sum(self.channel_counts.values())

    def metadata_dict(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (a later record of the same name wins)."""
        return {m.name: dict(m.metadata) for m, _ in self.metadata}

    def check(self, *, allow_truncated: bool) -> None:
        """Raise :class:`SessionFileError` for a problem (a truncation only if not allowed)."""
        if self.problem is None:
            return
        if self.problem_kind is ProblemKind.TRUNCATED and allow_truncated:
            return
        raise SessionFileError(f"{self.path}: {self.problem}")


class CorruptChunkError(Exception):
    pass


class _TruncatedError(Exception):
    pass


def _read_record(stream_bytes: bytes, cls: type[Schema] | type[Channel] | type[Metadata] | type[Attachment]) -> object:
    return cls.read(ReadDataStream(BytesIO(stream_bytes)))


def scan_part(
    path: Path | str,
    *,
    want: Callable[[str], bool] | None = None,
    collect: bool = True,
    validate_crcs: bool = True,
) -> PartScan:
    """Walk one part's data section; never raises for damage, which is reported in the result.

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
            scan.problem = f"{size} bytes: too short for an MCAP file"
            scan.problem_kind = ProblemKind.TRUNCATED
            if size and not MCAP_MAGIC.startswith(f.read()):
                raise SessionFileError(f"{p}: not an MCAP file (bad magic)")
            return scan
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            if mm[: len(MCAP_MAGIC)] != MCAP_MAGIC:
                raise SessionFileError(f"{p}: not an MCAP file (bad magic)")
            _scan(mm, scan, want, collect, validate_crcs)
        finally:
            mm.close()
    return scan


def _scan(
    mm: mmap.mmap,
    scan: PartScan,
    want: Callable[[str], bool] | None,
    collect: bool,
    validate_crcs: bool,
) -> None:
    size = len(mm)
    pos = len(MCAP_MAGIC)
    scan.data_end = pos
    # channel id -> TopicMessages to collect into, or None (counted only)
    targets: dict[int, TopicMessages | None] = {}
    header_seen = False

    def add_channel(ch: Channel) -> None:
        scan.channels[ch.id] = ch
        target: TopicMessages | None = None
        if collect and (want is None or want(ch.topic)):
            target = scan.topics.get(ch.topic)
            if target is None:
                schema = scan.schemas.get(ch.schema_id)
                target = TopicMessages(ch.topic, schema.name if schema else "", ch.message_encoding)
                scan.topics[ch.topic] = target
        targets[ch.id] = target

    def on_messages(buf: bytes, start: int, end: int, where: str) -> None:
        """Parse the records of ``buf[start:end]`` (a chunk's content or one top-level message)."""
        q = start
        counts = scan.channel_counts
        t_min = scan.message_start_time
        t_max = scan.message_end_time
        while q < end:
            if q + 9 > end:
                raise CorruptChunkError(f"{where}: record header runs past the end at {q}")
            op, ln = _REC.unpack_from(buf, q)
            body = q + 9
            nxt = body + ln
            if nxt > end:
                raise CorruptChunkError(f"{where}: record of {ln} bytes runs past the end")
            if op == _OP_MESSAGE:
                if ln < 22:
                    raise CorruptChunkError(f"{where}: message record of {ln} bytes is too short")
                cid, seq, log_t, pub_t = _MSG.unpack_from(buf, body)
                if cid not in targets:
                    raise CorruptChunkError(f"{where}: message on unknown channel {cid}")
                counts[cid] = counts.get(cid, 0) + 1
                if t_min is None or log_t < t_min:
                    t_min = log_t
                if t_max is None or log_t > t_max:
                    t_max = log_t
                tgt = targets[cid]
                if tgt is not None:
                    tgt.log_time.append(log_t)
                    tgt.publish_time.append(pub_t)
                    tgt.sequence.append(seq)
                    tgt.data.append(buf[body + 22 : nxt])
            elif op == _OP_SCHEMA:
                sc = _read_record(buf[body:nxt], Schema)
                assert isinstance(sc, Schema)
                scan.schemas[sc.id] = sc
            elif op == _OP_CHANNEL:
                ch = _read_record(buf[body:nxt], Channel)
                assert isinstance(ch, Channel)
                if ch.schema_id and ch.schema_id not in scan.schemas:
                    raise CorruptChunkError(f"{where}: channel {ch.topic} names unknown schema {ch.schema_id}")
                add_channel(ch)
            q = nxt
        scan.message_start_time = t_min
        scan.message_end_time = t_max

    try:
        while True:
            if pos == size:
                raise _TruncatedError("the part ends without a DataEnd record (recording not finished)")
            if pos + 9 > size:
                raise _TruncatedError(f"the part ends inside a record header at offset {pos}")
            op, ln = _REC.unpack_from(mm, pos)
            if op == 0 and ln == 0 and not any(mm[pos : min(size, pos + 4096)]):
                raise _TruncatedError(f"zero-filled tail from offset {pos} (unwritten file blocks)")
            body = pos + 9
            nxt = body + ln
            if not header_seen:
                if op != _OP_HEADER:
                    raise CorruptChunkError(f"expected the MCAP header at offset {pos}, found opcode 0x{op:02x}")
                header_seen = True
            elif op != _OP_DATA_END and op not in _DATA_OPS and op < 0x80:
                raise CorruptChunkError(f"unexpected record opcode 0x{op:02x} at offset {pos} in the data section")
            if nxt > size:
                raise _TruncatedError(f"the part ends inside a record (opcode 0x{op:02x}) at offset {pos}")
            where = f"record at offset {pos}"
            try:
                if op == _OP_HEADER:
                    (plen,) = struct.unpack_from("<I", mm, body)
                    (llen,) = struct.unpack_from("<I", mm, body + 4 + plen)
                    scan.library = mm[body + 8 + plen : body + 8 + plen + llen].decode("utf-8", "replace")
                elif op == _OP_CHUNK:
                    _t0, _t1, usize, ucrc = _CHUNK_HEAD.unpack_from(mm, body)
                    (clen,) = struct.unpack_from("<I", mm, body + 28)
                    comp = mm[body + 32 : body + 32 + clen].decode()
                    (rlen,) = struct.unpack_from("<Q", mm, body + 32 + clen)
                    rstart = body + 40 + clen
                    if rstart + rlen > nxt:
                        raise CorruptChunkError(f"chunk at offset {pos}: records run past the chunk")
                    raw = mm[rstart : rstart + rlen]
                    data = decompress_chunk(comp, raw, usize, where)
                    if validate_crcs and ucrc and zlib.crc32(data) != ucrc:
                        raise CorruptChunkError(f"chunk at offset {pos}: CRC mismatch (damaged data)")
                    on_messages(data, 0, len(data), f"chunk at offset {pos}")
                    scan.chunks.append(ChunkInfo(pos, nxt - pos, _t0, _t1, comp, int(rlen), usize))
                elif op in (_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                    block = mm[pos:nxt]
                    on_messages(block, 0, len(block), where)
                elif op == _OP_METADATA:
                    md = _read_record(mm[body:nxt], Metadata)
                    assert isinstance(md, Metadata)
                    scan.metadata.append((md, RecordRef(pos, nxt - pos)))
                elif op == _OP_ATTACHMENT:
                    att = _read_record(mm[body:nxt], Attachment)
                    assert isinstance(att, Attachment)
                    (acrc,) = struct.unpack_from("<I", mm, nxt - 4)
                    if validate_crcs and acrc and zlib.crc32(mm[body : nxt - 4]) != acrc:
                        raise CorruptChunkError(f"attachment {att.name!r} at offset {pos}: CRC mismatch")
                    scan.attachments.append((att, RecordRef(pos, nxt - pos)))
            except (struct.error, UnicodeDecodeError, ValueError, IndexError) as exc:
                if isinstance(exc, CorruptChunkError):
                    raise
                raise CorruptChunkError(f"{where} (opcode 0x{op:02x}) is damaged: {exc}") from exc
            pos = nxt
            if op == _OP_DATA_END:
                scan.data_end_found = True
                scan.finalized = _has_footer(mm)
                if not scan.finalized:
                    raise _TruncatedError("the part ends inside its summary (all data is there; no index)")
                return
            scan.data_end = pos
    except _TruncatedError as exc:
        scan.problem = str(exc)
        scan.problem_kind = ProblemKind.TRUNCATED
    except CorruptChunkError as exc:
        scan.problem = str(exc)
        scan.problem_kind = ProblemKind.CORRUPT


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


def _has_footer(mm: mmap.mmap) -> bool:
    size = len(mm)
    if size < 2 * len(MCAP_MAGIC) + _FOOTER_SIZE or mm[size - len(MCAP_MAGIC) :] != MCAP_MAGIC:
        return False
    op, ln = _REC.unpack_from(mm, size - len(MCAP_MAGIC) - _FOOTER_SIZE)
    return bool(op == _OP_FOOTER and ln == _FOOTER_SIZE - 9)


def iter_topic_messages(scans: list[PartScan], topic: str) -> Iterator[tuple[int, int, int, bytes]]:
    """(log_time, publish_time, sequence, data) of ``topic`` across scanned parts, in file order."""
    for s in scans:
        tm = s.topics.get(topic)
        if tm is not None:
            yield from zip(tm.log_time, tm.publish_time, tm.sequence, tm.data, strict=True)
