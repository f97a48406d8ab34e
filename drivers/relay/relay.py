"""The RTK correction relay: one source, whole-frame fan-out to any number of sinks, statistics.

One reader thread reads the source as soon as bytes arrive, hands every chunk to the ``tap``
(host receive time, raw bytes: what the recorder stores), frames it with
:class:`~drivers.relay.frames.CorrectionFramer` and offers each whole, checked frame to every
sink's queue (never blocking). Each sink writes from its own worker thread. A lost source is
reopened with back-off (waiting on the stop event, so :meth:`Relay.stop` is immediate); errors no
retry can cure (refused NTRIP credentials, unknown mountpoint, bad configuration) stop the relay
and are kept in :attr:`Relay.error`.

Usage::

    relay = Relay(open_source("ntrip://user:pw@caster:2101/MOUNT"),
                  [open_sink("/dev/ttyUSB1@115200"), open_sink("/dev/ttyUSB2@115200")],
                  tap=lambda t_ns, raw: ...)
    relay.start()
    relay.note_rover_diff_age("rover_a", 1.2)   # from the rover's BESTPOS
    snapshot = relay.stats()
    relay.stop()
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from drivers.relay.frames import CorrectionFrame, CorrectionFramer, CorrectionKind
from drivers.relay.sinks import Backoff, Sink, SinkStats
from drivers.relay.sources import FATAL_SOURCE_ERRORS, EndOfStream, Source
from vsccore.clock import Clock, SystemClock
from vsccore.errors import RigError

__all__ = ["Relay", "RelayState", "RelayStats", "RoverAge", "TapCallback"]

log = logging.getLogger(__name__)

#: tap(host receive time ns, raw bytes as read from the source)
TapCallback = Callable[[int, bytes], None]
#: on_frame(host receive time ns, the whole checked frame)
FrameCallback = Callable[[int, CorrectionFrame], None]


@dataclass(frozen=True, slots=True)
class RoverAge:
    """A rover's own differential age (BESTPOS ``diff_age``) as last noted."""

    age_s: float | None
    noted_ago_s: float


class RelayState:
    """What the reader is doing (strings, for status lines and JSON)."""

    IDLE = "idle"
    CONNECTING = "connecting"
    RUNNING = "running"
    WAITING = "waiting"  # back-off before reconnecting
    FINISHED = "finished"  # a finite source ended
    FAILED = "failed"  # a fatal error (see Relay.error)
    STOPPED = "stopped"


@dataclass(frozen=True, slots=True)
class RelayStats:
    """A snapshot of the relay's statistics.

    Rates are averages over the last ``window_s`` seconds (or since the start when shorter).
    """

    source: str
    state: str
    t_ns: int
    """Host time of the snapshot (the relay's clock)."""
    uptime_s: float
    window_s: float
    bytes_in: int
    frames_in: int
    bytes_per_s: float
    frames_per_s: float
    frames_by_type: dict[str, int]
    """Frames read by label (``"RTCM 1077"``, ``"RTCA 7"``, ``"CMR 0"``)."""
    frames_per_s_by_type: dict[str, float]
    frames_by_kind: dict[str, int]
    rejected_frames: int
    """Frames whose CRC/checksum failed (never forwarded)."""
    rejected_by_kind: dict[str, int]
    truncated_frames: int
    skipped_bytes: int
    last_correction_age_s: float | None
    """Time since the last whole frame arrived (None before the first)."""
    source_connects: int
    source_error: str | None
    callback_errors: int
    """Exceptions raised by the tap / on_frame callbacks (logged once, counted)."""
    sinks: tuple[SinkStats, ...]
    rovers: dict[str, RoverAge]

    @property
    def dropped_frames(self) -> int:
        return sum(s.dropped_total for s in self.sinks)

    @property
    def format(self) -> str:
        """The main framing seen (``rtcmv3``, ``rtca``, ``cmr``) or ``""`` before any frame."""
        if not any(self.frames_by_kind.values()):
            return ""
        kind = max(self.frames_by_kind, key=lambda k: self.frames_by_kind[k])
        return {"rtcm3": "rtcmv3"}.get(kind, kind)

    def to_topic_dict(self) -> dict[str, Any]:
        """The ``/relay/stats`` record (schema ``vsc_rig.relay.Stats`` in ``rig.core.topics``) and extras."""
        return {
            "source": self.source,
            "format": self.format,
            "state": self.state,
            "bytes_in": self.bytes_in,
            "frames_in": self.frames_in,
            "crc_errors": self.rejected_frames,
            "truncated": self.truncated_frames,
            "frames_by_type": dict(self.frames_by_type),
            "frames_per_s_by_type": dict(self.frames_per_s_by_type),
            "sinks": {
                s.name: {
                    "bytes_out": s.bytes_out,
                    "frames_out": s.frames_out,
                    "dropped": s.dropped_total,
                    "queue_depth": s.queue_depth,
                    "connected": s.connected,
                    "reconnects": s.reconnects,
                }
                for s in self.sinks
            },
            "age_s": self.last_correction_age_s,
            "rate_bps": self.bytes_per_s,
            "frames_per_s": self.frames_per_s,
            "rover_diff_age_s": {name: r.age_s for name, r in self.rovers.items()},
        }


