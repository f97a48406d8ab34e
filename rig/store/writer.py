"""The session recorder: one writer thread that drains every source's queue into MCAP parts.

Design:

- One thread owns the ``mcap.writer.Writer`` and the file; devices never touch either. Each device
  feeds its own bounded :class:`~rig.store.sources.Source` queue; the writer visits the queues
  round-robin and takes at most ``batch`` messages from each per round, so one flooding device
  cannot starve the others.
- Crash safety: at most every ``flush_interval_s`` (1 s) of host time, if anything was written,
  the open chunk is closed (``Writer.flush()``), the stream flushed and the file ``fsync``-ed. A
  killed process leaves a file that is readable up to its last complete chunk (≤ ~1 s lost);
  ``rig recover`` makes a finalized copy.
- Rollover: a part ends at the first round after it reaches ``rollover_size_bytes`` or
  ``rollover_duration_s``; the next part starts with the same schemas, channels, metadata and
  attachments. Sequence numbers run on per topic across parts, so (topic, sequence) identifies
  every message exactly once.
- Disk space: below ``warn_free_bytes`` an event is written once; below ``min_free_bytes`` the
  recording stops with the part finalized and :class:`~vsccore.errors.DiskFullError`. If a write
  still fails (ENOSPC), a reserve file is released and the part is finalized in place up to its
  last complete record (or, if even that fails, left readable up to it); the messages of the chunk
  in flight are counted as lost (summary and the part-end record). The reserve is locked while
  recording, so a reserve left by a killed recorder is recognised and removed by the next recording
  in that directory (or ``rig recover``). :func:`check_free_space` lets a command refuse a full disk
  before it sets up any device.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import platform
import socket
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any

import mcap
from mcap._chunk_builder import ChunkBuilder
from mcap.records import Channel, Message, Schema
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType
from mcap.writer import Writer as McapWriter

import vsccore
from rig.core.topics import (
    METADATA_CALIBRATION,
    METADATA_PART_END,
    METADATA_RECORDER,
    METADATA_SESSION,
    METADATA_VEHICLE,
    TOPIC_EVENTS,
    Event,
    EventKind,
    Severity,
    encode_record,
    flatten_metadata,
)
from rig.store.reader import PartScan, part_path
from rig.store.recover import finalize_in_place, lock_reserve, remove_stale_reserves, reserve_path
from rig.store.sources import ChannelState, ChannelTiming, DropWindow, Source, SourceHub, SourceStats, channel_timings
from vsccore.clock import Clock, SystemClock
from vsccore.errors import DiskFullError, RigError, SessionFileError

if TYPE_CHECKING:
    from rig.core.config import OutputConfig

__all__ = [
    "Attachment",
    "Compression",
    "FileSummary",
    "Recorder",
    "RecorderOptions",
    "check_free_space",
    "session_metadata",
]

log = logging.getLogger(__name__)

Opener = Callable[[Path, str], IO[bytes]]
"""Opens a file (``mode`` is "xb", "wb" or "r+b") and returns a binary stream with write/tell/flush."""


class Compression(StrEnum):
    """Chunk compression."""

    ZSTD = "zstd"
    LZ4 = "lz4"
    NONE = "none"

    @property
    def mcap(self) -> CompressionType:
        return {
            Compression.ZSTD: CompressionType.ZSTD,
            Compression.LZ4: CompressionType.LZ4,
            Compression.NONE: CompressionType.NONE,
        }[self]


@dataclass(frozen=True, slots=True)
class RecorderOptions:
    """How the recorder writes (defaults suit a road test: zstd, 1 s crash window, 2 GB parts)."""

    compression: Compression = Compression.ZSTD
    chunk_size: int = 4 * 1024 * 1024
    """A chunk also closes when it exceeds this many uncompressed bytes."""
    flush_interval_s: float = 1.0
    """Close the chunk, flush and fsync at most this often (host time) while data comes in."""
    rollover_size_bytes: int | None = 2_000_000_000
    rollover_duration_s: float | None = None
    min_free_bytes: int = 500_000_000
    """Stop (finalized, DiskFullError) when the disk has less free space than this."""
    warn_free_bytes: int | None = None
    """Write a disk-space warning event below this (default: twice ``min_free_bytes``)."""
    disk_check_interval_s: float = 1.0
    reserve_bytes: int = 8 * 1024 * 1024
    """Size of ``<base>.reserve``, deleted to make room for finalizing when a write hits ENOSPC (0: none)."""
    batch: int = 256
    """Messages taken from one source per round (fairness)."""
    idle_wait_s: float = 0.05
    """Longest wait (host s) for new messages when every queue is empty: new messages are written then,
    or as soon as a source has queued ``batch`` of them (a stop, drain or sync wakes the writer at once)."""
    event_queue_size: int = 10_000
    validate_json: bool = False
    """Check every JSON payload against its schema in ``put`` (tests; costs CPU)."""
    overwrite: bool = False

    @classmethod
    def from_output(cls, output: OutputConfig, **overrides: Any) -> RecorderOptions:
        """Options from the session configuration's ``[output]`` table (plus keyword overrides)."""
        mb = 1_000_000
        kwargs: dict[str, Any] = {
            "compression": Compression(output.compression),
            "rollover_size_bytes": None if output.rollover_size_mb is None else int(output.rollover_size_mb * mb),
            "rollover_duration_s": output.rollover_duration_s,
            "min_free_bytes": int(output.min_free_disk_mb * mb),
        }
        kwargs.update(overrides)
        return cls(**kwargs)

    def __post_init__(self) -> None:
        if self.chunk_size <= 0 or self.batch <= 0 or self.flush_interval_s <= 0:
            raise ValueError("chunk_size, batch and flush_interval_s must be > 0")
        if self.rollover_size_bytes is not None and self.rollover_size_bytes <= 0:
            raise ValueError(f"rollover_size_bytes must be > 0, got {self.rollover_size_bytes}")
        if self.rollover_duration_s is not None and self.rollover_duration_s <= 0:
            raise ValueError(f"rollover_duration_s must be > 0, got {self.rollover_duration_s}")


