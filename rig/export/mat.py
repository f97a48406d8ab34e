"""MATLAB export of a session: MAT v7.3 (HDF5 through h5py) streamed with bounded memory, or MAT v5 (scipy.io).

``rig export --format mat`` writes v7.3 by default. A v7.3 MAT file is an HDF5 file behind a 512-byte
userblock whose first 128 bytes are MATLAB's header: 116 bytes of text (``MATLAB 7.3 MAT-file, Platform: …,
Created on: … HDF5 schema 1.00 .``, padded with spaces), 8 bytes of subsystem offset (zero), the version
0x0200 and the endian indicator ``IM``. Inside, the layout MATLAB reads:

- a struct is an HDF5 group with ``MATLAB_class = "struct"`` and ``MATLAB_fields`` (its field names, in order,
  as variable-length arrays of single characters);
- a numeric field is a dataset with ``MATLAB_class`` ``double``, ``single``, ``int64``, ``uint32``, ``uint8``, …;
  a logical field is uint8 with ``MATLAB_class = "logical"`` and ``MATLAB_int_decode = 1``. HDF5 is row-major
  and MATLAB column-major, so every array is stored transposed: MATLAB's N×1 column is HDF5 shape (1, N),
  an N×W matrix (the CAN payloads) HDF5 (W, N);
- text is ``char``: UTF-16 code units as uint16 with ``MATLAB_int_decode = 2``. A unit or a name is a 1×L
  row (HDF5 (L, 1)); the empty text is MATLAB's empty char (its dimensions ``[0 0]`` as uint64 with
  ``MATLAB_empty = 1``). A text column (``sol_status``, an event's ``text``) is an N×W char matrix padded
  with spaces, as MATLAB's ``char({...})`` makes it (``cellstr(s.sol_status)`` gives the cell array of
  strings): a cell array would cost one HDF5 object per row.

Every field is a chunked, gzip-compressed dataset that grows along its rows. Each batch that
:func:`rig.data.stream.iter_groups` yields is buffered per field until it fills whole HDF5 chunks, which are then
written once each (the last, partial chunk at the end), so memory holds at most about one chunk per field
besides the batch being converted, whatever the session's length; HDF5's own chunk cache is turned off.

The structs: one per topic group (as in the Parquet and MDF4 exports) with ``time_ns`` (int64, the common
time base), ``time_s`` (seconds since the session's first message), the group's columns (unit-suffixed
names) and ``units`` (a struct: field → unit, as char); each dataset also carries its unit as the HDF5
attribute ``units``. The raw CAN frames of each bus are the struct ``can_<bus>_frames`` (``can_id``, ``dlc``,
``len``, the payload ``data`` as an N×8 or N×64 uint8 matrix, the flags as logicals, and ``channel``: the
bus's name). ``sideslip`` holds the GNSS reference sideslip, the VSC estimate and the error on one time
vector, and ``session`` the session's name and start.

A nullable integer column (a JSON integer that may be missing) is int64 when its unit is ``ns``, with
``intmin('int64')`` for missing (double would round times to 128 ns); any other is double with NaN.

v5 (``version="5"``, scipy.io): the same structs, but scipy writes each variable whole, so each group is
gathered in memory first, a text column is a cell array of strings, and no v5 variable may exceed 2 GB: use
v7.3 for long sessions.
"""

from __future__ import annotations

import os
import platform
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rig.data.stream import GroupChunk, GroupKind, SessionStream, iter_groups
from rig.export.files import ExportedFile, ExportKind, ExportReport, partial_path, progress_fn, single_file_export
from vsccore.errors import AnalysisError, ConfigError, SessionFileError

__all__ = [
    "MAT73_USERBLOCK_BYTES",
    "NULL_NS",
    "MatVersion",
    "export_mat",
    "mat73_header",
    "mat_name",
]


class MatVersion(StrEnum):
    """MAT-file version written by ``rig export --format mat --mat-version``."""

    V73 = "7.3"
    """HDF5 through h5py, streamed with bounded memory; no size limit per variable (the default)."""
    V5 = "5"
    """scipy.io: each group gathered in memory; at most 2 GB per variable."""


MAT73_USERBLOCK_BYTES = 512
NULL_NS = int(np.iinfo(np.int64).min)
"""A missing integer-nanosecond value in a MAT file (MATLAB's ``intmin('int64')``)."""

