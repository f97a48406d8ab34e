"""A reader thread around a DAQ backend: blocks to a consumer, events to an event callback, reconnects.

:class:`DaqLink` creates a backend with a factory, configures and starts it, reads fixed-size
blocks and hands each to ``on_block``. Overflows (reported by the backend on the block after the
gap), health events (:class:`~drivers.daq.health.ChannelHealth`) and connection changes go to
``on_event``. If the device fails or disappears (:class:`~vsccore.errors.DeviceError`, or a read
timeout), the backend is closed and a new one is made after a back-off that waits on the stop
event, so :meth:`DaqLink.stop` is immediate. Each (re)start is a new *segment*: sample indices
restart at 0, and every block and event carries its segment number.

A configuration error is not retried (it would fail the same way forever), and an exception from
a callback is not swallowed: either ends the thread with an ``ERROR`` event and is kept in
:attr:`DaqLink.error`.

With a sync channel, every edge of the sync pulse is reported as a ``SYNC_EDGE`` event whose
``edge_index`` is the fractional sample index of the edge (:class:`~drivers.daq.sync.SyncEdgeDetector`).

:meth:`DaqLink.from_config` builds all of it from the session configuration's ``[daq]`` table:
the backend by name (:func:`~drivers.daq.registry.resolve_backend`), the channels, the rate, block
and buffer sizes, a default channel-health checker and the sync-edge detector.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

from vsccore.clock import Clock, SystemClock
from vsccore.errors import ConfigError, DeviceError, DeviceTimeoutError

from .base import DaqBackend, DaqBlock, DaqChannelConfig, DaqEvent, DaqEventKind, LostSamples, validate_channels
from .health import ChannelHealth, HealthLimits
from .registry import resolve_backend
from .sync import EdgePolarity, SyncEdgeDetector

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ReconnectPolicy:
    """Exponential back-off between connection attempts (s); ``max_attempts`` None = for ever."""

    initial_s: float = 0.5
    max_s: float = 10.0
    factor: float = 2.0
    max_attempts: int | None = None

    def __post_init__(self) -> None:
        if not (self.initial_s >= 0 and self.max_s >= self.initial_s and self.factor >= 1.0):
            raise ConfigError(f"reconnect policy needs 0 <= initial_s <= max_s and factor >= 1, got {self}")


class _ConsumerError(Exception):
    """Wraps an exception raised by a callback so the loop can tell it from a device failure."""


class DaqLink:
    """Reads blocks from a (re)connected DAQ backend in a thread.

    Blocks are ``block_size`` samples; a reader that fell behind takes every whole block waiting
    (up to ``catch_up_s`` of samples) in one read, so a busy host costs latency, not samples.
    """

    def __init__(
        self,
        backend_factory: Callable[[], DaqBackend],
        channels: Sequence[DaqChannelConfig],
        rate_hz: float,
        *,
        on_block: Callable[[DaqBlock], None],
        on_event: Callable[[DaqEvent], None] | None = None,
        clock: Clock | None = None,
        block_size: int | None = None,
        buffer_size: int | None = None,
        read_timeout_s: float | None = None,
        catch_up_s: float = 1.0,
        reconnect: ReconnectPolicy | None = None,
        health: ChannelHealth | None = None,
        sync: SyncEdgeDetector | None = None,
        sync_channel: str | None = None,
        name: str = "daq",
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"DAQ session {name!r}: rate_hz must be > 0, got {rate_hz}")
        self._factory = backend_factory
        self._channels = validate_channels(channels, f"DAQ session {name!r}")
        self._rate_hz = rate_hz
        self._block_size = block_size if block_size is not None else max(1, round(rate_hz / 10.0))
        if self._block_size < 1:
            raise ConfigError(f"DAQ session {name!r}: block_size must be >= 1, got {self._block_size}")
        self._buffer_size = buffer_size
        if not (math.isfinite(catch_up_s) and catch_up_s >= 0):
            raise ConfigError(f"DAQ session {name!r}: catch_up_s must be >= 0, got {catch_up_s}")
        max_read = max(self._block_size, round(catch_up_s * rate_hz))
        if buffer_size is not None:
            max_read = min(max_read, buffer_size)
        self._max_blocks_per_read = max(1, max_read // self._block_size)
        block_s = self._block_size / rate_hz
        self._read_timeout_s = read_timeout_s if read_timeout_s is not None else 2.0 * block_s + 1.0
        self._reconnect = reconnect if reconnect is not None else ReconnectPolicy()
        self._on_block = on_block
        self._on_event = on_event
        self._clock: Clock = clock if clock is not None else SystemClock()
        self._health = health
        if (sync is None) != (sync_channel is None):
            raise ConfigError(f"DAQ session {name!r}: give both sync and sync_channel, or neither")
        if sync_channel is not None and sync_channel not in {c.name for c in self._channels}:
            raise ConfigError(
                f"DAQ session {name!r}: sync channel {sync_channel!r} is not one of the channels "
                f"{[c.name for c in self._channels]}"
            )
        self._sync = sync
        self._sync_channel = sync_channel
        self._name = name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._segment = 0
        self._error: BaseException | None = None
        self._blocks = 0

    @classmethod
    def from_config(
        cls,
        daq: Mapping[str, Any],
        *,
        on_block: Callable[[DaqBlock], None],
        on_event: Callable[[DaqEvent], None] | None = None,
        clock: Clock | None = None,
        backend_options: Mapping[str, Any] | None = None,
        health: ChannelHealth | None = None,
        quiet_channels: Sequence[str] = (),
        sync_hysteresis_v: float = 1.0,
        reconnect: ReconnectPolicy | None = None,
        read_timeout_s: float | None = None,
        where: str = "daq",
    ) -> DaqLink:
        """A session for the configuration's ``[daq]`` table (``DaqConfig.model_dump()`` of ``rig.core.config``).

        Uses ``backend`` (a registry name: ``sim``, ``nidaqmx`` or an entry point), ``device``,
        ``rate_hz``, ``block_size``, ``buffer_samples``, ``channels`` (see
        :meth:`DaqChannelConfig.from_config`), ``sync_channel`` and ``sync_threshold_v`` (rising
        edges through the threshold, hysteresis ±``sync_hysteresis_v``). The backend is made
        as ``create_backend(backend, clock=clock, device=device, **backend_options)`` would — for the
        simulated DAQ, ``backend_options`` carry ``truth``, ``sources``, ``link`` …

        Default health checks: saturation and floating inputs on every channel; no "stuck" check
        (a parked car's sensors are legitimately constant). On a unipolar input (range minimum
        >= 0 V) only the top of the range counts as saturation: 0 V there is a sensor at rest
        (no pressure, a status output saying "invalid"). Channels listed in ``quiet_channels``
        (the sync channel is added automatically) get the floating check only. Pass ``health``
        to replace all of this.

        One backend is constructed and closed at once, so a missing package or driver (e.g.
        NI-DAQmx) is raised here, not retried in the reader thread.

        Raises:
            ConfigError: a missing or invalid key, or an unknown backend name.
            DeviceError: the backend cannot be made (e.g. ``nidaqmx`` or the NI-DAQmx driver missing).
        """
        try:
            backend_name = str(daq["backend"])
            device = str(daq.get("device") or backend_name)
            rate_hz = float(daq["rate_hz"])
            channel_list = daq["channels"]
        except KeyError as exc:
            raise ConfigError(f"{where}: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: invalid value: {exc}") from None
        channels = [DaqChannelConfig.from_config(c, f"{where}.channels[{i}]") for i, c in enumerate(channel_list)]
        block_size = daq.get("block_size")
        buffer_size = daq.get("buffer_samples")
        sync_channel = daq.get("sync_channel")
        options = dict(backend_options or {})
        backend_cls = resolve_backend(backend_name)  # unknown name / bad registration: ConfigError now

        def factory() -> DaqBackend:
            return backend_cls(clock=clock, device=device, **options)

        factory().close()  # a missing optional package or driver fails here, once
        sync: SyncEdgeDetector | None = None
        if sync_channel is not None:
            level = float(daq.get("sync_threshold_v", 2.5))
            sync = SyncEdgeDetector(
                low=level - sync_hysteresis_v, high=level + sync_hysteresis_v, level=level, polarity=EdgePolarity.RISING
            )
        if health is None:
            quiet = set(quiet_channels) | ({str(sync_channel)} if sync_channel is not None else set())
            unknown = sorted(quiet - {c.name for c in channels})
            if unknown:
                raise ConfigError(f"{where}: quiet channels {unknown} are not DAQ channels")
            limits = {c.name: HealthLimits(check_stuck=False, check_low_end=False) for c in channels if c.min_v >= 0}
            limits.update({n: HealthLimits(check_saturation=False, check_stuck=False) for n in quiet})
            health = ChannelHealth(channels, limits=limits, default=HealthLimits(check_stuck=False), clock=clock)
        return cls(
            factory,
            channels,
            rate_hz,
            on_block=on_block,
            on_event=on_event,
            clock=clock,
            block_size=None if block_size is None else int(block_size),
            buffer_size=None if buffer_size is None else int(buffer_size),
            read_timeout_s=read_timeout_s,
            reconnect=reconnect,
            health=health,
            sync=sync,
            sync_channel=None if sync_channel is None else str(sync_channel),
            name=device,
        )

    @property
    def name(self) -> str:
        return self._name

    @property
    def segment(self) -> int:
        """Number of acquisitions started so far (1 after the first start)."""
        return self._segment

    @property
    def blocks_delivered(self) -> int:
        return self._blocks

    @property
    def error(self) -> BaseException | None:
        """The exception that ended the thread (configuration error or a callback's), if any."""
        return self._error

    @property
    def is_running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Start the reader thread (once)."""
        if self._thread is not None:
            raise DeviceError(f"DAQ session {self._name!r} already started")
        self._thread = threading.Thread(target=self._run, name=f"daq-session-{self._name}", daemon=False)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask the thread to stop and join it (it finishes at most the block it is reading)."""
        self._stop.set()
        self.join(timeout_s)

    def join(self, timeout_s: float | None = None) -> bool:
        """Wait for the thread; return True if it has ended."""
        if self._thread is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    # -- thread -----------------------------------------------------------------------------

    def _emit(
        self,
        kind: DaqEventKind,
        message: str,
        *,
        sample_index: int | None = None,
        lost: LostSamples | None = None,
        count: int | None = None,
    ) -> None:
        event = DaqEvent(
            kind,
            self._clock.now_ns(),
            message,
            sample_index=sample_index,
            segment=self._segment,
            lost=lost,
            count=count,
        )
        log.info("DAQ session %s: %s: %s", self._name, kind.value, message)
        if self._on_event is not None:
            try:
                self._on_event(event)
            except Exception as exc:
                raise _ConsumerError(exc) from exc

    def _run(self) -> None:
        delay = self._reconnect.initial_s
        failures = 0
        try:
            while not self._stop.is_set():
                backend = self._connect()
                if backend is None:
                    failures += 1
                    if self._reconnect.max_attempts is not None and failures >= self._reconnect.max_attempts:
                        self._emit(DaqEventKind.ERROR, f"giving up after {failures} failed connection attempts")
                        return
                    if self._stop.wait(delay):
                        return
                    delay = min(delay * self._reconnect.factor, self._reconnect.max_s)
                    continue
                failures = 0
                delay = self._reconnect.initial_s
                try:
                    self._read_loop(backend)
                finally:
                    self._close(backend)
                if not self._stop.is_set() and self._stop.wait(delay):
                    return
        except _ConsumerError as exc:
            cause = exc.__cause__ if exc.__cause__ is not None else exc
            self._error = cause
            log.error("DAQ session %s: callback raised %r; session ends", self._name, cause)
            if self._on_event is not None:
                try:
                    self._on_event(
                        DaqEvent(
                            DaqEventKind.ERROR,
                            self._clock.now_ns(),
                            f"callback raised {cause!r}; DAQ session ended",
                            segment=self._segment,
                        )
                    )
                except Exception:
                    log.exception("DAQ session %s: event callback failed while reporting an error", self._name)
        except ConfigError as exc:
            self._error = exc
            self._emit_final_error(f"configuration error, DAQ session ended: {exc}")
        except Exception as exc:  # a backend bug: end visibly rather than die silently in the thread
            self._error = exc
            log.exception("DAQ session %s: unexpected error; session ends", self._name)
            self._emit_final_error(f"unexpected error, DAQ session ended: {exc!r}")

    def _close(self, backend: DaqBackend) -> None:
        """Close a backend; a device that is already gone may fail to stop, which changes nothing."""
        try:
            backend.close()
        except (DeviceError, DeviceTimeoutError) as exc:
            log.warning("DAQ session %s: closing %s failed (ignored): %s", self._name, backend.device, exc)

    def _emit_final_error(self, message: str) -> None:
        try:
            self._emit(DaqEventKind.ERROR, message)
        except _ConsumerError:
            log.exception("DAQ session %s: event callback failed while reporting an error", self._name)

    def _connect(self) -> DaqBackend | None:
        """Create, configure and start a backend; None (after a CONNECT_FAILED event) if the device fails."""
        backend: DaqBackend | None = None
        try:
            backend = self._factory()
            backend.configure(self._channels)
            backend.start(self._rate_hz, self._buffer_size)
        except (DeviceError, DeviceTimeoutError) as exc:
            if backend is not None:
                self._close(backend)
            self._emit(DaqEventKind.CONNECT_FAILED, f"cannot start DAQ: {exc}")
            return None
        except BaseException:
            if backend is not None:
                self._close(backend)
            raise
        # The health checker resets its windows by itself on the index discontinuity of a new segment.
        if self._sync is not None:
            self._sync.reset()
        self._segment += 1
        kind = DaqEventKind.STARTED if self._segment == 1 else DaqEventKind.RECONNECTED
        self._emit(kind, f"{backend.device}: {len(self._channels)} channels at {self._rate_hz:g} Hz")
        return backend

    def _read_size(self, backend: DaqBackend) -> int:
        """One block, or as many whole blocks as are waiting (up to ``catch_up_s`` of samples).

        A reader that fell behind (a busy host) catches up with one read, one consumer call and one
        set of checks per ``catch_up_s`` instead of per block, so it does not stay behind until the
        buffer overflows.
        """
        n = self._block_size
        blocks = min(backend.available() // n, self._max_blocks_per_read)  # available() <= the buffer
        return n * max(1, blocks)

    def _read_loop(self, backend: DaqBackend) -> None:
        while not self._stop.is_set():
            try:
                block = backend.read(self._read_size(backend), self._read_timeout_s)
            except (DeviceError, DeviceTimeoutError) as exc:
                self._emit(DaqEventKind.DISCONNECTED, f"{backend.device}: {exc}")
                return
            block = dataclasses.replace(block, segment=self._segment)
            if block.lost_before is not None:
                lost = block.lost_before
                self._emit(
                    DaqEventKind.OVERFLOW,
                    f"{backend.device}: reader fell behind, {lost.count} samples lost "
                    f"(indices {lost.start_index}..{lost.stop_index - 1})",
                    sample_index=lost.start_index,
                    lost=lost,
                    count=lost.count,
                )
            events = [] if self._health is None else self._health.check(block)
            if self._sync is not None:
                assert self._sync_channel is not None
                for edge in self._sync.process(block.channel(self._sync_channel), block.first_sample_index):
                    events.append(
                        DaqEvent(
                            DaqEventKind.SYNC_EDGE,
                            block.host_time_ns,
                            f"{'rising' if edge.rising else 'falling'} sync edge on {self._sync_channel!r} "
                            f"at sample {edge.index:.4f}",
                            channel=self._sync_channel,
                            sample_index=math.floor(edge.index),
                            edge_index=edge.index,
                        )
                    )
            if self._on_event is not None:
                for event in events:
                    try:
                        self._on_event(dataclasses.replace(event, segment=self._segment))
                    except Exception as exc:
                        raise _ConsumerError(exc) from exc
            try:
                self._on_block(block)
            except Exception as exc:
                raise _ConsumerError(exc) from exc
            self._blocks += 1
        self._emit(DaqEventKind.STOPPED, f"{backend.device}: acquisition stopped")