@dataclass(frozen=True, slots=True)
class Attachment:
    """A file stored in every part (the DBC, the configuration file)."""

    name: str
    media_type: str
    data: bytes
    create_time_ns: int = 0

    @classmethod
    def from_file(cls, path: Path | str, media_type: str | None = None) -> Attachment:
        """The file's bytes under its name; the media type is guessed from the suffix when not given."""
        p = Path(path)
        try:
            data = p.read_bytes()
            mtime = p.stat().st_mtime_ns
        except OSError as exc:
            raise SessionFileError(f"{p}: cannot read the file to attach: {exc}") from exc
        return cls(p.name, media_type or _MEDIA_TYPES.get(p.suffix.lower(), "application/octet-stream"), data, mtime)


_MEDIA_TYPES = {
    ".dbc": "text/x-dbc",
    ".toml": "application/toml",
    ".json": "application/json",
    ".yaml": "application/yaml",
    ".txt": "text/plain",
}


def session_metadata(
    session: Mapping[str, Any] | None = None,
    vehicle: Mapping[str, Any] | None = None,
    calibration: Mapping[str, Any] | None = None,
    **records: Mapping[str, Any],
) -> dict[str, dict[str, str]]:
    """Metadata records for :class:`Recorder` from nested configuration mappings.

    ``session``, ``vehicle`` and ``calibration`` go to :data:`~rig.core.topics.METADATA_SESSION`,
    :data:`~rig.core.topics.METADATA_VEHICLE` and :data:`~rig.core.topics.METADATA_CALIBRATION`; further
    keyword records are stored under ``vsc_rig.<key>``. Values are flattened with
    :func:`rig.core.topics.flatten_metadata`. (Software version and host are added by the recorder.)
    """
    out: dict[str, dict[str, str]] = {}
    for name, obj in ((METADATA_SESSION, session), (METADATA_VEHICLE, vehicle), (METADATA_CALIBRATION, calibration)):
        if obj is not None:
            out[name] = flatten_metadata(obj)
    for key, obj in records.items():
        out[f"vsc_rig.{key}"] = flatten_metadata(obj)
    return out


@dataclass(frozen=True, slots=True)
class FileSummary:
    """What :meth:`Recorder.stop` returns."""

    parts: tuple[Path, ...]
    messages: int
    """Messages in the files (all parts; those lost in a failed write are not counted)."""
    sources: tuple[SourceStats, ...]
    error: RigError | None
    """Why the recording ended early (disk full, write error), or None."""
    finalized: bool
    """Every part ends with a summary and index."""
    lost_in_queues: int = 0
    """Messages still queued when the recording failed (0 after a clean stop)."""
    lost_in_write: int = 0
    """Messages handed to the MCAP writer that never reached the file (the chunk in flight at a write error)."""

    @property
    def dropped(self) -> int:
        """Messages not recorded: dropped by full queues, still queued or lost in the failed write."""
        return sum(s.dropped for s in self.sources) + self.lost_in_queues + self.lost_in_write


class _DiskLowError(Exception):
    def __init__(self, free: int) -> None:
        super().__init__(free)
        self.free = free


def _default_opener(path: Path, mode: str) -> IO[bytes]:
    return open(path, mode)


def _default_fsync(stream: IO[bytes]) -> None:
    os.fsync(stream.fileno())


def _default_disk_free(directory: Path) -> int:
    import shutil

    return shutil.disk_usage(directory).free


