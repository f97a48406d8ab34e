"""Recovering a part that was not finalized (killed recorder, write error, full disk).

An MCAP part is written as a data section that only grows, closed by a DataEnd record, a summary
(schemas, channels, statistics, chunk/metadata/attachment indexes) and a footer. A recorder killed
mid-recording leaves a prefix of the data section that ends inside some record. Recovery keeps
every complete record up to the first damaged or incomplete one and appends a summary built from
a scan of what was kept, so the result is an ordinary finalized, indexed MCAP file that any MCAP
reader opens (the chunks themselves are kept byte for byte, not re-compressed).

- :func:`recover` writes a finalized copy (``rig recover FILE``);
- :func:`finalize_in_place` cuts a part at its last complete record and appends the summary (the
  recorder uses it after a write error, when there is no room for a copy).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import struct
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from rig.core.topics import METADATA_PART_END
from rig.store.reader import (
    MCAP_MAGIC,
    DamagedRegion,
    DamageKind,
    PartScan,
    ProblemKind,
    damaged_chunk_count,
    damaged_seconds,
    scan_part,
    session_base,
)
from vsccore.errors import SessionFileError

__all__ = ["RecoverReport", "finalize_in_place", "recover", "remove_stale_reserve",
           "remove_stale_reserves", "reserve_is_stale", "reserve_path", "summary_bytes"]

log = logging.getLogger(__name__)

Opener = Callable[[Path, str], IO[bytes]]


@dataclass(frozen=True, slots=True)
class RecoverReport:
    """The outcome of a recovery."""

    path: Path
    """The file written (or finalized in place)."""
    messages: int
    """Messages in the recovered file."""
    chunks: int
    kept_bytes: int
    """Bytes of the original data section kept."""
    dropped_bytes: int
    """Bytes discarded: damaged regions and what follows the last complete record."""
    problem: str | None
    """Why the original was incomplete (None: it was complete)."""
    problem_kind: ProblemKind | None
    was_finalized: bool
    """The original was already finalized (nothing to do)."""
    finalized: bool
    """The result ends with a summary and footer."""
    error: str | None = None
    """Why finalizing failed (then the file is still readable up to its last complete record)."""
    damage: tuple[DamagedRegion, ...] = ()
    """Damaged regions of the original that were left out."""
    truncation: str | None = None
    """Why the original ended early (None: it did not)."""

    @property
    def damaged_chunks(self) -> int:
        return damaged_chunk_count(self.damage)

    @property
    def damaged_s(self) -> float:
        return damaged_seconds(self.damage)


OffsetMap = Callable[[int], int]
"""Maps a record's offset in the original part to its offset in the file being written."""