class _Rates:
    """Per-second buckets of bytes, frames and frames by label over a sliding window."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._buckets: collections.deque[tuple[int, list[int], collections.Counter[str]]] = collections.deque()

    def _bucket(self, t_ns: int) -> tuple[list[int], collections.Counter[str]]:
        sec = t_ns // 1_000_000_000
        if not self._buckets or self._buckets[-1][0] != sec:
            self._buckets.append((sec, [0, 0], collections.Counter()))
            horizon = sec - int(self.window_s) - 1
            while self._buckets and self._buckets[0][0] < horizon:
                self._buckets.popleft()
        _, counts, labels = self._buckets[-1]
        return counts, labels

    def add_bytes(self, t_ns: int, n: int) -> None:
        self._bucket(t_ns)[0][0] += n

    def add_frame(self, t_ns: int, label: str) -> None:
        counts, labels = self._bucket(t_ns)
        counts[1] += 1
        labels[label] += 1

    def snapshot(self, now_ns: int, start_ns: int) -> tuple[float, float, dict[str, float], float]:
        """(bytes/s, frames/s, frames/s by label, span s) over the whole seconds of the last window."""
        first_sec = (now_ns - int(self.window_s * 1e9)) // 1_000_000_000
        span_start = max(start_ns, first_sec * 1_000_000_000)
        span = max(1e-3, (now_ns - span_start) / 1e9)
        nbytes = nframes = 0
        labels: collections.Counter[str] = collections.Counter()
        for sec, counts, lab in self._buckets:
            if sec < first_sec:
                continue
            nbytes += counts[0]
            nframes += counts[1]
            labels.update(lab)
        return nbytes / span, nframes / span, {k: v / span for k, v in sorted(labels.items())}, span


class Relay:
    """Relays whole correction frames from one source to several sinks (see the module doc).

    Args:
        source: where corrections come from (:func:`~drivers.relay.sources.open_source`).
        sinks: where they go (:func:`~drivers.relay.sinks.open_sink`); started and stopped with the relay.
        tap: called in the reader thread with (host receive ns, raw bytes) for every chunk read,
            garbage included, before framing. Keep it fast (queue the bytes).
        on_frame: called in the reader thread with (host receive ns, frame) for every whole frame.
        clock: host clock for receive times and ages (default: the wall clock).
        kinds: framings to forward (all by default).
        backoff: reconnect delays for the source.
        read_timeout_s: longest single wait in the source's read (how often the stop flag is seen).
        rate_window_s: averaging window of the rates.
    """

    def __init__(
        self,
        source: Source,
        sinks: Sequence[Sink],
        *,
        tap: TapCallback | None = None,
        on_frame: FrameCallback | None = None,
        clock: Clock | None = None,
        kinds: Iterable[CorrectionKind] = tuple(CorrectionKind),
        backoff: Backoff | None = None,
        read_timeout_s: float = 0.1,
        rate_window_s: float = 5.0,
    ) -> None:
        names = [s.name for s in sinks]
        if len(set(names)) != len(names):
            raise ValueError(f"relay sinks must have distinct names, got {names}")
        self.source = source
        self.sinks = tuple(sinks)
        self._tap = tap
        self._on_frame = on_frame
        self._clock = clock or SystemClock()
        self._framer = CorrectionFramer(kinds)
        self._backoff = backoff or Backoff()
        self._read_timeout_s = read_timeout_s
        self._rates = _Rates(rate_window_s)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._state = RelayState.IDLE
        self._start_ns = 0
        self._last_frame_ns: int | None = None
        self._connects = 0
        self._source_error: str | None = None
        self.error: BaseException | None = None
        """The fatal error that stopped the relay (None while running or after a clean end)."""
        self._rovers: dict[str, tuple[float | None, int]] = {}
        self._callback_errors = 0
        self._changed = threading.Condition()  # notified when counts or state change (wait_until)
        self._generation = 0

    def __repr__(self) -> str:
        return f"Relay({self.source.name!r} -> {[s.name for s in self.sinks]!r}, {self._state})"

    def __enter__(self) -> Relay:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- control --------------------------------------------------------------------------

    def start(self) -> None:
        """Start the sinks' workers and the reader thread."""
        if self._thread is not None:
            raise RuntimeError("relay already started")
        self._stop.clear()
        self._done.clear()
        self._start_ns = self._clock.now_ns()
        for sink in self.sinks:
            sink.start()
        self._thread = threading.Thread(target=self._run, name="relay-reader", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0, *, drain_s: float = 0.0) -> None:
        """Stop reading, let the sinks write what they hold (up to ``drain_s``), join every thread."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("relay: reader did not stop within %.1f s", timeout_s)
        for sink in self.sinks:
            sink.stop(timeout_s, drain_s=drain_s)
        with self._lock:
            if self._state not in (RelayState.FAILED, RelayState.FINISHED):
                self._state = RelayState.STOPPED
        self._done.set()

    def drain(self, timeout_s: float) -> bool:
        """Wait until every sink has written (or dropped) what it holds; True if they did in time."""
        deadline = time.monotonic() + timeout_s
        return all(sink.drain(max(0.0, deadline - time.monotonic())) for sink in self.sinks)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the reader ends by itself (a file source ended, or a fatal error); True if it did."""
        return self._done.wait(timeout_s)

    @property
    def finished(self) -> threading.Event:
        """Set when the reader has ended (source exhausted, fatal error or stop)."""
        return self._done

    def note_rover_diff_age(self, name: str, age_s: float | None) -> None:
        """Record a rover's own differential age (from its BESTPOS) for the statistics."""
        with self._lock:
            self._rovers[name] = (age_s, self._clock.now_ns())
        self._tick()

    def wait_until(self, predicate: Callable[[RelayStats], bool], timeout_s: float) -> bool:
        """Wait until ``predicate(self.stats())`` holds (re-checked whenever the relay's counts or
        state change); True if it did within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self._changed:
                generation = self._generation
            if predicate(self.stats()):
                return True
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            with self._changed:
                if self._generation == generation:
                    self._changed.wait(min(left, 0.5))

    def _tick(self) -> None:
        with self._changed:
            self._generation += 1
            self._changed.notify_all()

    # --- statistics -----------------------------------------------------------------------

    def stats(self) -> RelayStats:
        """A consistent snapshot (safe from any thread)."""
        now = self._clock.now_ns()
        with self._lock:
            fs = self._framer.stats.copy()
            bps, fps, by_type_rate, span = self._rates.snapshot(now, self._start_ns or now)
            last = self._last_frame_ns
            rovers = {n: RoverAge(a, (now - t) / 1e9) for n, (a, t) in self._rovers.items()}
            state = self._state
            connects = self._connects
            error = self._source_error
            callback_errors = self._callback_errors
        return RelayStats(
            source=self.source.name,
            state=state,
            t_ns=now,
            uptime_s=(now - self._start_ns) / 1e9 if self._start_ns else 0.0,
            window_s=span,
            bytes_in=fs.bytes_in,
            frames_in=fs.total_frames,
            bytes_per_s=bps,
            frames_per_s=fps,
            frames_by_type=dict(sorted(fs.frames_by_label.items())),
            frames_per_s_by_type=by_type_rate,
            frames_by_kind={k.value: v for k, v in fs.frames.items() if v},
            rejected_frames=fs.total_rejected,
            rejected_by_kind={k.value: v for k, v in fs.rejected.items() if v},
            truncated_frames=fs.truncated,
            skipped_bytes=fs.skipped_bytes,
            last_correction_age_s=None if last is None else (now - last) / 1e9,
            source_connects=connects,
            source_error=error,
            callback_errors=callback_errors,
            sinks=tuple(s.stats() for s in self.sinks),
            rovers=rovers,
        )

    # --- reader ---------------------------------------------------------------------------

    def _set_state(self, state: str, error: str | None = None) -> None:
        with self._lock:
            self._state = state
            if error is not None:
                self._source_error = error
        self._tick()

    def _run(self) -> None:
        try:
            self._read_loop()
        except BaseException as exc:  # a bug: record it, then let it escape the thread
            self._fail(exc)
            raise

    def _read_loop(self) -> None:
        source = self.source
        delays = self._backoff.delays()
        try:
            while not self._stop.is_set():
                self._set_state(RelayState.CONNECTING)
                try:
                    source.open(self._stop)
                except FATAL_SOURCE_ERRORS as exc:
                    self._fail(exc)
                    return
                except (OSError, RigError) as exc:
                    source.close()
                    if self._stop.is_set():
                        break
                    delay = next(delays)
                    log.warning("relay source %s: %s; retrying in %.1f s", source.name, exc, delay)
                    self._set_state(RelayState.WAITING, str(exc))
                    self._stop.wait(delay)
                    continue
                with self._lock:
                    self._connects += 1
                    self._state = RelayState.RUNNING
                self._tick()
                try:
                    ended = self._pump()
                except FATAL_SOURCE_ERRORS as exc:
                    source.close()
                    self._fail(exc)
                    return
                except (OSError, RigError) as exc:
                    source.close()
                    with self._lock:
                        self._framer.reset()
                    if self._stop.is_set():
                        break
                    delay = next(delays)
                    log.warning("relay source %s: %s; reconnecting in %.1f s", source.name, exc, delay)
                    self._set_state(RelayState.WAITING, str(exc))
                    self._stop.wait(delay)
                    continue
                source.close()
                delays = self._backoff.delays()
                if ended:
                    self._set_state(RelayState.FINISHED)
                    log.info("relay source %s: end of stream", source.name)
                    return
        finally:
            source.close()
            self._done.set()
            self._tick()

    def _fail(self, exc: BaseException) -> None:
        self.error = exc
        self._set_state(RelayState.FAILED, str(exc))
        log.error("relay source %s: %s", self.source.name, exc)

    def _pump(self) -> bool:
        """Read and forward until stopped (False) or the source ends (True)."""
        source = self.source
        framer = self._framer
        tap = self._tap
        on_frame = self._on_frame
        rates = self._rates
        lock = self._lock
        now_ns = self._clock.now_ns
        timeout = self._read_timeout_s
        while not self._stop.is_set():
            try:
                data = source.read(timeout)
            except EndOfStream:
                with lock:
                    frames = framer.finish()
                self._forward(frames, now_ns())
                return True
            if not data:
                continue
            t_ns = now_ns()
            mono = time.monotonic_ns()
            if tap is not None:
                self._call(tap, t_ns, data)
            with lock:
                frames = framer.feed(data)
                rates.add_bytes(t_ns, len(data))
                for frame in frames:
                    rates.add_frame(t_ns, frame.label)
                if frames:
                    self._last_frame_ns = t_ns
            for frame in frames:
                self._fan_out(frame.raw, mono)
                if on_frame is not None:
                    self._call(on_frame, t_ns, frame)
            self._tick()
        return False

    def _fan_out(self, raw: bytes, mono_ns: int) -> None:
        """A finite source waits for room in every sink (loses nothing); a live one never waits
        (each sink drops its oldest frames and counts them)."""
        if self.source.finite:
            for sink in self.sinks:
                sink.put(raw, self._stop)
        else:
            for sink in self.sinks:
                sink.offer(raw, mono_ns)

    def _forward(self, frames: list[CorrectionFrame], t_ns: int) -> None:
        mono = time.monotonic_ns()
        with self._lock:
            for frame in frames:
                self._rates.add_frame(t_ns, frame.label)
            if frames:
                self._last_frame_ns = t_ns
        for frame in frames:
            self._fan_out(frame.raw, mono)
            if self._on_frame is not None:
                self._call(self._on_frame, t_ns, frame)

    def _call(self, callback: Callable[[int, Any], None], t_ns: int, arg: object) -> None:
        """Run a tap/on_frame callback; its failure must not stop the corrections to the rovers."""
        try:
            callback(t_ns, arg)
        except Exception:
            with self._lock:
                self._callback_errors += 1
                first = self._callback_errors == 1
            if first:
                log.exception("relay: tap/on_frame callback failed (corrections keep flowing; errors counted)")