@dataclass(slots=True)
class _Part:
    index: int
    path: Path
    stream: IO[bytes]
    writer: McapWriter
    started_ns: int
    schema_ids: dict[str, int] = field(default_factory=dict)
    messages: int = 0


class Recorder:
    """Records a session into ``<out_dir>/<name>.000.mcap``, ``<name>.001.mcap``, ...

    Usage::

        meta = session_metadata(session=cfg_dict, vehicle=vehicle_dict, calibration=cal_dict)
        with Recorder(out_dir, "run1", meta, attachments=[Attachment.from_file(dbc)]) as rec:
            gnss = rec.source("rover_a", maxsize=10_000)
            gnss.put(topics.gnss_raw("rover_a"), log_ns, host_ns, data)
        # stop() on exit: queues drained, parts finalized; a recording error is raised here.

    ``metadata`` maps record names (e.g. :data:`rig.core.topics.METADATA_SESSION`) to ``{str: str}``
    (see :func:`rig.core.topics.flatten_metadata`); it and ``attachments`` are written in every part.
    ``host_to_log_time`` maps a host time to the common time base for events the recorder writes
    itself (default: host time unchanged). ``opener``, ``fsync`` and ``disk_free`` are injectable
    for tests.
    """

    def __init__(
        self,
        out_dir: Path | str,
        name: str,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        *,
        attachments: Sequence[Attachment] = (),
        options: RecorderOptions | None = None,
        clock: Clock | None = None,
        host_to_log_time: Callable[[int], int] | None = None,
        opener: Opener | None = None,
        fsync: Callable[[IO[bytes]], None] | None = None,
        disk_free: Callable[[Path], int] | None = None,
    ) -> None:
        if not name or "/" in name or "\\" in name or name.endswith(".mcap"):
            raise ValueError(f"session name {name!r} must be a plain file name without .mcap")
        self._base = Path(out_dir) / name
        self._opts = options or RecorderOptions()
        self._clock: Clock = clock or SystemClock()
        self._opener: Opener = opener or _default_opener
        self._fsync = fsync or _default_fsync
        self._disk_free = disk_free or _default_disk_free
        self._metadata: dict[str, dict[str, str]] = {}
        for name, record in (metadata or {}).items():
            bad = [k for k, v in record.items() if not (isinstance(k, str) and isinstance(v, str))]
            if bad:
                raise ValueError(f"metadata {name!r}: keys and values must be str (see flatten_metadata), bad: {bad}")
            if name in (METADATA_RECORDER, METADATA_PART_END):
                raise ValueError(f"metadata name {name!r} is reserved for the recorder")
            self._metadata[name] = dict(record)
        self._attachments = tuple(attachments)
        self._hub = SourceHub(self._clock, host_to_log_time or (lambda t: t), self._opts.validate_json,
                         wake_depth=self._opts.batch)
        self._hub.events = Source("recorder.events", self._opts.event_queue_size, self._hub)
        self._hub.add_source(self._hub.events)
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._started = threading.Event()
        self._done = threading.Event()
        self.failed = threading.Event()
        """Set when the recording ended because of an error (see :attr:`error`)."""
        self._error: RigError | None = None
        self._stop_lock = threading.Lock()
        self._summary: FileSummary | None = None
        self._progress = threading.Condition()
        self._round_id = 0
        self._parts: list[Path] = []
        self._all_finalized = True
        self._part: _Part | None = None
        self._epoch = -1
        self._dirty = False
        self._last_flush_ns = 0
        self._last_disk_check_ns = 0
        self._warned_disk = False
        self._messages = 0
        self._sync_request = 0
        self._sync_done = 0
        self._lost_in_write = 0
        self._host = socket.gethostname()
        self._reserve = reserve_path(self._base)
        self._reserve_fd: int | None = None
        self.tap: Callable[[str, int, int, bytes], None] | None = None
        """Called on the writer thread with (topic, log_time, publish_time, data) of every message written
        (a live view, :mod:`rig.live`); it must not block (append to a bounded queue) and must not raise."""

    # --- public API ------------------------------------------------------------------------------

    @property
    def base(self) -> Path:
        """The session's base path (parts are ``<base>.NNN.mcap``)."""
        return self._base

    @property
    def parts(self) -> list[Path]:
        """The part files written so far."""
        return list(self._parts)

    @property
    def error(self) -> RigError | None:
        return self._error

    def source(self, name: str, maxsize: int = 10_000) -> Source:
        """A new source (one per device); may be added while recording."""
        if not name:
            raise ValueError("source name must not be empty")
        src = Source(name, maxsize, self._hub)
        self._hub.add_source(src)
        return src

    def event(
        self,
        kind: EventKind,
        text: str,
        *,
        source: str = "rig",
        severity: Severity = Severity.INFO,
        log_time_ns: int | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
        **details: Any,
    ) -> bool:
        """Record an event on ``/rig/events`` (e.g. a calibration result or an operator mark)."""
        events = self._hub.events
        assert events is not None
        return events._hub_event(Event(kind, source, text, severity, start_ns, end_ns, details), log_time_ns)

    def start(self, timeout_s: float = 10.0) -> None:
        """Open the first part and start the writer thread (raises SessionFileError if it cannot)."""
        if self._thread is not None:
            raise RuntimeError("recorder already started")
        directory = self._base.parent
        if not directory.is_dir():
            raise SessionFileError(f"session directory {directory} does not exist")
        first = part_path(self._base, 0)
        if first.exists() and not self._opts.overwrite:
            raise SessionFileError(f"{first} already exists (choose another session name or set overwrite)")
        check_free_space(directory, self._opts, self._disk_free)
        remove_stale_reserves(directory)
        self._make_reserve()
        self._hub.accepting = True
        self._thread = threading.Thread(target=self._run, name=f"rig-recorder:{self._base.name}")
        self._thread.start()
        while not (self._started.wait(0.05) or self._done.is_set()):
            timeout_s -= 0.05
            if timeout_s <= 0:
                break
        if not self._started.is_set():
            self.stop()
            raise self._error or SessionFileError(f"{first}: the recorder did not start")

    def stop(self, timeout_s: float = 30.0) -> FileSummary:
        """Stop accepting, drain every queue, finalize the part and join the thread (idempotent).

        Returns the summary; a recording error is in ``summary.error`` (and raised by ``__exit__``).
        """
        with self._stop_lock:
            if self._summary is not None:
                return self._summary
            self._hub.accepting = False
            self._stopping.set()
            self._hub.wake.set()
            if self._thread is not None:
                self._thread.join(timeout_s)
                if self._thread.is_alive():
                    # Cannot happen short of a hung disk: say so rather than pretend it stopped.
                    err = SessionFileError(f"{self._base}: the writer did not stop within {timeout_s} s")
                    self._error = self._error or err
                    log.error("%s", err)
            self._remove_reserve()
            # Every message a source accepted was handed to the MCAP writer or is lost in a queue: counted from
            # the sources' own tallies, not by the writer's last look at the queues (a producer that passed the
            # `accepting` check just before the writer failed or stopped appends after that look).
            lost_in_queues = sum(s._accepted - s._written for s in self._hub.sources)
            self._summary = FileSummary(
                parts=tuple(self._parts),
                messages=self._messages - self._lost_in_write,
                sources=tuple(s.stats() for s in self._hub.sources),
                error=self._error,
                finalized=self._all_finalized and self._thread is not None and not self._thread.is_alive(),
                lost_in_queues=lost_in_queues,
                lost_in_write=self._lost_in_write,
            )
            return self._summary

    def drain(self, timeout_s: float = 10.0) -> bool:
        """Wait until everything queued before this call has been handed to the MCAP writer.

        Returns False on timeout or if the recording has ended. (Written to the MCAP writer, not
        necessarily to disk: the flush policy decides that.)
        """
        with self._progress:
            target = self._round_id + 2
            self._hub.wake.set()
            return self._progress.wait_for(
                lambda: self._done.is_set() or (self._round_id >= target and self._queues_empty()),
                timeout_s,
            ) and not self._done.is_set()

    def sync(self, timeout_s: float = 10.0) -> bool:
        """Write everything queued before this call to disk now: chunk closed, stream flushed, fsync-ed.

        Returns False on timeout (the sources kept the writer busy) or if the recording has ended.
        """
        with self._progress:
            self._sync_request += 1
            target = self._sync_request
            self._hub.wake.set()
            return self._progress.wait_for(
                lambda: self._done.is_set() or self._sync_done >= target, timeout_s
            ) and not self._done.is_set()

    def stats(self) -> list[SourceStats]:
        """Counters of every source (the recorder's own event source first)."""
        return [s.stats() for s in self._hub.sources]

    def channel_timings(self) -> list[ChannelTiming]:
        """The log-time record of every channel: period, clamps, stalls (:mod:`rig.store.sources`)."""
        return channel_timings(self._hub)

    @property
    def running(self) -> bool:
        """The writer thread is recording."""
        return self._started.is_set() and not self._done.is_set()

    def check(self) -> None:
        """Raise the recording error, if there is one."""
        if self._error is not None:
            raise self._error

    def __enter__(self) -> Recorder:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        summary = self.stop()
        if exc_type is None and summary.error is not None:
            raise summary.error

    # --- writer thread ----------------------------------------------------------------------------

    def _queues_empty(self) -> bool:
        return not any(s._q for s in self._hub.sources)

    def _run(self) -> None:
        try:
            now = self._clock.now_ns()
            self._open_part(0, now, previous=None)
            self._write_event(
                Event(EventKind.SESSION_START, "recorder", f"recording started: {self._parts[0].name}"), now
            )
            self._started.set()
            self._loop()
            now = self._clock.now_ns()
            self._write_event(
                Event(EventKind.SESSION_STOP, "recorder", f"recording stopped after {self._messages} messages"), now
            )
            self._close_part("stop", next_part=None)
        except _DiskLowError as low:
            self._stop_on_low_disk(low.free)
        except OSError as exc:
            self._abandon_part(exc)
        except BaseException as exc:
            log.exception("recorder writer failed")
            self._abandon_part(exc)
        finally:
            self._hub.accepting = False
            if self._error is not None:  # what is left is lost (counted by stop() from the sources' tallies)
                for s in self._hub.sources:
                    s._q.clear()
                self.failed.set()
            self._done.set()
            with self._progress:
                self._progress.notify_all()

    def _loop(self) -> None:
        opts = self._opts
        hub = self._hub
        clock = self._clock
        flush_ns = int(opts.flush_interval_s * 1e9)
        disk_ns = int(opts.disk_check_interval_s * 1e9)
        roll_ns = None if opts.rollover_duration_s is None else int(opts.rollover_duration_s * 1e9)
        roll_bytes = opts.rollover_size_bytes
        self._last_flush_ns = self._last_disk_check_ns = clock.now_ns()
        while True:
            n = self._round()
            now = clock.now_ns()
            if n:
                self._dirty = True
            part = self._part
            assert part is not None
            # Flush policy: close the chunk and push it to disk once per interval while data comes in.
            if now - self._last_flush_ns >= flush_ns or now < self._last_flush_ns:
                if self._dirty:
                    self._flush_part(part)
                self._last_flush_ns = now
            if now - self._last_disk_check_ns >= disk_ns or now < self._last_disk_check_ns:
                self._last_disk_check_ns = now
                self._check_disk(now)
            if (roll_bytes is not None and part.stream.tell() >= roll_bytes) or (
                roll_ns is not None and now - part.started_ns >= roll_ns
            ):
                reason = "size" if roll_bytes is not None and part.stream.tell() >= roll_bytes else "duration"
                self._rollover(now, reason)
            sync_req = self._sync_request
            if sync_req > self._sync_done and self._queues_empty():
                assert self._part is not None  # the current part (a rollover may just have replaced it)
                self._flush_part(self._part)
                self._last_flush_ns = now
                self._sync_done = sync_req
            with self._progress:
                self._round_id += 1
                self._progress.notify_all()
            if n == 0:
                if self._stopping.is_set() and self._queues_empty():
                    return
                hub.idle = True
                if self._queues_empty() and not self._stopping.is_set():
                    hub.wake.wait(opts.idle_wait_s)
                hub.wake.clear()
                hub.idle = False

    def _round(self) -> int:
        """One fair pass over the sources; returns the number of messages written."""
        part = self._part
        assert part is not None
        add = part.writer.add_message
        epoch = self._epoch
        batch = self._opts.batch
        tap = self.tap
        total = 0
        for src in self._hub.sources:
            q = src._q
            if q:
                n = min(len(q), batch)
                pop = q.popleft
                i = -1
                try:
                    for i in range(n):  # noqa: B007 - read in the except clause
                        ch, log_ns, pub_ns, data = pop()
                        if ch.epoch != epoch:
                            self._register(part, ch)
                        add(ch.mcap_id, log_ns, data, pub_ns, ch.seq & 0xFFFFFFFF)
                        ch.seq += 1
                        if tap is not None:
                            tap(ch.topic, log_ns, pub_ns, data)
                except BaseException:
                    # a write failed inside add (a chunk going out): count what this round handed over,
                    # the message in hand included, so the loss is measured against the file afterwards
                    src._written += i + 1
                    part.messages += total + i + 1
                    self._messages += total + i + 1
                    raise
                src._written += n
                total += n
            if src._drops is not None and len(q) < src._maxsize:
                window = src._take_drops()
                if window is not None:
                    self._report_drops(src, window)
                    total += 1
        part.messages += total
        self._messages += total
        return total

    def _register(self, part: _Part, ch: ChannelState) -> None:
        sid = part.schema_ids.get(ch.schema.name)
        if sid is None:
            sid = part.writer.register_schema(ch.schema.name, ch.schema.schema_encoding, ch.schema.data)
            part.schema_ids[ch.schema.name] = sid
        ch.mcap_id = part.writer.register_channel(ch.topic, ch.schema.message_encoding, sid)
        ch.epoch = self._epoch

    def _write_event(self, ev: Event, host_ns: int) -> None:
        """Write an event directly (writer thread only): recorder events never wait in a queue."""
        part = self._part
        assert part is not None
        ch = self._hub.channel(TOPIC_EVENTS)
        if ch.epoch != self._epoch:
            self._register(part, ch)
        log_ns = ev.start_ns if ev.start_ns is not None else self._hub.host_to_log_time(host_ns)
        data = encode_record(ev.to_json())
        part.writer.add_message(ch.mcap_id, log_ns, data, host_ns, ch.seq & 0xFFFFFFFF)
        ch.seq += 1
        tap = self.tap
        if tap is not None:
            tap(ch.topic, log_ns, host_ns, data)
        part.messages += 1
        self._messages += 1
        self._dirty = True

    def _report_drops(self, src: Source, w: DropWindow) -> None:
        log.warning("source %s: queue full, %d messages dropped", src.name, w.count)
        self._write_event(
            Event(
                EventKind.OVERFLOW,
                src.name,
                f"queue full: {w.count} messages dropped",
                Severity.WARNING,
                start_ns=w.first_ns,
                end_ns=w.last_ns,
                details={"dropped": w.count, "topics": dict(w.topics), "maxsize": src._maxsize},
            ),
            self._clock.now_ns(),
        )
        self._messages -= 1  # counted by the caller of _round as well
        assert self._part is not None
        self._part.messages -= 1

    def _recorder_metadata(self, index: int, path: Path, previous: Path | None, now: int) -> dict[str, str]:
        opts = self._opts
        return {
            "software": "vsc-rig",
            "version": vsccore.__version__,
            "mcap_library": LIBRARY_IDENTIFIER,
            "python": platform.python_version(),
            "host": self._host,
            "session": self._base.name,
            "part_index": str(index),
            "part_file": path.name,
            "previous_part": previous.name if previous is not None else "",
            "started_host_ns": str(now),
            "compression": opts.compression.value,
            "chunk_size": str(opts.chunk_size),
            "flush_interval_s": repr(opts.flush_interval_s),
            "rollover_size_bytes": str(opts.rollover_size_bytes or ""),
            "rollover_duration_s": "" if opts.rollover_duration_s is None else repr(opts.rollover_duration_s),
            "sources": ",".join(s.name for s in self._hub.sources),
        }

    def _open_part(self, index: int, now: int, previous: Path | None) -> None:
        path = part_path(self._base, index)
        mode = "wb" if self._opts.overwrite else "xb"
        try:
            stream = self._opener(path, mode)
        except FileExistsError:
            raise SessionFileError(f"{path} already exists (choose another session name)") from None
        self._parts.append(path)
        writer = McapWriter(
            stream,
            chunk_size=self._opts.chunk_size,
            compression=self._opts.compression.mcap,
            index_types=IndexType.ALL,
            enable_data_crcs=True,  # DataEnd's CRC of the data section: damage no chunk CRC can see
        )
        _self_describing_chunks(writer)
        self._epoch += 1
        part = _Part(index=index, path=path, stream=stream, writer=writer, started_ns=now)
        self._part = part
        writer.start(profile="", library=f"vsc-rig/{vsccore.__version__}; {LIBRARY_IDENTIFIER}")
        writer.add_metadata(METADATA_RECORDER, self._recorder_metadata(index, path, previous, now))
        for name, record in self._metadata.items():
            writer.add_metadata(name, record)
        log_ns = self._hub.host_to_log_time(now)
        for att in self._attachments:
            writer.add_attachment(att.create_time_ns, log_ns, att.name, att.media_type, att.data)
        # Every part declares every channel known so far, even before its first message.
        for ch in self._hub.channels.values():
            self._register(part, ch)
        self._flush_part(part)
        log.info("recording to %s", path)

    def _flush_part(self, part: _Part) -> None:
        _flush_writer(part.writer)
        part.stream.flush()
        self._fsync(part.stream)
        self._dirty = False

    def _close_part(self, reason: str, next_part: Path | None) -> None:
        part = self._part
        assert part is not None
        end = {
            "reason": reason,
            "next_part": next_part.name if next_part is not None else "",
            "messages": str(part.messages),
            "ended_host_ns": str(self._clock.now_ns()),
        }
        for s in self._hub.sources:
            st = s.stats()
            end[f"source.{st.name}.written"] = str(st.written)
            end[f"source.{st.name}.dropped"] = str(st.dropped)
        part.writer.add_metadata(METADATA_PART_END, end)
        part.writer.finish()
        part.stream.flush()
        self._fsync(part.stream)
        part.stream.close()
        self._part = part  # keep for reference; a closed part is not written again

    def _rollover(self, now: int, reason: str) -> None:
        old = self._part
        assert old is not None
        nxt = part_path(self._base, old.index + 1)
        self._close_part(f"rollover ({reason})", next_part=nxt)
        self._open_part(old.index + 1, now, previous=old.path)
        self._write_event(
            Event(
                EventKind.ROLLOVER,
                "recorder",
                f"part {old.index + 1} started ({reason} limit reached in {old.path.name})",
                details={"previous_part": old.path.name, "part": nxt.name},
            ),
            now,
        )
        self._last_flush_ns = now

    def _check_disk(self, now: int) -> None:
        try:
            free = self._disk_free(self._base.parent)
        except OSError as exc:
            log.warning("cannot read free disk space of %s: %s", self._base.parent, exc)
            return
        if free < self._opts.min_free_bytes:
            raise _DiskLowError(free)
        warn = self._opts.warn_free_bytes if self._opts.warn_free_bytes is not None else 2 * self._opts.min_free_bytes
        if free < warn and not self._warned_disk:
            self._warned_disk = True
            self._write_event(
                Event(
                    EventKind.DISK_SPACE,
                    "recorder",
                    f"low disk space: {free / 1e6:.0f} MB free on {self._base.parent}; the recording stops "
                    f"below {self._opts.min_free_bytes / 1e6:.0f} MB",
                    Severity.WARNING,
                    details={"free_bytes": free, "min_free_bytes": self._opts.min_free_bytes},
                ),
                now,
            )
        elif free >= warn:
            self._warned_disk = False

    def _stop_on_low_disk(self, free: int) -> None:
        part = self._part
        path = part.path if part is not None else self._base
        msg = (
            f"disk full: {free / 1e6:.0f} MB free on {self._base.parent}, below the "
            f"{self._opts.min_free_bytes / 1e6:.0f} MB minimum; recording stopped"
        )
        try:
            now = self._clock.now_ns()
            self._write_event(Event(EventKind.DISK_SPACE, "recorder", msg, Severity.ERROR), now)
            self._close_part("disk_full", next_part=None)
            self._error = DiskFullError(f"{path}: {msg}; the file is finalized")
        except OSError as exc:
            self._abandon_part(exc)
            return
        log.error("%s", self._error)

    def _abandon_part(self, exc: BaseException) -> None:
        """A write failed: give up on the MCAP writer, keep the file readable, finalize it if possible."""
        self._all_finalized = False
        part = self._part
        if part is None:
            self._error = (
                exc if isinstance(exc, RigError) else SessionFileError(f"{self._base}: cannot start recording: {exc}")
            )
            return
        # The buffered tail may not fit; what reached the file is a prefix of a valid stream.
        with contextlib.suppress(OSError):
            part.stream.close()
        self._remove_reserve()
        disk_full = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
        handed = part.messages

        def part_end(scan: PartScan) -> dict[str, str]:
            """The part-end record of a failed part: what reached the file and what was lost."""
            end = {
                "reason": "disk_full" if disk_full else "write_error",
                "next_part": "",
                "messages": str(scan.message_count),
                "lost_in_write": str(max(0, handed - scan.message_count)),
                "error": str(exc),
                "ended_host_ns": str(self._clock.now_ns()),
            }
            for s in self._hub.sources:
                st = s.stats()
                end[f"source.{st.name}.written"] = str(st.written)
                end[f"source.{st.name}.dropped"] = str(st.dropped)
            return end

        report = finalize_in_place(part.path, opener=self._opener, fsync=self._fsync, part_end=part_end)
        lost = max(0, handed - report.messages)
        self._lost_in_write += lost
        lost_text = f"; {lost} messages of the chunk in flight were lost" if lost else ""
        if report.finalized:
            self._all_finalized = True
            state = f"finalized up to its last complete record ({report.messages} messages){lost_text}"
        else:
            state = (
                f"readable up to its last complete record ({report.messages} messages{lost_text}) but not "
                f"finalized ({report.error}); run `rig recover {part.path}`"
            )
        if disk_full:
            self._error = DiskFullError(f"{part.path}: disk full while writing; recording stopped; the file is {state}")
        else:
            self._error = SessionFileError(f"{part.path}: write failed ({exc}); recording stopped; the file is {state}")
        log.error("%s", self._error)

    def _make_reserve(self) -> None:
        size = self._opts.reserve_bytes
        if size <= 0:
            return
        try:
            with self._opener(self._reserve, "wb") as f:
                block = b"\0" * min(size, 1 << 20)
                left = size
                while left > 0:
                    f.write(block[:left])
                    left -= len(block)
                f.flush()
            self._reserve_fd = lock_reserve(self._reserve)
        except OSError as exc:
            self._remove_reserve()
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                raise DiskFullError(f"{self._reserve}: no room for the {size} byte reserve; disk full") from exc
            raise SessionFileError(f"{self._reserve}: cannot create the disk-space reserve: {exc}") from exc

    def _remove_reserve(self) -> None:
        if self._reserve_fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._reserve_fd)
            self._reserve_fd = None
        try:
            self._reserve.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            log.warning("cannot remove %s: %s", self._reserve, exc)


