"""Sources: each device's bounded, non-blocking queue into the recorder's one writer thread.

A device thread calls :meth:`Source.put` for every message. ``put`` never blocks: it resolves the
topic, encodes JSON payloads (so the caller may reuse its dict), and appends to the source's own
queue. When the queue is full the message is dropped, *counted*, and the loss is written to
``/rig/events`` (count, topics and log-time range) by the writer as soon as the queue has room again.
Nothing is lost silently.

The queue is a ``collections.deque`` (its ``append``/``popleft`` are atomic in CPython); the bound
is checked before appending, so concurrent producers on one source may overshoot it by a few
messages. Exact per-source counters assume one producer thread per source, which is how the rig
uses them (one source per device).

``log_time`` is monotonic per channel: ``put`` holds the channel's small lock while it compares the
message's ``log_time`` with the channel's last one and appends, and a message whose time runs back
is queued at the channel's last time instead — *clamped*, counted per channel
(:class:`ChannelTiming`), and reported on ``/rig/events`` (one ``timebase`` event per channel and
second of log time, with the count and the largest step back). ``/rig/events`` itself is exempt: an
event's ``log_time`` *is* the time it is about (an operator mark's key press, a gap's start, the
first drop of an overflow), which often comes after later ones were written; moving it would
falsify it, and readers sort events by time. The same pass learns each periodic channel's
period (median of its recent intervals) and keeps a silence longer than
:func:`rig.core.quality.stall_threshold_ns` of it as a stall with its span (:attr:`ChannelTiming.stall_spans`);
the recording session writes the stalls its devices did not report themselves as ``gap`` events
(one per device and span, :mod:`rig.record.recording`).
"""

from __future__ import annotations

import logging
import operator
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from rig.core.quality import stall_threshold_ns
from rig.core.topics import (
    TOPIC_EVENTS,
    TOPIC_TIMEBASE,
    Event,
    EventKind,
    SchemaSpec,
    Severity,
    TopicSpec,
    encode_record,
    spec_for_topic,
    validate_json,
)
from vsccore.clock import Clock

__all__ = ["ChannelTiming", "Source", "SourceStats", "channel_timings"]

log = logging.getLogger(__name__)

_U64 = 2**64 - 1
_CLAMP_EVENT_EVERY_NS = 1_000_000_000
"""At most one clamp event per channel and second of log time (the count covers the clamps between)."""
_MAX_SPANS = 10_000
"""Stall spans kept per channel (the count and total go on beyond)."""
_PERIOD_SAMPLES = 64
"""Intervals a channel's period estimate is the median of (re-estimated every that many)."""
_NOT_PERIODIC_SUFFIXES = ("/markpos", "/marktime", "/raw")
"""Event-driven GNSS logs (the sync switch) and raw byte chunks (as the port delivered them): no period,
no stalls (the decoded topics of the same device are judged)."""


def _is_periodic(topic: str) -> bool:
    return topic not in (TOPIC_EVENTS, TOPIC_TIMEBASE) and not topic.endswith(_NOT_PERIODIC_SUFFIXES)


@dataclass(frozen=True, slots=True)
class ChannelTiming:
    """The log-time record of one channel so far (:func:`channel_timings`)."""

    topic: str
    source: str
    """The source that last wrote to it."""
    messages: int
    first_log_ns: int | None
    last_log_ns: int | None
    period_ns: float | None
    """Median interval of its recent messages (None: not periodic, or too few messages yet)."""
    clamped: int
    """Messages whose ``log_time`` ran back and was clamped to the channel's last one."""
    clamp_max_ns: int
    """The largest such step back."""
    stalls: int
    """Silences longer than :func:`rig.core.quality.stall_threshold_ns` of the period (each a gap event)."""
    stalled_ns: int
    """Their total length."""
    stall_spans: tuple[tuple[int, int], ...] = ()
    """(start, end) log times of the stalls (the first :data:`_MAX_SPANS`)."""
    source_gaps: tuple[tuple[int, int], ...] = ()
    """Gaps the source reported itself (:meth:`Source.gap`: a disconnect, a bus gap …)."""

    def late_ns(self, now_log_ns: int) -> int | None:
        """How long the channel has been silent at ``now_log_ns`` if that is a stall (else None)."""
        if self.period_ns is None or self.last_log_ns is None:
            return None
        late = now_log_ns - self.last_log_ns
        return late if late > stall_threshold_ns(self.period_ns) else None


