"""A recorded session read back into numpy arrays on the common time base.

:func:`load_session` scans every part once (in order; a crashed last part is read up to its last
complete chunk) and keeps each topic's payloads; the accessors decode on first use and cache:

- :meth:`Session.gnss` — BESTPOS/BESTVEL/HEADING/MARKPOS/MARKTIME/TIME of a receiver as column
  tables with validity; times from the log header's GPS time converted to UTC with the
  receiver-reported leap seconds; from the decoded topics, or (``source="raw"``) decoded again from
  the receiver's raw port bytes;
- :meth:`Session.can_frames` / :meth:`Session.can_roles` — every frame of a bus, and its rig roles
  through :class:`drivers.can.vector_decode.VectorRoleDecoder` (DBC and role map from the session's
  attachments unless given); frame times mapped interface clock → host → GPS by lower-envelope
  estimators (:class:`rig.core.timebase.ClockEstimator`) fitted over the whole session. Host → GPS comes
  from the reference receiver's BESTPOS/BESTVEL/TIME logs less each log's known latency, as the live
  time base takes it off: the receiver's output latency (``receivers[].output_latency_s``, or the
  simulated receivers') and the log's serial transmission time at the recorded baud rate;
- :meth:`Session.daq`, :meth:`Session.analog`, :meth:`Session.optical` — DAQ sample blocks joined
  into channels (volts), scaled analog channels and optical-sensor quantities; sample times from
  the sync pulse (edges on a DAQ channel matched with MARKTIME) when asked, fitted per unbroken run
  of sample indices (an acquisition: indices restart after a DAQ reconnect) with a flagged
  host-clock fallback for a run without sync edges, else from the blocks' log times;
- :meth:`Session.truth` — the simulator's ground truth (simulated sessions) as a
  :class:`sim_devices.vehicle.truth.GroundTruth` with its times;
- :attr:`Session.events`, :attr:`Session.config`, :attr:`Session.metadata`, attachments.

Every series carries ``time_ns`` (common time base: UTC ns since the Unix epoch) and, where the
file has it, ``host_ns`` (host receive time). :func:`align` samples one series at another's times.
"""

from __future__ import annotations

import json
import logging
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.core.timebase import OEM7_OUTPUT_LATENCY_S, ClockEstimator, SyncFit, align_sync_pulses, causality_bound_ns
from rig.store.reader import DamagedRegion, PartScan, TopicMessages, find_parts, scan_part
from vsccore.errors import AnalysisError, ConfigError, DecodeError, RigError, SessionFileError
from vsccore.gpstime import GPS_EPOCH_UNIX_NS

if TYPE_CHECKING:
    from cantools.database.can import Database

    from drivers.analog import AnalogChannelSpec
    from drivers.can.roles import RoleMap
    from drivers.can.vector_decode import FrameBatch, RoleSeries
    from drivers.optical import OpticalSample, OpticalSensorSpec
    from sim_devices.vehicle.truth import GroundTruth

__all__ = [
    "CanFrames",
    "DaqData",
    "DaqSegment",
    "GnssData",
    "Session",
    "Table",
    "Truth",
    "align",
    "load_session",
]

log = logging.getLogger(__name__)

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

_NS = 1_000_000_000
GOOD_SOLUTION = "SOL_COMPUTED"
RTK_FIXED_TYPES = frozenset({"NARROW_INT", "L1_INT", "WIDE_INT", "INS_RTKFIXED"})


def _default_include(topic: str) -> bool:
    """Topics kept by default: everything but the bulky per-frame role JSON and the raw GNSS/relay bytes."""
    return not (topic.endswith("/roles") and topic.startswith("/can/")) and not topic.endswith("/raw")


# ---------------------------------------------------------------------------------------------
# Result types
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Table:
    """Decoded JSON messages of one topic as columns (numbers float64 with NaN for null, ints int64, text str)."""

    topic: str
    time_ns: IntArray
    """Common time base (UTC ns since the Unix epoch)."""
    host_ns: IntArray
    """Host receive time (the message's publish_time)."""
    columns: Mapping[str, npt.NDArray[Any]]
    valid: BoolArray

    def __len__(self) -> int:
        return int(self.time_ns.shape[0])

    def __getitem__(self, name: str) -> npt.NDArray[Any]:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"{self.topic}: no column {name!r}; columns: {sorted(self.columns)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self.columns


@dataclass(frozen=True, slots=True)
class GnssData:
    """The decoded logs of one receiver (empty tables for logs it did not record)."""

    receiver: str
    bestpos: Table
    bestvel: Table
    heading: Table
    markpos: Table
    marktime: Table
    time: Table

    @property
    def rtk_fixed(self) -> BoolArray:
        """Per BESTPOS row: a valid solution with an integer-ambiguity (RTK fixed) position type."""
        if len(self.bestpos) == 0:
            return np.zeros(0, dtype=bool)
        return self.bestpos.valid & np.isin(self.bestpos["pos_type"], list(RTK_FIXED_TYPES))


@dataclass(frozen=True, slots=True)
class CanFrames:
    """Every frame of one bus, in receive order (error and remote frames included; see ``flags``)."""

    bus: str
    records: npt.NDArray[Any]
    """Structured array (:func:`rig.core.topics.can_dtype`): device_ts_ns, host_ts_ns, can_id, flags, dlc, len, data."""
    time_ns: IntArray
    """Common time base of each frame."""
    time_source: str
    """How ``time_ns`` was obtained: ``interface`` (interface clock → host → GPS), ``host`` (host → GPS) or
    ``host_unmapped`` (host time: the session has no GNSS to map it)."""

    def __len__(self) -> int:
        return int(self.records.shape[0])

    def batch(self, *, data_frames_only: bool = True) -> FrameBatch:
        """The frames as a :class:`drivers.can.vector_decode.FrameBatch` stamped with ``time_ns``."""
        from drivers.can.checks import CAN_EFF_FLAG
        from drivers.can.vector_decode import FrameBatch

        rec = self.records
        keep = np.ones(rec.shape[0], dtype=bool)
        if data_frames_only:
            keep = (rec["flags"] & (T.CanFlag.ERROR | T.CanFlag.REMOTE)) == 0
        r = rec[keep]
        ids = r["can_id"].astype(np.uint32) & np.uint32(0x1FFFFFFF)
        ext = (r["flags"] & T.CanFlag.EXTENDED) != 0
        ids = np.where(ext, ids | np.uint32(CAN_EFF_FLAG), ids).astype(np.uint32)
        return FrameBatch(self.time_ns[keep], ids, np.ascontiguousarray(r["data"]), r["len"].astype(np.int16))


@dataclass(frozen=True, slots=True)
class DaqSegment:
    """An unbroken run of DAQ sample indices (an acquisition, or its part between lost samples), timed on its own."""

    first_index: int
    stop_index: int
    """One past the last sample index."""
    time_source: str
    """``sync_pulse``, ``host`` (too few sync edges: the host clock on the GNSS time base), ``host_unmapped``
    (the host clock itself: no GNSS mapping) or ``log_time``."""
    sync: SyncFit | None = None
    note: str = ""
    """Why the segment is not synchronised (empty when it is)."""

    @property
    def n_samples(self) -> int:
        return self.stop_index - self.first_index


@dataclass(frozen=True, slots=True)
class DaqData:
    """One DAQ device's samples joined over all blocks (sample-index order, duplicates removed)."""

    device: str
    rate_hz: float
    channel_names: tuple[str, ...]
    sample_index: IntArray
    volts: FloatArray
    """Shape (n_channels, n_samples)."""
    time_ns: IntArray
    time_source: str
    """``sync_pulse`` (every segment: sample index → GPS from its sync edges and MARKTIME), ``sync_pulse+host``
    (some segments fell back to the host clock), ``host`` (all did), or ``log_time`` (no sync channel asked:
    a line per segment through the blocks' log times)."""
    sync: SyncFit | None = None
    """The sync fit of the segment with the most matched edges (each segment's own is in ``segments``)."""
    lost: int = 0
    """Samples missing between the first and the last index (gaps in the sample index)."""
    segments: tuple[DaqSegment, ...] = ()
    """Unbroken runs of sample indices, each timed on its own (in index order)."""

    def __len__(self) -> int:
        return int(self.sample_index.shape[0])

    @property
    def synced(self) -> BoolArray:
        """Per sample: its time comes from the sync pulse (False where a segment fell back to the host clock)."""
        out = np.zeros(self.sample_index.shape, dtype=bool)
        for seg in self.segments:
            if seg.time_source == "sync_pulse":
                out[(self.sample_index >= seg.first_index) & (self.sample_index < seg.stop_index)] = True
        return out

    def channel(self, name: str) -> FloatArray:
        try:
            return self.volts[self.channel_names.index(name)]
        except ValueError:
            raise ConfigError(f"DAQ {self.device}: no channel {name!r}; channels: {list(self.channel_names)}") from None