def _existing(directory: Path) -> Path:
    """``directory`` or its nearest existing ancestor (the file system it will be created on)."""
    d = directory.absolute()
    while not d.exists() and d.parent != d:
        d = d.parent
    return d


def check_free_space(
    directory: Path | str, options: RecorderOptions, disk_free: Callable[[Path], int] | None = None
) -> int:
    """Refuse to record into ``directory`` with less free space than ``options.min_free_bytes``.

    Call it before anything else is set up (devices, simulated world): the recorder checks again
    when it starts. ``directory`` need not exist yet (its nearest existing ancestor is checked).
    Returns the free bytes; raises :class:`~vsccore.errors.DiskFullError` naming the directory and
    the configuration key, or :class:`~vsccore.errors.SessionFileError` when it cannot be read.
    """
    d = Path(directory)
    where = _existing(d)
    try:
        free = (disk_free or _default_disk_free)(where)
    except OSError as exc:
        raise SessionFileError(f"cannot read the free space of {d}: {exc}") from exc
    if free < options.min_free_bytes:
        raise DiskFullError(
            f"{d}: only {free / 1e6:.0f} MB free, below the {options.min_free_bytes / 1e6:.0f} MB "
            "minimum (output.min_free_disk_mb); not starting the recording"
        )
    return free