def summary_bytes(
    scan: PartScan,
    summary_start: int,
    *,
    offset_of: OffsetMap | None = None,
    extra_metadata: Sequence[Metadata] = (),
) -> bytes:
    """Records appended at ``summary_start`` to finish a file holding the records found by ``scan``.

    ``summary_start`` is where the first returned byte will be written. From there: the leading
    magic and a header if ``summary_start`` is before the end of where they belong (an empty or tiny
    part), ``extra_metadata`` records (e.g. a part-end record written after a failure), DataEnd,
    the summary section (schemas, channels, statistics, chunk/attachment/metadata indexes), the
    footer and the closing magic. ``offset_of`` maps the scan's record offsets to those in the file
    written (default: unchanged).
    """
    where = offset_of or (lambda off: off)
    head = RecordBuilder()
    prefix = b""
    if summary_start < len(MCAP_MAGIC):  # not even the magic survived: start the file over
        prefix = MCAP_MAGIC
        summary_start = 0
    if summary_start <= len(MCAP_MAGIC):  # killed before even the header was complete
        Header(profile="", library="vsc-rig recover").write(head)
    base = summary_start + len(prefix)  # file offset of head's first byte
    extra_refs: list[MetadataIndex] = []
    for md in extra_metadata:
        at = base + head.count
        md.write(head)
        extra_refs.append(MetadataIndex(offset=at, length=base + head.count - at, name=md.name))
    DataEnd(0).write(head)  # 0: no data-section CRC (the recorder does not compute one)
    head_bytes = prefix + head.end()
    start = summary_start + len(head_bytes)
    b = RecordBuilder()
    offsets: list[SummaryOffset] = []

    def group(opcode: Opcode, records: Sequence[McapRecord]) -> None:
        g0 = b.count
        for r in records:
            r.write(b)
        if b.count > g0:
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=start + g0, group_length=b.count - g0))

    t0 = [c.message_start_time for c in scan.chunks] + ([scan.message_start_time] if scan.message_start_time else [])
    stats = Statistics(
        attachment_count=len(scan.attachments),
        channel_count=len(scan.channels),
        channel_message_counts=dict(scan.channel_counts),
        chunk_count=len(scan.chunks),
        message_count=scan.message_count,
        message_end_time=scan.message_end_time or 0,
        message_start_time=min(t0) if t0 and scan.message_count else 0,
        metadata_count=len(scan.metadata) + len(extra_metadata),
        schema_count=len(scan.schemas),
    )
    chunk_indexes = [
        ChunkIndex(
            chunk_length=c.length,
            chunk_start_offset=where(c.offset),
            compression=c.compression,
            compressed_size=c.compressed_size,
            message_end_time=c.message_end_time,
            message_index_length=0,
            message_index_offsets={},
            message_start_time=c.message_start_time,
            uncompressed_size=c.uncompressed_size,
        )
        for c in scan.chunks
    ]
    attachment_indexes = [
        AttachmentIndex(
            offset=where(ref.offset),
            length=ref.length,
            log_time=a.log_time,
            create_time=a.create_time,
            data_size=len(a.data),
            name=a.name,
            media_type=a.media_type,
        )
        for a, ref in scan.attachments
    ]
    metadata_indexes = [
        MetadataIndex(offset=where(ref.offset), length=ref.length, name=m.name) for m, ref in scan.metadata
    ] + extra_refs
    group(Opcode.SCHEMA, list(scan.schemas.values()))
    group(Opcode.CHANNEL, list(scan.channels.values()))
    group(Opcode.STATISTICS, [stats])
    group(Opcode.CHUNK_INDEX, chunk_indexes)
    group(Opcode.ATTACHMENT_INDEX, attachment_indexes)
    group(Opcode.METADATA_INDEX, metadata_indexes)
    offset_start = start + b.count
    for o in offsets:
        o.write(b)
    summary = b.end()
    crc = zlib.crc32(summary)
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, start, offset_start), crc)
    tail = RecordBuilder()
    Footer(summary_start=start, summary_offset_start=offset_start, summary_crc=crc).write(tail)
    return head_bytes + summary + tail.end() + MCAP_MAGIC


def _default_opener(path: Path, mode: str) -> IO[bytes]:
    return open(path, mode)


def _default_fsync(stream: IO[bytes]) -> None:
    os.fsync(stream.fileno())


PartEnd = Callable[[PartScan], Mapping[str, str]]
"""Builds a part-end metadata record (:data:`rig.core.topics.METADATA_PART_END`) from the scan of what survived."""


def finalize_in_place(
    path: Path | str,
    *,
    opener: Opener | None = None,
    fsync: Callable[[IO[bytes]], None] | None = None,
    part_end: PartEnd | None = None,
) -> RecoverReport:
    """Cut ``path`` after its last complete record and append a summary; never raises for damage.

    A part that is already finalized is left untouched. A part too short to hold even the magic
    and header becomes a valid empty MCAP file. ``part_end`` (the recorder's, after a write
    failure) adds a part-end metadata record saying what was lost. If the summary cannot be written
    (e.g. the disk is still full) the file is cut at its last complete record, which stays readable
    by :func:`rig.store.reader.scan_part`, and the report says why (``error``).
    """
    p = Path(path)
    open_ = opener or _default_opener
    sync = fsync or _default_fsync
    scan = scan_part(p, collect=False)
    if scan.finalized and scan.problem is None:
        return _report(p, scan, was_finalized=True, finalized=True)
    cut = scan.data_end if scan.data_end >= len(MCAP_MAGIC) else 0
    extra = [Metadata(name=METADATA_PART_END, metadata=dict(part_end(scan)))] if part_end is not None else []
    tail = summary_bytes(scan, cut, extra_metadata=extra)
    try:
        with open_(p, "r+b") as f:
            f.seek(cut)
            f.truncate(cut)
            f.write(tail)
            f.flush()
            sync(f)
    except OSError as exc:
        log.error("cannot finalize %s: %s", p, exc)
        try:
            with open_(p, "r+b") as f:
                f.truncate(cut)
        except OSError:
            log.warning("cannot cut %s at its last complete record; readers stop there anyway", p)
        return _report(p, scan, was_finalized=False, finalized=False, error=str(exc))
    return _report(p, scan, was_finalized=False, finalized=True)