@dataclass(frozen=True, slots=True)
class SourceStats:
    """Counters of one source (messages)."""

    name: str
    accepted: int
    """Messages queued by :meth:`Source.put`."""
    written: int
    """Messages the writer has written to the file."""
    dropped: int
    """Messages refused because the queue was full (each loss is also an event on ``/rig/events``)."""
    rejected: int
    """Messages refused because the recording had stopped or failed."""
    queued: int
    """Messages waiting in the queue now."""
    maxsize: int


class ChannelState:
    """A concrete topic: its schema, its MCAP id in the current part, and its sequence counter."""

    __slots__ = ("clamp_event_ns", "clamp_max", "clamp_reported", "clamped", "epoch", "first_log", "intervals",
                 "is_json", "last_log", "lock", "mcap_id", "n", "period", "periodic", "schema", "seq", "source",
                 "spec", "stall_spans", "stalled_ns", "stalls", "topic")

    def __init__(self, topic: str, spec: TopicSpec) -> None:
        self.topic = topic
        self.spec = spec
        self.schema: SchemaSpec = spec.schema
        self.is_json = spec.schema.is_json
        self.mcap_id = 0
        self.epoch = -1
        """Part number in which ``mcap_id`` was registered (-1: not yet)."""
        self.seq = 0
        """Next sequence number; it runs on across parts, so every message has one (topic, sequence)."""
        self.lock = threading.Lock()
        self.source = ""
        self.n = 0
        self.first_log = -1
        self.last_log = -1
        """Largest log time queued on the channel (-1: none yet)."""
        self.clamped = 0
        self.clamp_max = 0
        self.clamp_reported = 0
        self.clamp_event_ns = -1
        self.periodic = _is_periodic(topic)
        self.intervals: list[int] = []
        self.period = 0.0
        self.stalls = 0
        self.stalled_ns = 0
        self.stall_spans: list[tuple[int, int]] = []

    def timing(self, source_gaps: tuple[tuple[int, int], ...] = ()) -> ChannelTiming:
        with self.lock:
            return ChannelTiming(
                topic=self.topic, source=self.source, messages=self.n,
                first_log_ns=self.first_log if self.n else None, last_log_ns=self.last_log if self.n else None,
                period_ns=self.period if self.periodic and self.period > 0 else None,
                clamped=self.clamped, clamp_max_ns=self.clamp_max, stalls=self.stalls, stalled_ns=self.stalled_ns,
                stall_spans=tuple(self.stall_spans), source_gaps=source_gaps,
            )


@dataclass(slots=True)
class DropWindow:
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    topics: dict[str, int] = field(default_factory=dict)


class SourceHub:
    """State shared by the recorder and its sources: channels, the wake-up event, accepting or not."""

    def __init__(self, clock: Clock, host_to_log_time: Callable[[int], int], validate: bool,
                 wake_depth: int = 1) -> None:
        self.clock = clock
        self.host_to_log_time = host_to_log_time
        self.validate = validate
        self.channels: dict[str, ChannelState] = {}
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.idle = False
        self.wake_depth = wake_depth
        """Messages a source queues before it wakes an idle writer (which otherwise looks again at
        its idle wait): one wake-up per message costs more than the writing, and most under a busy
        host, where messages come one by one."""
        self.accepting = False
        self.sources: tuple[Source, ...] = ()
        self.events: Source | None = None

    def channel(self, topic: str) -> ChannelState:
        """The channel of ``topic``, created on first use (ValueError for a topic not in rig.core.topics)."""
        ch = self.channels.get(topic)
        if ch is not None:
            return ch
        spec, _params = spec_for_topic(topic)
        with self.lock:
            ch = self.channels.get(topic)
            if ch is None:
                ch = ChannelState(topic, spec)
                self.channels = {**self.channels, topic: ch}
        return ch

    def add_source(self, src: Source) -> None:
        with self.lock:
            if any(s.name == src.name for s in self.sources):
                raise ValueError(f"recorder already has a source named {src.name!r}")
            self.sources = (*self.sources, src)