@dataclass(frozen=True, slots=True)
class Truth:
    """Simulator ground truth with its times on the common time base."""

    time_ns: IntArray
    truth: GroundTruth


# ---------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------


def align(
    t_ns: npt.ArrayLike, src_t_ns: npt.ArrayLike, values: npt.ArrayLike, *, max_gap_ns: int | None = None
) -> FloatArray:
    """``values`` (sampled at ``src_t_ns``) linearly interpolated at ``t_ns``; NaN outside the data
    and, with ``max_gap_ns``, where the neighbouring source samples are further apart than that."""
    t = np.asarray(t_ns, dtype=np.int64)
    st = np.asarray(src_t_ns, dtype=np.int64)
    v = np.asarray(values, dtype=np.float64)
    if st.size == 0:
        return np.full(t.shape, np.nan)
    base = int(st[0])
    out = np.interp((t - base).astype(np.float64), (st - base).astype(np.float64), v, left=np.nan, right=np.nan)
    if max_gap_ns is not None and st.size > 1:
        j = np.clip(np.searchsorted(st, t), 1, st.size - 1)
        gap = st[j] - st[j - 1]
        out[gap > max_gap_ns] = np.nan
    return out


def _json_rows(data: Sequence[bytes]) -> list[dict[str, Any]]:
    if not data:
        return []
    rows: list[dict[str, Any]] = json.loads(b"[" + b",".join(data) + b"]")
    return rows


def _columns(rows: Sequence[Mapping[str, Any]], topic: str) -> dict[str, npt.NDArray[Any]]:
    keys: dict[str, None] = {}
    for r in rows[:50]:
        keys.update(dict.fromkeys(r))
    for r in rows:
        if len(r) != len(keys) or any(k not in keys for k in r):
            keys.update(dict.fromkeys(r))
    spec, _params = _spec(topic)
    props: Mapping[str, Any] = spec.schema.document.get("properties", {}) if spec is not None else {}
    # integer-ns times written as two integers ({week, tow_ns}, {sec, nsec}) or, in older files, as one
    # plain integer: the same int64 ns column either way (rig.core.topics.NsField)
    ns_by_key = {k: f for f in (spec.schema.ns_fields if spec is not None else ()) for k in (f.key, f.column)}
    if rows:
        # a field left out while unknown (rig.core.topics.encode_record) is still a column, all unknown
        for k, sub in props.items():
            if k not in keys and (sub.get("type") in ("number", "integer") or k in ns_by_key):
                keys[k] = None
    cols: dict[str, npt.NDArray[Any]] = {}
    for k in keys:
        ns = ns_by_key.get(k)
        if ns is not None:
            if ns.column not in cols:
                ints = [ns.read(r) for r in rows]
                if any(v is None for v in ints):
                    cols[ns.column] = np.asarray([np.nan if v is None else float(v) for v in ints], dtype=np.float64)
                    log.debug("%s: integer column %s has nulls; stored as float", topic, ns.column)
                else:
                    cols[ns.column] = np.asarray(ints, dtype=np.int64)
            continue
        vals = [r.get(k) for r in rows]
        declared = props.get(k, {}).get("type")
        sample = next((v for v in vals if v is not None), None)
        if (declared == "number" and not isinstance(sample, dict | list)) or (declared == "integer" and sample is None):
            cols[k] = np.asarray([np.nan if v is None else float(v) for v in vals], dtype=np.float64)
        elif isinstance(sample, bool):
            cols[k] = np.asarray([bool(v) for v in vals], dtype=bool)
        elif isinstance(sample, int) and all(v is None or (isinstance(v, int) and not isinstance(v, bool))
                                             for v in vals):
            if any(v is None for v in vals):
                cols[k] = np.asarray([np.nan if v is None else float(v) for v in vals], dtype=np.float64)
                if k.endswith("_ns"):
                    log.debug("%s: integer column %s has nulls; stored as float", topic, k)
            else:
                cols[k] = np.asarray(vals, dtype=np.int64)
        elif isinstance(sample, int | float):
            cols[k] = np.asarray([np.nan if v is None else float(v) for v in vals], dtype=np.float64)
        elif isinstance(sample, str) or sample is None:
            cols[k] = np.asarray(["" if v is None else str(v) for v in vals], dtype=str)
        else:
            arr = np.empty(len(vals), dtype=object)
            arr[:] = vals
            cols[k] = arr
    return cols


def _unflatten(flat: Mapping[str, str]) -> dict[str, Any]:
    """Inverse of :func:`rig.core.topics.flatten_metadata` (JSON values decoded, other strings kept)."""
    out: dict[str, Any] = {}
    for key, text in flat.items():
        try:
            value: Any = json.loads(text)
        except ValueError:
            value = text
        node = out
        parts = key.split(".")
        for p in parts[:-1]:
            nxt = node.get(p)
            if not isinstance(nxt, dict):
                nxt = {}
                node[p] = nxt
            node = nxt
        node[parts[-1]] = value
    return out


# ---------------------------------------------------------------------------------------------
# The session
# ---------------------------------------------------------------------------------------------


