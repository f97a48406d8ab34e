"""Parquet datasets of a session: one per topic group, hive-partitioned by session, streamed chunk by chunk."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rig.data.stream import GroupChunk, iter_groups, open_stream
from rig.export.files import ExportedFile, ExportKind, ExportReport, check_new, partial_path, progress_fn
from vsccore.errors import AnalysisError, SessionFileError


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
        for chunk in iter_groups(stream, topics=topics, progress=progress_fn(progress, stream)):
            if not len(chunk):
                continue
            table = _arrow_table(chunk, stream.start_ns)
            w = writers.get(chunk.group)
            if w is None:
                final = _group_path(out, chunk.group, stream.name)
                check_new(final, overwrite)
                final.parent.mkdir(parents=True, exist_ok=True)
                schema = table.schema.with_metadata({
                    "vsc_rig.session": stream.name, "vsc_rig.group": chunk.group, "vsc_rig.kind": chunk.kind.value,
                    "vsc_rig.session_start_ns": str(stream.start_ns)})
                w = (pq.ParquetWriter(partial_path(final), schema, **_parquet_options(schema)), final, schema)
                writers[chunk.group] = w
            try:
                w[0].write_table(pa.Table.from_arrays(table.columns, schema=w[2]))
            except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
                raise SessionFileError(f"{w[1]}: group {chunk.group} changes its columns mid-session: {exc}") from exc
            rows[chunk.group] = rows.get(chunk.group, 0) + len(chunk)
        for w, final, _schema in writers.values():
            w.close()
            os.replace(partial_path(final), final)
    except BaseException:
        for w, final, _schema in writers.values():
            w.close()
            partial_path(final).unlink(missing_ok=True)
        raise
    if not writers:
        raise AnalysisError(f"{path}: nothing to export as Parquet (no table topics"
                            f"{' matching --topics' if topics else ''})")
    files = [ExportedFile(final, ExportKind.TABLE, g, final.stat().st_size, rows[g])
             for g, (_w, final, _s) in sorted(writers.items())]
    return ExportReport(tuple(files), tuple(stream.warnings))