class _SelfDescribingChunkBuilder(ChunkBuilder):
    """A chunk builder that puts the Schema and Channel records of every channel a chunk holds messages
    of into that chunk, before its first message there.

    mcap's writer puts a Schema or Channel record into the chunk that is open when the channel is
    registered, and only there (and in the summary, written at the end). A part cut short (kill -9,
    power loss: no summary) whose chunk with a Channel record is damaged could then not say whose every
    later message on that channel is: they were lost, though their own chunks were intact. With each
    chunk describing its own channels, every intact chunk can be read on its own. The MCAP
    specification allows a Schema or Channel record to appear again (with the same content); mcap's
    reader and the recorder's scanner (:mod:`rig.store.reader`) take the repeats as they are.
    """

    def __init__(self, schemas: Mapping[int, Schema], channels: Mapping[int, Channel]) -> None:
        super().__init__()
        self._schemas = schemas
        self._channels = channels
        self._schemas_here: set[int] = set()

    def add_schema(self, schema: Schema) -> None:
        self._schemas_here.add(schema.id)
        super().add_schema(schema)

    def add_message(self, message: Message) -> None:
        cid = message.channel_id
        if cid not in self.message_indices:  # the channel's first message in this chunk
            channel = self._channels[cid]
            sid = channel.schema_id
            if sid and sid not in self._schemas_here:
                self.add_schema(self._schemas[sid])
            self.add_channel(channel)
        super().add_message(message)

    def reset(self) -> None:
        super().reset()
        self._schemas_here.clear()


