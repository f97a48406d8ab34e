"""Each receiver's port bytes and the relayed corrections as byte-exact files for post-processing (RTKLIB
convbin, NovAtel Convert)."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.data.stream import damage_notes
from rig.export.files import ExportedFile, ExportKind, ExportReport, check_new, export_dir, partial_path
from rig.store.reader import PartScan, find_parts, scan_part
from vsccore.errors import AnalysisError, SessionFileError

log = logging.getLogger(__name__)


NOVATEL_SUFFIX = ".gps"
"""RTKLIB convbin's extension for NovAtel OEM4/6/7 raw data (``-r nov``)."""


CORRECTIONS_STEM = "corrections"


_CORRECTION_SUFFIXES = {"rtcmv3": ".rtcm3", "rtcm3": ".rtcm3", "rtca": ".rtca", "cmr": ".cmr", "novatel": ".gps"}


_SEQ_MOD = 1 << 32


def correction_suffix(relay_format: str | None) -> str:
    """File suffix for the relayed corrections of ``relay_format`` (``rtcmv3`` → ``.rtcm3``; unknown → ``.rtcm3``)."""
    if not relay_format:
        return ".rtcm3"
    return _CORRECTION_SUFFIXES.get(relay_format.lower(), "." + "".join(c for c in relay_format.lower() if c.isalnum()))


def _is_raw_stream(topic: str) -> bool:
    if topic == T.TOPIC_RELAY_RAW:
        return True
    try:
        spec, _params = T.spec_for_topic(topic)
    except ValueError:
        return False
    return spec.pattern == "/gnss/{receiver}/raw"


def _scan_parts(path: Path | str, want: Callable[[str], bool]) -> Iterable[tuple[int, int, PartScan, list[str]]]:
    """(index, count, scan, warnings) of every part in order; a truncated last part and damaged chunks are
    tolerated (every intact chunk is read; the warnings name the damage), a truncated earlier part is not."""
    parts = find_parts(path)
    for i, p in enumerate(parts):
        where = f"{p} (part {i + 1} of {len(parts)})"
        try:
            scan = scan_part(p, want=want)
        except SessionFileError as exc:
            raise SessionFileError(f"{where}: {exc}") from exc
        if scan.truncation is not None and i < len(parts) - 1:
            raise SessionFileError(f"{where}: {scan.problem}")
        notes = damage_notes(where, scan)
        for note in notes:
            log.warning("%s", note)
        yield i, len(parts), scan, notes


@dataclass(slots=True)
class _Stream:
    topic: str
    kind: ExportKind
    path: Path
    file: IO[bytes]
    bytes: int = 0
    records: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    parts: set[int] = field(default_factory=set)
    next_seq: int | None = None
    breaks: int = 0


def rtklib_format(path: Path | str, sniff_bytes: int = 1 << 18) -> str:
    """RTKLIB ``convbin -r`` format of an exported raw file, from its content: ``rtcm3`` when RTCM 3
    frames outnumber NovAtel ones (a base receiver's correction output), else ``nov``."""
    from drivers.novatel import FrameKind, Framer

    with open(path, "rb") as f:
        head = f.read(sniff_bytes)
    framer = Framer(decode_logs=False, decode_nmea=False, decode_rtcm=False)
    frames = framer.feed(head)
    rtcm = sum(1 for fr in frames if fr.kind is FrameKind.RTCM3)
    return "rtcm3" if rtcm > len(frames) - rtcm else "nov"


