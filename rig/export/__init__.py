"""Getting data out of a session: raw GNSS streams for post-processing, decoded tables as CSV.

:func:`export_raw_gnss` writes each receiver's port bytes (``/gnss/<receiver>/raw``, every read as
received) concatenated in recording order into ``<dir>/<receiver>.gps``, and the relayed correction
bytes (``/relay/raw``) into ``<dir>/corrections.rtcm3``. The files are byte-exact copies of what
the ports delivered, across every part of the session:

- ``.gps`` is the extension by which RTKLIB's ``convbin`` recognises NovAtel OEM4/6/7 data (the same
  as ``convbin -r nov``); NovAtel Convert and other NovAtel tools read the binary/ASCII mix as a
  receiver log file. (``.bin`` would be taken for Hemisphere by ``convbin``.)
- ``.rtcm3`` is ``convbin``'s extension for RTCM 3 (another relay format gets ``.rtca``, ``.cmr``).
  RTCM 3 carries no GPS week; ``convbin`` takes it from the file's modification time when no
  ``-tr`` is given, so every exported file's modification time is set to the log time of its
  first bytes.

Parts are read one at a time (memory stays at one part's raw data). A message's sequence number
runs on per topic across parts; a break in the sequence (lost or repeated reads) is reported.

:func:`export_csv` writes decoded tables: GNSS logs per receiver and the event list through
:mod:`rig.data`, CAN roles per bus (with the DBC and role map attached to the session) and
optical-sensor topics streamed batch by batch.

:func:`export_parquet`, :func:`export_mdf4` and :func:`export_mat` read the session through
:func:`iter_groups`: each part's chunks are located from its summary (CRC-checked) and read one at a
time; only the exported channels are taken out of a chunk, through its MessageIndex records, so raw
byte streams are never copied out; JSON topics are parsed in bulk by Arrow's JSON reader, CAN and DAQ
blocks as numpy record arrays. A damaged chunk or an unfinished part is skipped with a warning (the
session reader's :mod:`rig.store.reader` describes it) and every intact chunk is exported.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import struct
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.store.reader import PartScan, find_parts, scan_part
from vsccore.errors import AnalysisError, ConfigError, SessionFileError

__all__ = [
    "CORRECTIONS_STEM",
    "NOVATEL_SUFFIX",
    "ExportKind",
    "ExportReport",
    "ExportedFile",
    "correction_suffix",
    "export_csv",
    "export_raw_gnss",
]

log = logging.getLogger(__name__)

NOVATEL_SUFFIX = ".gps"
"""RTKLIB convbin's extension for NovAtel OEM4/6/7 raw data (``-r nov``)."""
CORRECTIONS_STEM = "corrections"
_CORRECTION_SUFFIXES = {"rtcmv3": ".rtcm3", "rtcm3": ".rtcm3", "rtca": ".rtca", "cmr": ".cmr", "novatel": ".gps"}
_SEQ_MOD = 1 << 32
_CHUNK_ROWS = 131_072
"""Rows (JSON messages, CAN frames, DAQ samples) gathered per topic before a batch is converted and written."""
_CHUNK_BYTES = 8 << 20
"""Payload bytes gathered per topic before a batch is converted (bounds memory whatever the message size)."""


class ExportKind(StrEnum):
    """What an exported file holds."""

    GNSS_RAW = "gnss_raw"
    CORRECTIONS = "corrections"
    TABLE = "table"


@dataclass(frozen=True, slots=True)
class ExportedFile:
    """One file written by an export."""

    path: Path
    kind: ExportKind
    source: str
    """The topic (raw streams) or what the table holds (``gnss rover_a bestpos``)."""
    bytes: int
    records: int
    """Messages concatenated (raw streams) or rows (tables)."""
    first_ns: int | None = None
    last_ns: int | None = None
    parts: int = 0
    """Session parts that contributed (raw streams)."""
    sequence_breaks: int = 0
    """Places where the topic's sequence numbers do not run on by one (lost or repeated reads)."""


@dataclass(frozen=True, slots=True)
class ExportReport:
    """The files an export wrote, and what it noticed."""

    files: tuple[ExportedFile, ...]
    warnings: tuple[str, ...] = ()

    @property
    def total_bytes(self) -> int:
        return sum(f.bytes for f in self.files)


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
        notes = _damage_notes(where, scan)
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