def _self_describing_chunks(writer: McapWriter) -> None:
    """Give ``writer`` a :class:`_SelfDescribingChunkBuilder` (before it has written anything).

    mcap's ``Writer`` has no public hook for its chunk builder: its name-mangled attributes are used,
    checked here, so a change in mcap fails the first recording loudly instead of silently writing
    chunks that depend on each other (``tests/recorder/test_damage.py`` holds the behaviour)."""
    try:
        schemas = writer._Writer__schemas  # type: ignore[attr-defined]
        channels = writer._Writer__channels  # type: ignore[attr-defined]
        builder = writer._Writer__chunk_builder  # type: ignore[attr-defined]
    except AttributeError as exc:
        raise RigError(f"mcap {mcap.__version__}: its Writer no longer has the chunk builder the recorder "
                       f"replaces ({exc}); pin mcap to a version this recorder supports") from exc
    if builder is not None:  # None: chunking off (chunk_size 0 is refused by RecorderOptions)
        writer._Writer__chunk_builder = _SelfDescribingChunkBuilder(schemas, channels)  # type: ignore[attr-defined]


def _flush_writer(writer: McapWriter) -> None:
    """Close the open chunk and write it out.

    ``Writer.flush()`` is public since mcap-python 1.3 (it finishes the chunk in progress). Older
    versions only close a chunk when it exceeds ``chunk_size``; there the name-mangled private
    ``__finalize_chunk`` is the only way to bound the crash-loss window by time.
    """
    flush = getattr(writer, "flush", None)
    if flush is not None:
        flush()
    else:  # pragma: no cover - old mcap
        writer._Writer__finalize_chunk()  # type: ignore[attr-defined]