def _segments(scan: PartScan, header_end: int) -> list[tuple[int, int]]:
    """The byte ranges of the data section to keep (after the header): ``[header_end, data_end)`` minus damage."""
    keep: list[tuple[int, int]] = []
    pos = header_end
    for d in sorted(scan.damage, key=lambda d: d.offset):
        if d.kind not in (DamageKind.CHUNK, DamageKind.RECORD) or d.offset + d.length <= pos:
            continue
        if d.offset >= scan.data_end:
            break
        if d.offset > pos:
            keep.append((pos, d.offset))
        pos = max(pos, d.offset + d.length)
    if pos < scan.data_end:
        keep.append((pos, scan.data_end))
    return keep


def reserve_path(base: Path) -> Path:
    """The disk-space reserve file of the session whose base path is ``base`` (``<base>.reserve``)."""
    return base.with_name(base.name + ".reserve")


def lock_reserve(path: Path) -> int | None:
    """Hold an exclusive lock on the reserve file ``path`` while recording (the descriptor; None: no locks here).

    The lock tells :func:`reserve_is_stale` that a recorder is alive; the kernel drops it when the
    process dies, however it dies.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: an open file cannot be deleted there anyway
        return None
    fd = os.open(path, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise
    return fd


def reserve_is_stale(path: Path) -> bool:
    """No living recorder holds the reserve file ``path`` (a kill -9 left it behind)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover
        return True
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    finally:
        os.close(fd)  # closing drops the lock taken just now
    return True


def remove_stale_reserves(directory: Path) -> list[Path]:
    """Delete every stale disk-space reserve (``*.reserve``) in ``directory``; returns those removed."""
    removed = []
    for f in sorted(directory.glob("*.reserve")):
        if f.is_file() and reserve_is_stale(f):
            try:
                f.unlink()
            except OSError as exc:
                log.warning("cannot remove the stale reserve %s: %s", f, exc)
                continue
            log.info("removed the stale disk-space reserve %s", f)
            removed.append(f)
    return removed


def remove_stale_reserve(part: Path) -> Path | None:
    """Delete the disk-space reserve (``<base>.reserve``) that a killed recorder of ``part``'s session left.

    A reserve that a running recorder holds (it keeps a lock on it) is left alone. Returns the file
    removed, or None.
    """
    reserve = reserve_path(session_base(part))
    if reserve.exists() and reserve_is_stale(reserve):
        try:
            reserve.unlink()
        except OSError as exc:
            log.warning("cannot remove the stale reserve %s: %s", reserve, exc)
            return None
        log.info("removed the stale disk-space reserve %s", reserve)
        return reserve
    return None