class Session:
    """A recorded session (use :func:`load_session`)."""

    def __init__(
        self, path: Path, scans: Sequence[PartScan], warnings: Sequence[str], gnss_min_latency_s: float | None = None
    ) -> None:
        self.path = path
        self._gnss_min_latency_s = gnss_min_latency_s
        self.parts: tuple[Path, ...] = tuple(s.path for s in scans)
        self.warnings: tuple[str, ...] = tuple(warnings)
        """Problems tolerated while reading (a truncated last part, damaged chunks skipped)."""
        self.damage: tuple[tuple[Path, DamagedRegion], ...] = tuple((s.path, d) for s in scans for d in s.damage)
        """Damaged regions skipped while reading, by part (every intact chunk was read)."""
        self._topics: dict[str, list[TopicMessages]] = {}
        self._counts: dict[str, int] = {}
        for s in scans:
            for topic, tm in s.topics.items():
                self._topics.setdefault(topic, []).append(tm)
            for cid, n in s.channel_counts.items():
                ch = s.channels[cid]
                self._counts[ch.topic] = self._counts.get(ch.topic, 0) + n
        self.metadata: dict[str, dict[str, str]] = {}
        """Metadata records by name (first part's; part-end records are in :attr:`part_ends`)."""
        self.part_ends: list[dict[str, str]] = []
        for i, s in enumerate(scans):
            for m, _ref in s.metadata:
                if m.name == T.METADATA_PART_END:
                    self.part_ends.append(dict(m.metadata))
                elif i == 0 or m.name not in self.metadata:
                    self.metadata[m.name] = dict(m.metadata)
        self.attachments: dict[str, bytes] = {}
        if scans:
            for a, _ref in scans[0].attachments:
                self.attachments[a.name] = bytes(a.data)
        self._cache: dict[Any, Any] = {}

    # --- basics -----------------------------------------------------------------------------

    def damage_events(self) -> list[T.Event]:
        """Each damaged region skipped while reading, as a ``/rig/events``-style warning (time span, topics)."""
        return [d.event(path) for path, d in self.damage]

    @property
    def topic_counts(self) -> dict[str, int]:
        """Messages per topic in the file (all topics, loaded or not)."""
        return dict(self._counts)

    @property
    def config(self) -> dict[str, Any]:
        """The session configuration recorded in the file (nested)."""
        return _unflatten(self.metadata.get(T.METADATA_SESSION, {}))

    @property
    def vehicle(self) -> dict[str, Any]:
        return _unflatten(self.metadata.get(T.METADATA_VEHICLE, {}))

    @property
    def calibration(self) -> dict[str, Any]:
        """The calibration in force during the session."""
        return _unflatten(self.metadata.get(T.METADATA_CALIBRATION, {}))

    def _messages(self, topic: str) -> tuple[IntArray, IntArray, list[bytes]]:
        tms = self._topics.get(topic, [])
        log_t = np.fromiter((t for tm in tms for t in tm.log_time), dtype=np.int64)
        pub_t = np.fromiter((t for tm in tms for t in tm.publish_time), dtype=np.int64)
        data = [d for tm in tms for d in tm.data]
        return log_t, pub_t, data

    def message_times(self, topic: str) -> tuple[IntArray, IntArray]:
        """(log_time, publish_time) of every message of ``topic``, in file order (used by :mod:`rig.core.quality`)."""
        log_t, pub_t, _data = self._messages(topic)
        return log_t, pub_t

    def _table(self, topic: str, valid: Callable[[dict[str, npt.NDArray[Any]]], BoolArray] | None = None) -> Table:
        key = ("table", topic)
        if key in self._cache:
            cached: Table = self._cache[key]
            return cached
        log_t, pub_t, data = self._messages(topic)
        try:
            rows = _json_rows(data)
        except ValueError as exc:
            raise SessionFileError(f"{self.path}: topic {topic}: undecodable JSON message ({exc})") from exc
        order = np.argsort(log_t, kind="stable")
        rows = [rows[i] for i in order.tolist()]
        try:
            cols = _columns(rows, topic)
        except ValueError as exc:
            raise SessionFileError(f"{self.path}: topic {topic}: {exc}") from exc
        v = valid(cols) if valid is not None and rows else np.ones(len(rows), dtype=bool)
        tbl = Table(topic, log_t[order], pub_t[order], cols, np.asarray(v, dtype=bool))
        self._cache[key] = tbl
        return tbl

    @cached_property
    def events(self) -> list[tuple[int, T.Event]]:
        """``/rig/events`` as (log time, event), in time order."""
        log_t, _pub, data = self._messages(T.TOPIC_EVENTS)
        evs = [T.Event.from_json(r) for r in _json_rows(data)]
        order = np.argsort(log_t, kind="stable").tolist()
        return [(int(log_t[i]), evs[i]) for i in order]

    def timebase_records(self) -> Table:
        """``/rig/timebase`` quality records."""
        return self._table(T.TOPIC_TIMEBASE)

    # --- GNSS -------------------------------------------------------------------------------

    def receivers(self) -> list[str]:
        """Receivers with decoded GNSS topics in the file."""
        out: set[str] = set()
        for topic in self._counts:
            spec, params = _spec(topic)
            if spec is not None and "receiver" in params and not topic.endswith("/raw"):
                out.add(params["receiver"])
        return sorted(out)

    @cached_property
    def leap_seconds(self) -> int | None:
        """GPS − UTC (s) reported by a receiver's TIME log (None if no receiver reported it)."""
        for r in self.receivers():
            tbl = self._table(T.gnss_time(r))
            if len(tbl) and "leap_seconds" in tbl:
                vals = tbl["leap_seconds"]
                vals = vals[np.isfinite(vals.astype(np.float64))]
                if vals.size:
                    return int(vals[-1])
        return None

    def gps_to_utc(self, gps_ns: npt.ArrayLike) -> IntArray:
        """GPS ns → common time base (needs :attr:`leap_seconds`)."""
        if self.leap_seconds is None:
            raise AnalysisError(f"{self.path}: no TIME log with leap seconds; GPS time cannot be put on UTC")
        return np.asarray(gps_ns, dtype=np.int64) + (GPS_EPOCH_UNIX_NS - self.leap_seconds * _NS)

    def _gnss_table(self, topic: str, valid: Callable[[dict[str, npt.NDArray[Any]]], BoolArray] | None) -> Table:
        tbl = self._table(topic, valid)
        if len(tbl) and "gps_time_ns" in tbl and self.leap_seconds is not None:
            g = tbl["gps_time_ns"]
            if g.dtype.kind == "i":
                order = np.argsort(g, kind="stable")
                cols = {k: v[order] for k, v in tbl.columns.items()}
                return Table(topic, self.gps_to_utc(g[order]), tbl.host_ns[order], cols, tbl.valid[order])
        return tbl

    def gnss(self, receiver: str, *, source: str = "decoded") -> GnssData:
        """The decoded logs of ``receiver``; times from the GPS time of each log (UTC when leap seconds are known).

        Validity: BESTPOS/BESTVEL/HEADING/MARKPOS rows with ``sol_status == SOL_COMPUTED``.

        ``source="decoded"`` (default) reads the decoded topics the recorder wrote. ``source="raw"``
        decodes the logs again from the receiver's raw port bytes (``/gnss/<receiver>/raw``) with the
        columnar decoder :func:`drivers.novatel.columns.decode_columns`, and gives tables with the same
        columns and dtypes; see :meth:`gnss_from_raw`.

        Raises:
            AnalysisError: no such receiver (or, for ``raw``, no raw stream of it).
            ConfigError: ``source`` is neither ``decoded`` nor ``raw``.
        """
        if source == "raw":
            return self.gnss_from_raw(receiver)
        if source != "decoded":
            raise ConfigError(f"{self.path}: GNSS source {source!r} is neither 'decoded' nor 'raw'")
        if receiver not in self.receivers():
            raise AnalysisError(f"{self.path}: no GNSS data for receiver {receiver!r}; receivers: {self.receivers()}")

        def sol_ok(cols: dict[str, npt.NDArray[Any]]) -> BoolArray:
            return np.asarray(cols["sol_status"] == GOOD_SOLUTION) if "sol_status" in cols else np.ones(0, bool)

        def all_ok(cols: dict[str, npt.NDArray[Any]]) -> BoolArray:
            return np.ones(len(next(iter(cols.values()))), dtype=bool)

        return GnssData(
            receiver=receiver,
            bestpos=self._gnss_table(T.gnss_bestpos(receiver), sol_ok),
            bestvel=self._gnss_table(T.gnss_bestvel(receiver), sol_ok),
            heading=self._gnss_table(T.gnss_heading(receiver), sol_ok),
            markpos=self._gnss_table(T.gnss_markpos(receiver), sol_ok),
            marktime=self._gnss_table(T.gnss_marktime(receiver), all_ok),
            time=self._gnss_table(T.gnss_time(receiver), all_ok),
        )

    def raw_gnss_receivers(self) -> list[str]:
        """Receivers whose raw port bytes are in the file."""
        out = set()
        for topic, n in self._counts.items():
            spec, params = _spec(topic)
            if n and spec is not None and "receiver" in params and topic.endswith("/raw"):
                out.add(params["receiver"])
        return sorted(out)

    def _raw_chunks(self, receiver: str) -> tuple[IntArray, list[bytes]]:
        """The raw byte chunks of a receiver in receive order, with their host receive times."""
        topic = T.gnss_raw(receiver)
        if topic in self._topics:
            _log_t, pub, data = self._messages(topic)
        else:  # not loaded (raw topics are left out by default): read that topic alone again
            tms = [tm for p in self.parts for tm in scan_part(p, want=topic.__eq__).topics.values()]
            pub = np.fromiter((t for tm in tms for t in tm.publish_time), dtype=np.int64)
            data = [d for tm in tms for d in tm.data]
        order = np.argsort(pub, kind="stable")
        return pub[order], [data[i] for i in order.tolist()]

    def gnss_from_raw(self, receiver: str) -> GnssData:
        """The logs of ``receiver`` decoded again from its raw port bytes, as :meth:`gnss` gives the decoded ones.

        The chunks of ``/gnss/<receiver>/raw`` are joined in receive order and decoded in bulk by
        :func:`drivers.novatel.columns.decode_columns` (the same values as the receiver session's
        per-message decoder); the tables have the decoded topics' columns and dtypes (built by
        :func:`gnss_record_columns`). ``host_ns`` of a log is the receive time of the chunk that
        completed its frame; ``time_ns`` its GPS time on UTC with :attr:`leap_seconds` (else the
        receiver's own TIME logs in the raw stream; with neither, ``host_ns`` through
        :meth:`host_to_utc`). Unlike the decoded topics this also holds logs configured ``raw_only``.
        Frames that failed their CRC or were cut off (e.g. at a reconnect) are skipped and logged.

        Raises:
            AnalysisError: the file has no raw stream of ``receiver``.
        """
        from drivers.novatel.columns import MISSING_INT, decode_columns

        key = ("gnss_raw", receiver)
        if key in self._cache:
            cached: GnssData = self._cache[key]
            return cached
        if receiver not in self.raw_gnss_receivers():
            raise AnalysisError(f"{self.path}: no raw GNSS stream {T.gnss_raw(receiver)}; receivers with one: "
                                f"{self.raw_gnss_receivers()}")
        pub, chunks = self._raw_chunks(receiver)
        chunk_end = np.cumsum([len(c) for c in chunks], dtype=np.int64)
        batch = decode_columns(b"".join(chunks), logs=_RAW_GNSS_LOGS)
        if any(batch.rejected.values()):
            log.info("%s: raw stream of %s: frames skipped: %s", self.path, receiver,
                     {k.value: v for k, v in batch.rejected.items() if v})
        records = gnss_record_columns(batch)
        leap = self.leap_seconds
        if leap is None:
            t_leap = records["time"].columns.get("leap_seconds")
            ok = t_leap[t_leap != MISSING_INT] if t_leap is not None else np.zeros(0, dtype=np.int64)
            leap = int(ok[-1]) if ok.size else None
        topics = {"bestpos": T.gnss_bestpos(receiver), "bestvel": T.gnss_bestvel(receiver),
                  "heading": T.gnss_heading(receiver), "markpos": T.gnss_markpos(receiver),
                  "marktime": T.gnss_marktime(receiver), "time": T.gnss_time(receiver)}
        tables: dict[str, Table] = {}
        for kind, topic in topics.items():
            rec = records[kind]
            host = pub[np.searchsorted(chunk_end, rec.frame_end - 1, side="right")]
            order = np.argsort(rec.gps_ns, kind="stable")
            cols = {k: v[order] for k, v in rec.columns.items()} if len(order) else {}
            if leap is not None:
                time_ns = rec.gps_ns[order] + (GPS_EPOCH_UNIX_NS - leap * _NS)
            else:
                time_ns = self.host_to_utc(host[order])[0]
            valid = (np.asarray(cols["sol_status"] == GOOD_SOLUTION) if "sol_status" in cols
                     else np.ones(len(order), dtype=bool))
            tables[kind] = Table(topic, time_ns, host[order], cols, valid)
        out = GnssData(receiver=receiver, **tables)
        self._cache[key] = out
        return out

    # --- GNSS latency and the host clock --------------------------------------------------------

    @cached_property
    def _receiver_configs(self) -> dict[str, dict[str, Any]]:
        recs = self.config.get("receivers")
        out: dict[str, dict[str, Any]] = {}
        if isinstance(recs, list):
            for rc in recs:
                if isinstance(rc, dict) and isinstance(rc.get("name"), str):
                    out[rc["name"]] = rc
        return out

    def _warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings = (*self.warnings, text)
            log.warning("%s", text)

    @property
    def gnss_min_latency_ns(self) -> int | None:
        """The constant GNSS log latency given to :func:`load_session` as ``gnss_min_latency_s`` (None:
        not given; each log's known latency is then :meth:`gnss_log_latency_ns`)."""
        return None if self._gnss_min_latency_s is None else round(self._gnss_min_latency_s * 1e9)

    def gnss_output_latency_ns(self, receiver: str) -> int:
        """A receiver's fixed output latency (data time → first byte on the port), which the lower envelope of
        its own pairs cannot see: ``receivers[].output_latency_s`` of the recorded configuration; else, for the
        receiver whose logs make the host map, measured from the DAQ's sync pulse (:attr:`measured_output_latency`);
        else the OEM7 figure
        :data:`OEM7_OUTPUT_LATENCY_S` with a warning that the host-timed streams carry its uncertainty."""
        configured = self._configured_latency_ns(receiver)
        if configured is not None:
            return configured
        measured, why = self.measured_output_latency
        raw = self._raw_host_clock
        if measured is not None and raw is not None and raw.name == f"gnss:{receiver}":
            return measured  # the DAQ measures the receiver whose logs make the host map, and only that one
        if measured is not None:
            why = "measured for the reference receiver only"
        self._warn(f"{self.path}: receiver {receiver!r}: output latency neither configured nor measured ({why}); "
                   f"taken as OEM7's typical {OEM7_OUTPUT_LATENCY_S * 1e3:.0f} ms (20-30 ms typical, 50 ms at most): "
                   "times of CAN and DAQ data on the host clock carry that uncertainty")
        return round(OEM7_OUTPUT_LATENCY_S * 1e9)

    def _configured_latency_ns(self, receiver: str) -> int | None:
        v = self._receiver_configs.get(receiver, {}).get("output_latency_s")
        if isinstance(v, int | float) and not isinstance(v, bool):
            return round(float(v) * 1e9)
        return None

    @cached_property
    def measured_output_latency(self) -> tuple[int | None, str]:
        """The reference receiver's output latency measured from the data (ns; None: not measurable) and why not.

        The receiver writes its logs a constant time after their GPS time, which shifts every (GPS time,
        host time) pair alike, so the host → GPS map fitted to them is early by exactly that. The DAQ sees
        it: each block's last sample is on GPS time through the sync pulse and MARKTIME/MARK1TIME (no host
        clock involved), and a block cannot reach the host before that sample was taken. Through the map
        fitted with no output latency, the blocks arrive early by the latency less the most prompt block's
        delivery time: :func:`rig.core.timebase.causality_bound_ns` of those arrivals is the latency, short by
        the DAQ's prompt delivery (a lower bound; tens of µs on a USB DAQ).
        """
        daq_cfg = self.config.get("daq")
        device = daq_cfg.get("device") if isinstance(daq_cfg, Mapping) else None
        if not isinstance(device, str):
            return None, "no DAQ"
        bound, why = self.daq_causality_ns(device, raw=True)
        return (None, why) if bound is None else (round(bound), "")

    def daq_causality_ns(self, device: str, *, raw: bool = False) -> tuple[float | None, str]:
        """How early the host → GPS map puts ``device``'s blocks (ns; None: not judged) and why not.

        Each block's last sample is timed by the sync pulse against MARKTIME/MARK1TIME (GPS time; the host
        map does not enter), and the block cannot reach the host before that sample was taken: where its host
        receive time, mapped to GPS time, lies earlier, the map is early by at least that much
        (:func:`rig.core.timebase.causality_bound_ns`). Only blocks whose segment is synchronised count.
        ``raw``: through the map fitted without any unconfigured output latency (:attr:`measured_output_latency`),
        else through :attr:`host_clock`.
        """
        daq_cfg = self.config.get("daq")
        if not isinstance(daq_cfg, Mapping) or not daq_cfg.get("sync_channel"):
            return None, "no sync channel"
        if daq_cfg.get("device") not in (None, device) or device not in self.daq_devices():
            return None, "not the configured DAQ"
        est = self._raw_host_clock if raw else self.host_clock
        if est is None or self.leap_seconds is None:
            return None, "no host → GPS map"
        marks = [r for r in self.receivers() if len(self.gnss(r).marktime) or len(self.gnss(r).markpos)]
        if not marks:
            return None, "no MARKTIME/MARKPOS"
        try:
            d = self.daq(device, sync_channel=str(daq_cfg["sync_channel"]), receiver=marks[0])
            _first, last, host = self.daq_blocks(device)
        except RigError as exc:
            return None, f"not judged ({exc})"
        if not len(d):
            return None, "no samples"
        pos = np.minimum(np.searchsorted(d.sample_index, last), len(d) - 1)
        ok = (d.sample_index[pos] == last) & d.synced[pos]
        if not ok.any():
            return None, "no block timed by the sync pulse"
        arrival = self.gps_to_utc(est.mapping().inverse_ns(host[ok]))
        bound = causality_bound_ns(d.time_ns[pos[ok]], arrival)
        return bound, "" if bound is not None else "too few blocks"

    def gnss_log_latency_ns(self, receiver: str, log_name: str, gps_ns: npt.ArrayLike) -> IntArray:
        """The known part of the latency of each ``log_name`` log (e.g. ``BESTPOS``) of ``receiver`` at
        ``gps_ns``: the receiver's output latency plus the log's serial transmission time (frame bytes ×
        10 bits / the port's baud rate; the host stamps a read when its last byte is in), as the live
        time base removes them. Binary logs have their fixed length; ASCII logs are measured in the
        receiver's raw byte stream. Problems (no baud, no raw stream) are noted in :attr:`warnings`.
        """
        g = np.asarray(gps_ns, dtype=np.int64)
        return self.gnss_output_latency_ns(receiver) + self._log_tx_ns(receiver, log_name, g)

    def _log_tx_ns(self, receiver: str, log_name: str, gps_ns: IntArray) -> IntArray:
        from drivers.novatel.binary import CRC_LEN, LONG_HEADER_LEN
        from drivers.novatel.layouts import CODECS_BY_NAME

        rc = self._receiver_configs.get(receiver)
        baud = rc.get("baud") if rc is not None else None
        if rc is None or not isinstance(baud, int) or isinstance(baud, bool) or baud <= 0:
            self._warn(f"{self.path}: receiver {receiver!r}: no baud rate in the recorded configuration; the serial "
                       "transmission time of its logs is not removed from the host clock mapping (a few ms late)")
            return np.zeros(gps_ns.shape, dtype=np.int64)
        codec = CODECS_BY_NAME.get(log_name)
        binary_len = LONG_HEADER_LEN + codec.size + CRC_LEN if codec is not None and codec.fixed_layout else 0
        suffixes = {str(lr.get("name", ""))[len(log_name):] for lr in rc.get("logs", []) or []
                    if isinstance(lr, dict) and str(lr.get("name", "")).startswith(log_name)}
        if binary_len and suffixes == {"B"}:
            lengths = np.full(gps_ns.shape, binary_len, dtype=np.float64)
        else:
            measured = self._raw_frame_lengths(receiver)
            if measured is None:
                self._warn(f"{self.path}: receiver {receiver!r}: {log_name} is not a binary log and the raw stream "
                           f"{T.gnss_raw(receiver)} is not recorded; its transmission time is taken as that of the "
                           "binary log (a lower bound)")
                lengths = np.full(gps_ns.shape, binary_len, dtype=np.float64)
            else:
                got = [measured.get((log_name, g), -1) for g in gps_ns.tolist()]
                lengths = np.asarray(got, dtype=np.float64)
                missing = lengths < 0
                if missing.any():
                    self._warn(f"{self.path}: receiver {receiver!r}: {int(missing.sum())} {log_name} logs not found "
                               f"in the raw stream {T.gnss_raw(receiver)}; their transmission time is a lower bound")
                    lengths[missing] = binary_len
        return np.round(lengths * (10e9 / baud)).astype(np.int64)

    def _raw_frame_lengths(self, receiver: str) -> dict[tuple[str, int], int] | None:
        """(log name, GPS ns) → frame bytes of every log in the receiver's raw stream (None: not recorded)."""
        from drivers.novatel.framer import Framer

        key = ("raw_lengths", receiver)
        if key in self._cache:
            cached: dict[tuple[str, int], int] | None = self._cache[key]
            return cached
        topic = T.gnss_raw(receiver)
        out: dict[tuple[str, int], int] | None = None
        if self._counts.get(topic):
            _pub, chunks = self._raw_chunks(receiver)
            framer = Framer()
            out = {}
            for chunk in chunks:
                for fr in framer.feed(chunk):
                    lg = fr.log
                    if lg is not None:
                        out[(lg.name, lg.header.gps_ns)] = len(fr.raw)
        self._cache[key] = out
        return out

    def _clock_receivers(self) -> list[str]:
        """Receivers in the order the live time base chooses its reference: rovers by antenna, then the others."""
        have = self.receivers()
        cfgs = self._receiver_configs
        rovers = sorted((r for r in have if cfgs.get(r, {}).get("role") == "rover"),
                        key=lambda r: (str(cfgs[r].get("antenna") or "z"), r))
        return rovers + [r for r in have if r not in rovers]

    @cached_property
    def host_clock(self) -> ClockEstimator | None:
        """The GPS → host clock fitted over the whole session from the GNSS logs (None without GNSS).

        The reference receiver's BESTPOS, BESTVEL and TIME logs give (GPS time of the log, host
        receive time) pairs; the known part of each log's latency (:meth:`gnss_log_latency_ns`, or the
        constant ``gnss_min_latency_s`` given to :func:`load_session`) is taken off the host time
        before the lower envelope is fitted, as the live time base does.
        """
        return self._fit_host_clock(with_output_latency=True)

    @cached_property
    def _raw_host_clock(self) -> ClockEstimator | None:
        """:attr:`host_clock` with only the configured output latency taken off (none measured or assumed): the
        map the output-latency measurement starts from, and the prior that finds the DAQ's sync edges."""
        return self._fit_host_clock(with_output_latency=False)

    def _raw_host_to_utc(self, host_ns: npt.ArrayLike) -> tuple[IntArray, bool]:
        h = np.asarray(host_ns, dtype=np.int64)
        est = self._raw_host_clock
        if est is None or self.leap_seconds is None:
            return h, False
        return self.gps_to_utc(est.mapping().inverse_ns(h)), True

    def _fit_host_clock(self, *, with_output_latency: bool) -> ClockEstimator | None:
        for r in self._clock_receivers():
            gps: list[IntArray] = []
            ref: list[IntArray] = []
            for log_name, topic in (("BESTPOS", T.gnss_bestpos(r)), ("BESTVEL", T.gnss_bestvel(r)),
                                    ("TIME", T.gnss_time(r))):
                tbl = self._table(topic)
                if not len(tbl) or "gps_time_ns" not in tbl or tbl["gps_time_ns"].dtype.kind != "i":
                    continue
                g = tbl["gps_time_ns"]
                if self.gnss_min_latency_ns is not None:
                    known = np.full(g.shape, self.gnss_min_latency_ns, dtype=np.int64)
                elif with_output_latency:
                    known = self.gnss_log_latency_ns(r, log_name, g)
                else:
                    known = (self._configured_latency_ns(r) or 0) + self._log_tx_ns(r, log_name, g)
                gps.append(g)
                ref.append(tbl.host_ns - known)
            if gps:
                g_all = np.concatenate(gps)
                h_all = np.concatenate(ref)
                order = np.argsort(g_all, kind="stable")
                est = ClockEstimator(f"gnss:{r}")
                est.add_many(g_all[order], h_all[order])
                return est
        return None

    def host_to_utc(self, host_ns: npt.ArrayLike) -> tuple[IntArray, bool]:
        """Host times → common time base through the session's GNSS clock; (times, mapped?)."""
        h = np.asarray(host_ns, dtype=np.int64)
        est = self.host_clock
        if est is None or self.leap_seconds is None:
            return h, False
        gps = est.mapping().inverse_ns(h)
        return self.gps_to_utc(gps), True

    # --- CAN --------------------------------------------------------------------------------

    def can_buses(self) -> list[str]:
        return sorted(_spec(t)[1]["bus"] for t in self._counts if t.startswith("/can/") and t.endswith("/frames"))

    def can_frames(self, bus: str) -> CanFrames:
        """Every frame recorded on ``bus``, with per-frame times on the common base."""
        key = ("can", bus)
        if key in self._cache:
            cached: CanFrames = self._cache[key]
            return cached
        topic = T.can_frames(bus)
        if topic not in self._counts:
            raise AnalysisError(f"{self.path}: no CAN frames for bus {bus!r}; buses: {self.can_buses()}")
        _log, _pub, data = self._messages(topic)
        try:
            rec = T.unpack_can_blocks(data)
        except DecodeError as exc:
            raise SessionFileError(f"{self.path}: {topic}: {exc}") from exc
        dev = rec["device_ts_ns"].astype(np.int64)
        host = rec["host_ts_ns"].astype(np.int64)
        has_dev = bool(rec.shape[0]) and bool(np.all(dev != T.NO_TIME_NS))
        source = "host"
        host_event = host
        if has_dev:
            # interface clock → host: lower envelope over the whole session, then host → GPS
            est = ClockEstimator(f"can:{bus}")
            order = np.argsort(dev, kind="stable")
            est.add_many(dev[order], host[order])
            host_event = est.mapping()(dev)
            source = "interface"
        t, mapped = self.host_to_utc(host_event)
        if not mapped:
            source = "host_unmapped"
        out = CanFrames(bus, rec, t, source)
        self._cache[key] = out
        return out

    def dbc(self, name: str | None = None) -> Database:
        """The DBC attached to the session (``name``, or the only ``.dbc`` attachment)."""
        from drivers.can.dbc import parse_dbc_text

        cands = [n for n in self.attachments if n.lower().endswith(".dbc")] if name is None else [name]
        if len(cands) != 1 or cands[0] not in self.attachments:
            raise AnalysisError(
                f"{self.path}: cannot choose a DBC attachment (asked {name!r}; attached: {sorted(self.attachments)})"
            )
        return parse_dbc_text(self.attachments[cands[0]].decode("utf-8", "replace"), source=f"{self.path}:{cands[0]}")

    def rolemap(self, db: Database, bus: str, name: str | None = None) -> RoleMap:
        """The CAN role map attached to the session (``name``, ``<bus>.roles.toml`` or the only ``*roles*.toml``)."""
        from drivers.can.roles import RoleMap

        if name is None:
            if f"{bus}.roles.toml" in self.attachments:
                name = f"{bus}.roles.toml"
            else:
                cands = [n for n in self.attachments if "roles" in n and n.endswith(".toml")]
                if len(cands) != 1:
                    raise AnalysisError(
                        f"{self.path}: no role map for bus {bus!r} among the attachments {sorted(self.attachments)}"
                    )
                name = cands[0]
        try:
            doc = tomllib.loads(self.attachments[name].decode())
        except (KeyError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise AnalysisError(f"{self.path}: attachment {name!r} is not a readable role map: {exc}") from exc
        table = doc if ("roles" in doc or "checks" in doc) else doc.get("can", {})
        return RoleMap.from_mapping(table, db, source=f"{self.path}:{name}")

    def can_roles(
        self, bus: str, *, db: Database | None = None, rolemap: RoleMap | None = None
    ) -> dict[str, RoleSeries]:
        """The rig roles of ``bus`` (SI, ISO 8855) decoded from every frame with the vectorised decoder.

        ``db``/``rolemap`` default to the session's attachments. Each :class:`RoleSeries` has
        ``timestamps_ns`` on the common time base, ``values``, ``flags`` and ``ok``.
        """
        from drivers.can.vector_decode import VectorRoleDecoder

        key = ("roles", bus, id(db), id(rolemap))
        if key in self._cache:
            cached: dict[str, RoleSeries] = self._cache[key]
            return cached
        database = db if db is not None else self.dbc()
        rm = rolemap if rolemap is not None else self.rolemap(database, bus)
        batch = self.can_frames(bus).batch()
        roles = dict(VectorRoleDecoder(database, rm).decode(batch).roles)
        self._cache[key] = roles
        return roles

    # --- DAQ --------------------------------------------------------------------------------

    def daq_devices(self) -> list[str]:
        return sorted(_spec(t)[1]["device"] for t in self._counts if t.startswith("/daq/"))

    def daq_blocks(self, device: str) -> tuple[IntArray, IntArray, IntArray]:
        """(first sample index, last sample index, host receive ns) of every block of ``device``, in file order
        (the file's sample indices, as :meth:`daq` joins them; used by :mod:`rig.core.quality`'s causality check)."""
        _log, pub_t, data = self._messages(T.daq_samples(device))
        try:
            heads = [T.unpack_daq_block(d) for d in data]
        except DecodeError as exc:
            raise SessionFileError(f"{self.path}: {T.daq_samples(device)}: {exc}") from exc
        first = np.asarray([b.first_sample_index for b in heads], dtype=np.int64)
        n = np.asarray([b.samples.shape[1] for b in heads], dtype=np.int64)
        return first, first + n - 1, pub_t

    def daq(
        self,
        device: str,
        *,
        sync_channel: str | None = None,
        receiver: str | None = None,
        sync_low_v: float = 1.0,
        sync_high_v: float = 4.0,
    ) -> DaqData:
        """The samples of one DAQ device (volts) with their times.

        Sample indices restart with every acquisition (a DAQ reconnect); the recorder keeps them
        unique by starting a new acquisition after an estimated gap, so the file's indices are one
        clock only within an unbroken run. Each run (:class:`DaqSegment`) is therefore timed on its own:

        - with ``sync_channel`` (the DAQ channel wired to the sync switch) and a ``receiver`` whose
          MARKTIME (or MARKPOS) logs saw the same edges, sample index → GPS time comes from
          :func:`rig.core.timebase.align_sync_pulses` over the run's edges; a run with fewer than two
          matched edges falls back to the host clock (the blocks' receive times on the GNSS-derived
          time base, less the DAQ's delivery latency measured on the synchronised runs) and is
          flagged (:attr:`DaqData.synced`, its segment's ``time_source``, a warning);
        - otherwise from a line through the run's blocks' log times.
        """
        key = ("daq", device, sync_channel, receiver, sync_low_v, sync_high_v)
        if key in self._cache:
            cached: DaqData = self._cache[key]
            return cached
        topic = T.daq_samples(device)
        if topic not in self._counts:
            raise AnalysisError(f"{self.path}: no DAQ samples for device {device!r}; devices: {self.daq_devices()}")
        log_t, pub_t, data = self._messages(topic)
        try:
            blocks = [T.unpack_daq_block(d) for d in data]
        except DecodeError as exc:
            raise SessionFileError(f"{self.path}: {topic}: {exc}") from exc
        if not blocks:
            raise AnalysisError(f"{self.path}: {topic} has no blocks")
        names = blocks[0].channel_names
        rate = blocks[0].rate_hz
        for b in blocks:
            if b.channel_names != names or b.rate_hz != rate:
                raise SessionFileError(f"{self.path}: {topic}: channels or rate change between blocks")
        firsts = np.asarray([b.first_sample_index for b in blocks], dtype=np.int64)
        lengths = np.asarray([b.samples.shape[1] for b in blocks], dtype=np.int64)
        order = np.argsort(firsts, kind="stable")
        idx = np.concatenate([np.arange(blocks[i].first_sample_index, blocks[i].first_sample_index
                                        + blocks[i].samples.shape[1], dtype=np.int64) for i in order])
        volts = np.concatenate([blocks[i].volts() for i in order], axis=1)
        uniq, first_pos = np.unique(idx, return_index=True)
        if uniq.size != idx.size:
            idx, volts = uniq, volts[:, first_pos]
        lost = int(idx[-1] - idx[0] + 1 - idx.size) if idx.size else 0
        blk = _Blocks(firsts[order], firsts[order] + lengths[order] - 1, log_t[order], pub_t[order])
        runs = _runs(idx)
        if sync_channel is not None and receiver is not None:
            time_ns, segments = self._daq_sync(device, names, idx, volts, rate, runs, blk, sync_channel, receiver,
                                               sync_low_v, sync_high_v)
            n_sync = sum(s.time_source == "sync_pulse" for s in segments)
            source = "sync_pulse" if n_sync == len(segments) else ("sync_pulse+host" if n_sync else "host")
        else:
            time_ns = np.empty(idx.size, dtype=np.int64)
            seg_list: list[DaqSegment] = []
            for lo, hi in runs:
                i0, i1 = int(idx[lo]), int(idx[hi - 1])
                m = (blk.first >= i0) & (blk.first <= i1)
                time_ns[lo:hi] = _line_fit(blk.first[m], blk.log_t[m], rate)(idx[lo:hi])
                seg_list.append(DaqSegment(i0, i1 + 1, "log_time"))
            segments = tuple(seg_list)
            source = "log_time"
        fits = [s.sync for s in segments if s.sync is not None]
        best = max(fits, key=lambda f: f.matched_edges.size) if fits else None
        out = DaqData(device, rate, names, idx, volts, time_ns, source, best, lost, segments)
        self._cache[key] = out
        return out

    def _daq_sync(
        self,
        device: str,
        names: tuple[str, ...],
        idx: IntArray,
        volts: FloatArray,
        rate: float,
        runs: Sequence[tuple[int, int]],
        blk: _Blocks,
        sync_channel: str,
        receiver: str,
        low: float,
        high: float,
    ) -> tuple[IntArray, tuple[DaqSegment, ...]]:
        """Times of every sample and the segments, each run fitted to the marks on its own."""
        from drivers.daq.sync import find_edges

        if sync_channel not in names:
            raise ConfigError(f"DAQ {device}: sync channel {sync_channel!r} not recorded; channels: {list(names)}")
        x = volts[names.index(sync_channel)]
        g = self.gnss(receiver)
        marks_tbl = g.marktime if len(g.marktime) else g.markpos
        if len(marks_tbl) == 0:
            raise AnalysisError(f"{self.path}: receiver {receiver!r} has no MARKTIME/MARKPOS to align DAQ {device}")
        marks = marks_tbl["gps_time_ns"].astype(np.int64)
        utc_minus_gps = None if self.leap_seconds is None else GPS_EPOCH_UNIX_NS - self.leap_seconds * _NS
        nominal = 1e9 / rate
        # the map before the output-latency measurement (which needs these very fits): a prior for matching
        # edges to marks, and the fallback's offset (taken relative to the synchronised runs on the same map)
        arrival, mapped = self._raw_host_to_utc(blk.pub)
        fits: list[SyncFit | None] = []
        reasons: list[str] = []
        for a, b in runs:
            i0, i1 = int(idx[a]), int(idx[b - 1])
            edge_idx = find_edges(x[a:b], low=low, high=high, first_sample_index=i0)
            m = (blk.first >= i0) & (blk.first <= i1)
            approx = None
            if utc_minus_gps is not None and edge_idx.size:
                # prior: the blocks' receive times on the common base (within a few ms), else their log times
                if mapped and m.any():
                    off = int(np.min(arrival[m] - np.round((blk.last[m] - i0) * nominal).astype(np.int64)))
                    utc = off + np.round((edge_idx - i0) * nominal).astype(np.int64)
                else:
                    utc = _line_fit(blk.first[m], blk.log_t[m], rate)(np.round(edge_idx).astype(np.int64))
                approx = utc - utc_minus_gps
            try:
                fit = align_sync_pulses(device, edge_idx, marks, rate, approx_gps_ns=approx)
            except AnalysisError as exc:
                fits.append(None)
                reasons.append(str(exc))
            else:
                fits.append(fit)
                reasons.append("")
        time_ns = np.empty(idx.size, dtype=np.int64)
        segments: list[DaqSegment] = []
        # the host fallback: slope from the synchronised runs (one oscillator), offset from the lower
        # envelope of the blocks' receive times less the DAQ's delivery latency seen on those runs
        synced = [(run, f) for run, f in zip(runs, fits, strict=True) if f is not None]
        period = float(np.mean([f.map.slope for _r, f in synced])) if synced else nominal
        latency = 0
        if synced and mapped and utc_minus_gps is not None:
            per_run = []
            for (a, b), f in synced:
                m = (blk.first >= idx[a]) & (blk.first <= idx[b - 1])
                if m.any():
                    per_run.append(int(np.min(arrival[m] - (f.gps_ns(blk.last[m]) + utc_minus_gps))))
            latency = int(np.median(per_run)) if per_run else 0
        for k, ((a, b), seg_fit) in enumerate(zip(runs, fits, strict=True)):
            i0, i1 = int(idx[a]), int(idx[b - 1])
            if seg_fit is not None and utc_minus_gps is not None:
                time_ns[a:b] = seg_fit.gps_ns(idx[a:b]) + utc_minus_gps
                segments.append(DaqSegment(i0, i1 + 1, "sync_pulse", seg_fit))
                continue
            m = (blk.first >= i0) & (blk.first <= i1)
            times = arrival[m] if m.any() else blk.pub[:1]
            lasts = blk.last[m] if m.any() else np.asarray([i1])
            off = int(np.min(times - np.round((lasts - i0) * period).astype(np.int64))) - latency
            time_ns[a:b] = off + np.round((idx[a:b] - i0) * period).astype(np.int64)
            src = "host" if mapped else "host_unmapped"
            why = reasons[k] if seg_fit is None else "GPS − UTC leap seconds unknown"
            lat = (f"less the {latency / 1e6:.1f} ms delivery latency of the synchronised segments" if synced
                   else "late by the DAQ's unknown delivery latency")
            note = f"not synchronised ({why}): times from the host clock, {lat}"
            segments.append(DaqSegment(i0, i1 + 1, src, None, note))
            self._warn(f"{self.path}: DAQ {device}: segment {k + 1} of {len(runs)} (samples {i0}..{i1}, "
                       f"{(i1 - i0 + 1) / rate:.1f} s) {note}")
        return time_ns, tuple(segments)

    def analog(self, device: str, specs: Sequence[AnalogChannelSpec], **daq_kw: Any) -> dict[str, FloatArray]:
        """Scaled analog channels (SI) of ``device``; times are ``self.daq(device, **daq_kw).time_ns``."""
        d = self.daq(device, **daq_kw)
        return {s.name: s.decode(d.channel(s.channel)) for s in specs}

    def optical(
        self, sensor: str, spec: OpticalSensorSpec | None = None, *, device: str | None = None, **daq_kw: Any
    ) -> tuple[IntArray, OpticalSample]:
        """Times (common base) and quantities of an optical sensor.

        With ``spec`` the sensor is computed from its DAQ channels (``device``: the DAQ, default the
        only one) with :func:`drivers.optical.convert_volts`; without, from the recorded
        ``/optical/<sensor>`` topic.
        """
        from drivers.optical import OpticalSample, convert_volts

        if spec is not None:
            devs = self.daq_devices()
            dev = device if device is not None else (devs[0] if len(devs) == 1 else None)
            if dev is None:
                raise AnalysisError(f"{self.path}: optical {sensor!r}: name the DAQ device (devices: {devs})")
            d = self.daq(dev, **daq_kw)
            volts = {c: d.channel(c) for c in spec.daq_channels}
            sample = convert_volts(spec, volts, first_sample_index=int(d.sample_index[0]) if len(d) else None)
            return d.time_ns, sample
        topic = T.optical(sensor)
        if topic not in self._counts:
            raise AnalysisError(f"{self.path}: no {topic} topic; give the sensor spec to compute it from the DAQ")
        tbl = self._table(topic)

        def col(name: str) -> FloatArray:
            return np.asarray(tbl[name], dtype=np.float64) if name in tbl else np.full(len(tbl), np.nan)

        valid = np.asarray(tbl["valid"], dtype=bool) if "valid" in tbl else np.ones(len(tbl), bool)
        sample = OpticalSample(
            sensor=sensor, vx=col("vx_mps"), vy=col("vy_mps"), slip_angle=col("slip_angle_rad"),
            speed=col("speed_mps"), valid=valid, zero_offset_applied_rad=float("nan"), time_ns=tbl.time_ns,
        )
        return tbl.time_ns, sample

    # --- simulation truth -------------------------------------------------------------------

    def truth(self) -> Truth:
        """The simulator's ground truth (``/sim/truth``), in time order without duplicates."""
        from sim_devices.vehicle.truth import GroundTruth

        if "truth" in self._cache:
            cached: Truth = self._cache["truth"]
            return cached
        _log, _pub, data = self._messages(T.TOPIC_SIM_TRUTH)
        if not data:
            raise AnalysisError(f"{self.path}: no {T.TOPIC_SIM_TRUTH} (not a simulated session)")
        try:
            unpacked = [T.unpack_truth_block(d) for d in data]
        except DecodeError as exc:
            raise SessionFileError(f"{self.path}: {T.TOPIC_SIM_TRUTH}: {exc}") from exc
        rec = np.concatenate([r for r, _o in unpacked])
        rec = rec[np.argsort(rec["time_ns"], kind="stable")]
        _u, first = np.unique(rec["time_ns"], return_index=True)
        rec = rec[first]
        lat0, lon0, h0 = unpacked[0][1]
        fields: dict[str, Any] = {name: np.ascontiguousarray(rec[name]) for name in T.TRUTH_DTYPE.names or ()
                                  if name not in ("time_ns", "t_s")}
        gt = GroundTruth(t=np.ascontiguousarray(rec["t_s"]), lat0_deg=lat0, lon0_deg=lon0, h0_m=h0, **fields)
        out = Truth(np.ascontiguousarray(rec["time_ns"]), gt)
        self._cache["truth"] = out
        return out


# ---------------------------------------------------------------------------------------------
# GNSS logs decoded from raw bytes, in the decoded topics' columns
# ---------------------------------------------------------------------------------------------

_RAW_GNSS_LOGS = ("BESTPOS", "BESTVEL", "HEADING", "HEADING2", "MARKPOS", "MARKTIME", "MARK1TIME", "TIME")


@dataclass(frozen=True, slots=True)
class RawGnssRecords:
    """One decoded GNSS topic's records rebuilt from raw logs (buffer order)."""

    gps_ns: IntArray
    """GPS time of each record (the log header's; for MARKTIME the event's) as ns since the GPS epoch."""
    frame_end: IntArray
    """Offset one past each log's frame in the raw buffer."""
    columns: dict[str, npt.NDArray[Any]]
    """The record fields as :meth:`Session._table` gives them from the JSON records."""


def _names(values: npt.NDArray[Any], enum: Any) -> npt.NDArray[np.str_]:
    """Enum values → their names (``UNKNOWN_<n>`` for values outside the table), as the records hold them."""
    uniq, inverse = np.unique(values, return_inverse=True)
    return np.asarray([enum(int(v)).name for v in uniq.tolist()], dtype=str)[inverse.reshape(-1)]


def _text(values: npt.NDArray[Any]) -> npt.NDArray[np.str_]:
    return np.asarray(values.tolist(), dtype=str)  # the width of the longest value, as from JSON


def _finite(values: npt.NDArray[Any]) -> FloatArray:
    """JSON has no NaN or infinity: the recorder writes null, which reads back as NaN."""
    x = np.asarray(values, dtype=np.float64)
    return np.where(np.isfinite(x), x, np.nan)


def _record_columns(kind: str, c: Any) -> dict[str, npt.NDArray[Any]]:
    """The fields of :data:`rig.core.topics.GNSS_RECORD_FIELDS` ``kind`` from one log's columns."""
    out: dict[str, npt.NDArray[Any]] = {}
    for f in T.GNSS_RECORD_FIELDS[kind]:
        v = (c.header if f.header else c.body)[f.name]
        if f.enum is not None:
            out[f.key] = _names(v, f.enum)
        elif v.dtype.kind == "f":
            out[f.key] = _finite(v)
        elif v.dtype.kind in "US":
            out[f.key] = _text(v)
        else:
            out[f.key] = v
    return out


def gnss_record_columns(batch: Any) -> dict[str, RawGnssRecords]:
    """The decoded GNSS topics' records (``bestpos``, ``bestvel``, ``heading``, ``markpos``, ``marktime``,
    ``time``) built from a :class:`drivers.novatel.columns.ColumnBatch` from the same field table as the
    recorder's (:data:`rig.core.topics.GNSS_RECORD_FIELDS`), and typed as :func:`_columns` reads them back
    from JSON."""
    out: dict[str, RawGnssRecords] = {}
    for topic, log, kind in (("bestpos", "BESTPOS", "position"), ("markpos", "MARKPOS", "position"),
                             ("bestvel", "BESTVEL", "velocity")):
        c = batch.log(log)
        out[topic] = RawGnssRecords(c.header["gps_ns"], c.end, _record_columns(kind, c))
    # the sync switch's event time: MARK1TIME, or the deprecated MARKTIME of older configurations (one topic)
    m0, m1 = batch.log("MARKTIME"), batch.log("MARK1TIME")
    order = np.argsort(np.concatenate([m0.offset, m1.offset]), kind="stable")
    c0, c1 = _record_columns("marktime", m0), _record_columns("marktime", m1)
    marks = {k: np.concatenate([c0[k], c1[k]])[order] for k in c0}
    marks["event_input"] = np.full(order.size, "MARK1")
    out["marktime"] = RawGnssRecords(np.concatenate([m0.body["event_gps_ns"], m1.body["event_gps_ns"]])[order],
                                     np.concatenate([m0.end, m1.end])[order], marks)
    c = batch.log("TIME")
    b = c.body
    iso = [f"{y:04d}-{mo:02d}-{d:02d}T{hh:02d}:{mi:02d}:{ms // 1000:02d}.{ms % 1000:03d}Z" for y, mo, d, hh, mi, ms in
           zip(*(b[k].tolist() for k in ("utc_year", "utc_month", "utc_day", "utc_hour", "utc_min", "utc_ms")),
               strict=True)]
    out["time"] = RawGnssRecords(c.header["gps_ns"], c.end,
                                 {**_record_columns("time", c), "utc_iso": np.asarray(iso, dtype=str)})
    h1, h2 = batch.log("HEADING"), batch.log("HEADING2")
    order = np.argsort(np.concatenate([h1.offset, h2.offset]), kind="stable")
    c1, c2 = _record_columns("heading", h1), _record_columns("heading", h2)
    heading = {k: np.concatenate([c1[k], c2[k]])[order] for k in c1}
    out["heading"] = RawGnssRecords(heading["gps_time_ns"], np.concatenate([h1.end, h2.end])[order], heading)
    return out


def _spec(topic: str) -> tuple[T.TopicSpec | None, dict[str, str]]:
    try:
        return T.spec_for_topic(topic)
    except ValueError:
        return None, {}


@dataclass(frozen=True, slots=True)
class _Blocks:
    """Per DAQ block in index order: first and last sample index, log time, host receive time."""

    first: IntArray
    last: IntArray
    log_t: IntArray
    pub: IntArray


def _runs(idx: IntArray) -> list[tuple[int, int]]:
    """Positions ``[a, b)`` of the unbroken runs of consecutive sample indices."""
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) != 1) + 1
    return list(zip(np.r_[0, breaks].tolist(), np.r_[breaks, idx.size].tolist(), strict=True))


