"""The streaming group reader: a session's topics as column chunks per group (GNSS logs, CAN frames and roles,
DAQ blocks, optical, truth), chunk by chunk with bounded memory; every exporter reads through it."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.store.chunks import BadChunkError, chunk_messages, indexed_messages, plan_part, read_chunk
from rig.store.reader import PartScan, find_parts, scan_part
from vsccore.errors import AnalysisError, ConfigError, SessionFileError

log = logging.getLogger(__name__)


CHUNK_ROWS = 131_072
"""Rows (JSON messages, CAN frames, DAQ samples) gathered per topic before a batch is converted and written."""


CHUNK_BYTES = 8 << 20
"""Payload bytes gathered per topic before a batch is converted (bounds memory whatever the message size)."""


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


def group_of_topic(topic: str) -> tuple[str, GroupKind] | None:
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


def can_chunk(group: str, log_time: _Times, data: Sequence[bytes]) -> GroupChunk:
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
class RoleDecoding:
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


def role_decoding(path: Path, attachments: Mapping[str, bytes], bus: str) -> RoleDecoding:
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
    return RoleDecoding(bus, VectorRoleDecoder(db, rm), tuple((s.role, s.si_unit) for s in rm.roles))


def decode_roles(rd: RoleDecoding, frames: GroupChunk) -> tuple[Any, int, Any]:
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


def roles_chunk(rd: RoleDecoding, frames: GroupChunk) -> GroupChunk | None:
    """The roles the frames carry, wide: one column per role (``<role>_<unit>``, NaN where a frame does not
    carry it), ``<role>_ok``; one row per frame that carries a role (decoded by :func:`decode_roles`)."""
    result, n_carry, batch = decode_roles(rd, frames)
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


_ROW_COUNT_AT = {GroupKind.CAN_FRAMES: 8, GroupKind.DAQ: 12}
"""Byte offset of the u32 frame / sample count in a CAN or DAQ block (the other groups: a row per message)."""


def damage_notes(where: str, scan: PartScan) -> list[str]:
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
    chunk_rows: int = CHUNK_ROWS,
    chunk_bytes: int = CHUNK_BYTES,
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
        g = group_of_topic(topic)
        if g is None:
            return None
        if topics and not any(fnmatchcase(g[0], p) or fnmatchcase(topic, p) for p in topics):
            return None
        return g

    role_dec: dict[str, RoleDecoding | None] = {}

    def convert(p: _Pending) -> Iterator[GroupChunk]:
        if not p.data:
            return
        lt, host, data = np.concatenate(p.log_time), np.concatenate(p.host), p.data
        p.log_time, p.host, p.data, p.rows, p.nbytes = [], [], [], 0, 0
        try:
            if p.kind is GroupKind.CAN_FRAMES:
                ch = can_chunk(p.group, lt, data)
                del data
                yield ch
                bus = T.spec_for_topic(p.topic)[1]["bus"]
                if roles:
                    if bus not in role_dec:
                        try:
                            role_dec[bus] = role_decoding(stream.path, stream.attachments, bus)
                        except (AnalysisError, ConfigError) as exc:
                            role_dec[bus] = None
                            stream.warnings.append(f"CAN bus {bus}: roles not exported: {exc}")
                    rd = role_dec[bus]
                    if rd is not None:
                        rc = roles_chunk(rd, ch)
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
        plan = plan_part(part)
        if plan.scan is not None:
            stream.warnings.extend(damage_notes(where, plan.scan))
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
                    head, data = read_chunk(fd, ref)
                    counts = {cid: _ROW_COUNT_AT.get(p.kind) for cid, p in targets.items()}
                    msgs = indexed_messages(fd, ref, data, head, counts)
                    if msgs is None:
                        msgs = chunk_messages(data, head, counts)
                except BadChunkError as exc:
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
            notes = damage_notes(where, scan_part(part, collect=False)) or [
                f"{where}: damaged {b}; skipped, every intact chunk exported" for b in bad]
            stream.warnings.extend(notes)
        elif plan.scan is not None:
            notes = damage_notes(where, plan.scan)
        else:
            notes = []
        for note in notes:
            log.warning("%s", note)
    for rest in by_topic.values():
        if rest is not None:
            yield from convert(rest)
    if progress is not None:
        progress(stream.end_ns)