CHUNK_BYTES = 64 << 10
"""Uncompressed bytes of one HDF5 chunk (and so of the most a field buffers before writing): the smaller
chunk keeps the peak memory lower at no cost in speed (``benchmarks/bench_export.py``)."""
_GZIP_LEVEL = 1
_MATLAB_CLASS = {
    np.dtype(np.float64): "double", np.dtype(np.float32): "single",
    np.dtype(np.int8): "int8", np.dtype(np.int16): "int16", np.dtype(np.int32): "int32", np.dtype(np.int64): "int64",
    np.dtype(np.uint8): "uint8", np.dtype(np.uint16): "uint16", np.dtype(np.uint32): "uint32",
    np.dtype(np.uint64): "uint64",
}
_SPACE = 0x20
_DAYS = ("Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun")
_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")


def mat73_header(now: datetime | None = None) -> bytes:
    """MATLAB's 512-byte v7.3 userblock: the 116-byte text (``… Created on: Wed Dec 02 19:05:10 2026 HDF5
    schema 1.00 .``, space-padded), 8 zero bytes (no subsystem data), version 0x0200, ``IM``, then zeros."""
    t = now or datetime.now(tz=UTC)
    created = f"{_DAYS[t.weekday()]} {_MONTHS[t.month - 1]} {t:%d %H:%M:%S %Y}"
    text = (f"MATLAB 7.3 MAT-file, Platform: CPython {platform.python_version()}, Created on: {created} "
            "HDF5 schema 1.00 .")
    raw = text.encode("ascii")
    if len(raw) > 116:
        raise ValueError(f"MAT v7.3 header text is {len(raw)} bytes, more than 116: {text!r}")
    return (raw.ljust(116, b" ") + bytes(8) + b"\x00\x02IM").ljust(MAT73_USERBLOCK_BYTES, b"\x00")


def mat_name(name: str) -> str:
    """A MATLAB variable or field name for a group or column: letters, digits and ``_``, a letter first, at
    most 63 characters (``namelengthmax``)."""
    out = "".join(c if c.isascii() and (c.isalnum() or c == "_") else "_" for c in name)
    if not out[:1].isalpha():
        out = "g_" + out
    return out[:63]


def _matlab_column(chunk: GroupChunk, name: str) -> npt.NDArray[Any]:
    """Column ``name`` as it goes into the MAT file: nullable integers as int64 with :data:`NULL_NS` when their
    unit is ns, else as double with NaN; everything else as it is."""
    v = chunk.columns[name]
    mask = chunk.nulls.get(name)
    if mask is None:
        return v
    if chunk.units.get(name) == "ns":
        out = v.astype(np.int64, copy=True)
        out[mask] = NULL_NS
        return out
    return chunk.numeric(name)


