"""Sources: each device's bounded, non-blocking queue into the recorder's one writer thread.

A device thread calls :meth:`Source.put` for every message. ``put`` never blocks: it resolves the
topic, encodes JSON payloads (so the caller may reuse its dict), and appends to the source's own
queue. When the queue is full the message is dropped, *counted*, and the loss is written to
``/rig/events`` (count, topics and log-time range) by the writer as soon as the queue has room again.
Nothing is lost silently.

The queue is a ``collections.deque`` (its ``append``/``popleft`` are atomic in CPython), so the hot
path takes no lock; the bound is checked before appending, so concurrent producers on one source
may overshoot it by a few messages. Exact per-source counters assume one producer thread per
source, which is how the rig uses them (one source per device).
"""

from __future__ import annotations

import logging
import operator
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from rig.topics import (
    TOPIC_EVENTS,
    Event,
    EventKind,
    SchemaSpec,
    Severity,
    TopicSpec,
    encode_json,
    spec_for_topic,
    validate_json,
)
from vsccore.clock import Clock

__all__ = ["Source", "SourceStats"]

log = logging.getLogger(__name__)

_U64 = 2**64 - 1


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


class _Channel:
    """A concrete topic: its schema, its MCAP id in the current part, and its sequence counter."""

    __slots__ = ("epoch", "is_json", "mcap_id", "schema", "seq", "spec", "topic")

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


@dataclass(slots=True)
class _DropWindow:
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    topics: dict[str, int] = field(default_factory=dict)


class _Hub:
    """State shared by the recorder and its sources: channels, the wake-up event, accepting or not."""

    def __init__(self, clock: Clock, host_to_log_time: Callable[[int], int], validate: bool) -> None:
        self.clock = clock
        self.host_to_log_time = host_to_log_time
        self.validate = validate
        self.channels: dict[str, _Channel] = {}
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.idle = False
        self.accepting = False
        self.sources: tuple[Source, ...] = ()
        self.events: Source | None = None

    def channel(self, topic: str) -> _Channel:
        """The channel of ``topic``, created on first use (ValueError for a topic not in rig.topics)."""
        ch = self.channels.get(topic)
        if ch is not None:
            return ch
        spec, _params = spec_for_topic(topic)
        with self.lock:
            ch = self.channels.get(topic)
            if ch is None:
                ch = _Channel(topic, spec)
                self.channels = {**self.channels, topic: ch}
        return ch

    def add_source(self, src: Source) -> None:
        with self.lock:
            if any(s.name == src.name for s in self.sources):
                raise ValueError(f"recorder already has a source named {src.name!r}")
            self.sources = (*self.sources, src)


class Source:
    """One device's way into the recording (create with :meth:`rig.recorder.Recorder.source`).

    ``put`` is non-blocking and returns False when the message was not queued (queue full: counted
    and reported on ``/rig/events``; or the recording has stopped). ``event`` and ``error`` write to
    ``/rig/events`` through the recorder's own event queue, so they are not lost when this source's
    queue is full.
    """

    __slots__ = (
        "_accepted",
        "_dropped_total",
        "_drops",
        "_hub",
        "_lock",
        "_maxsize",
        "_q",
        "_rejected",
        "_written",
        "name",
    )

    def __init__(self, name: str, maxsize: int, hub: _Hub) -> None:
        if maxsize < 1:
            raise ValueError(f"source {name!r}: maxsize must be >= 1, got {maxsize}")
        self.name = name
        self._hub = hub
        self._maxsize = maxsize
        self._q: deque[tuple[_Channel, int, int, bytes]] = deque()
        self._lock = threading.Lock()
        self._drops: _DropWindow | None = None
        self._accepted = 0
        self._written = 0
        self._rejected = 0
        self._dropped_total = 0

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
            data = encode_json(payload)
        else:
            raise TypeError(f"source {self.name!r}: {topic} is a raw topic, payload must be bytes")
        q = self._q
        if len(q) >= self._maxsize:
            self._count_drop(topic, log_time_ns)
            return False
        q.append((ch, log_time_ns, publish_time_ns, data))
        self._accepted += 1
        if hub.idle:
            hub.wake.set()
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

    def _count_drop(self, topic: str, log_time_ns: int) -> None:
        with self._lock:
            w = self._drops
            if w is None:
                w = self._drops = _DropWindow(first_ns=log_time_ns, last_ns=log_time_ns)
            w.count += 1
            w.first_ns = min(w.first_ns, log_time_ns)
            w.last_ns = max(w.last_ns, log_time_ns)
            w.topics[topic] = w.topics.get(topic, 0) + 1

    def _take_drops(self) -> _DropWindow | None:
        """Called by the writer: the losses since the last report (and reset)."""
        with self._lock:
            w, self._drops = self._drops, None
            if w is not None:
                self._dropped_total += w.count
        return w