class Source:
    """One device's way into the recording (create with :meth:`rig.store.Recorder.source`).

    ``put`` is non-blocking and returns False when the message was not queued (queue full: counted
    and reported on ``/rig/events``; or the recording has stopped). ``event`` and ``error`` write to
    ``/rig/events`` through the recorder's own event queue, so they are not lost when this source's
    queue is full.
    """

    __slots__ = (
        "_accepted",
        "_dropped_total",
        "_drops",
        "_gaps",
        "_hub",
        "_lock",
        "_maxsize",
        "_q",
        "_rejected",
        "_written",
        "name",
    )

    def __init__(self, name: str, maxsize: int, hub: SourceHub) -> None:
        if maxsize < 1:
            raise ValueError(f"source {name!r}: maxsize must be >= 1, got {maxsize}")
        self.name = name
        self._hub = hub
        self._maxsize = maxsize
        self._q: deque[tuple[ChannelState, int, int, bytes]] = deque()
        self._lock = threading.Lock()
        self._drops: DropWindow | None = None
        self._accepted = 0
        self._written = 0
        self._rejected = 0
        self._dropped_total = 0
        self._gaps: list[tuple[int, int]] = []

    def put(self, topic: str, log_time_ns: int, publish_time_ns: int, payload: bytes | Mapping[str, Any]) -> bool:
        """Queue one message; never blocks.

        ``log_time_ns``: when it happened on the common time base (ns since the Unix epoch, UTC);
        ``publish_time_ns``: host receive time. ``payload``: bytes (raw topics, or already-encoded
        JSON), or a mapping for JSON topics (encoded here). Returns False if the message was not
        queued. Raises ValueError for an unknown topic or a time outside uint64, TypeError for a
        non-bytes payload on a raw topic.
        """
        hub = self._hub
        if not hub.accepting:
            self._rejected += 1
            return False
        ch = hub.channels.get(topic)
        if ch is None:
            ch = hub.channel(topic)
        if type(log_time_ns) is not int:
            log_time_ns = operator.index(log_time_ns)
        if type(publish_time_ns) is not int:
            publish_time_ns = operator.index(publish_time_ns)
        if not (0 <= log_time_ns <= _U64 and 0 <= publish_time_ns <= _U64):
            raise ValueError(
                f"source {self.name!r}, topic {topic}: times must be ns in [0, 2^64), "
                f"got log {log_time_ns}, publish {publish_time_ns}"
            )
        if type(payload) is bytes:
            data = payload
        elif isinstance(payload, bytes | bytearray | memoryview):
            data = bytes(payload)
        elif ch.is_json:
            if hub.validate:
                problems = validate_json(ch.schema.document, payload)
                if problems:
                    raise ValueError(f"source {self.name!r}, topic {topic}: {'; '.join(problems)}")
            data = encode_record(payload)
        else:
            raise TypeError(f"source {self.name!r}: {topic} is a raw topic, payload must be bytes")
        q = self._q
        if len(q) >= self._maxsize:
            self._count_drop(topic, log_time_ns)
            return False
        clamp: tuple[int, int, int] | None = None
        with ch.lock:
            last = ch.last_log
            if log_time_ns < last and topic != TOPIC_EVENTS:
                back = last - log_time_ns
                log_time_ns = last
                ch.clamped += 1
                if back > ch.clamp_max:
                    ch.clamp_max = back
                due = ch.clamp_event_ns < 0 or last - ch.clamp_event_ns >= _CLAMP_EVENT_EVERY_NS
                if due:
                    clamp = (last, ch.clamped - ch.clamp_reported, back)
                    ch.clamp_reported = ch.clamped
                    ch.clamp_event_ns = last
            else:
                if last >= 0 and ch.periodic and log_time_ns >= last:
                    dt = log_time_ns - last
                    if ch.period > 0 and dt > stall_threshold_ns(ch.period):
                        ch.stalls += 1
                        ch.stalled_ns += dt
                        if len(ch.stall_spans) < _MAX_SPANS:
                            ch.stall_spans.append((last, log_time_ns))
                    elif dt > 0:
                        iv = ch.intervals
                        iv.append(dt)
                        if len(iv) >= _PERIOD_SAMPLES:
                            iv.sort()
                            ch.period = float(iv[len(iv) // 2])
                            iv.clear()
                if ch.first_log < 0:
                    ch.first_log = log_time_ns
                ch.last_log = max(last, log_time_ns)
            ch.n += 1
            ch.source = self.name
            q.append((ch, log_time_ns, publish_time_ns, data))
        self._accepted += 1
        if hub.idle and (len(q) >= hub.wake_depth or 2 * len(q) >= self._maxsize):
            hub.wake.set()
        if clamp is not None:
            self._report_clamp(topic, *clamp)
        return True

    def event(
        self,
        kind: EventKind,
        text: str,
        *,
        severity: Severity = Severity.INFO,
        log_time_ns: int | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
        **details: Any,
    ) -> bool:
        """Record an event from this source on ``/rig/events`` (log time defaults to now)."""
        ev = Event(kind, self.name, text, severity, start_ns, end_ns, details)
        return self._hub_event(ev, log_time_ns)

    def error(self, text: str, exc: BaseException | None = None, **details: Any) -> bool:
        """Record a device error (the recording goes on; other sources are not affected)."""
        if exc is not None:
            details = {"exception": type(exc).__name__, "message": str(exc), **details}
        log.warning("source %s: %s", self.name, text)
        return self.event(EventKind.ERROR, text, severity=Severity.ERROR, **details)

    def gap(self, start_ns: int, end_ns: int, text: str, **details: Any) -> bool:
        """Record a gap in this source's data between two times on the common time base."""
        with self._lock:
            if len(self._gaps) < _MAX_SPANS:
                self._gaps.append((int(start_ns), int(end_ns)))
        return self.event(
            EventKind.GAP, text, severity=Severity.WARNING, log_time_ns=start_ns, start_ns=start_ns, end_ns=end_ns,
            **details,
        )

    def stats(self) -> SourceStats:
        with self._lock:
            dropped_pending = self._drops.count if self._drops is not None else 0
        return SourceStats(
            name=self.name,
            accepted=self._accepted,
            written=self._written,
            dropped=self._dropped_total + dropped_pending,
            rejected=self._rejected,
            queued=len(self._q),
            maxsize=self._maxsize,
        )

    # --- internal ------------------------------------------------------------------------------

    def _hub_event(self, ev: Event, log_time_ns: int | None) -> bool:
        hub = self._hub
        now = hub.clock.now_ns()
        t = hub.host_to_log_time(now) if log_time_ns is None else log_time_ns
        events = hub.events
        if events is None:
            return False
        return events.put(TOPIC_EVENTS, t, now, ev.to_json())

    def _report_clamp(self, topic: str, at_ns: int, count: int, back_ns: int) -> None:
        self._hub_event(Event(
            EventKind.TIMEBASE, self.name,
            f"{topic}: {count} message(s) with log_time running back (last {back_ns / 1e6:.3f} ms) written at the "
            "channel's last log_time", Severity.WARNING, None, None,
            {"topic": topic, "clamped": count, "step_back_ns": back_ns},
        ), at_ns)

    def _count_drop(self, topic: str, log_time_ns: int) -> None:
        with self._lock:
            w = self._drops
            if w is None:
                w = self._drops = DropWindow(first_ns=log_time_ns, last_ns=log_time_ns)
            w.count += 1
            w.first_ns = min(w.first_ns, log_time_ns)
            w.last_ns = max(w.last_ns, log_time_ns)
            w.topics[topic] = w.topics.get(topic, 0) + 1

    def _take_drops(self) -> DropWindow | None:
        """Called by the writer: the losses since the last report (and reset)."""
        with self._lock:
            w, self._drops = self._drops, None
            if w is not None:
                self._dropped_total += w.count
        return w


def channel_timings(hub: SourceHub) -> list[ChannelTiming]:
    """The log-time record of every channel of a recording (topic order), with the gaps its source reported."""
    gaps: dict[str, tuple[tuple[int, int], ...]] = {}
    for src in hub.sources:
        with src._lock:
            gaps[src.name] = tuple(src._gaps)
    out = []
    for t in sorted(hub.channels):
        ch = hub.channels[t]
        out.append(ch.timing(gaps.get(ch.source, ())))
    return out