def export_raw_gnss(path: Path | str, out_dir: Path | str, *, overwrite: bool = False) -> ExportReport:
    """Write every receiver's raw byte stream and the relayed corrections of a session into ``out_dir``.

    ``<out_dir>/<receiver>.gps`` per ``/gnss/<receiver>/raw`` topic and
    ``<out_dir>/corrections.rtcm3`` (suffix after the relay's format) for ``/relay/raw``; the
    directory is created if needed. Files are written under temporary names and renamed when the
    whole session has been read, so a failed export leaves no partial file behind. Raises
    :class:`~vsccore.errors.SessionFileError` for a missing or damaged part, a file that exists
    (unless ``overwrite``) or a write error, and :class:`~vsccore.errors.AnalysisError` when the
    session has no raw GNSS or correction stream.
    """
    out = export_dir(out_dir)
    streams: dict[str, _Stream] = {}
    warnings: list[str] = []
    relay_format: str | None = None
    try:
        for i, _n, scan, notes in _scan_parts(path, lambda t: _is_raw_stream(t) or t == T.TOPIC_RELAY_STATS):
            warnings.extend(notes)
            stats = scan.topics.get(T.TOPIC_RELAY_STATS)
            if stats is not None and len(stats):
                try:
                    fmt = json.loads(stats.data[-1]).get("format")
                except (ValueError, AttributeError):
                    fmt = None
                if isinstance(fmt, str) and fmt:
                    relay_format = fmt
            for topic in sorted(scan.topics):
                tm = scan.topics[topic]
                if topic == T.TOPIC_RELAY_STATS or not len(tm):
                    continue
                st = streams.get(topic)
                if st is None:
                    if topic == T.TOPIC_RELAY_RAW:
                        # the suffix follows the relay format, known for sure only at the end
                        final = out / f"{CORRECTIONS_STEM}.rtcm3"
                        kind = ExportKind.CORRECTIONS
                    else:
                        final = out / f"{T.spec_for_topic(topic)[1]['receiver']}{NOVATEL_SUFFIX}"
                        kind = ExportKind.GNSS_RAW
                        check_new(final, overwrite)
                    tmp = partial_path(final)
                    try:
                        fobj = open(tmp, "wb")  # noqa: SIM115 - closed below, also on errors
                    except OSError as exc:
                        raise SessionFileError(f"{tmp}: cannot create the export file: {exc}") from exc
                    st = _Stream(topic, kind, final, fobj)
                    streams[topic] = st
                _append(st, i, tm.log_time, tm.sequence, tm.data)
        for st in streams.values():
            st.file.close()
        if T.TOPIC_RELAY_RAW in streams:
            st = streams[T.TOPIC_RELAY_RAW]
            old = st.path
            st.path = out / f"{CORRECTIONS_STEM}{correction_suffix(relay_format)}"
            os.replace(partial_path(old), partial_path(st.path))
            check_new(st.path, overwrite)
        for st in streams.values():
            os.replace(partial_path(st.path), st.path)
    except BaseException:
        for st in streams.values():
            st.file.close()
            partial_path(st.path).unlink(missing_ok=True)
        partial_path(out / f"{CORRECTIONS_STEM}.rtcm3").unlink(missing_ok=True)
        raise
    if not streams:
        raise AnalysisError(f"{path}: the session has no raw GNSS (/gnss/<receiver>/raw) or {T.TOPIC_RELAY_RAW} data")
    files: list[ExportedFile] = []
    for st in sorted(streams.values(), key=lambda s: (s.kind != ExportKind.GNSS_RAW, s.topic)):
        if st.first_ns is not None:
            os.utime(st.path, ns=(st.first_ns, st.first_ns))
        if st.breaks:
            warnings.append(f"{st.topic}: sequence numbers break {st.breaks} times (reads lost or repeated)")
        files.append(ExportedFile(st.path, st.kind, st.topic, st.bytes, st.records, st.first_ns, st.last_ns,
                                  len(st.parts), st.breaks))
    return ExportReport(tuple(files), tuple(warnings))


def _append(st: _Stream, part: int, log_time: Sequence[int], sequence: Sequence[int], data: Sequence[bytes]) -> None:
    try:
        for chunk in data:
            st.file.write(chunk)
    except OSError as exc:
        raise SessionFileError(f"{st.path}: write failed: {exc}") from exc
    st.bytes += sum(len(d) for d in data)
    st.records += len(data)
    st.parts.add(part)
    if log_time:
        lo, hi = min(log_time), max(log_time)
        st.first_ns = lo if st.first_ns is None else min(st.first_ns, lo)
        st.last_ns = hi if st.last_ns is None else max(st.last_ns, hi)
    seq = np.asarray(sequence, dtype=np.int64)
    if seq.size:
        if st.next_seq is not None and int(seq[0]) != st.next_seq:
            st.breaks += 1
        st.breaks += int(np.count_nonzero((np.diff(seq) % _SEQ_MOD) != 1))
        st.next_seq = (int(seq[-1]) + 1) % _SEQ_MOD

