"""CSV tables of a session: GNSS logs per receiver, CAN roles per bus, optical data and events, batch by batch."""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.data.stream import (
    CHUNK_ROWS,
    GroupChunk,
    GroupKind,
    RoleDecoding,
    SessionStream,
    decode_roles,
    group_of_topic,
    iter_groups,
    open_stream,
    role_decoding,
)
from rig.export.files import ExportedFile, ExportKind, ExportReport, check_new, export_dir, partial_path
from rig.store.chunks import plan_part
from vsccore.errors import AnalysisError, ConfigError, SessionFileError


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
    check_new(path, overwrite)
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


def export_csv(path: Path | str, out_dir: Path | str, *, overwrite: bool = False, chunk_rows: int = CHUNK_ROWS
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

    out = export_dir(out_dir)
    stream = open_stream(path)
    small = sorted({t for part in stream.parts for t in plan_part(part).topics.values()
                    if t == T.TOPIC_EVENTS or (t.startswith("/gnss/") and group_of_topic(t) is not None)})
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
    role_dec: dict[str, RoleDecoding | None] = {}
    buses: set[str] = set()

    def write(name: str, source: str, tbl: Any) -> None:
        st = outs.get(name)
        if st is None:
            st = outs[name] = _CsvStream(out / name, source)
            check_new(st.path, overwrite)
            try:
                st.sink = pa.OSFile(str(partial_path(st.path)), "wb")
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
                    role_dec[bus] = role_decoding(stream.path, stream.attachments, bus)
                except (AnalysisError, ConfigError) as exc:
                    role_dec[bus] = None
                    warnings.append(f"CAN bus {bus}: roles not exported: {exc}")
            rd = role_dec[bus]
            if rd is None:
                continue
            result, n_carry, _batch = decode_roles(rd, chunk)
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
            os.replace(partial_path(st.path), st.path)
    except BaseException:
        for st in outs.values():
            if st.sink is not None and not st.sink.closed:
                st.sink.close()
            partial_path(st.path).unlink(missing_ok=True)
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

