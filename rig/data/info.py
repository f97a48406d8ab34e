"""What is in a recorded session: the summary behind ``rig info`` (text for people, JSON for scripts).

:func:`read_session_info` reads every part of a session once and returns a :class:`SessionInfo`
(frozen): time span, parts, topics with counts, rates and gaps, devices, device gaps (disconnects,
gap and overflow events), time-base quality from ``/rig/timebase``, calibration in force, events,
attachments. :func:`info_to_json` and :func:`format_info` are pure functions of it.

Fast path: a finalized part is read from its summary section (statistics, chunk indexes, metadata
and attachment indexes) and its message-index records, which give every message's log time without
decompressing a chunk; only the chunks holding ``/rig/events`` and ``/rig/timebase`` messages are
decompressed, and only those messages are decoded. The time-base verdicts are either the recorder's
own, recorded at the end of the recording (``rig info``), or computed again from every stream
(:class:`VerdictSource`). That path does not check chunk CRCs; ``verify=True``
(``rig info --verify``) scans every part instead, checking every chunk's CRC and the summary's, and
reports damaged chunks ("damaged: N chunks, T s of data"). A part without a usable summary or message index (a
crashed part, a ``rig recover`` copy) is scanned instead (:func:`rig.store.reader.scan_part`,
which stops at the last complete record); the part says which way it was read (``read_via``).

Gaps: for each periodic topic the typical interval between consecutive log times is the
time-weighted median interval (the interval length below which half of the topic's span is
covered), which is the burst period for bursty streams (corrections once a second, read in several
reads) and the message period for regular ones; an interval longer than
``max(gap_factor × typical interval, min_gap_s)`` is a gap. Event-like topics (``/rig/events``,
``/rig/timebase``, MARKPOS/MARKTIME) are not checked.

JSON document (``rig info --json``), format ``vsc-rig.info`` version 1. Stable keys; times are int ns
on the session's common time base (UTC ns since the Unix epoch) plus ISO 8601 UTC text; ``null``
where a value is unknown:

- ``format``, ``version``, ``session`` (name), ``path``, ``start_ns``, ``end_ns``, ``start_utc``,
  ``end_utc``, ``duration_s`` (the span of the recorded data: every topic but ``/rig/events``, whose
  times may come from the host clock before the time base is known), ``messages``, ``truncated``
  (a part was not finalized or damaged), ``verified`` (every chunk's CRC was checked: ``--verify``),
  ``damaged_chunks`` and ``damaged_s`` (chunks lost to damage and the seconds of data in them; 0
  when not verified and no damage was met);
- ``recorder``: the recorder's metadata of the first part (software, version, host, compression, ...);
- ``parts``: [{``index``, ``file``, ``bytes``, ``messages``, ``finalized``, ``read_via`` (summary|scan),
  ``problem``, ``problem_kind`` (truncated|corrupt|null), ``end_reason``, ``start_ns``, ``end_ns``,
  ``damaged_chunks``, ``damaged_s``, ``damage``: [the ``details`` of each damaged region's warning
  (``file``, ``damage``, ``offset``, ``length``, ``chunks``, ``topics``, ``messages``, ``duration_s``)
  plus ``start_ns``, ``end_ns``, ``text``]}];
- ``topics``: [{``topic``, ``schema``, ``encoding``, ``raw``, ``messages``, ``first_ns``, ``last_ns``,
  ``rate_hz``, ``typical_interval_s``, ``max_interval_s``, ``gap_threshold_s``, ``gap_count``,
  ``gap_total_s``, ``gaps``: [{``start_ns``, ``end_ns``, ``duration_s``}]}] (at most
  ``max_gaps_listed`` gaps listed per topic, all counted);
- ``devices``: [{``name``, ``kind`` (gnss|can|daq|optical|relay|sim|source), ``topics``, ``messages``,
  ``written``, ``dropped``, ``connects``, ``disconnects``, ``errors``, ``warnings``}];
- ``device_gaps``: [{``device``, ``kind`` (disconnect|gap|overflow), ``start_ns``, ``end_ns``,
  ``duration_s``, ``open`` (no reconnect before the end), ``dropped``, ``text``}];
- ``timebase``: {``records``, ``clocks``: [the last ``/rig/timebase`` record of each clock: ``clock``,
  ``method``, ``reference``, ``status``, ``n``, ``span_s``, ``offset_ns``, ``drift_ppm``, ``jitter_ns``,
  ``latency_p50_ns``, ``latency_p95_ns``, ``rms_ns``, ``max_abs_ns``, ``leap_seconds``, ``time_ns``,
  ``records``], ``verdicts``: {``problem``, ``streams``: {stream: :meth:`rig.core.quality.StreamQuality.to_json`},
  ``source`` (recorded|data: the recorder's verdicts at the end of the recording, or computed from the
  data — ``rig info --verify``; see :class:`VerdictSource`)} or ``null`` when not asked for};
- ``calibration``: the calibration metadata in force, flat ``{key: value text}`` as recorded;
- ``calibration_file``: the calibration results next to the session (``<base>.calibration.json``,
  written by ``rig calibrate-baseline`` and the other ``rig calibrate-*`` commands), or ``null`` when
  there is none: {``path``, ``format``, ``results`` (``{key: entry}`` as written, e.g. ``mount_offset``
  with ``offset_deg`` and ``u95_deg``), ``problem`` (why an existing file could not be read, else ``null``)};
- ``events``: {``total``, ``by_kind``, ``by_severity``, ``problems`` (warnings and errors), ``marks``:
  [{``time_ns``, ``time_utc``, ``kind``, ``severity``, ``source``, ``text``}]};
- ``attachments``: [{``name``, ``media_type``, ``bytes``}];
- ``warnings``: [text] (truncated or damaged parts, undecodable records).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace of topic names
from rig.store.parts import AttachmentInfo, PartRead, ReadVia, read_part
from rig.store.reader import (
    DamagedRegion,
    ProblemKind,
    damaged_chunk_count,
    damaged_seconds,
    find_parts,
    part_index,
    session_base,
)
from vsccore.errors import SessionFileError

__all__ = [
    "INFO_FORMAT",
    "INFO_JSON_KEYS",
    "INFO_VERSION",
    "AttachmentInfo",
    "CalibrationFileInfo",
    "ClockInfo",
    "DeviceGap",
    "DeviceGapKind",
    "DeviceInfo",
    "EventLine",
    "EventSummary",
    "Gap",
    "PartInfo",
    "ReadVia",
    "SessionInfo",
    "TopicInfo",
    "VerdictSource",
    "VerdictsInfo",
    "format_info",
    "format_utc",
    "info_to_json",
    "read_session_info",
]

INFO_FORMAT = "vsc-rig.info"
INFO_VERSION = 1
INFO_JSON_KEYS = (
    "format",
    "version",
    "session",
    "path",
    "start_ns",
    "end_ns",
    "start_utc",
    "end_utc",
    "duration_s",
    "messages",
    "truncated",
    "verified",
    "damaged_chunks",
    "damaged_s",
    "recorder",
    "parts",
    "topics",
    "devices",
    "device_gaps",
    "timebase",
    "calibration",
    "calibration_file",
    "events",
    "attachments",
    "warnings",
)
"""Top-level keys of the JSON document, in order (documented in this module's docstring)."""

_NS = 1_000_000_000
_NOT_PERIODIC = frozenset({"/rig/events", "/rig/timebase", "/gnss/{receiver}/markpos", "/gnss/{receiver}/marktime"})
"""Topic families that are not periodic: no gap check."""
_EVENT_SLACK_NS = 60 * _NS
"""Events further than this outside the data span are reported (their clock is suspect)."""
_RECORDER_PER_PART_KEYS = frozenset({"part_index", "part_file", "previous_part", "started_host_ns", "sources"})
_DEVICE_KINDS = {"receiver": "gnss", "bus": "can", "device": "daq", "sensor": "optical"}


# ---------------------------------------------------------------------------------------------
# Result types
# ---------------------------------------------------------------------------------------------


class VerdictSource(StrEnum):
    """Where the time-base verdicts that ``rig info`` shows come from."""

    DATA = "data"
    """Computed from the recorded streams (:func:`rig.data.verdicts.session_verdicts`): every stream is read
    and decoded, seconds on a long session (``rig info --verify``, and :func:`read_session_info`'s default)."""
    RECORDED = "recorded"
    """The recorder's own verdicts at the end of the recording (the last ``timebase`` event in
    ``/rig/events`` that carries ``verdicts``): nothing beyond the events is read (``rig info``)."""


@dataclass(frozen=True, slots=True)
class VerdictsInfo:
    """The time-base verdicts block of ``rig info``."""

    source: VerdictSource
    lines: tuple[str, ...]
    """One line per stream and its gaps (:func:`rig.core.quality.verdict_lines`), or why there are none."""
    streams: Mapping[str, Any] = field(default_factory=dict)
    """stream → :meth:`rig.core.quality.StreamQuality.to_json`."""
    problem: str | None = None
    """Why no verdicts could be given (then ``streams`` is empty)."""


@dataclass(frozen=True, slots=True)
class PartInfo:
    """One part file of the session."""

    index: int
    path: Path
    size_bytes: int
    messages: int
    finalized: bool
    read_via: ReadVia
    problem: str | None = None
    problem_kind: ProblemKind | None = None
    end_reason: str | None = None
    """Why the recorder ended the part (``stop``, ``rollover (size)``, ``disk_full``), from its part-end record."""
    start_ns: int | None = None
    end_ns: int | None = None
    damage: tuple[DamagedRegion, ...] = ()
    """Damaged regions skipped (found when the part was scanned: ``verify`` or no usable summary)."""
    verified: bool = False
    """Every chunk CRC (and the summary CRC) of the part was checked."""

    @property
    def damaged_chunks(self) -> int:
        return damaged_chunk_count(self.damage)

    @property
    def damaged_s(self) -> float:
        return damaged_seconds(self.damage)


@dataclass(frozen=True, slots=True)
class Gap:
    """An interval between two consecutive messages of a topic that is much longer than its period."""

    start_ns: int
    """Log time of the last message before the gap."""
    end_ns: int
    """Log time of the first message after it."""

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / _NS


@dataclass(frozen=True, slots=True)
class TopicInfo:
    """Counts, rate and gaps of one topic over all parts."""

    topic: str
    schema: str
    encoding: str
    raw: bool
    messages: int
    first_ns: int | None = None
    last_ns: int | None = None
    rate_hz: float | None = None
    """Mean rate over the topic's own span: (messages − 1) / (last − first)."""
    typical_interval_s: float | None = None
    """Time-weighted median interval between consecutive messages (see the module docstring)."""
    max_interval_s: float | None = None
    gap_threshold_s: float | None = None
    """Intervals longer than this are gaps (None: the topic is not checked)."""
    gap_count: int = 0
    gap_total_s: float = 0.0
    gaps: tuple[Gap, ...] = ()
    """The first gaps (at most ``max_gaps_listed``); ``gap_count`` counts all."""


class DeviceGapKind(StrEnum):
    """Where a device gap comes from."""

    DISCONNECT = "disconnect"
    """A disconnect event, closed by the next connect event of the same device (or open to the end)."""
    GAP = "gap"
    """A gap event written by the device's code (``Source.gap``)."""
    OVERFLOW = "overflow"
    """Messages dropped because the device's queue was full."""


@dataclass(frozen=True, slots=True)
class DeviceGap:
    """A period in which a device delivered nothing (or lost messages), from ``/rig/events``."""

    device: str
    kind: DeviceGapKind
    start_ns: int
    end_ns: int | None
    text: str
    open: bool = False
    """A disconnect with no reconnect before the end of the session (``end_ns`` is the session end)."""
    dropped: int | None = None

    @property
    def duration_s(self) -> float | None:
        return None if self.end_ns is None else (self.end_ns - self.start_ns) / _NS


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """A device of the session: from topic names (receivers, buses, DAQs, sensors) and recorder sources."""

    name: str
    kind: str
    topics: tuple[str, ...]
    messages: int
    """Messages on its topics."""
    written: int | None = None
    """Messages its recorder source wrote (from the part-end records; None when not known)."""
    dropped: int = 0
    """Messages lost because its queue was full (part-end records and overflow events)."""
    connects: int = 0
    disconnects: int = 0
    errors: int = 0
    warnings: int = 0


@dataclass(frozen=True, slots=True)
class ClockInfo:
    """The last ``/rig/timebase`` record of one clock."""

    clock: str
    method: str
    reference: str
    status: str
    n: int
    span_s: float | None
    offset_ns: int | None
    drift_ppm: float | None
    jitter_ns: float | None
    latency_p50_ns: float | None
    latency_p95_ns: float | None
    rms_ns: float | None
    max_abs_ns: float | None
    leap_seconds: int | None
    time_ns: int
    """Log time of the record."""
    records: int
    """Records of this clock in the session."""


@dataclass(frozen=True, slots=True)
class EventLine:
    """One event, for listing."""

    time_ns: int
    kind: str
    severity: str
    source: str
    text: str


@dataclass(frozen=True, slots=True)
class EventSummary:
    """``/rig/events`` in short."""

    total: int = 0
    by_kind: Mapping[str, int] = field(default_factory=dict)
    by_severity: Mapping[str, int] = field(default_factory=dict)
    problems: tuple[EventLine, ...] = ()
    """Warnings and errors, in time order."""
    marks: tuple[EventLine, ...] = ()
    """Operator marks, in time order."""


@dataclass(frozen=True, slots=True)
class CalibrationFileInfo:
    """The session's calibration results file (``<base>.calibration.json``, see :mod:`rig.data.inputs`)."""

    path: Path
    results: Mapping[str, Any]
    """``results`` of the file: one entry per calibration (``mount_offset``, ``optical_zero``, …) as written."""
    format: str | None = None
    problem: str | None = None
    """Why the file could not be read (then ``results`` is empty)."""


@dataclass(frozen=True, slots=True)
class SessionInfo:
    """Everything ``rig info`` reports about one session."""

    path: Path
    name: str
    parts: tuple[PartInfo, ...]
    start_ns: int | None
    end_ns: int | None
    messages: int
    recorder: Mapping[str, str]
    topics: tuple[TopicInfo, ...]
    devices: tuple[DeviceInfo, ...]
    device_gaps: tuple[DeviceGap, ...]
    clocks: tuple[ClockInfo, ...]
    timebase_records: int
    calibration: Mapping[str, str]
    events: EventSummary
    attachments: tuple[AttachmentInfo, ...]
    warnings: tuple[str, ...]
    calibration_file: CalibrationFileInfo | None = None
    verdicts: VerdictsInfo | None = None
    """The streams' time-base verdicts (None: not asked for)."""

    @property
    def duration_s(self) -> float | None:
        if self.start_ns is None or self.end_ns is None:
            return None
        return (self.end_ns - self.start_ns) / _NS

    @property
    def truncated(self) -> bool:
        """A part was not finalized or is damaged (it was read up to its last complete record)."""
        return any(p.problem is not None or not p.finalized for p in self.parts)

    @property
    def verified(self) -> bool:
        """Every part's chunk CRCs were checked."""
        return all(p.verified for p in self.parts)

    @property
    def damaged_chunks(self) -> int:
        return sum(p.damaged_chunks for p in self.parts)

    @property
    def damaged_s(self) -> float:
        return sum(p.damaged_s for p in self.parts)

    def topic(self, name: str) -> TopicInfo:
        """The topic ``name`` (KeyError naming the topics present)."""
        for t in self.topics:
            if t.topic == name:
                return t
        raise KeyError(f"{self.path}: no topic {name!r}; topics: {[t.topic for t in self.topics]}")

    def device(self, name: str) -> DeviceInfo:
        for d in self.devices:
            if d.name == name:
                return d
        raise KeyError(f"{self.path}: no device {name!r}; devices: {[d.name for d in self.devices]}")


# ---------------------------------------------------------------------------------------------
# Reading parts
# ---------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------
# Building the summary
# ---------------------------------------------------------------------------------------------


def read_session_info(
    path: Path | str,
    *,
    gap_factor: float = 5.0,
    min_gap_s: float = 0.5,
    max_gaps_listed: int = 100,
    verify: bool = False,
    verdicts: VerdictSource | None = VerdictSource.DATA,
) -> SessionInfo:
    """Summarize the session at ``path`` (its base, any part file, or a directory holding one session).

    Every part is read; a truncated part is read up to its last complete record, a damaged one
    around its damaged chunks, and either is noted in :attr:`SessionInfo.warnings` (never raised).
    ``verify``: scan every part, checking every chunk's CRC and the summary's (slower; the
    finalized parts are otherwise read from their summary, decompressing only the chunks that hold
    ``/rig/events`` and ``/rig/timebase`` messages). ``verdicts``: where the time-base verdicts come
    from (:class:`VerdictSource`; ``DATA`` reads and decodes every stream again, ``RECORDED`` takes the
    recorder's own from the events; None: none). Raises
    :class:`~vsccore.errors.SessionFileError` when no part is found, a part in the sequence is
    missing, or a file is not MCAP at all.
    """
    if gap_factor <= 1.0 or min_gap_s < 0:
        raise ValueError(f"gap_factor must be > 1 and min_gap_s >= 0, got {gap_factor}, {min_gap_s}")
    files = find_parts(path)
    parts: list[PartRead] = []
    for i, p in enumerate(files):
        try:
            parts.append(read_part(p, verify))
        except SessionFileError as exc:
            raise SessionFileError(f"{exc} (part {i + 1} of {len(files)})") from exc
    warnings: list[str] = []
    part_infos: list[PartInfo] = []
    for i, pr in enumerate(parts):
        ends = [md for name, md in pr.metadata if name == T.METADATA_PART_END]
        end_reason = ends[-1].get("reason") if ends else None
        idx = part_index(pr.path)
        part_infos.append(
            PartInfo(
                index=idx if idx is not None else i,
                path=pr.path,
                size_bytes=pr.size,
                messages=pr.messages,
                finalized=pr.finalized,
                read_via=pr.via,
                problem=pr.problem,
                problem_kind=pr.problem_kind,
                end_reason=end_reason,
                start_ns=pr.start_ns,
                end_ns=pr.end_ns,
                damage=pr.damage,
                verified=pr.verified,
            )
        )
        if pr.problem is not None:
            where = f"{pr.path.name} (part {i + 1} of {len(parts)})"
            if pr.problem_kind is ProblemKind.TRUNCATED:
                note = "" if i == len(parts) - 1 else " — not the last part: later parts follow a crash"
                warnings.append(f"{where}: truncated: {pr.problem}; read up to its last complete record{note}")
            else:
                for d in pr.damage:
                    warnings.append(f"{where}: {d.describe()}; every intact chunk read")

    metadata_first: dict[str, dict[str, str]] = {}
    for pr in parts:
        for name, md in pr.metadata:
            if name != T.METADATA_PART_END and name not in metadata_first:
                metadata_first[name] = md
    recorder = {k: v for k, v in metadata_first.get(T.METADATA_RECORDER, {}).items()
                if k not in _RECORDER_PER_PART_KEYS}

    topics = _topics(parts, gap_factor, min_gap_s, max_gaps_listed)
    start_ns, end_ns = _span(parts, topics)
    events, event_warnings = _events(parts)
    warnings.extend(event_warnings)
    if start_ns is not None and end_ns is not None:
        far = [t for t, _e in events if t < start_ns - _EVENT_SLACK_NS or t > end_ns + _EVENT_SLACK_NS]
        if far:
            worst = max(max(start_ns - t, t - end_ns) for t in far) / _NS
            warnings.append(f"{T.TOPIC_EVENTS}: {len(far)} events lie outside the recorded data by up to {worst:.0f} s "
                            "(host clock not on the common time base when they were written?)")
    clocks, n_tb, tb_warnings = _timebase(parts)
    warnings.extend(tb_warnings)
    devices = _devices(parts, topics, events)
    device_gaps = _device_gaps(events, end_ns)
    attachments: list[AttachmentInfo] = []
    seen: set[str] = set()
    for pr in parts:
        for a in pr.attachments:
            if a.name not in seen:
                seen.add(a.name)
                attachments.append(a)
    base = session_base(files[0]) if part_index(files[0]) is not None else files[0]
    cal_file = _calibration_file(files[0])
    if cal_file is not None and cal_file.problem is not None:
        warnings.append(cal_file.problem)
    verdict_info = None
    if verdicts is VerdictSource.DATA:
        verdict_info = _data_verdicts(base)
    elif verdicts is VerdictSource.RECORDED:
        verdict_info = _recorded_verdicts(events)
    return SessionInfo(
        path=base,
        name=recorder.get("session") or base.name,
        parts=tuple(part_infos),
        start_ns=start_ns,
        end_ns=end_ns,
        messages=sum(p.messages for p in parts),
        recorder=recorder,
        topics=topics,
        devices=devices,
        device_gaps=device_gaps,
        clocks=clocks,
        timebase_records=n_tb,
        calibration=dict(metadata_first.get(T.METADATA_CALIBRATION, {})),
        events=_event_summary(events),
        attachments=tuple(attachments),
        warnings=tuple(warnings),
        calibration_file=cal_file,
        verdicts=verdict_info,
    )


def _data_verdicts(base: Path) -> VerdictsInfo:
    """The verdicts computed from the session's streams (never raises for a bad session)."""
    from rig.core.quality import verdict_lines
    from rig.data import load_session
    from rig.data.verdicts import session_verdicts
    from vsccore.errors import RigError

    try:
        found = session_verdicts(load_session(base))
    except (RigError, OSError) as exc:
        problem = f"not judged: {exc}"
        return VerdictsInfo(VerdictSource.DATA, (problem,), {}, problem)
    lines = verdict_lines(found) or ["(no GNSS, CAN or DAQ stream to judge)"]
    return VerdictsInfo(VerdictSource.DATA, tuple(lines), {k: q.to_json() for k, q in sorted(found.items())})


_NO_RECORDED_VERDICTS = ("none recorded (a recording that did not finish, or an older recorder); "
                         "rig info --verify computes them from the data")


def _recorded_verdicts(events: Sequence[tuple[int, T.Event]]) -> VerdictsInfo:
    """The recorder's verdicts at the end of the recording, from its last ``timebase`` event that has them."""
    from rig.core.quality import THRESHOLDS, Figure, Gap, StreamQuality, Verdict, verdict_lines

    recorded: Mapping[str, Any] | None = None
    for _t, ev in events:
        v = ev.details.get("verdicts") if ev.kind is T.EventKind.TIMEBASE else None
        if isinstance(v, Mapping):
            recorded = v
    if recorded is None:
        return VerdictsInfo(VerdictSource.RECORDED, (_NO_RECORDED_VERDICTS,), {}, _NO_RECORDED_VERDICTS)
    found: dict[str, StreamQuality] = {}
    bad: list[str] = []
    for name, q in recorded.items():
        try:
            figures = tuple(
                Figure(fname, float("nan") if f.get("value") is None else float(f["value"]), Verdict(f["verdict"]),
                       str(f.get("fix", "")))
                for fname, f in q["figures"].items() if fname in THRESHOLDS
            )
            gaps = tuple(Gap(str(g["stream"]), str(g["topic"]), str(g["kind"]), int(g["start_ns"]), int(g["end_ns"]))
                         for g in q.get("gaps", ()))
            found[str(name)] = StreamQuality(str(name), figures, gaps, str(q.get("note", "")))
        except (KeyError, TypeError, ValueError, AttributeError):
            bad.append(str(name))
    lines = verdict_lines(found) or ["(no GNSS, CAN or DAQ stream to judge)"]
    problem = None
    if bad:
        problem = f"undecodable recorded verdicts of {', '.join(bad)}"
        lines.append(problem)
    return VerdictsInfo(VerdictSource.RECORDED, tuple(lines), {k: q.to_json() for k, q in sorted(found.items())},
                        problem)


def _calibration_file(part: Path) -> CalibrationFileInfo | None:
    """The calibration results file of the session that ``part`` belongs to (None when there is none)."""
    # rig.data.inputs, which names and reads the file, imports pydantic, the configuration models and
    # the dataset (a large share of `rig info`'s run time): only when such a file can exist at all
    if next(part.parent.glob("*.calibration.json"), None) is None:
        return None
    from rig.data.sidefiles import calibration_file_path, read_calibration_file

    path = calibration_file_path(part)
    if not path.exists():
        return None
    try:
        doc = read_calibration_file(part)
    except SessionFileError as exc:
        return CalibrationFileInfo(path, {}, None, str(exc))
    results = doc.get("results")
    fmt = doc.get("format")
    return CalibrationFileInfo(path, dict(results) if isinstance(results, Mapping) else {},
                               fmt if isinstance(fmt, str) else None)


def _span(parts: Sequence[PartRead], topics: Sequence[TopicInfo]) -> tuple[int | None, int | None]:
    """First and last log time of the data (events excluded; all messages if there is nothing else)."""
    data = [t for t in topics if t.first_ns is not None and t.last_ns is not None and t.topic != T.TOPIC_EVENTS]
    if data:
        return min(t.first_ns for t in data if t.first_ns is not None), max(
            t.last_ns for t in data if t.last_ns is not None)
    starts = [p.start_ns for p in parts if p.start_ns is not None]
    ends = [p.end_ns for p in parts if p.end_ns is not None]
    return (min(starts) if starts else None), (max(ends) if ends else None)


def _family(topic: str) -> tuple[T.TopicSpec | None, dict[str, str]]:
    try:
        return T.spec_for_topic(topic)
    except ValueError:
        return None, {}


def _topics(parts: Sequence[PartRead], gap_factor: float, min_gap_s: float, max_listed: int) -> tuple[TopicInfo, ...]:
    names: dict[str, tuple[str, str]] = {}
    for pr in parts:
        for topic, se in pr.topics.items():
            names.setdefault(topic, se)
    out: list[TopicInfo] = []
    for topic in sorted(names):
        schema, encoding = names[topic]
        spec, _params = _family(topic)
        count = sum(pr.counts.get(topic, 0) for pr in parts)
        arrays = [a for pr in parts for a in pr.times.get(topic, [])]
        t = np.sort(np.concatenate(arrays)) if arrays else np.zeros(0, dtype=np.int64)
        raw = spec.raw if spec is not None else encoding == T.BINARY_ENCODING
        if t.size == 0:
            out.append(TopicInfo(topic, schema, encoding, raw, count))
            continue
        first, last = int(t[0]), int(t[-1])
        rate = (t.size - 1) / ((last - first) / _NS) if t.size > 1 and last > first else None
        typical = max_iv = threshold = None
        gaps: tuple[Gap, ...] = ()
        gap_count, gap_total = 0, 0.0
        if t.size > 1:
            d = np.diff(t)
            typical = _typical_interval(d) / _NS
            max_iv = float(d.max()) / _NS
            periodic = spec is None or spec.pattern not in _NOT_PERIODIC
            if periodic and t.size >= 5:
                threshold = max(gap_factor * typical, min_gap_s)
                where = np.flatnonzero(d > threshold * _NS)
                gap_count = int(where.size)
                gap_total = float(d[where].sum()) / _NS
                gaps = tuple(Gap(int(t[i]), int(t[i + 1])) for i in where[:max_listed].tolist())
        out.append(TopicInfo(topic, schema, encoding, raw, count, first, last, rate, typical, max_iv, threshold,
                             gap_count, gap_total, gaps))
    return tuple(out)


def _typical_interval(d: npt.NDArray[np.int64]) -> float:
    """The interval length below which half of the total time is covered (a time-weighted median)."""
    s = np.sort(d)
    cum = np.cumsum(s)
    if cum[-1] <= 0:
        return 0.0
    return float(s[int(np.searchsorted(cum, 0.5 * cum[-1]))])


def _events(parts: Sequence[PartRead]) -> tuple[list[tuple[int, T.Event]], list[str]]:
    out: list[tuple[int, T.Event]] = []
    bad = 0
    for pr in parts:
        for log_t, data in pr.payloads.get(T.TOPIC_EVENTS, []):
            try:
                out.append((int(log_t), T.Event.from_json(json.loads(data))))
            except (ValueError, KeyError, TypeError):
                bad += 1
    out.sort(key=lambda e: e[0])
    warnings = [f"{T.TOPIC_EVENTS}: {bad} undecodable event messages skipped"] if bad else []
    return out, warnings


def _event_line(t: int, ev: T.Event) -> EventLine:
    return EventLine(t, ev.kind.value, ev.severity.value, ev.source, ev.text)


def _event_summary(events: Sequence[tuple[int, T.Event]]) -> EventSummary:
    by_kind: dict[str, int] = {}
    by_sev: dict[str, int] = {}
    for _t, ev in events:
        by_kind[ev.kind.value] = by_kind.get(ev.kind.value, 0) + 1
        by_sev[ev.severity.value] = by_sev.get(ev.severity.value, 0) + 1
    problems = tuple(_event_line(t, ev) for t, ev in events if ev.severity is not T.Severity.INFO)
    marks = tuple(_event_line(t, ev) for t, ev in events if ev.kind is T.EventKind.MARK)
    return EventSummary(len(events), dict(sorted(by_kind.items())), dict(sorted(by_sev.items())), problems, marks)


def _opt_int(v: Any) -> int | None:
    return int(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def _opt_float(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def _timebase(parts: Sequence[PartRead]) -> tuple[tuple[ClockInfo, ...], int, list[str]]:
    records = sorted((int(t), d) for pr in parts for t, d in pr.payloads.get(T.TOPIC_TIMEBASE, []))
    last: dict[str, tuple[int, dict[str, Any]]] = {}
    counts: dict[str, int] = {}
    bad = 0
    for t, data in records:
        try:
            rec = json.loads(data)
            clock = str(rec["clock"])
        except (ValueError, KeyError, TypeError):
            bad += 1
            continue
        last[clock] = (t, rec)
        counts[clock] = counts.get(clock, 0) + 1
    clocks = tuple(
        ClockInfo(
            clock=clock,
            method=str(rec.get("method", "")),
            reference=str(rec.get("reference", "")),
            status=str(rec.get("status", "")),
            n=_opt_int(rec.get("n")) or 0,
            span_s=_opt_float(rec.get("span_s")),
            offset_ns=_opt_int(T.TIMEBASE_OFFSET.read(rec)),
            drift_ppm=_opt_float(rec.get("drift_ppm")),
            jitter_ns=_opt_float(rec.get("jitter_ns")),
            latency_p50_ns=_opt_float(rec.get("latency_p50_ns")),
            latency_p95_ns=_opt_float(rec.get("latency_p95_ns")),
            rms_ns=_opt_float(rec.get("rms_ns")),
            max_abs_ns=_opt_float(rec.get("max_abs_ns")),
            leap_seconds=_opt_int(rec.get("leap_seconds")),
            time_ns=t,
            records=counts[clock],
        )
        for clock, (t, rec) in sorted(last.items())
    )
    warnings = [f"{T.TOPIC_TIMEBASE}: {bad} undecodable records skipped"] if bad else []
    return clocks, len(records), warnings


def _devices(
    parts: Sequence[PartRead], topics: Sequence[TopicInfo], events: Sequence[tuple[int, T.Event]]
) -> tuple[DeviceInfo, ...]:
    kinds: dict[str, str] = {}
    dev_topics: dict[str, list[str]] = {}
    messages: dict[str, int] = {}
    for ti in topics:
        spec, params = _family(ti.topic)
        if spec is None:
            continue
        if params:
            key, name = next(iter(params.items()))
            kind = _DEVICE_KINDS.get(key, "source")
        elif ti.topic.startswith("/relay/"):
            name, kind = "relay", "relay"
        elif ti.topic == T.TOPIC_SIM_TRUTH:
            name, kind = "sim", "sim"
        else:
            continue  # /rig/* are the rig's own topics
        kinds.setdefault(name, kind)
        dev_topics.setdefault(name, []).append(ti.topic)
        messages[name] = messages.get(name, 0) + ti.messages
    written: dict[str, int] = {}
    dropped: dict[str, int] = {}
    for pr in parts:
        for name, md in pr.metadata:
            if name == T.METADATA_RECORDER:
                for src in filter(None, md.get("sources", "").split(",")):
                    if src != "recorder.events":
                        kinds.setdefault(src, "source")
            elif name == T.METADATA_PART_END:
                for key, value in md.items():
                    if not key.startswith("source.") or not value.isdigit():
                        continue
                    src, _, what = key[len("source.") :].rpartition(".")
                    if src == "recorder.events":
                        continue
                    kinds.setdefault(src, "source")
                    # counters are cumulative over the session: the latest (largest) is the total
                    if what == "written":
                        written[src] = max(written.get(src, 0), int(value))
                    elif what == "dropped":
                        dropped[src] = max(dropped.get(src, 0), int(value))
    counters: dict[str, dict[str, int]] = {}
    overflow_drops: dict[str, int] = {}
    for _t, ev in events:
        c = counters.setdefault(ev.source, {"connect": 0, "disconnect": 0, "error": 0, "warning": 0})
        if ev.kind is T.EventKind.CONNECT:
            c["connect"] += 1
        elif ev.kind is T.EventKind.DISCONNECT:
            c["disconnect"] += 1
        if ev.kind is T.EventKind.OVERFLOW:
            n = _opt_int(ev.details.get("dropped"))
            overflow_drops[ev.source] = overflow_drops.get(ev.source, 0) + (n or 0)
        if ev.severity is T.Severity.ERROR:
            c["error"] += 1
        elif ev.severity is T.Severity.WARNING:
            c["warning"] += 1
    out: list[DeviceInfo] = []
    for name in sorted(kinds):
        c = counters.get(name, {})
        out.append(
            DeviceInfo(
                name=name,
                kind=kinds[name],
                topics=tuple(dev_topics.get(name, ())),
                messages=messages.get(name, 0),
                written=written.get(name),
                dropped=max(dropped.get(name, 0), overflow_drops.get(name, 0)),
                connects=c.get("connect", 0),
                disconnects=c.get("disconnect", 0),
                errors=c.get("error", 0),
                warnings=c.get("warning", 0),
            )
        )
    return tuple(out)


def _device_gaps(events: Sequence[tuple[int, T.Event]], session_end: int | None) -> tuple[DeviceGap, ...]:
    out: list[DeviceGap] = []
    open_since: dict[str, tuple[int, str]] = {}
    for t, ev in events:
        if ev.kind is T.EventKind.DISCONNECT:
            start = ev.start_ns if ev.start_ns is not None else t
            open_since.setdefault(ev.source, (start, ev.text))
        elif ev.kind is T.EventKind.CONNECT and ev.source in open_since:
            start, text = open_since.pop(ev.source)
            end = ev.end_ns if ev.end_ns is not None else t
            out.append(DeviceGap(ev.source, DeviceGapKind.DISCONNECT, start, max(end, start), text))
        elif ev.kind is T.EventKind.GAP:
            start = ev.start_ns if ev.start_ns is not None else t
            out.append(DeviceGap(ev.source, DeviceGapKind.GAP, start, ev.end_ns, ev.text))
        elif ev.kind is T.EventKind.OVERFLOW:
            start = ev.start_ns if ev.start_ns is not None else t
            out.append(DeviceGap(ev.source, DeviceGapKind.OVERFLOW, start, ev.end_ns, ev.text,
                                 dropped=_opt_int(ev.details.get("dropped"))))
    for source, (start, text) in open_since.items():
        until = max(session_end, start) if session_end is not None else None
        out.append(DeviceGap(source, DeviceGapKind.DISCONNECT, start, until, text, open=True))
    out.sort(key=lambda g: (g.start_ns, g.device))
    return tuple(out)


# ---------------------------------------------------------------------------------------------
# Output: JSON and text
# ---------------------------------------------------------------------------------------------


def format_utc(t_ns: int | None, *, date: bool = True) -> str:
    """ISO 8601 UTC text of an int-ns time with milliseconds (``2025-06-15T12:00:00.123Z``); ``-`` for None."""
    if t_ns is None:
        return "-"
    sec, ns = divmod(int(t_ns), _NS)
    dt = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(seconds=sec, microseconds=ns // 1000)
    text = dt.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
    return text if date else text[11:]


def _round(v: float | None, digits: int = 6) -> float | None:
    return None if v is None else round(v, digits)


def _event_json(e: EventLine) -> dict[str, Any]:
    return {"time_ns": e.time_ns, "time_utc": format_utc(e.time_ns), "kind": e.kind, "severity": e.severity,
            "source": e.source, "text": e.text}


def _damage_json(d: DamagedRegion, path: Path) -> dict[str, Any]:
    ev = d.event(path)
    return {**ev.details, "start_ns": ev.start_ns, "end_ns": ev.end_ns, "text": d.describe()}


def info_to_json(info: SessionInfo) -> dict[str, Any]:
    """The JSON document of ``rig info --json`` (keys :data:`INFO_JSON_KEYS`, see the module docstring)."""
    doc: dict[str, Any] = {
        "format": INFO_FORMAT,
        "version": INFO_VERSION,
        "session": info.name,
        "path": str(info.path),
        "start_ns": info.start_ns,
        "end_ns": info.end_ns,
        "start_utc": None if info.start_ns is None else format_utc(info.start_ns),
        "end_utc": None if info.end_ns is None else format_utc(info.end_ns),
        "duration_s": _round(info.duration_s, 9),
        "messages": info.messages,
        "truncated": info.truncated,
        "verified": info.verified,
        "damaged_chunks": info.damaged_chunks,
        "damaged_s": _round(info.damaged_s, 9),
        "recorder": dict(info.recorder),
        "parts": [
            {
                "index": p.index,
                "file": p.path.name,
                "bytes": p.size_bytes,
                "messages": p.messages,
                "finalized": p.finalized,
                "read_via": p.read_via.value,
                "problem": p.problem,
                "problem_kind": None if p.problem_kind is None else p.problem_kind.value,
                "end_reason": p.end_reason,
                "start_ns": p.start_ns,
                "end_ns": p.end_ns,
                "damaged_chunks": p.damaged_chunks,
                "damaged_s": _round(p.damaged_s, 9),
                "damage": [_damage_json(d, p.path) for d in p.damage],
            }
            for p in info.parts
        ],
        "topics": [
            {
                "topic": t.topic,
                "schema": t.schema,
                "encoding": t.encoding,
                "raw": t.raw,
                "messages": t.messages,
                "first_ns": t.first_ns,
                "last_ns": t.last_ns,
                "rate_hz": _round(t.rate_hz),
                "typical_interval_s": _round(t.typical_interval_s, 9),
                "max_interval_s": _round(t.max_interval_s, 9),
                "gap_threshold_s": _round(t.gap_threshold_s, 9),
                "gap_count": t.gap_count,
                "gap_total_s": _round(t.gap_total_s, 9),
                "gaps": [{"start_ns": g.start_ns, "end_ns": g.end_ns, "duration_s": _round(g.duration_s, 9)}
                         for g in t.gaps],
            }
            for t in info.topics
        ],
        "devices": [
            {
                "name": d.name,
                "kind": d.kind,
                "topics": list(d.topics),
                "messages": d.messages,
                "written": d.written,
                "dropped": d.dropped,
                "connects": d.connects,
                "disconnects": d.disconnects,
                "errors": d.errors,
                "warnings": d.warnings,
            }
            for d in info.devices
        ],
        "device_gaps": [
            {
                "device": g.device,
                "kind": g.kind.value,
                "start_ns": g.start_ns,
                "end_ns": g.end_ns,
                "duration_s": _round(g.duration_s, 9),
                "open": g.open,
                "dropped": g.dropped,
                "text": g.text,
            }
            for g in info.device_gaps
        ],
        "timebase": {
            "records": info.timebase_records,
            "clocks": [
                {
                    "clock": c.clock,
                    "method": c.method,
                    "reference": c.reference,
                    "status": c.status,
                    "n": c.n,
                    "span_s": c.span_s,
                    "offset_ns": c.offset_ns,
                    "drift_ppm": c.drift_ppm,
                    "jitter_ns": c.jitter_ns,
                    "latency_p50_ns": c.latency_p50_ns,
                    "latency_p95_ns": c.latency_p95_ns,
                    "rms_ns": c.rms_ns,
                    "max_abs_ns": c.max_abs_ns,
                    "leap_seconds": c.leap_seconds,
                    "time_ns": c.time_ns,
                    "records": c.records,
                }
                for c in info.clocks
            ],
            "verdicts": _verdicts_json(info.verdicts),
        },
        "calibration": dict(info.calibration),
        "calibration_file": None if info.calibration_file is None else {
            "path": str(info.calibration_file.path),
            "format": info.calibration_file.format,
            "results": _jsonable(info.calibration_file.results),
            "problem": info.calibration_file.problem,
        },
        "events": {
            "total": info.events.total,
            "by_kind": dict(info.events.by_kind),
            "by_severity": dict(info.events.by_severity),
            "problems": [_event_json(e) for e in info.events.problems],
            "marks": [_event_json(e) for e in info.events.marks],
        },
        "attachments": [{"name": a.name, "media_type": a.media_type, "bytes": a.size_bytes} for a in info.attachments],
        "warnings": list(info.warnings),
    }
    assert tuple(doc) == INFO_JSON_KEYS
    return doc


def _verdicts_json(v: VerdictsInfo | None) -> dict[str, Any] | None:
    if v is None:
        return None
    return {"problem": v.problem, "streams": _jsonable(dict(v.streams)), "source": v.source.value}


def _jsonable(v: Any) -> Any:
    """A JSON-loaded value made strict-JSON safe (non-finite floats, which the file should not hold, to null)."""
    if isinstance(v, float):
        return v if np.isfinite(v) else None
    if isinstance(v, Mapping):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_jsonable(x) for x in v]
    return v


def _value_text(v: Any) -> str | None:
    """A short text for a scalar or a short list of scalars (None for anything bigger: see --json)."""
    if isinstance(v, bool) or v is None:
        return str(v).lower() if isinstance(v, bool) else "-"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, int | str):
        return str(v)
    if isinstance(v, list | tuple) and len(v) <= 8 and all(isinstance(x, int | float | str) for x in v):
        return "[" + ", ".join(_value_text(x) or "?" for x in v) + "]"
    return None


def _entry_lines(entry: Any, indent: str) -> list[str]:
    """``k = v, …`` of an entry's scalar fields; nested tables of scalars (per sensor) one per line."""
    if not isinstance(entry, Mapping):
        text = _value_text(entry)
        return [f"{indent}{text if text is not None else '(see --json)'}"]
    flat: list[str] = []
    nested: list[str] = []
    skipped = 0
    for k, v in entry.items():
        text = _value_text(v)
        if text is not None:
            flat.append(f"{k} = {text}")
        elif isinstance(v, Mapping) and all(_value_text(x) is not None for x in v.values()):
            nested.append(f"{indent}  {k}: " + ", ".join(f"{kk} = {_value_text(x)}" for kk, x in v.items()))
        else:
            skipped += 1
    more = [f"{skipped} more field{'s' if skipped != 1 else ''} (see --json)"] if skipped else []
    head = [f"{indent}{', '.join(flat + more)}"] if flat or more else []
    return head + nested


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"


def _secs(v: float | None) -> str:
    if v is None:
        return "-"
    if abs(v) < 1.0:
        return f"{v * 1e3:.1f} ms"
    return f"{v:.2f} s"


def _ns_text(v: float | None) -> str:
    if v is None:
        return "-"
    if abs(v) >= 1e6:
        return f"{v / 1e6:.2f} ms"
    return f"{v / 1e3:.1f} µs"


def _rel(t: int | None, t0: int | None) -> str:
    return "-" if t is None or t0 is None else f"{(t - t0) / _NS:+.2f}"


def _table(rows: Sequence[Sequence[str]], right: Sequence[bool]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = []
    for r in rows:
        cells = [c.rjust(w) if right[i] else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True))]
        lines.append("  " + "  ".join(cells).rstrip())
    return lines


def format_info(info: SessionInfo, *, max_list: int = 20) -> str:
    """The text ``rig info`` prints (``max_list``: longest list of gaps or events before "… more")."""
    t0 = info.start_ns
    out: list[str] = []
    n_parts = len(info.parts)
    bad = sum(1 for p in info.parts if p.problem is not None or not p.finalized)
    damaged = sum(1 for p in info.parts if p.damage)
    state = f", {bad} not finalized" if bad - damaged > 0 else ""
    state += f", {damaged} damaged" if damaged else ""
    out.append(f"session    {info.name}  ({n_parts} part{'s' if n_parts != 1 else ''}{state})  {info.path}")
    dur = info.duration_s
    out.append(f"time       {format_utc(info.start_ns)} → {format_utc(info.end_ns)}  "
               f"({'-' if dur is None else f'{dur:.3f} s'})")
    out.append(f"messages   {info.messages}")
    if info.damaged_chunks or any(p.damage for p in info.parts):
        out.append(f"integrity  damaged: {info.damaged_chunks} chunks, {info.damaged_s:.3f} s of data "
                   f"({'every chunk CRC checked' if info.verified else 'met while scanning'}; "
                   "`rig recover` keeps every intact chunk)")
    elif info.verified:
        out.append("integrity  every chunk CRC checked: no damage")
    else:
        out.append("integrity  chunk CRCs not checked (rig info --verify checks them)")
    if info.recorder:
        r = info.recorder
        out.append(f"recorder   {r.get('software', '?')} {r.get('version', '')} on {r.get('host', '?')}, "
                   f"{r.get('compression', '?')} chunks")

    out.append("")
    out.append("parts")
    rows: list[tuple[str, ...]] = [("file", "size", "messages", "state", "read via", "ended")]
    for p in info.parts:
        st = "finalized" if p.finalized and p.problem is None else (
            "DAMAGED" if p.damage else (p.problem_kind or "unfinished").upper())
        rows.append((p.path.name, _size(p.size_bytes), str(p.messages), str(st), p.read_via.value, p.end_reason or "-"))
    out.extend(_table(rows, (False, True, True, False, False, False)))
    for p in info.parts:
        if p.problem is not None:
            out.append(f"  ! {p.path.name}: {p.problem}")

    out.append("")
    out.append(f"topics ({len(info.topics)}; times in s from the start)")
    rows = [("topic", "messages", "rate", "typical dt", "max dt", "from", "to", "gaps")]
    for t in info.topics:
        gaps = "-" if t.gap_threshold_s is None else (
            "0" if not t.gap_count else f"{t.gap_count} ({t.gap_total_s:.2f} s)")
        rows.append((t.topic, str(t.messages), "-" if t.rate_hz is None else f"{t.rate_hz:.2f} Hz",
                     _secs(t.typical_interval_s), _secs(t.max_interval_s), _rel(t.first_ns, t0), _rel(t.last_ns, t0),
                     gaps))
    out.extend(_table(rows, (False, True, True, True, True, True, True, False)))

    out.append("")
    out.append("devices")
    if info.devices:
        rows = [("device", "kind", "topics", "messages", "written", "dropped", "connects", "disconnects", "errors",
                 "warnings")]
        for d in info.devices:
            written = "-" if d.written is None else str(d.written)
            rows.append((d.name, d.kind, str(len(d.topics)), str(d.messages), written, str(d.dropped), str(d.connects),
                         str(d.disconnects), str(d.errors), str(d.warnings)))
        out.extend(_table(rows, (False, False, True, True, True, True, True, True, True, True)))
    else:
        out.append("  (none)")

    out.append("")
    topic_gaps = [(t.topic, g) for t in info.topics for g in t.gaps]
    total_topic_gaps = sum(t.gap_count for t in info.topics)
    out.append(f"gaps ({total_topic_gaps} in topics, {len(info.device_gaps)} device events)")
    if not topic_gaps and not info.device_gaps:
        out.append("  (none)")
    topic_gaps.sort(key=lambda x: (x[1].start_ns, x[0]))
    for topic, g in topic_gaps[:max_list]:
        out.append(f"  {format_utc(g.start_ns, date=False)} → {format_utc(g.end_ns, date=False)}  "
                   f"{g.duration_s:8.3f} s  {topic}")
    if len(topic_gaps) > max_list or total_topic_gaps > len(topic_gaps):
        out.append(f"  … {total_topic_gaps - min(max_list, len(topic_gaps))} more topic gaps (see --json)")
    for dg in info.device_gaps[:max_list]:
        span = "open" if dg.open else _secs(dg.duration_s)
        extra = f", {dg.dropped} dropped" if dg.dropped else ""
        out.append(f"  {format_utc(dg.start_ns, date=False)} → {format_utc(dg.end_ns, date=False)}  {span:>10}  "
                   f"{dg.device} {dg.kind.value}{extra}: {dg.text}")
    if len(info.device_gaps) > max_list:
        out.append(f"  … {len(info.device_gaps) - max_list} more device gaps (see --json)")

    out.append("")
    out.append(f"time base ({info.timebase_records} records in {T.TOPIC_TIMEBASE})")
    if info.clocks:
        rows = [("clock", "method", "status", "n", "span", "drift", "jitter", "p95 latency", "sync rms", "sync max",
                 "leap")]
        for c in info.clocks:
            rows.append((c.clock, c.method, c.status, str(c.n), _secs(c.span_s),
                         "-" if c.drift_ppm is None else f"{c.drift_ppm:+.2f} ppm", _ns_text(c.jitter_ns),
                         _ns_text(c.latency_p95_ns), _ns_text(c.rms_ns), _ns_text(c.max_abs_ns),
                         "-" if c.leap_seconds is None else str(c.leap_seconds)))
        out.extend(_table(rows, (False, False, False, True, True, True, True, True, True, True, True)))
    else:
        out.append("  (no time-base records: the time base quality is unknown)")
    if info.verdicts is not None:
        recorded = info.verdicts.source is VerdictSource.RECORDED
        out.append("time-base verdicts (good / degraded / unusable, see rig.core.quality"
                   + ("; as the recorder judged at the end of the recording, rig info --verify recomputes them "
                      "from the data)" if recorded else ")"))
        out.extend(f"  {line}" for line in info.verdicts.lines)

    out.append("")
    out.append("calibration in force")
    if info.calibration:
        width = max(len(k) for k in info.calibration)
        out.extend(f"  {k.ljust(width)} = {v}" for k, v in sorted(info.calibration.items()))
    else:
        out.append("  (none recorded)")

    cf = info.calibration_file
    out.append("")
    if cf is None:
        out.append("calibration results")
        out.append("  (no calibration file: rig calibrate-baseline writes <session>.calibration.json)")
    else:
        out.append(f"calibration results ({cf.path.name})")
        if cf.problem is not None:
            out.append(f"  ! {cf.problem}")
        elif not cf.results:
            out.append("  (the file holds no results)")
        for key, entry in cf.results.items():
            out.append(f"  {key}")
            out.extend(_entry_lines(entry, "    "))

    out.append("")
    ev = info.events
    kinds = ", ".join(f"{k} {n}" for k, n in ev.by_kind.items())
    out.append(f"events ({ev.total}{': ' + kinds if kinds else ''})")
    listed = sorted(ev.problems + ev.marks, key=lambda e: e.time_ns)
    for e in listed[:max_list]:
        out.append(f"  {format_utc(e.time_ns, date=False)}  {e.severity.upper():7}  {e.kind:10}  {e.source}: {e.text}")
    if len(listed) > max_list:
        out.append(f"  … {len(listed) - max_list} more (see --json)")

    if info.attachments:
        out.append("")
        out.append("attachments")
        out.extend(f"  {a.name}  ({a.media_type}, {_size(a.size_bytes)})" for a in info.attachments)

    if info.warnings:
        out.append("")
        out.append("warnings")
        out.extend(f"  ! {w}" for w in info.warnings)
    return "\n".join(out) + "\n"