def _utf16_matrix(values: npt.NDArray[Any]) -> npt.NDArray[np.uint16]:
    """Strings as an N×W matrix of UTF-16 code units, padded with spaces (W ≥ 1)."""
    strs = ["" if x is None else str(x) for x in values.tolist()]
    u = np.asarray(strs, dtype=np.str_)
    codes = u.view(np.uint32).reshape(len(strs), u.dtype.itemsize // 4) if len(strs) else np.zeros((0, 1), np.uint32)
    if codes.size and int(codes.max()) > 0xFFFF:  # beyond the BMP: surrogate pairs, one string at a time
        enc = [np.frombuffer(s.encode("utf-16-le"), dtype="<u2") for s in strs]
        out = np.full((len(enc), max(1, *(e.size for e in enc))), _SPACE, dtype=np.uint16)
        for i, e in enumerate(enc):
            out[i, : e.size] = e
        return out
    out16 = codes.astype(np.uint16)
    out16[codes == 0] = _SPACE
    return out16


# --- MAT v7.3 -----------------------------------------------------------------------------------


def _set_class(obj: Any, cls: str, int_decode: int | None = None) -> None:
    obj.attrs.create("MATLAB_class", np.bytes_(cls))
    if int_decode is not None:
        obj.attrs.create("MATLAB_int_decode", np.int32(int_decode))


def _write_char(parent: Any, name: str, text: str) -> None:
    """A 1×L char (HDF5 (L, 1) uint16), or MATLAB's empty char for ``""``."""
    if not text:
        ds = parent.create_dataset(name, data=np.zeros(2, dtype=np.uint64))
        _set_class(ds, "char", 2)
        ds.attrs.create("MATLAB_empty", np.uint8(1))
        return
    codes = np.frombuffer(text.encode("utf-16-le"), dtype="<u2").astype(np.uint16)
    _set_class(parent.create_dataset(name, data=codes.reshape(-1, 1)), "char", 2)


def _write_scalar(parent: Any, name: str, value: np.generic) -> None:
    arr = np.asarray(value).reshape(1, 1)
    _set_class(parent.create_dataset(name, data=arr), _MATLAB_CLASS[arr.dtype])


def _set_fields(group: Any, names: Sequence[str]) -> None:
    import h5py

    fields = np.empty(len(names), dtype=h5py.vlen_dtype(np.dtype("S1")))
    for i, n in enumerate(names):
        fields[i] = np.frombuffer(n.encode("ascii"), dtype="S1")
    group.attrs.create("MATLAB_fields", fields)


class _Field:
    """One array field of a struct, growing along MATLAB's rows (HDF5's last axis), written a chunk at a time."""

    def __init__(self, parent: Any, name: str, sample: npt.NDArray[Any], unit: str, *,
                 chunk_bytes: int = CHUNK_BYTES) -> None:
        self.where = f"{parent.name}/{name}"
        self.char = sample.dtype.kind in "OUS"
        self.logical = sample.dtype == np.bool_
        self.dtype: np.dtype[Any]
        if self.char:
            self.dtype, cls, decode, fill = np.dtype(np.uint16), "char", 2, _SPACE
        elif self.logical:
            self.dtype, cls, decode, fill = np.dtype(np.uint8), "logical", 1, 0
        else:
            self.dtype = sample.dtype
            cls = _MATLAB_CLASS.get(sample.dtype, "")
            if not cls:
                raise ValueError(f"{self.where}: no MATLAB class for values of type {sample.dtype}")
            decode, fill = None, 0
        self.fill = fill
        self.matrix = self.char or sample.ndim == 2
        self.width = (_utf16_matrix(sample).shape[1] if self.char else max(int(sample.shape[1]), 1)) \
            if self.matrix else 1
        # text widens as longer strings come: its chunks are at least 32 characters wide, so that they stay few
        chunk_width = max(self.width, 32) if self.char else self.width
        self.chunk_rows = max(64, chunk_bytes // (self.dtype.itemsize * chunk_width))
        self.ds = parent.create_dataset(
            name, shape=(self.width, 0), maxshape=(None if self.matrix else 1, None),
            chunks=(chunk_width, self.chunk_rows), dtype=self.dtype, fillvalue=fill,
            compression="gzip", compression_opts=_GZIP_LEVEL, shuffle=True)
        _set_class(self.ds, cls, decode)
        self.ds.attrs.create("H5PATH", np.bytes_(parent.name))
        if unit:
            self.ds.attrs.create("units", np.bytes_(unit.encode("utf-8")))
        self.rows = 0
        self.pending: list[npt.NDArray[Any]] = []
        self.n_pending = 0

    def append(self, values: npt.NDArray[Any]) -> None:
        if self.char:
            rows = _utf16_matrix(values)
        elif self.logical:
            if values.dtype != np.bool_:
                raise ValueError(f"{self.where}: values of type {values.dtype} where logical ones were")
            rows = values.astype(np.uint8)
        else:
            if values.dtype != self.dtype and not np.can_cast(values.dtype, self.dtype, "safe"):
                raise ValueError(f"{self.where}: values of type {values.dtype} where {self.dtype} ones were")
            rows = values.astype(self.dtype, copy=False)
            if self.matrix != (rows.ndim == 2):
                raise ValueError(f"{self.where}: values of shape {rows.shape[1:]} where "
                                 f"{'a matrix' if self.matrix else 'one value'} per row was")
        self.pending.append(rows)
        self.n_pending += int(rows.shape[0])
        if self.n_pending >= self.chunk_rows:
            self._write(final=False)

    def _write(self, *, final: bool) -> None:
        n = self.n_pending
        k = n if final else n - n % self.chunk_rows
        if k == 0:
            return
        if self.matrix:
            width = max(self.width, *(p.shape[1] for p in self.pending))
            block = np.full((n, width), self.fill, dtype=self.dtype)
            at = 0
            for p in self.pending:
                block[at : at + p.shape[0], : p.shape[1]] = p
                at += p.shape[0]
            if width > self.width:  # earlier rows read as the fill value (space, 0) in the new columns
                self.ds.resize(width, axis=0)
                self.width = width
        else:
            block = np.concatenate(self.pending) if len(self.pending) > 1 else self.pending[0]
        self.ds.resize(self.rows + k, axis=1)
        self.ds[:, self.rows : self.rows + k] = block[:k].T if self.matrix else block[:k].reshape(1, k)
        self.rows += k
        rest = block[k:]
        self.pending = [rest] if rest.shape[0] else []
        self.n_pending = int(rest.shape[0])

    def close(self) -> None:
        self._write(final=True)


class _Struct:
    """A MATLAB struct (an HDF5 group) of row-aligned fields, a ``units`` struct and scalar fields."""

    def __init__(self, parent: Any, name: str, *, chunk_bytes: int = CHUNK_BYTES) -> None:
        self.name = name
        self.group = parent.create_group(name)
        _set_class(self.group, "struct")
        self.fields: dict[str, _Field] = {}
        self.columns: tuple[str, ...] | None = None
        self.units: dict[str, str] = {}
        self.extra: list[str] = []
        self.rows = 0
        self.chunk_bytes = chunk_bytes

    def append(self, columns: Mapping[str, npt.NDArray[Any]], units: Mapping[str, str]) -> None:
        """One batch of rows: ``columns`` (MATLAB field name → values, equal lengths), the same every batch."""
        names = tuple(columns)
        if self.columns is None:
            self.columns = names
            for n, v in columns.items():
                self.units[n] = units.get(n, "")
                self.fields[n] = _Field(self.group, n, v, self.units[n], chunk_bytes=self.chunk_bytes)
        elif names != self.columns:
            raise ValueError(f"{self.group.name}: the fields change mid-session, from {list(self.columns)} to "
                             f"{list(names)}")
        for n, v in columns.items():
            self.fields[n].append(v)
        self.rows += len(next(iter(columns.values())))

    def char(self, name: str, text: str) -> None:
        _write_char(self.group, name, text)
        self.extra.append(name)

    def scalar(self, name: str, value: np.generic) -> None:
        _write_scalar(self.group, name, value)
        self.extra.append(name)

    def close(self) -> None:
        for f in self.fields.values():
            f.close()
        names = list(self.columns or ())
        if names:
            u = self.group.create_group("units")
            _set_class(u, "struct")
            for n in names:
                _write_char(u, n, self.units[n])
            _set_fields(u, names)
            names.append("units")
        _set_fields(self.group, names + self.extra)


def _chunk_columns(chunk: GroupChunk, start_ns: int) -> tuple[dict[str, npt.NDArray[Any]], dict[str, str]]:
    """A batch's MATLAB fields: ``time_ns``, ``time_s``, then the group's columns (names made MATLAB's)."""
    cols: dict[str, npt.NDArray[Any]] = {"time_ns": chunk.time_ns, "time_s": (chunk.time_ns - start_ns) / 1e9}
    units = {"time_ns": "ns", "time_s": "s"}
    for name in chunk.columns:
        key = mat_name(name)
        if key in cols:
            raise ValueError(f"group {chunk.group}: columns {name!r} and another both become the MATLAB field "
                             f"{key!r}")
        cols[key], units[key] = _matlab_column(chunk, name), chunk.units.get(name, "")
    return cols, units


def _bus_of(group: str) -> str:
    return group.removeprefix("can_").removesuffix("_frames")


_SIDESLIP_ROLES = ("yaw_rate", "lat_accel", "vsc_beta_estimate")
"""The CAN roles the sideslip struct needs: the gyro and the lateral accelerometer (the reference's IMU) and the
VSC's estimate."""


def _sideslip_series(inp: Any) -> tuple[Any, npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(reference, estimate, error) of :func:`rig.evaluate.validate.validate_session` with its defaults (RTS reference,
    the recorded ``[validation]`` table, the CAN ``vsc_beta_estimate``), computed as it computes them but without
    the rest of validation (manoeuvres, scores, the optical cross-check, the steering reconstruction, whose
    working memory on a one-hour session is 1.5 GB). ``tests/inspect/test_export_mat_memory.py`` holds the two
    equal."""
    from rig.analysis.metrics import error_series
    from rig.evaluate.validate import session_estimate, session_reference

    ref, _imu = session_reference(inp)
    est, _source = session_estimate(inp, ref.t)
    return ref, est, error_series(est, ref.beta)


def _sideslip(stream: SessionStream, warnings: list[str]) -> tuple[dict[str, npt.NDArray[Any]], dict[str, str]] | None:
    """The reference sideslip, the VSC estimate and the error on one time vector (``rig validate``'s), or None
    with a warning when the session lacks what it needs.

    Memory: the session is read with ``load_inputs(bounded_memory=True)`` (only the GNSS logs, the events and
    the CAN roles asked for; each bus decoded a batch of blocks at a time) and only the reference and the
    estimate are computed (:func:`_sideslip_series`), not the whole validation (its peak memory against the
    full path: ``benchmarks/bench_export.py``).
    """
    try:
        from rig.data.inputs import load_inputs

        inp = load_inputs(stream.path, optical=False, truth=False, bounded_memory=True, can_roles=_SIDESLIP_ROLES)
        ref, est, err = _sideslip_series(inp)
    except (AnalysisError, ConfigError, SessionFileError) as exc:
        warnings.append(f"sideslip: reference and estimate not exported: {exc}")
        return None
    t_ns = inp.t0_ns + np.round(np.asarray(ref.t, dtype=np.float64) * 1e9).astype(np.int64)
    cols: dict[str, npt.NDArray[Any]] = {
        "time_ns": t_ns,
        "time_s": (t_ns - stream.start_ns) / 1e9,
        "reference_rad": np.asarray(ref.beta, dtype=np.float64),
        "reference_sigma_rad": np.asarray(ref.sigma, dtype=np.float64),
        "estimate_rad": np.asarray(est, dtype=np.float64),
        "error_rad": np.asarray(err, dtype=np.float64),
    }
    units = {"time_ns": "ns", "time_s": "s", "reference_rad": "rad", "reference_sigma_rad": "rad",
             "estimate_rad": "rad", "error_rad": "rad"}
    return cols, units


def _utc_text(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns / 1e9, tz=UTC).isoformat()


def _export_v73(stream: SessionStream, final: Path, topics: Sequence[str] | None,
                progress: Callable[[int, int, int], None] | None, validation: bool,
                chunk_bytes: int) -> ExportReport:
    import h5py

    tmp = partial_path(final)
    structs: dict[str, _Struct] = {}
    warnings: list[str] = []
    try:
        # rdcc_nbytes=0: whole chunks are written once each, so HDF5's chunk cache would only hold memory
        with h5py.File(tmp, "w", userblock_size=MAT73_USERBLOCK_BYTES, libver="earliest", rdcc_nbytes=0) as f:
            for chunk in iter_groups(stream, topics=topics, progress=progress_fn(progress, stream)):
                if not len(chunk):
                    continue
                name = mat_name(chunk.group)
                st = structs.get(name)
                if st is None:
                    st = structs[name] = _Struct(f, name, chunk_bytes=chunk_bytes)
                    if chunk.kind is GroupKind.CAN_FRAMES:
                        st.char("channel", _bus_of(chunk.group))
                try:
                    st.append(*_chunk_columns(chunk, stream.start_ns))
                except ValueError as exc:
                    raise SessionFileError(f"{final}: {exc}") from exc
            warnings.extend(stream.warnings)
            for s in structs.values():  # the buffered rows go out before the sideslip is computed
                s.close()
            if validation:
                side = _sideslip(stream, warnings)
                if side is not None:
                    st = structs["sideslip"] = _Struct(f, "sideslip", chunk_bytes=chunk_bytes)
                    st.append(*side)
                    st.close()
            if not structs:
                raise AnalysisError(f"{stream.path}: nothing to export as MAT (no table topics"
                                    f"{' matching --topics' if topics else ''})")
            rows = {n: s.rows for n, s in structs.items()}
            st = structs["session"] = _Struct(f, "session")
            st.char("name", stream.name)
            st.scalar("start_ns", np.int64(stream.start_ns))
            st.char("start_utc", _utc_text(stream.start_ns))
            st.close()
        with open(tmp, "r+b") as fh:
            fh.write(mat73_header())
        os.replace(tmp, final)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise SessionFileError(f"{final}: cannot write the MAT file: {exc}") from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    files = [ExportedFile(final, ExportKind.TABLE, f"MAT v7.3, {len(structs)} structs: " + ", ".join(sorted(structs)),
                          final.stat().st_size, sum(rows.values()))]
    return ExportReport(tuple(files), tuple(warnings))


# --- MAT v5 -------------------------------------------------------------------------------------


def _gather(chunks: Sequence[tuple[dict[str, npt.NDArray[Any]], dict[str, str]]]) -> dict[str, Any]:
    first, units = chunks[0]
    st: dict[str, Any] = {}
    for n, v0 in first.items():
        parts = [c[0][n] for c in chunks]
        if v0.ndim == 2:  # CAN payloads: widened to the widest batch
            w = max(p.shape[1] for p in parts)
            v = np.zeros((sum(p.shape[0] for p in parts), w), dtype=v0.dtype)
            at = 0
            for p in parts:
                v[at : at + p.shape[0], : p.shape[1]] = p
                at += p.shape[0]
        else:
            v = np.concatenate(parts)
        if v.dtype == object:
            v = np.asarray([str(x) for x in v.tolist()], dtype=object)
        st[n] = v
    st["units"] = dict(units)
    return st


def _export_v5(stream: SessionStream, final: Path, topics: Sequence[str] | None,
               progress: Callable[[int, int, int], None] | None, validation: bool) -> ExportReport:
    from scipy.io.matlab import savemat

    gathered: dict[str, list[tuple[dict[str, npt.NDArray[Any]], dict[str, str]]]] = {}
    buses: dict[str, str] = {}
    for chunk in iter_groups(stream, topics=topics, progress=progress_fn(progress, stream)):
        if not len(chunk):
            continue
        name = mat_name(chunk.group)
        try:
            gathered.setdefault(name, []).append(_chunk_columns(chunk, stream.start_ns))
        except ValueError as exc:
            raise SessionFileError(f"{final}: {exc}") from exc
        if chunk.kind is GroupKind.CAN_FRAMES:
            buses[name] = _bus_of(chunk.group)
    warnings = list(stream.warnings)
    structs: dict[str, dict[str, Any]] = {}
    rows: dict[str, int] = {}
    for name, chunks in gathered.items():
        structs[name] = _gather(chunks)
        if name in buses:
            structs[name]["channel"] = buses[name]
        rows[name] = sum(len(c[0]["time_ns"]) for c in chunks)
    del gathered
    if validation:
        side = _sideslip(stream, warnings)
        if side is not None:
            structs["sideslip"] = {**side[0], "units": side[1]}
            rows["sideslip"] = int(side[0]["time_ns"].size)
    if not structs:
        raise AnalysisError(f"{stream.path}: nothing to export as MAT (no table topics"
                            f"{' matching --topics' if topics else ''})")
    structs["session"] = {"name": stream.name, "start_ns": np.int64(stream.start_ns),
                          "start_utc": _utc_text(stream.start_ns)}
    tmp = partial_path(final)
    try:
        savemat(tmp, structs, do_compression=True, long_field_names=True, oned_as="column")
        os.replace(tmp, final)
    except (OSError, ValueError) as exc:  # ValueError: a variable past v5's 2 GB
        tmp.unlink(missing_ok=True)
        raise SessionFileError(f"{final}: cannot write the MAT v5 file: {exc}"
                               + ("; use --mat-version 7.3" if isinstance(exc, ValueError) else "")) from exc
    files = [ExportedFile(final, ExportKind.TABLE, f"MAT v5, {len(structs)} structs: " + ", ".join(sorted(structs)),
                          final.stat().st_size, sum(rows.values()))]
    return ExportReport(tuple(files), tuple(warnings))


def export_mat(
    path: Path | str,
    out_dir: Path | str,
    *,
    topics: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
    validation: bool = True,
    version: MatVersion | str = MatVersion.V73,
    chunk_bytes: int = CHUNK_BYTES,
) -> ExportReport:
    """Write a session as the MATLAB file ``<out_dir>/<session>.mat``: one struct per topic group (the raw CAN
    frames of each bus included), each with its units, plus ``sideslip`` (with ``validation``: the reference,
    the estimate and the error on one time vector) and ``session``. See the module's description of the layout.

    ``version`` ``"7.3"`` (default) streams into HDF5 with bounded memory (``chunk_bytes``: the uncompressed
    size of one HDF5 chunk, the most any field buffers); ``"5"`` writes through scipy.io, holding each group in
    memory. ``progress(done_ns, start_ns, end_ns)`` follows the log time read. Raises
    :class:`~vsccore.errors.ConfigError` for an unknown version,
    :class:`~vsccore.errors.SessionFileError` for unreadable parts, an existing file or a failed write, and
    :class:`~vsccore.errors.AnalysisError` when nothing is exported.
    """
    try:
        ver = MatVersion(str(version))
    except ValueError:
        raise ConfigError(f"rig export --mat-version: {version!r} is not one of "
                          f"{', '.join(v.value for v in MatVersion)}") from None
    stream, final = single_file_export(path, out_dir, ".mat", overwrite)
    if ver is MatVersion.V5:
        return _export_v5(stream, final, topics, progress, validation)
    return _export_v73(stream, final, topics, progress, validation, chunk_bytes)