def _line_fit(first_index: IntArray, log_t: IntArray, rate_hz: float) -> Callable[[IntArray], IntArray]:
    """Sample index → time from the blocks' (first index, log time): LS line with the nominal rate as fallback."""
    if first_index.size >= 2 and np.ptp(first_index) > 0:
        i0 = int(first_index.min())
        t0 = int(log_t[np.argmin(first_index)])
        x = (first_index - i0).astype(np.float64)
        y = (log_t - t0).astype(np.float64)
        b, a = np.polyfit(x, y, 1)
    else:
        i0 = int(first_index[0]) if first_index.size else 0
        t0 = int(log_t[0]) if log_t.size else 0
        a, b = 0.0, 1e9 / rate_hz

    def f(idx: IntArray) -> IntArray:
        return t0 + np.round(a + b * (np.asarray(idx, dtype=np.int64) - i0).astype(np.float64)).astype(np.int64)

    return f


def load_session(
    path: Path | str,
    *,
    include: Callable[[str], bool] | None = None,
    topics: Iterable[str] | None = None,
    allow_truncated: bool = True,
    gnss_min_latency_s: float | None = None,
) -> Session:
    """Read every part of a session (base path, any part file, or a directory holding one session).

    Messages are kept for ``topics`` (exact names), else for ``include(topic)``, else for every topic
    except the per-frame CAN role JSON and raw byte streams. A truncated *last* part (a killed
    recorder) is read up to its last complete chunk and noted in :attr:`Session.warnings` (unless
    ``allow_truncated`` is False). A damaged chunk or record is skipped, every intact chunk before and
    after it is read, and the damage is named in :attr:`Session.warnings` and :attr:`Session.damage`
    (:meth:`Session.damage_events` gives it as ``/rig/events``-style warnings).
    ``gnss_min_latency_s``: a constant GNSS log latency to use instead
    of each log's known latency (:meth:`Session.gnss_log_latency_ns`: the receiver's configured output
    latency plus the log's serial transmission time), for sessions whose configuration lacks them.
    Raises :class:`~vsccore.errors.SessionFileError` naming the file
    and part for a missing part, a file that is not MCAP, or an unfinished part that is not the last.
    """
    parts = find_parts(path)
    want: Callable[[str], bool]
    if topics is not None:
        wanted = set(topics)
        want = wanted.__contains__
    else:
        want = include or _default_include
    scans: list[PartScan] = []
    warnings: list[str] = []
    for i, p in enumerate(parts):
        where = f"{p} (part {i + 1} of {len(parts)})"
        try:
            scan = scan_part(p, want=want)
        except SessionFileError as exc:
            raise SessionFileError(f"{where}: {exc}") from exc
        for region in scan.damage:  # salvaged: every intact chunk is read, the damaged ones are named
            warnings.append(f"{where}: {region.describe()}; read every intact chunk")
            log.warning("%s", warnings[-1])
        if scan.truncation is not None:
            last = i == len(parts) - 1
            if last and allow_truncated:
                warnings.append(f"{where}: {scan.truncation}; read up to its last complete record")
                log.warning("%s", warnings[-1])
            else:
                raise SessionFileError(f"{where}: {scan.truncation}")
        scans.append(scan)
    return Session(Path(path), scans, warnings, gnss_min_latency_s)

