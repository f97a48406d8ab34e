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

import logging
import shutil
import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    MetadataIndex,
    Statistics,
    SummaryOffset,
)

from rig.recorder.reader import MCAP_MAGIC, PartScan, ProblemKind, scan_part
from vsccore.errors import SessionFileError

__all__ = ["RecoverReport", "finalize_in_place", "recover", "summary_bytes"]

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
    """Bytes after the last complete record, discarded."""
    problem: str | None
    """Why the original was incomplete (None: it was complete)."""
    problem_kind: ProblemKind | None
    was_finalized: bool
    """The original was already finalized (nothing to do)."""
    finalized: bool
    """The result ends with a summary and footer."""
    error: str | None = None
    """Why finalizing failed (then the file is still readable up to its last complete record)."""


def summary_bytes(scan: PartScan, summary_start: int) -> bytes:
    """DataEnd, summary section, footer and closing magic for the records found by ``scan``.

    ``summary_start`` is the offset at which the DataEnd record will be written (the scan's
    ``data_end``); the returned bytes are appended there.
    """
    head = RecordBuilder()
    if summary_start <= len(MCAP_MAGIC):  # killed before even the header was complete
        Header(profile="", library="vsc-rig recover").write(head)
    DataEnd(0).write(head)  # 0: no data-section CRC (the recorder does not compute one)
    head_bytes = head.end()
    start = summary_start + len(head_bytes)
    b = RecordBuilder()
    offsets: list[SummaryOffset] = []

    def group(opcode: Opcode, records: Sequence[McapRecord]) -> None:
        g0 = b.count
        for r in records:
            r.write(b)
        if b.count > g0:
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=start + g0, group_length=b.count - g0))

    stats = Statistics(
        attachment_count=len(scan.attachments),
        channel_count=len(scan.channels),
        channel_message_counts=dict(scan.channel_counts),
        chunk_count=len(scan.chunks),
        message_count=scan.message_count,
        message_end_time=scan.message_end_time or 0,
        message_start_time=scan.message_start_time or 0,
        metadata_count=len(scan.metadata),
        schema_count=len(scan.schemas),
    )
    chunk_indexes = [
        ChunkIndex(
            chunk_length=c.length,
            chunk_start_offset=c.offset,
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
            offset=ref.offset,
            length=ref.length,
            log_time=a.log_time,
            create_time=a.create_time,
            data_size=len(a.data),
            name=a.name,
            media_type=a.media_type,
        )
        for a, ref in scan.attachments
    ]
    metadata_indexes = [MetadataIndex(offset=ref.offset, length=ref.length, name=m.name) for m, ref in scan.metadata]
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
    import os

    os.fsync(stream.fileno())


def finalize_in_place(
    path: Path | str,
    *,
    opener: Opener | None = None,
    fsync: Callable[[IO[bytes]], None] | None = None,
) -> RecoverReport:
    """Cut ``path`` after its last complete record and append a summary; never raises for damage.

    A part that is already finalized is left untouched. If the summary cannot be written (e.g. the
    disk is still full) the file is cut at its last complete record, which stays readable by
    :func:`rig.recorder.reader.scan_part`, and the report says why (``error``).
    """
    p = Path(path)
    open_ = opener or _default_opener
    sync = fsync or _default_fsync
    scan = scan_part(p, collect=False)
    if scan.finalized and scan.problem is None:
        return _report(p, scan, was_finalized=True, finalized=True)
    tail = summary_bytes(scan, scan.data_end)
    try:
        with open_(p, "r+b") as f:
            f.seek(scan.data_end)
            f.truncate(scan.data_end)
            f.write(tail)
            f.flush()
            sync(f)
    except OSError as exc:
        log.error("cannot finalize %s: %s", p, exc)
        try:
            with open_(p, "r+b") as f:
                f.truncate(scan.data_end)
        except OSError:
            log.warning("cannot cut %s at its last complete record; readers stop there anyway", p)
        return _report(p, scan, was_finalized=False, finalized=False, error=str(exc))
    return _report(p, scan, was_finalized=False, finalized=True)


def recover(src: Path | str, dst: Path | str | None = None, *, overwrite: bool = False) -> RecoverReport:
    """Write a finalized, indexed copy of ``src`` with everything up to its last complete record.

    ``dst`` defaults to ``<src stem>.recovered.mcap`` beside it. Raises
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
    keep = scan.data_end
    tmp = d.with_name(d.name + ".partial")
    try:
        with open(s, "rb") as fin, open(tmp, "wb") as fout:
            left = keep
            while left > 0:
                block = fin.read(min(left, 1 << 22))
                if not block:
                    raise SessionFileError(f"{s}: shorter than when it was scanned")
                fout.write(block)
                left -= len(block)
            fout.write(summary_bytes(scan, keep))
            fout.flush()
            _default_fsync(fout)
        shutil.move(tmp, d)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, SessionFileError):
            raise
        raise SessionFileError(f"{d}: cannot write the recovered copy of {s}: {exc}") from exc
    log.info("recovered %s -> %s (%d messages)", s, d, scan.message_count)
    return _report(d, scan, was_finalized=scan.finalized and scan.problem is None, finalized=True)


def _report(
    p: Path, scan: PartScan, *, was_finalized: bool, finalized: bool, error: str | None = None
) -> RecoverReport:
    return RecoverReport(
        path=p,
        messages=scan.message_count,
        chunks=len(scan.chunks),
        kept_bytes=scan.data_end,
        dropped_bytes=max(0, scan.size - scan.data_end) if not was_finalized else 0,
        problem=scan.problem,
        problem_kind=scan.problem_kind,
        was_finalized=was_finalized,
        finalized=finalized,
        error=error,
    )