def _check_new(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise SessionFileError(f"{path} already exists (remove it or pass --overwrite)")


def _export_dir(out_dir: Path | str) -> Path:
    """The export directory, made when missing (a SessionFileError naming it when it cannot be)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"{out}: cannot create the export directory: {exc}") from exc
    return out


def _single_file_export(
    path: Path | str, out_dir: Path | str, suffix: str, overwrite: bool,
) -> tuple[SessionStream, Path]:
    """The session's stream and its one export file ``<out_dir>/<session><suffix>``: refused when it exists and
    ``overwrite`` is not set (before the directory is made), the directory made."""
    stream = open_stream(path)
    final = Path(out_dir) / f"{stream.name}{suffix}"
    _check_new(final, overwrite)
    _export_dir(out_dir)
    return stream, final


def _partial(path: Path) -> Path:
    return path.with_name(f".{path.name}.partial")


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
    out = _export_dir(out_dir)
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
                        _check_new(final, overwrite)
                    tmp = _partial(final)
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
            os.replace(_partial(old), _partial(st.path))
            _check_new(st.path, overwrite)
        for st in streams.values():
            os.replace(_partial(st.path), st.path)
    except BaseException:
        for st in streams.values():
            st.file.close()
            _partial(st.path).unlink(missing_ok=True)
        _partial(out / f"{CORRECTIONS_STEM}.rtcm3").unlink(missing_ok=True)
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


# ---------------------------------------------------------------------------------------------
# CSV tables
# ---------------------------------------------------------------------------------------------


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    if isinstance(v, bool | np.bool_):
        return "1" if v else "0"
    if v is None:
        return ""
    if isinstance(v, dict | list):
        return json.dumps(v, separators=(",", ":"))
    return str(v)


def _write_csv(path: Path, header: Sequence[str], columns: Sequence[npt.NDArray[Any] | list[Any]],
               overwrite: bool) -> int:
    _check_new(path, overwrite)
    n = len(columns[0]) if columns else 0
    lists = [c.tolist() if isinstance(c, np.ndarray) else list(c) for c in columns]
    try:
        with open(path, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(header)
            for i in range(n):
                w.writerow([_cell(col[i]) for col in lists])
    except OSError as exc:
        raise SessionFileError(f"{path}: cannot write the CSV file: {exc}") from exc
    return n


def export_csv(path: Path | str, out_dir: Path | str, *, overwrite: bool = False, chunk_rows: int = _CHUNK_ROWS
               ) -> ExportReport:
    """Write the session's decoded tables as CSV files into ``out_dir`` (created if needed).

    - ``gnss_<receiver>_<log>.csv`` for BESTPOS, BESTVEL, HEADING, MARKPOS, MARKTIME and TIME:
      ``time_ns`` (common time base), ``host_ns``, ``valid``, then every field of the log;
    - ``can_<bus>_roles.csv``: ``time_ns, role, value, unit, ok, flags`` (SI, ISO 8855), long
      format in time order, decoded with the session's attached DBC and role map;
    - ``optical_<sensor>.csv`` from the ``/optical/<sensor>`` topics;
    - ``events.csv``: ``time_ns, kind, severity, source, text, start_ns, end_ns, details``.

    The bulk (CAN roles, optical samples) is streamed in batches of ``chunk_rows`` through every part
    (:func:`iter_groups`), each batch in time order, on the recorded time base as in the Parquet, MDF4 and MAT
    exports (CAN: a block's log time plus the interface clock); the GNSS logs and events are read through
    :mod:`rig.data` (only those topics: their times go on UTC from the GPS time with the receivers' leap
    seconds). A table that cannot be made
    (e.g. no DBC attached) is skipped with a warning; damaged chunks are skipped with a warning naming them.
    Raises :class:`~vsccore.errors.SessionFileError` for unreadable parts and existing files.
    """
    from rig.data import load_session

    out = _export_dir(out_dir)
    stream = open_stream(path)
    small = sorted({t for part in stream.parts for t in _plan_part(part).topics.values()
                    if t == T.TOPIC_EVENTS or (t.startswith("/gnss/") and _group_of_topic(t) is not None)})
    session = load_session(path, topics=small)
    files: list[ExportedFile] = []
    warnings: list[str] = list(session.warnings)

    def table(name: str, source: str, header: Sequence[str], cols: Sequence[npt.NDArray[Any] | list[Any]]) -> None:
        p = out / name
        rows = _write_csv(p, header, cols, overwrite)
        files.append(ExportedFile(p, ExportKind.TABLE, source, p.stat().st_size, rows))

    for rx in session.receivers():
        g = session.gnss(rx)
        for log_name in ("bestpos", "bestvel", "heading", "markpos", "marktime", "time"):
            tbl = getattr(g, log_name)
            if len(tbl) == 0:
                continue
            names = list(tbl.columns)
            table(f"gnss_{rx}_{log_name}.csv", f"gnss {rx} {log_name}", ["time_ns", "host_ns", "valid", *names],
                  [tbl.time_ns, tbl.host_ns, tbl.valid, *(tbl.columns[k] for k in names)])
    files.extend(_stream_csv_tables(stream, out, overwrite, warnings, chunk_rows))
    evs = session.events
    if evs:
        header = ["time_ns", "kind", "severity", "source", "text", "start_ns", "end_ns", "details"]
        table("events.csv", "events", header,
              [[t for t, _e in evs], [e.kind.value for _t, e in evs], [e.severity.value for _t, e in evs],
               [e.source for _t, e in evs], [e.text for _t, e in evs], [e.start_ns for _t, e in evs],
               [e.end_ns for _t, e in evs], [dict(e.details) for _t, e in evs]])
    if not files:
        raise AnalysisError(f"{path}: nothing to export as CSV (no decoded GNSS, CAN, optical or event data)")
    return ExportReport(tuple(files), tuple(warnings))


@dataclass(slots=True)
class _CsvStream:
    """One CSV file written batch by batch (Arrow's CSV writer), under a temporary name until complete."""

    path: Path
    source: str
    sink: Any = None
    writer: Any = None
    rows: int = 0


def _stream_csv_tables(stream: SessionStream, out: Path, overwrite: bool, warnings: list[str], chunk_rows: int
                       ) -> list[ExportedFile]:
    """``can_<bus>_roles.csv`` (long) and ``optical_<sensor>.csv``, streamed from the session's frames and samples."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    opts = pcsv.WriteOptions(quoting_style="needed")
    outs: dict[str, _CsvStream] = {}
    role_dec: dict[str, _RoleDecoding | None] = {}
    buses: set[str] = set()

    def write(name: str, source: str, tbl: Any) -> None:
        st = outs.get(name)
        if st is None:
            st = outs[name] = _CsvStream(out / name, source)
            _check_new(st.path, overwrite)
            try:
                st.sink = pa.OSFile(str(_partial(st.path)), "wb")
            except OSError as exc:
                raise SessionFileError(f"{st.path}: cannot write the CSV file: {exc}") from exc
            st.writer = pcsv.CSVWriter(st.sink, tbl.schema, write_options=opts)
        try:
            st.writer.write_table(tbl)
        except OSError as exc:
            raise SessionFileError(f"{st.path}: cannot write the CSV file: {exc}") from exc
        st.rows += tbl.num_rows

    def nullable(v: npt.NDArray[np.float64]) -> Any:
        return pa.array(v, pa.float64(), mask=np.isnan(v))

    try:
        for chunk in iter_groups(stream, topics=["can_*_frames", "optical_*"], roles=False, chunk_rows=chunk_rows):
            if chunk.kind is GroupKind.OPTICAL:
                sensor = chunk.group.removeprefix("optical_")
                order = np.argsort(chunk.time_ns, kind="stable")

                def col(name: str, order: npt.NDArray[np.intp] = order, chunk: GroupChunk = chunk) -> Any:
                    v = chunk.numeric(name)[order] if name in chunk.columns else np.full(len(order), np.nan)
                    return nullable(np.asarray(v, dtype=np.float64))

                valid = chunk.columns["valid"][order] if "valid" in chunk.columns else np.ones(len(order), bool)
                write(f"optical_{sensor}.csv", f"optical {sensor}", pa.table({
                    "time_ns": chunk.time_ns[order], "vx_mps": col("vx_mps"), "vy_mps": col("vy_mps"),
                    "speed_mps": col("speed_mps"), "slip_angle_rad": col("slip_angle_rad"),
                    "valid": valid.astype(np.int8)}))
                continue
            bus = chunk.group.removeprefix("can_").removesuffix("_frames")
            buses.add(bus)
            if bus not in role_dec:
                try:
                    role_dec[bus] = _role_decoding(stream.path, stream.attachments, bus)
                except (AnalysisError, ConfigError) as exc:
                    role_dec[bus] = None
                    warnings.append(f"CAN bus {bus}: roles not exported: {exc}")
            rd = role_dec[bus]
            if rd is None:
                continue
            result, n_carry, _batch = _decode_roles(rd, chunk)
            series = [(role, s) for role, s in result.roles.items() if len(s)]
            parts = []
            for role, s in series:
                mine = np.asarray(s.batch_index, dtype=np.int64) >= n_carry
                if np.any(mine):
                    parts.append((role, s.unit, s.timestamps_ns[mine], s.values[mine], s.ok[mine], s.flags[mine]))
            if not parts:
                continue
            t = np.concatenate([p[2] for p in parts])
            order = np.argsort(t, kind="stable")
            role_names = pa.array([p[0] for p in parts], pa.string())
            unit_names = pa.array([p[1] for p in parts], pa.string())
            which = np.concatenate([np.full(p[2].size, i, dtype=np.int32) for i, p in enumerate(parts)])[order]
            write(f"can_{bus}_roles.csv", f"can {bus} roles", pa.table({
                "time_ns": t[order], "role": role_names.take(pa.array(which)),
                "value": nullable(np.concatenate([p[3] for p in parts])[order]),
                "unit": unit_names.take(pa.array(which)),
                "ok": np.concatenate([p[4] for p in parts])[order].astype(np.int8),
                "flags": np.concatenate([p[5] for p in parts])[order]}))
        for st in outs.values():
            st.writer.close()
            st.sink.close()
            os.replace(_partial(st.path), st.path)
    except BaseException:
        for st in outs.values():
            if st.sink is not None and not st.sink.closed:
                st.sink.close()
            _partial(st.path).unlink(missing_ok=True)
        raise
    for bus in sorted(buses):
        if role_dec.get(bus) is not None and f"can_{bus}_roles.csv" not in outs:
            warnings.append(f"CAN bus {bus}: no role values decoded")
    warnings.extend(w for w in stream.warnings if w not in warnings and w.startswith("CAN bus"))
    return [ExportedFile(st.path, ExportKind.TABLE, st.source, st.path.stat().st_size, st.rows)
            for st in sorted(outs.values(), key=lambda x: x.path.name)]


def _optical_sensor(topic: str) -> str | None:
    try:
        spec, params = T.spec_for_topic(topic)
    except ValueError:
        return None
    return params["sensor"] if spec.pattern == "/optical/{sensor}" else None


# ---------------------------------------------------------------------------------------------
# Streaming table exports: MDF4, Parquet, MAT
# ---------------------------------------------------------------------------------------------


class ExportFormat(StrEnum):
    """Output format of ``rig export --format``."""

    MDF4 = "mdf4"
    PARQUET = "parquet"
    MAT = "mat"
    CSV = "csv"


class GroupKind(StrEnum):
    """What a topic group (one output table / channel group / struct) holds."""

    GNSS = "gnss"
    CAN_FRAMES = "can_frames"
    CAN_ROLES = "can_roles"
    DAQ = "daq"
    OPTICAL = "optical"
    TRUTH = "truth"
    EVENTS = "events"
    TIMEBASE = "timebase"
    RELAY = "relay"


MF4_EXTRA = "vsc-rig[mf4]"
_UNIT_OF_SUFFIX = {
    "deg": "deg", "m": "m", "mps": "m/s", "mps2": "m/s²", "s": "s", "ns": "ns", "rad": "rad", "radps": "rad/s",
    "ppm": "ppm", "bps": "B/s", "hz": "Hz", "v": "V", "pa": "Pa", "kmh": "km/h", "bar": "bar", "n": "N",
}
_SUFFIX_OF_UNIT = {
    "rad/s": "radps", "m/s": "mps", "m/s²": "mps2", "m/s^2": "mps2", "m/s2": "mps2", "rad": "rad", "deg": "deg",
    "Pa": "pa", "m": "m", "N": "n", "s": "s", "V": "v", "km/h": "kmh", "bar": "bar", "deg/s": "degps", "g": "g",
    "Hz": "hz", "1/m": "per_m",
}
_TRUTH_UNITS = {
    "east": "m", "north": "m", "yaw": "rad", "vx": "m/s", "vy": "m/s", "yaw_rate": "rad/s", "ax": "m/s²",
    "ay": "m/s²", "ax_meas": "m/s²", "ay_meas": "m/s²", "roll": "rad", "roll_rate": "rad/s",
    "road_wheel_angle": "rad", "swa": "rad", "wheel_speed": "m/s", "wheel_load": "N", "ltr": "",
}
_WHEELS = ("fl", "fr", "rl", "rr")


def unit_suffix(unit: str) -> str:
    """The column-name suffix of a unit: ``rad/s`` → ``radps``, ``m/s²`` → ``mps2``, ``""`` → ``""``."""
    if not unit or unit == "1":
        return ""
    known = _SUFFIX_OF_UNIT.get(unit)
    if known is not None:
        return known
    return "".join(c if c.isalnum() else "_" for c in unit).strip("_").lower()


def unit_of_column(name: str) -> str:
    """The unit a column name carries in its suffix (``lat_deg`` → ``deg``; none → ``""``)."""
    if name in ("time_ns", "host_ns", "device_ns", "gps_time_ns"):
        return "ns"
    if name == "time_s":
        return "s"
    tail = name.rsplit("_", 1)[-1].lower() if "_" in name else ""
    return _UNIT_OF_SUFFIX.get(tail, "")


@dataclass(slots=True)
class GroupChunk:
    """Rows of one topic group, from one stretch of the session (written as one row group / data block)."""

    group: str
    """Output name: ``gnss_rover_a_bestpos``, ``can_vsc_frames``, ``can_vsc_roles``, ``daq_SimDAQ``, …"""
    kind: GroupKind
    time_ns: npt.NDArray[np.int64]
    columns: dict[str, npt.NDArray[Any]]
    """Column name (unit-suffixed where the quantity has a unit) → values, one per row."""
    units: dict[str, str]
    nulls: dict[str, npt.NDArray[np.bool_]] = field(default_factory=dict)
    """Integer columns that may be null (JSON integers left out or null): their values are int64 (0 where
    null) and this is their null mask (True: null)."""

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])

    @property
    def nullable_int(self) -> frozenset[str]:
        """Names of the integer columns that may be null."""
        return frozenset(self.nulls)

    def numeric(self, name: str) -> npt.NDArray[Any]:
        """Column ``name`` with nullable integers as float64 (NaN for null)."""
        v = self.columns[name]
        mask = self.nulls.get(name)
        if mask is None:
            return v
        out = v.astype(np.float64)
        out[mask] = np.nan
        return out


def _group_of_topic(topic: str) -> tuple[str, GroupKind] | None:
    """The output group of a topic (None: not exported as a table: raw bytes, LocationFix, live role JSON)."""
    if topic == T.TOPIC_EVENTS:
        return "events", GroupKind.EVENTS
    if topic == T.TOPIC_TIMEBASE:
        return "timebase", GroupKind.TIMEBASE
    if topic == T.TOPIC_RELAY_STATS:
        return "relay_stats", GroupKind.RELAY
    if topic == T.TOPIC_SIM_TRUTH:
        return "truth", GroupKind.TRUTH
    try:
        spec, params = T.spec_for_topic(topic)
    except ValueError:
        return None
    if spec.pattern.startswith("/gnss/{receiver}/") and spec.pattern.rsplit("/", 1)[-1] not in ("raw", "fix"):
        return f"gnss_{params['receiver']}_{spec.pattern.rsplit('/', 1)[-1]}", GroupKind.GNSS
    if spec.pattern == "/can/{bus}/frames":
        return f"can_{params['bus']}_frames", GroupKind.CAN_FRAMES
    if spec.pattern == "/daq/{device}/samples":
        return f"daq_{params['device']}", GroupKind.DAQ
    if spec.pattern == "/optical/{sensor}":
        return f"optical_{params['sensor']}", GroupKind.OPTICAL
    return None


def _json_topic_spec(topic: str) -> T.TopicSpec | None:
    """The topic's spec in :data:`rig.core.topics.TOPICS` (fixed topics by name, the others by pattern), or None."""
    try:
        if topic in (T.TOPIC_EVENTS, T.TOPIC_TIMEBASE, T.TOPIC_RELAY_STATS):
            return next(s for s in T.TOPICS if s.pattern == topic)
        return T.spec_for_topic(topic)[0]
    except (ValueError, StopIteration):
        return None


def _schema_types(topic: str) -> dict[str, str]:
    """JSON-schema type of each top-level property of a JSON topic (fixes column types across batches)."""
    spec = _json_topic_spec(topic)
    if spec is None:
        return {}
    doc = spec.schema.document
    props: Mapping[str, Any] = doc.get("properties", {}) if isinstance(doc, Mapping) else {}
    ns = {f.key: f for f in spec.schema.ns_fields}
    out: dict[str, str] = {}
    for name, p in props.items():
        if name in ns:  # an integer-ns time written as two integers: exported as its int64 ns column
            out[ns[name].column] = "integer"
            continue
        t = p.get("type", "object") if isinstance(p, dict) else "object"
        if isinstance(t, list):
            t = next((x for x in t if x != "null"), "object")
        out[name] = str(t)
    return out


_ARROW_JSON_TYPES = ("number", "integer", "boolean", "string")
_Times = npt.NDArray[np.int64] | Sequence[int]


def _topic_ns_fields(topic: str) -> dict[str, T.NsField]:
    """The integer-ns times of a JSON topic by column (``gps_time_ns``: ``gps_time`` as ``{week, tow_ns}``)."""
    spec = _json_topic_spec(topic)
    if spec is None:
        return {}
    return {f.column: f for f in spec.schema.ns_fields}


def _json_columns_arrow(types: Mapping[str, str], data: Sequence[bytes], ns: Mapping[str, T.NsField] | None = None,
                        ) -> tuple[dict[str, npt.NDArray[Any]], dict[str, npt.NDArray[np.bool_]]] | None:
    """The columns of flat JSON messages parsed in bulk by Arrow's JSON reader, typed by the topic's schema;
    None when a message does not fit that (then the rows are decoded one by one, which says what is wrong).
    A column of ``ns`` is read from its two-integer object or, in older files, its plain integer."""
    import pyarrow as pa
    import pyarrow.json as pj

    ns = ns or {}
    if not types or any(t not in _ARROW_JSON_TYPES for t in types.values()):
        return None
    arrow_type = {"number": pa.float64(), "integer": pa.int64(), "boolean": pa.bool_(), "string": pa.string()}
    schema = pa.schema([(n, arrow_type[t]) for n, t in types.items()]
                       + [(f.key, pa.struct([(part, pa.int64()) for part in f.parts])) for f in ns.values()])
    buf = b"\n".join(data)
    try:
        tbl = pj.read_json(pa.BufferReader(buf),
                           read_options=pj.ReadOptions(use_threads=False, block_size=max(len(buf) + 1, 1 << 16)),
                           parse_options=pj.ParseOptions(explicit_schema=schema, unexpected_field_behavior="ignore"))
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return None
    if tbl.num_rows != len(data):  # e.g. a pretty-printed message spread over lines
        return None
    cols: dict[str, npt.NDArray[Any]] = {}
    nulls: dict[str, npt.NDArray[np.bool_]] = {}
    for name, t in types.items():
        col = tbl.column(name)
        f = ns.get(name)
        if f is not None:
            obj = tbl.column(f.key).combine_chunks()
            hi, lo = (np.asarray(obj.field(p).fill_null(0).to_numpy(zero_copy_only=False), dtype=np.int64)
                      for p in f.parts)
            new = np.asarray(obj.is_valid().to_numpy(zero_copy_only=False), dtype=bool)
            old = np.asarray(col.fill_null(0).to_numpy(zero_copy_only=False), dtype=np.int64)
            cols[name] = np.where(new, hi * f.scale + lo, old)
            nulls[name] = ~new & np.asarray(col.is_null().to_numpy(zero_copy_only=False), dtype=bool)
        elif t == "number":
            cols[name] = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)
        elif t == "integer":
            nulls[name] = np.asarray(col.is_null().to_numpy(zero_copy_only=False), dtype=bool)
            cols[name] = np.asarray(col.fill_null(0).to_numpy(zero_copy_only=False), dtype=np.int64)
        elif t == "boolean":
            cols[name] = np.asarray(col.fill_null(False).to_numpy(zero_copy_only=False), dtype=bool)
        else:
            cols[name] = np.asarray(col.fill_null("").to_numpy(zero_copy_only=False), dtype=object)
    return cols, nulls


def _json_columns_python(types: Mapping[str, str], data: Sequence[bytes], ns: Mapping[str, T.NsField] | None = None,
                         ) -> tuple[dict[str, npt.NDArray[Any]], dict[str, npt.NDArray[np.bool_]]]:
    rows: list[dict[str, Any]] = json.loads(b"[" + b",".join(data) + b"]") if data else []
    names = list(types) or sorted({k for r in rows for k in r})
    cols: dict[str, npt.NDArray[Any]] = {}
    nulls: dict[str, npt.NDArray[np.bool_]] = {}
    for name in names:
        t = types.get(name, "object")
        f = (ns or {}).get(name)
        vals = [r.get(name) for r in rows] if f is None else [f.read(r) for r in rows]
        if t == "number":
            cols[name] = np.asarray([np.nan if v is None else float(v) for v in vals], dtype=np.float64)
        elif t == "integer":
            nulls[name] = np.asarray([v is None for v in vals], dtype=bool)
            cols[name] = np.asarray([0 if v is None else int(v) for v in vals], dtype=np.int64)
        elif t == "boolean":
            cols[name] = np.asarray([bool(v) for v in vals], dtype=bool)
        elif t == "string":
            cols[name] = np.asarray(["" if v is None else str(v) for v in vals], dtype=object)
        else:
            cols[name] = np.asarray(["" if v is None else json.dumps(v, separators=(",", ":")) for v in vals],
                                    dtype=object)
    return cols, nulls


def _json_chunk(group: str, kind: GroupKind, topic: str, log_time: _Times, host: _Times,
                data: Sequence[bytes]) -> GroupChunk:
    """The messages of a JSON topic as columns (every property of its schema, typed by it)."""
    types = _schema_types(topic)
    ns = _topic_ns_fields(topic)
    parsed = _json_columns_arrow(types, data, ns)
    fields, nulls = parsed if parsed is not None else _json_columns_python(types, data, ns)
    cols: dict[str, npt.NDArray[Any]] = {"host_ns": np.asarray(host, dtype=np.int64), **fields}
    if kind is GroupKind.EVENTS and "time_ns" in cols:
        cols["event_time_ns"] = cols.pop("time_ns")
        if "time_ns" in nulls:
            nulls["event_time_ns"] = nulls.pop("time_ns")
    units = {k: unit_of_column(k) for k in cols}
    return GroupChunk(group, kind, np.asarray(log_time, dtype=np.int64), cols, units, nulls)


def _can_chunk(group: str, log_time: _Times, data: Sequence[bytes]) -> GroupChunk:
    """Every frame of the blocks; a frame's time is its block's log time (the live time base's estimate for
    the block's first frame) plus its offset from that frame on the interface clock (host clock without one)."""
    recs = [T.unpack_can_block(d) for d in data]
    width = max((r.dtype["data"].shape[0] for r in recs), default=8)
    counts = np.asarray([r.shape[0] for r in recs], dtype=np.int64)
    if recs and all(r.dtype["data"].shape[0] == width for r in recs):  # one copy of the records (checked above)
        rec = np.frombuffer(b"".join([d[T.CAN_BLOCK_HEADER.size:] for d in data]), dtype=T.can_dtype(width))
    else:
        rec = np.concatenate([r if r.dtype["data"].shape[0] == width else _widen(r, width) for r in recs]) \
            if recs else np.zeros(0, dtype=T.can_dtype(8))
    dev = rec["device_ts_ns"].astype(np.int64)
    host = rec["host_ts_ns"].astype(np.int64)
    t = np.zeros(0, dtype=np.int64)
    if rec.shape[0]:
        full = counts > 0
        starts = (np.cumsum(counts) - counts)[full]
        # a block's clock: the interface's when every frame of the block has an interface time, else the host's
        dev_block = np.logical_and.reduceat(dev != T.NO_TIME_NS, starts)
        block = np.repeat(np.arange(int(full.sum())), counts[full])
        clock = np.where(dev_block[block], dev, host)
        t = np.repeat(np.asarray(log_time, dtype=np.int64)[full], counts[full]) + (clock - clock[starts][block])
    flags = rec["flags"].astype(np.uint8)
    cols: dict[str, npt.NDArray[Any]] = {
        "host_ns": host,
        "device_ns": dev,
        "can_id": (rec["can_id"] & np.uint32(0x1FFFFFFF)).astype(np.uint32),
        "extended": (flags & T.CanFlag.EXTENDED) != 0,
        "error_frame": (flags & T.CanFlag.ERROR) != 0,
        "remote_frame": (flags & T.CanFlag.REMOTE) != 0,
        "fd": (flags & T.CanFlag.FD) != 0,
        "rx": (flags & T.CanFlag.RX) != 0,
        "dlc": rec["dlc"].astype(np.uint8),
        "len": rec["len"].astype(np.uint8),
        "data": np.ascontiguousarray(rec["data"]),
    }
    return GroupChunk(group, GroupKind.CAN_FRAMES, t, cols, {k: unit_of_column(k) for k in cols})


def _widen(rec: npt.NDArray[Any], width: int) -> npt.NDArray[Any]:
    out = np.zeros(rec.shape[0], dtype=T.can_dtype(width))
    for name in rec.dtype.names or ():
        if name == "data":
            out["data"][:, : rec.dtype["data"].shape[0]] = rec["data"]
        else:
            out[name] = rec[name]
    return out


@dataclass(frozen=True, slots=True)
class _DaqLayout:
    """What the DAQ blocks of one device share: everything but the first sample index (and the samples)."""

    head: bytes
    """The block's bytes up to its samples, with the first sample index zeroed."""
    names: tuple[str, ...]
    scale: npt.NDArray[np.float64]
    offset: npt.NDArray[np.float64]
    dtype: np.dtype[Any]
    n: int
    rate_hz: float


_DAQ_FIRST = slice(16, 24)
"""Bytes of the first sample index in a DAQ block header (``rig.core.topics.DAQ_BLOCK_HEADER``)."""


def _daq_layout(payload: bytes, known: _DaqLayout | None) -> tuple[_DaqLayout, int]:
    """The block's layout (``known`` when the block shares it: one bytes comparison) and its first sample index."""
    first = int.from_bytes(payload[_DAQ_FIRST], "little", signed=True)
    if known is not None:
        h = len(known.head)
        if (len(payload) == h + known.n * len(known.names) * known.dtype.itemsize
                and payload[:16] == known.head[:16] and payload[24:h] == known.head[24:]):
            return known, first
    b = T.unpack_daq_block(payload)
    n_ch, n = b.samples.shape
    itemsize = b.samples.dtype.itemsize
    start = len(payload) - n_ch * n * itemsize
    head = bytes(payload[:16]) + bytes(8) + bytes(payload[24:start])
    return _DaqLayout(head, b.channel_names, np.asarray(b.scale or (1.0,) * n_ch, dtype=np.float64),
                      np.asarray(b.offset or (0.0,) * n_ch, dtype=np.float64), b.samples.dtype, int(n),
                      b.rate_hz), first


def _daq_chunk(group: str, log_time: _Times, data: Sequence[bytes]) -> GroupChunk:
    """Samples of the blocks in volts (float32, lossless for the DAQ's int16 counts and float32 volts); a
    sample's time is its block's log time plus its index offset at the nominal rate. Consecutive blocks of
    one layout are decoded as one array."""
    runs: list[tuple[_DaqLayout, list[int], list[int], list[bytes]]] = []
    layout: _DaqLayout | None = None
    for t0, d in zip(log_time, data, strict=True):
        lay, first = _daq_layout(d, layout)
        if lay is not layout or not runs:
            runs.append((lay, [], [], []))
            layout = lay
        runs[-1][1].append(t0)
        runs[-1][2].append(first)
        runs[-1][3].append(d)
    names = runs[0][0].names
    idx: list[npt.NDArray[np.int64]] = []
    times: list[npt.NDArray[np.int64]] = []
    volts: list[npt.NDArray[np.float32]] = []
    for lay, t0s, firsts, payloads in runs:
        if lay.names != names:
            raise ValueError(f"DAQ channels change from {list(names)} to {list(lay.names)} within the session")
        k, n, h = len(payloads), lay.n, len(lay.head)
        raw = np.frombuffer(b"".join(p[h:] for p in payloads), dtype=lay.dtype).reshape(k, len(names), n)
        v = raw.transpose(1, 0, 2).reshape(len(names), k * n).astype(np.float64)
        volts.append((v * lay.scale[:, None] + lay.offset[:, None]).astype(np.float32))
        step = np.round(np.arange(n) * (1e9 / lay.rate_hz)).astype(np.int64)
        times.append((np.asarray(t0s, dtype=np.int64)[:, None] + step[None, :]).reshape(-1))
        idx.append((np.asarray(firsts, dtype=np.int64)[:, None] + np.arange(n, dtype=np.int64)[None, :]).reshape(-1))
    vol = np.concatenate(volts, axis=1)
    cols: dict[str, npt.NDArray[Any]] = {"sample_index": np.concatenate(idx)}
    units = {"sample_index": ""}
    for i, name in enumerate(names):
        cols[f"{name}_V"] = vol[i]
        units[f"{name}_V"] = "V"
    return GroupChunk(group, GroupKind.DAQ, np.concatenate(times), cols, units)


def _truth_chunk(data: list[bytes]) -> GroupChunk:
    rec = np.concatenate([T.unpack_truth_block(d)[0] for d in data])
    cols: dict[str, npt.NDArray[Any]] = {"t_drive_s": rec["t_s"].astype(np.float64)}
    units = {"t_drive_s": "s"}
    for name, unit in _TRUTH_UNITS.items():
        v = rec[name]
        sfx = unit_suffix(unit)
        if v.ndim == 2:
            for j, w in enumerate(_WHEELS):
                col = f"{name}_{w}" + (f"_{sfx}" if sfx else "")
                cols[col], units[col] = np.ascontiguousarray(v[:, j], dtype=np.float64), unit
        else:
            col = name + (f"_{sfx}" if sfx else "")
            cols[col], units[col] = v.astype(np.float64), unit
    return GroupChunk("truth", GroupKind.TRUTH, rec["time_ns"].astype(np.int64), cols, units)


@dataclass(slots=True)
class _RoleDecoding:
    bus: str
    decoder: Any
    roles: tuple[tuple[str, str], ...]
    """(role, SI unit) in the role map's order."""
    carry: Any = None
    """The last frame of each identifier of the previous batch (a FrameBatch), decoded again in front of the
    next batch so that counter checks run on across batches as over the whole bus."""


def _session_attachments(parts: Sequence[Path]) -> dict[str, bytes]:
    from mcap.reader import make_reader

    out: dict[str, bytes] = {}
    if not parts:
        return out
    try:
        with open(parts[0], "rb") as f:
            for a in make_reader(f).iter_attachments():
                out[a.name] = bytes(a.data)
    except Exception as exc:  # a damaged summary: no attachments, said in the warning
        log.warning("%s: attachments not readable: %s", parts[0], exc)
    return out


def _role_decoding(path: Path, attachments: Mapping[str, bytes], bus: str) -> _RoleDecoding:
    """The VectorRoleDecoder of ``bus`` from the session's attached DBC and role map (as rig.data finds them)."""
    import tomllib

    from drivers.can.dbc import parse_dbc_text
    from drivers.can.roles import RoleMap
    from drivers.can.vector_decode import VectorRoleDecoder

    dbcs = [n for n in attachments if n.lower().endswith(".dbc")]
    if len(dbcs) != 1:
        raise AnalysisError(f"{path}: cannot choose a DBC attachment (attached: {sorted(attachments)})")
    db = parse_dbc_text(attachments[dbcs[0]].decode("utf-8", "replace"), source=f"{path}:{dbcs[0]}")
    name = f"{bus}.roles.toml"
    if name not in attachments:
        cands = [n for n in attachments if "roles" in n and n.endswith(".toml")]
        if len(cands) != 1:
            raise AnalysisError(f"{path}: no role map for bus {bus!r} among the attachments {sorted(attachments)}")
        name = cands[0]
    try:
        doc = tomllib.loads(attachments[name].decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise AnalysisError(f"{path}: attachment {name!r} is not a readable role map: {exc}") from exc
    table = doc if ("roles" in doc or "checks" in doc) else doc.get("can", {})
    rm = RoleMap.from_mapping(table, db, source=f"{path}:{name}")
    return _RoleDecoding(bus, VectorRoleDecoder(db, rm), tuple((s.role, s.si_unit) for s in rm.roles))


def _decode_roles(rd: _RoleDecoding, frames: GroupChunk) -> tuple[Any, int, Any]:
    """(RoleBatch, frames carried from the previous batch, the FrameBatch decoded) of a CAN frame batch: the
    data frames decoded after the previous batch's last frame of each identifier (``rd.carry``), so that
    counter checks run on across batches as over the whole bus. Batches of a bus must come in receive order."""
    from drivers.can.checks import CAN_EFF_FLAG
    from drivers.can.vector_decode import FrameBatch

    c = frames.columns
    keep = ~(c["error_frame"] | c["remote_frame"])
    ids = np.where(c["extended"][keep], c["can_id"][keep] | np.uint32(CAN_EFF_FLAG), c["can_id"][keep])
    ts, data, dlc = frames.time_ns[keep], c["data"][keep], c["len"][keep].astype(np.int16)
    n_carry = 0
    prev = rd.carry
    if prev is not None and len(prev):
        n_carry = len(prev)
        width = max(data.shape[1], prev.data.shape[1])
        pad = np.zeros((n_carry + data.shape[0], width), dtype=np.uint8)
        pad[:n_carry, : prev.data.shape[1]] = prev.data
        pad[n_carry:, : data.shape[1]] = data
        ts, ids, data = np.concatenate([prev.timestamps_ns, ts]), np.concatenate([prev.ids, ids]), pad
        dlc = np.concatenate([prev.dlc, dlc])
    batch = FrameBatch(ts, ids.astype(np.uint32), data, dlc)
    result = rd.decoder.decode(batch)
    if len(batch):
        _u, last_rev = np.unique(batch.ids[::-1], return_index=True)
        last = np.sort(len(batch) - 1 - last_rev)
        rd.carry = FrameBatch(batch.timestamps_ns[last], batch.ids[last], batch.data[last], batch.dlc[last])
    return result, n_carry, batch


def _roles_chunk(rd: _RoleDecoding, frames: GroupChunk) -> GroupChunk | None:
    """The roles the frames carry, wide: one column per role (``<role>_<unit>``, NaN where a frame does not
    carry it), ``<role>_ok``; one row per frame that carries a role (decoded by :func:`_decode_roles`)."""
    result, n_carry, batch = _decode_roles(rd, frames)
    c = frames.columns
    keep = ~(c["error_frame"] | c["remote_frame"])
    rows = np.unique(np.concatenate([np.asarray(s.batch_index, dtype=np.int64) for s in result.roles.values()]
                                    or [np.zeros(0, dtype=np.int64)]))
    rows = rows[rows >= n_carry]  # the carried frames were exported with their own batch
    if rows.size == 0:
        return None
    cols: dict[str, npt.NDArray[Any]] = {"can_id": c["can_id"][keep][rows - n_carry]}
    units = {"can_id": ""}
    for role, unit in rd.roles:
        s = result.roles.get(role)
        sfx = unit_suffix(unit)
        name = role + (f"_{sfx}" if sfx else "")
        v = np.full(rows.size, np.nan)
        ok = np.zeros(rows.size, dtype=bool)
        if s is not None and len(s.values):
            bi = np.asarray(s.batch_index, dtype=np.int64)
            mine = bi >= n_carry
            pos = np.searchsorted(rows, bi[mine])
            v[pos] = s.values[mine]
            ok[pos] = s.ok[mine]
        cols[name], units[name] = v, unit
        cols[f"{role}_ok"], units[f"{role}_ok"] = ok, ""
    return GroupChunk(f"can_{rd.bus}_roles", GroupKind.CAN_ROLES, batch.timestamps_ns[rows], cols, units)


@dataclass(slots=True)
class _Pending:
    topic: str
    group: str
    kind: GroupKind
    log_time: list[npt.NDArray[np.int64]] = field(default_factory=list)
    host: list[npt.NDArray[np.int64]] = field(default_factory=list)
    data: list[bytes] = field(default_factory=list)
    rows: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class SessionStream:
    """What :func:`iter_groups` read: the session's start, parts and attachments, and what it noticed."""

    path: Path
    parts: tuple[Path, ...]
    name: str
    start_ns: int = 0
    end_ns: int = 0
    attachments: dict[str, bytes] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    dbc_name: str | None = None


def open_stream(path: Path | str) -> SessionStream:
    """The parts of a session, its time span (from the parts' summaries) and attachments."""
    from mcap.reader import make_reader

    parts = tuple(find_parts(path))
    name = parts[0].name.split(".")[0] if parts else Path(path).name
    st = SessionStream(Path(path), parts, name, attachments=_session_attachments(parts))
    lo: int | None = None
    hi: int | None = None
    for p in parts:
        try:
            with open(p, "rb") as f:
                summary = make_reader(f).get_summary()
        except Exception:  # an unfinished or damaged part has no usable summary: its span is learnt while reading
            summary = None
        if summary is not None and summary.statistics is not None and summary.statistics.message_count:
            s = summary.statistics
            lo = s.message_start_time if lo is None else min(lo, s.message_start_time)
            hi = s.message_end_time if hi is None else max(hi, s.message_end_time)
    st.start_ns, st.end_ns = lo or 0, hi or 0
    dbcs = [n for n in st.attachments if n.lower().endswith(".dbc")]
    st.dbc_name = dbcs[0] if len(dbcs) == 1 else None
    return st


# --- reading a part chunk by chunk ----------------------------------------------------------------

_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_CHUNK_HEAD = struct.Struct("<QQQII")
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06


@dataclass(frozen=True, slots=True)
class _ChunkRef:
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
class _PartPlan:
    topics: dict[int, str]
    """Channel id → topic."""
    chunks: list[_ChunkRef]
    scan: PartScan | None
    """The scanner's result when the part's summary was not usable (an unfinished or damaged part)."""


def _plan_part(part: Path) -> _PartPlan:
    """The part's channels and chunks from its summary when that is intact (its CRC checked against the footer),
    else from a scan of the whole part (:func:`rig.store.reader.scan_part`, which skips damaged chunks)."""
    import mmap

    from rig.store.reader import _read_summary

    try:
        with open(part, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            summary: Any = None
            problem: str | None = "empty part"
            if size:
                with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                    summary, problem = _read_summary(mm, True)
    except OSError as exc:
        raise SessionFileError(f"{part}: cannot open session part: {exc}") from exc
    if summary is not None and problem is None and (summary.chunk_indexes or summary.channels):
        chunks = [_ChunkRef(ci.chunk_start_offset, ci.chunk_length, ci.compression, ci.uncompressed_size,
                            ci.message_start_time, ci.message_end_time, dict(ci.message_index_offsets),
                            ci.message_index_length) for ci in summary.chunk_indexes]
        return _PartPlan({cid: ch.topic for cid, ch in summary.channels.items()}, chunks, None)
    scan = scan_part(part, collect=False)
    chunks = [_ChunkRef(c.offset, c.length, c.compression, c.uncompressed_size, c.message_start_time,
                        c.message_end_time) for c in scan.chunks]
    return _PartPlan({cid: ch.topic for cid, ch in scan.channels.items()}, chunks, scan)


class _BadChunkError(Exception):
    """A chunk that cannot be read as its index says (damage): skipped, and the part is scanned to describe it."""


def _read_chunk(fd: int, ref: _ChunkRef) -> tuple[tuple[int, int], bytes]:
    """The chunk's header times and records, decompressed and checked (framing, sizes, CRC); raises
    _BadChunkError."""
    import zlib

    from rig.store.reader import CorruptChunkError, decompress_chunk

    where = f"chunk at offset {ref.offset}"
    raw = os.pread(fd, ref.length, ref.offset)
    try:
        op, ln = _REC.unpack_from(raw, 0)
        if op != _OP_CHUNK or len(raw) != ref.length or 9 + ln != ref.length:
            raise _BadChunkError(f"{where}: not the chunk record its index points at")
        t0, t1, usize, ucrc, clen = _CHUNK_HEAD.unpack_from(raw, 9)
        comp = raw[41 : 41 + clen].decode()
        (rlen,) = struct.unpack_from("<Q", raw, 41 + clen)
        rstart = 49 + clen
        if rstart + rlen != len(raw) or usize != ref.uncompressed_size or comp != ref.compression:
            raise _BadChunkError(f"{where}: header disagrees with its index")
        data = decompress_chunk(comp, raw[rstart:], usize, where)
    except (struct.error, UnicodeDecodeError, CorruptChunkError) as exc:
        raise _BadChunkError(f"{where}: {exc}") from exc
    if len(data) != usize or (ucrc and zlib.crc32(data) != ucrc):
        raise _BadChunkError(f"{where}: CRC or size mismatch (damaged data)")
    return (int(t0), int(t1)), data


@dataclass(slots=True)
class _Messages:
    """One channel's messages in one chunk, in file order."""

    log_time: npt.NDArray[np.int64]
    publish_time: npt.NDArray[np.int64]
    data: list[bytes]
    rows: npt.NDArray[np.int64]
    """Rows each message makes (:func:`_block_rows`)."""


def _chunk_messages(data: bytes, chunk_head: tuple[int, int], wanted: Mapping[int, _Pending]
                    ) -> dict[int, _Messages]:
    """The chunk's messages on ``wanted`` channels, record by record; the chunk's header times must match its
    messages' (as the scanner checks). Raises _BadChunkError."""
    got: dict[int, tuple[list[int], list[int], list[bytes]]] = {}
    end = len(data)
    q = 0
    lo: int | None = None
    hi: int | None = None
    unpack_rec = _REC.unpack_from
    unpack_msg = _MSG.unpack_from
    try:
        while q < end:
            op, ln = unpack_rec(data, q)
            nxt = q + 9 + ln
            if nxt > end:
                raise _BadChunkError(f"record of {ln} bytes at {q} runs past the end of the chunk")
            if op == _OP_MESSAGE:
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
        raise _BadChunkError(f"records do not parse: {exc}") from exc
    if ((lo, hi) if lo is not None else (0, 0)) != chunk_head:
        raise _BadChunkError(f"header times {chunk_head} disagree with its messages' {lo}..{hi}")
    return {cid: _Messages(np.asarray(lt, dtype=np.int64), np.asarray(pt, dtype=np.int64), d,
                           np.asarray([_block_rows(wanted[cid].kind, x) for x in d], dtype=np.int64))
            for cid, (lt, pt, d) in got.items()}


def _gather(buf: npt.NDArray[np.uint8], pos: npt.NDArray[np.int64], dtype: str) -> npt.NDArray[Any]:
    """The little-endian ``dtype`` value at each byte offset ``pos`` of ``buf``."""
    size = np.dtype(dtype).itemsize
    return np.ascontiguousarray(buf[pos[:, None] + np.arange(size)]).view(dtype).reshape(-1)


def _indexed_messages(fd: int, ref: _ChunkRef, data: bytes, chunk_head: tuple[int, int],
                      wanted: Mapping[int, _Pending]) -> dict[int, _Messages] | None:
    """The chunk's messages on ``wanted`` channels found through its MessageIndex records (no walk over the
    other channels' messages), each checked against the record it points at; None when the index is missing
    or does not fit the chunk (then the chunk is walked record by record)."""
    if not ref.message_index or chunk_head != (ref.start_ns, ref.end_ns):
        return None
    base = min(ref.message_index.values())
    region = os.pread(fd, ref.message_index_length, base)
    buf = np.frombuffer(data, dtype=np.uint8)
    out: dict[int, _Messages] = {}
    for cid, pend in wanted.items():
        at = ref.message_index.get(cid)
        if at is None:
            continue
        p = at - base
        try:
            op, ln = _REC.unpack_from(region, p)
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
        if (np.any(buf[off] != _OP_MESSAGE) or np.any(ln_rec < 22) or np.any(ends > len(data))
                or np.any(_gather(buf, off + 9, "<u2") != cid) or np.any(_gather(buf, off + 15, "<u8") != pairs[:, 0])):
            return None
        starts = off + 31
        rows = np.ones(off.shape[0], dtype=np.int64)
        hdr = {GroupKind.CAN_FRAMES: 8, GroupKind.DAQ: 12}.get(pend.kind)
        if hdr is not None:
            fits = ends - starts >= hdr + 4
            if np.any(fits):
                rows[fits] = np.maximum(_gather(buf, starts[fits] + hdr, "<u4").astype(np.int64), 1)
        out[cid] = _Messages(pairs[:, 0], _gather(buf, off + 23, "<u8").astype(np.int64),
                             [data[a:b] for a, b in zip(starts.tolist(), ends.tolist(), strict=True)], rows)
    return out


def _block_rows(kind: GroupKind, payload: bytes) -> int:
    """Rows a message makes: frames of a CAN block, samples of a DAQ block (from their headers), else 1."""
    if kind is GroupKind.CAN_FRAMES and len(payload) >= 12:
        return max(1, int.from_bytes(payload[8:12], "little"))
    if kind is GroupKind.DAQ and len(payload) >= 16:
        return max(1, int.from_bytes(payload[12:16], "little"))
    return 1


def _damage_notes(where: str, scan: PartScan) -> list[str]:
    notes = [f"{where}: {d.describe()}; every intact chunk exported" for d in scan.damage]
    if scan.truncation is not None:
        notes.append(f"{where}: {scan.truncation}; exported up to its last complete record")
    return notes


def iter_groups(
    stream: SessionStream,
    *,
    topics: Sequence[str] | None = None,
    roles: bool = True,
    progress: Callable[[int], None] | None = None,
    chunk_rows: int = _CHUNK_ROWS,
    chunk_bytes: int = _CHUNK_BYTES,
) -> Iterator[GroupChunk]:
    """The session's topic groups as :class:`GroupChunk` batches, streamed chunk by chunk through every part.

    Memory holds one MCAP chunk and, per topic, at most ``chunk_rows`` rows (a CAN frame, a DAQ sample, a
    JSON message) or ``chunk_bytes`` of payload waiting to be converted. Only the channels exported are
    taken out of a chunk (raw byte streams and LocationFix are skipped unread). ``topics``: keep only groups
    whose name or topic matches one of these (``fnmatch`` patterns, e.g. ``gnss_*`` or ``/can/*``). With
    ``roles`` each CAN bus's frames are also decoded into its rig roles with the session's attached DBC and
    role map (a bus without them is noted in ``stream.warnings``). ``progress(log_time_ns)`` is called as
    the reading advances.

    A damaged chunk (or an unfinished part) does not stop the export: every intact chunk is read and
    ``stream.warnings`` names the damage as the session reader describes it (offset, chunk, time span, topics).
    """
    from fnmatch import fnmatchcase

    def wanted(topic: str) -> tuple[str, GroupKind] | None:
        g = _group_of_topic(topic)
        if g is None:
            return None
        if topics and not any(fnmatchcase(g[0], p) or fnmatchcase(topic, p) for p in topics):
            return None
        return g

    role_dec: dict[str, _RoleDecoding | None] = {}

    def convert(p: _Pending) -> Iterator[GroupChunk]:
        if not p.data:
            return
        lt, host, data = np.concatenate(p.log_time), np.concatenate(p.host), p.data
        p.log_time, p.host, p.data, p.rows, p.nbytes = [], [], [], 0, 0
        try:
            if p.kind is GroupKind.CAN_FRAMES:
                ch = _can_chunk(p.group, lt, data)
                del data
                yield ch
                bus = T.spec_for_topic(p.topic)[1]["bus"]
                if roles:
                    if bus not in role_dec:
                        try:
                            role_dec[bus] = _role_decoding(stream.path, stream.attachments, bus)
                        except (AnalysisError, ConfigError) as exc:
                            role_dec[bus] = None
                            stream.warnings.append(f"CAN bus {bus}: roles not exported: {exc}")
                    rd = role_dec[bus]
                    if rd is not None:
                        rc = _roles_chunk(rd, ch)
                        if rc is not None:
                            yield rc
            elif p.kind is GroupKind.DAQ:
                yield _daq_chunk(p.group, lt, data)
            elif p.kind is GroupKind.TRUTH:
                yield _truth_chunk(data)
            else:
                yield _json_chunk(p.group, p.kind, p.topic, lt, host, data)
        except (ValueError, KeyError, TypeError) as exc:
            raise SessionFileError(f"{stream.path}: topic {p.topic}: undecodable message ({exc})") from exc

    by_topic: dict[str, _Pending | None] = {}
    for i, part in enumerate(stream.parts):
        where = f"{part} (part {i + 1} of {len(stream.parts)})"
        plan = _plan_part(part)
        if plan.scan is not None:
            stream.warnings.extend(_damage_notes(where, plan.scan))
        targets: dict[int, _Pending] = {}
        for cid, topic in plan.topics.items():
            if topic not in by_topic:
                g = wanted(topic)
                by_topic[topic] = None if g is None else _Pending(topic, g[0], g[1])
            tgt = by_topic[topic]
            if tgt is not None:
                targets[cid] = tgt
        bad: list[str] = []
        if not plan.chunks and targets:
            # messages outside chunks (an unchunked MCAP file, e.g. written by another tool): read whole
            names = {pend.topic for pend in targets.values()}
            loose = scan_part(part, want=names.__contains__)
            for tm in loose.topics.values():
                pend = by_topic[tm.topic]
                if pend is not None and len(tm):
                    pend.log_time.append(np.asarray(tm.log_time, dtype=np.int64))
                    pend.host.append(np.asarray(tm.publish_time, dtype=np.int64))
                    pend.data.extend(tm.data)
                    yield from convert(pend)
        try:
            f = open(part, "rb")  # noqa: SIM115 - closed by the with statement
        except OSError as exc:
            raise SessionFileError(f"{where}: cannot open session part: {exc}") from exc
        with f:
            fd = f.fileno()
            for ref in plan.chunks:
                if not targets:
                    break
                try:
                    head, data = _read_chunk(fd, ref)
                    msgs = _indexed_messages(fd, ref, data, head, targets)
                    if msgs is None:
                        msgs = _chunk_messages(data, head, targets)
                except _BadChunkError as exc:
                    bad.append(str(exc))
                    continue
                del data
                for cid, m in msgs.items():
                    pend = targets[cid]
                    n = len(m.data)
                    rows_cum = np.cumsum(m.rows)
                    bytes_cum = np.cumsum(np.fromiter((len(d) for d in m.data), dtype=np.int64, count=n))
                    i0 = 0
                    while i0 < n:
                        # as many messages as fit the batch (at least one), then the batch goes out when full
                        r0 = int(rows_cum[i0 - 1]) if i0 else 0
                        b0 = int(bytes_cum[i0 - 1]) if i0 else 0
                        k = min(int(np.searchsorted(rows_cum, r0 + chunk_rows - pend.rows, side="right")),
                                int(np.searchsorted(bytes_cum, b0 + chunk_bytes - pend.nbytes, side="right")))
                        i1 = max(k, i0 + 1) if not pend.data else max(k, i0)
                        if i1 > i0:
                            pend.log_time.append(m.log_time[i0:i1])
                            pend.host.append(m.publish_time[i0:i1])
                            pend.data.extend(m.data[i0:i1])
                            pend.rows += int(rows_cum[i1 - 1]) - r0
                            pend.nbytes += int(bytes_cum[i1 - 1]) - b0
                        if pend.rows >= chunk_rows or pend.nbytes >= chunk_bytes or i1 < n:
                            yield from convert(pend)
                        i0 = i1
                del msgs
                if progress is not None:
                    progress(ref.end_ns)
        if bad:
            # the summary looked intact but a chunk is not: the scanner describes the damage as rig info does
            notes = _damage_notes(where, scan_part(part, collect=False)) or [
                f"{where}: damaged {b}; skipped, every intact chunk exported" for b in bad]
            stream.warnings.extend(notes)
        elif plan.scan is not None:
            notes = _damage_notes(where, plan.scan)
        else:
            notes = []
        for note in notes:
            log.warning("%s", note)
    for rest in by_topic.values():
        if rest is not None:
            yield from convert(rest)
    if progress is not None:
        progress(stream.end_ns)


# --- writers ------------------------------------------------------------------------------------


def _arrow_column(chunk: GroupChunk, name: str) -> Any:
    import pyarrow as pa

    v = chunk.columns[name]
    mask = chunk.nulls.get(name)
    if mask is not None:
        return pa.array(v, pa.int64(), mask=mask)
    if v.dtype == object:
        return pa.array(v.tolist(), pa.string())
    if v.ndim == 2:  # CAN payloads: variable-length binary, trimmed to each frame's length
        lengths = chunk.columns["len"].astype(np.int64)
        mask = np.arange(v.shape[1])[None, :] < lengths[:, None]
        offsets = np.zeros(v.shape[0] + 1, dtype=np.int32)
        np.cumsum(lengths, out=offsets[1:])
        return pa.BinaryArray.from_buffers(pa.binary(), v.shape[0], [None, pa.py_buffer(offsets.tobytes()),
                                                                     pa.py_buffer(v[mask].tobytes())])
    return pa.array(v)


def _arrow_table(chunk: GroupChunk, start_ns: int) -> Any:
    import pyarrow as pa

    arrays = [pa.array(chunk.time_ns, pa.int64()), pa.array((chunk.time_ns - start_ns) / 1e9, pa.float64())]
    fields = [pa.field("time_ns", pa.int64(), metadata={"unit": "ns", "description": "common time base: UTC ns "
                                                                                  "since the Unix epoch"}),
              pa.field("time_s", pa.float64(), metadata={"unit": "s", "description": "seconds since the start "
                                                                                  "of the session"})]
    for name in chunk.columns:
        arr = _arrow_column(chunk, name)
        meta = {"unit": chunk.units.get(name, "")}
        fields.append(pa.field(name, arr.type, metadata=meta))
        arrays.append(arr)
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def _parquet_options(schema: Any) -> dict[str, Any]:
    """Writer options: zstd; dictionaries only for text (tried on every float column they cost three times the
    CPU and grow the file); integer columns delta-encoded (times and counters: a third of the size)."""
    import pyarrow as pa

    text = [f.name for f in schema if pa.types.is_string(f.type)]
    ints = {f.name: "DELTA_BINARY_PACKED" for f in schema if pa.types.is_int64(f.type)}
    return {"compression": "zstd", "compression_level": 1, "use_dictionary": text, "column_encoding": ints}


def _group_path(out: Path, group: str, session: str) -> Path:
    return out / group / f"session={session}" / "part-0.parquet"


def export_parquet(
    path: Path | str,
    out_dir: Path | str,
    *,
    topics: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
) -> ExportReport:
    """Write every topic group of a session as a Parquet dataset, streaming (bounded memory).

    ``<out_dir>/<group>/session=<session name>/part-0.parquet``: one dataset per topic group (a hive
    partitioning by session, so a campaign's sessions append into the same ``<out_dir>``); each
    streaming batch is a row group. Columns: ``time_ns`` (int64, common time base), ``time_s`` (float
    seconds since the session's first message), then the group's columns, unit-suffixed (``lat_deg``,
    ``yaw_rate_radps``), each field's unit also in its Arrow metadata (``unit``). ``progress(done_ns,
    start_ns, end_ns)`` follows the log time read. Raises :class:`~vsccore.errors.SessionFileError` for
    unreadable parts or existing files, :class:`~vsccore.errors.AnalysisError` when nothing is exported.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = Path(out_dir)
    stream = open_stream(path)
    writers: dict[str, tuple[Any, Path, Any]] = {}
    rows: dict[str, int] = {}
    try:
        for chunk in iter_groups(stream, topics=topics, progress=_progress_fn(progress, stream)):
            if not len(chunk):
                continue
            table = _arrow_table(chunk, stream.start_ns)
            w = writers.get(chunk.group)
            if w is None:
                final = _group_path(out, chunk.group, stream.name)
                _check_new(final, overwrite)
                final.parent.mkdir(parents=True, exist_ok=True)
                schema = table.schema.with_metadata({
                    "vsc_rig.session": stream.name, "vsc_rig.group": chunk.group, "vsc_rig.kind": chunk.kind.value,
                    "vsc_rig.session_start_ns": str(stream.start_ns)})
                w = (pq.ParquetWriter(_partial(final), schema, **_parquet_options(schema)), final, schema)
                writers[chunk.group] = w
            try:
                w[0].write_table(pa.Table.from_arrays(table.columns, schema=w[2]))
            except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
                raise SessionFileError(f"{w[1]}: group {chunk.group} changes its columns mid-session: {exc}") from exc
            rows[chunk.group] = rows.get(chunk.group, 0) + len(chunk)
        for w, final, _schema in writers.values():
            w.close()
            os.replace(_partial(final), final)
    except BaseException:
        for w, final, _schema in writers.values():
            w.close()
            _partial(final).unlink(missing_ok=True)
        raise
    if not writers:
        raise AnalysisError(f"{path}: nothing to export as Parquet (no table topics"
                            f"{' matching --topics' if topics else ''})")
    files = [ExportedFile(final, ExportKind.TABLE, g, final.stat().st_size, rows[g])
             for g, (_w, final, _s) in sorted(writers.items())]
    return ExportReport(tuple(files), tuple(stream.warnings))


def _progress_fn(progress: Callable[[int, int, int], None] | None, stream: SessionStream
                 ) -> Callable[[int], None] | None:
    if progress is None:
        return None
    return lambda t: progress(t, stream.start_ns, stream.end_ns)


_MDF_STRING_WIDTH = {"text": 256, "details": 512, "utc_iso": 40}


def _mdf_samples(chunk: GroupChunk, name: str) -> npt.NDArray[Any]:
    v = chunk.columns[name]
    if name in chunk.nullable_int:
        return chunk.numeric(name)
    if v.dtype == object:
        width = _MDF_STRING_WIDTH.get(name, 64)
        return np.asarray([s.encode("utf-8")[:width] for s in v.tolist()], dtype=f"S{width}")
    if v.dtype == bool:
        return v.astype(np.uint8)
    return v


def _can_dataframe(chunk: GroupChunk, width: int) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]:
    """ASAM MDF bus-logging records (``CAN_DataFrame`` with its ``CAN_DataFrame.*`` fields) of the data frames."""
    from can.util import len2dlc

    c = chunk.columns
    keep = ~(c["error_frame"] | c["remote_frame"])
    n = int(np.count_nonzero(keep))
    dt = np.dtype([("CAN_DataFrame.BusChannel", "<u1"), ("CAN_DataFrame.ID", "<u4"), ("CAN_DataFrame.IDE", "<u1"),
                   ("CAN_DataFrame.DLC", "<u1"), ("CAN_DataFrame.DataLength", "<u1"),
                   ("CAN_DataFrame.DataBytes", "<u1", (width,)), ("CAN_DataFrame.Dir", "<u1"),
                   ("CAN_DataFrame.EDL", "<u1"), ("CAN_DataFrame.BRS", "<u1"), ("CAN_DataFrame.ESI", "<u1")])
    rec = np.zeros(n, dtype=dt)
    rec["CAN_DataFrame.BusChannel"] = 1
    rec["CAN_DataFrame.ID"] = c["can_id"][keep]
    rec["CAN_DataFrame.IDE"] = c["extended"][keep]
    ln = c["len"][keep]
    rec["CAN_DataFrame.DataLength"] = ln
    rec["CAN_DataFrame.DLC"] = np.asarray([len2dlc(int(x)) for x in ln.tolist()], dtype=np.uint8) \
        if bool(np.any(ln > 8)) else ln
    data = c["data"][keep]
    w = min(width, data.shape[1])
    rec["CAN_DataFrame.DataBytes"][:, :w] = data[:, :w]
    rec["CAN_DataFrame.Dir"] = np.where(c["rx"][keep], 0, 1)
    rec["CAN_DataFrame.EDL"] = c["fd"][keep]
    return rec, keep


def export_mdf4(
    path: Path | str,
    out_dir: Path | str,
    *,
    topics: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
) -> ExportReport:
    """Write a session as one ASAM MDF 4.10 file ``<out_dir>/<session>.mf4`` through asammdf, streaming.

    - every CAN bus as an ASAM bus-logging channel group (``CAN_DataFrame`` with ``CAN_DataFrame.ID``,
      ``.DataBytes``, … and a CAN bus source), so CANape and asammdf (``MDF.extract_bus_logging``) decode
      the raw frames with the DBC, which is attached to the file;
    - the rig roles decoded from those frames (``can_<bus>_roles``) as physical channels with SI units;
    - GNSS logs, optical sensors, DAQ channels (volts), the simulator's truth, events and time-base
      records as channel groups named after the group, channels ``<group>.<column>`` with their units.

    Every group's time is the session's common time base, in seconds from the file's start time (the
    session's first message, UTC). Appended data goes to asammdf's temporary file, not memory.
    Raises :class:`~vsccore.errors.ConfigError` naming the ``vsc-rig[mf4]`` extra when asammdf is missing.
    """
    try:
        from asammdf import MDF, Signal
        from asammdf.blocks.v4_blocks import SourceInformation
        from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS
    except ImportError:
        raise ConfigError(f"rig export --format mdf4 needs the asammdf package: install the {MF4_EXTRA} extra "
                          f"(pip install '{MF4_EXTRA}')") from None
    from datetime import UTC, datetime

    stream, final = _single_file_export(path, out_dir, ".mf4", overwrite)
    mdf = MDF(version="4.10")
    mdf.header.start_time = datetime.fromtimestamp(stream.start_ns / 1e9, tz=UTC)
    attachment: Any = None
    if stream.dbc_name is not None:
        import hashlib

        dbc_bytes = stream.attachments[stream.dbc_name]
        attachment = (dbc_bytes, Path(stream.dbc_name), hashlib.md5(dbc_bytes).digest())
    groups: dict[str, tuple[int, int]] = {}  # group → (MDF group index, CAN data width or 0)
    rows: dict[str, int] = {}
    try:
        for chunk in iter_groups(stream, topics=topics, progress=_progress_fn(progress, stream)):
            if not len(chunk):
                continue
            t_s = (chunk.time_ns - stream.start_ns) / 1e9
            if chunk.kind is GroupKind.CAN_FRAMES:
                known = groups.get(chunk.group)
                width = known[1] if known else int(chunk.columns["data"].shape[1])
                rec, keep = _can_dataframe(chunk, width)
                if known is None:
                    bus = chunk.group.removeprefix("can_").removesuffix("_frames")
                    source = SourceInformation(source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)
                    source.name = bus
                    source.path = bus
                    mdf.append(Signal(samples=rec, timestamps=t_s[keep], name="CAN_DataFrame", source=source,
                                      attachment=attachment, comment=f"CAN bus {bus}: every data frame"),
                               acq_name=chunk.group, comment=f"vsc-rig {chunk.group}")
                    groups[chunk.group] = (len(mdf.groups) - 1, width)
                else:
                    mdf.extend(known[0], [(t_s[keep], None), (rec, None)])
                rows[chunk.group] = rows.get(chunk.group, 0) + len(rec)
                continue
            names = list(chunk.columns)
            known = groups.get(chunk.group)
            if known is None:
                samples = {n: _mdf_samples(chunk, n) for n in names}
                sigs = [Signal(samples=v, timestamps=t_s, name=f"{chunk.group}.{n}", unit=chunk.units.get(n, ""),
                               comment=n, encoding="utf-8" if v.dtype.kind == "S" else None)
                        for n, v in samples.items()]
                mdf.append(sigs, acq_name=chunk.group, comment=f"vsc-rig {chunk.group} ({chunk.kind.value})")
                groups[chunk.group] = (len(mdf.groups) - 1, 0)
            else:
                mdf.extend(known[0], [(t_s, None)] + [(_mdf_samples(chunk, n), None) for n in names])
            rows[chunk.group] = rows.get(chunk.group, 0) + len(chunk)
        if not groups:
            raise AnalysisError(f"{path}: nothing to export as MDF4 (no table topics"
                                f"{' matching --topics' if topics else ''})")
        tmp = final.with_name(f".{final.stem}.partial.mf4")  # asammdf keeps a .mf4 suffix
        saved = Path(mdf.save(tmp, overwrite=True, compression=1))
        os.replace(saved, final)
    except BaseException:
        final.with_name(f".{final.stem}.partial.mf4").unlink(missing_ok=True)
        raise
    finally:
        mdf.close()
    files = [ExportedFile(final, ExportKind.TABLE, f"{len(groups)} channel groups: " + ", ".join(sorted(groups)),
                          final.stat().st_size, sum(rows.values()))]
    return ExportReport(tuple(files), tuple(stream.warnings))


def export_mat(
    path: Path | str,
    out_dir: Path | str,
    *,
    topics: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
    validation: bool = True,
    version: str = "7.3",
) -> ExportReport:
    """Write a session as the MATLAB file ``<out_dir>/<session>.mat``: MAT v7.3 (HDF5, streamed with bounded
    memory) by default, v5 (scipy.io) with ``version="5"``; :func:`rig.export.mat.export_mat` says how."""
    from rig.export.mat import export_mat as _export_mat

    return _export_mat(path, out_dir, topics=topics, overwrite=overwrite, progress=progress, validation=validation,
                       version=version)