def recover(src: Path | str, dst: Path | str | None = None, *, overwrite: bool = False) -> RecoverReport:
    """Write a finalized, indexed copy of ``src`` with every intact record, before and after any damage.

    ``dst`` defaults to ``<src stem>.recovered.mcap`` beside it. The header, every intact chunk,
    message index, metadata and attachment record are copied byte for byte; damaged regions are
    left out (the report lists them); a part too short for even the magic gives a valid empty file.
    The disk-space reserve a killed recorder left beside the part is removed. Raises
    :class:`~vsccore.errors.SessionFileError` when ``src`` is not an MCAP file or ``dst`` exists
    (unless ``overwrite``).
    """
    s = Path(src)
    d = Path(dst) if dst is not None else s.with_name(s.name.removesuffix(".mcap") + ".recovered.mcap")
    if d.resolve() == s.resolve():
        raise SessionFileError(f"{d}: recovery target must differ from the source")
    if d.exists() and not overwrite:
        raise SessionFileError(f"{d} already exists (remove it or pass overwrite)")
    scan = scan_part(s, collect=False)
    tmp = d.with_name(d.name + ".partial")
    try:
        with open(s, "rb") as fin, open(tmp, "wb") as fout:
            out = RecordBuilder()
            header_end = len(MCAP_MAGIC)
            if scan.header_ok:
                fin.seek(len(MCAP_MAGIC))
                _op, ln = struct.unpack("<BQ", fin.read(9))
                header_end = len(MCAP_MAGIC) + 9 + ln
                fin.seek(len(MCAP_MAGIC))
                head = MCAP_MAGIC + _read_exactly(fin, header_end - len(MCAP_MAGIC), s)
            else:
                Header(profile="", library="vsc-rig recover").write(out)
                head = MCAP_MAGIC
            # channels whose Channel record was lost with a damaged chunk: defined again up front (from the
            # summary; or, when that is gone too, as placeholders so that their messages stay readable)
            scan = _with_placeholder_channels(scan)
            lost = [scan.channels[c] for c in sorted(scan.channels_from_summary | set(scan.orphans))]
            placeholders = {sid for sid, sc in scan.schemas.items() if sc.name == f"unknown{sid}" and not sc.data}
            for sid in sorted({c.schema_id for c in lost if c.schema_id} | placeholders):
                if sid in scan.schemas:
                    scan.schemas[sid].write(out)
            for ch in lost:
                ch.write(out)
            head += out.end()
            fout.write(head)
            moved: list[tuple[int, int, int]] = []  # (old start, old end, new start)
            at = len(head)
            for a, b in _segments(scan, header_end):
                moved.append((a, b, at))
                fin.seek(a)
                left = b - a
                while left > 0:
                    block = _read_exactly(fin, min(left, 1 << 22), s)
                    fout.write(block)
                    left -= len(block)
                at += b - a

            def offset_of(off: int) -> int:
                for a, b, n in moved:
                    if a <= off < b:
                        return n + off - a
                raise SessionFileError(f"{s}: record at offset {off} is not in a kept range (scanner bug)")

            fout.write(summary_bytes(scan, at, offset_of=offset_of))
            fout.flush()
            _default_fsync(fout)
        shutil.move(tmp, d)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, SessionFileError):
            raise
        raise SessionFileError(f"{d}: cannot write the recovered copy of {s}: {exc}") from exc
    remove_stale_reserve(s)
    log.info("recovered %s -> %s (%d messages)", s, d, scan.message_count)
    return _report(d, scan, was_finalized=scan.finalized and scan.problem is None, finalized=True)


def _with_placeholder_channels(scan: PartScan) -> PartScan:
    """``scan`` with a placeholder channel (``/unknown/channel<N>``, no schema) for each unknown channel id."""
    missing = {ch.schema_id for ch in scan.channels.values() if ch.schema_id and ch.schema_id not in scan.schemas}
    if not scan.orphans and not missing:
        return scan
    schemas = dict(scan.schemas)
    for sid in missing:  # its Schema record was lost with a damaged chunk
        schemas[sid] = Schema(id=sid, name=f"unknown{sid}", encoding="", data=b"")
    channels = dict(scan.channels)
    counts = dict(scan.channel_counts)
    for cid, n in scan.orphans.items():
        channels[cid] = Channel(id=cid, schema_id=0, topic=f"/unknown/channel{cid}", message_encoding="",
                                metadata={"vsc_rig.recovered": "the Channel record was lost in a damaged chunk"})
        counts[cid] = n
    return dataclasses.replace(scan, schemas=schemas, channels=channels, channel_counts=counts)


def _read_exactly(f: IO[bytes], n: int, path: Path) -> bytes:
    data = f.read(n)
    if len(data) != n:
        raise SessionFileError(f"{path}: shorter than when it was scanned")
    return data


def _report(
    p: Path, scan: PartScan, *, was_finalized: bool, finalized: bool, error: str | None = None
) -> RecoverReport:
    damaged = sum(d.length for d in scan.damage if d.kind in (DamageKind.CHUNK, DamageKind.RECORD)
                  and d.offset < scan.data_end)
    return RecoverReport(
        path=p,
        messages=scan.message_count,
        chunks=len(scan.chunks),
        kept_bytes=scan.data_end - damaged,
        dropped_bytes=max(0, scan.size - scan.data_end) + damaged if not was_finalized else 0,
        problem=scan.problem,
        problem_kind=scan.problem_kind,
        was_finalized=was_finalized,
        finalized=finalized,
        error=error,
        damage=tuple(scan.damage),
        truncation=scan.truncation,
    )
