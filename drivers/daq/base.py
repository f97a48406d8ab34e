"""The DAQ backend interface: channel configuration, sample blocks, events and the abstract backend.

A backend runs one hardware-timed, continuous analog-input acquisition. The DAQ's own sample
clock is the time reference: every :class:`DaqBlock` carries the index of its first sample on
that clock (sample ``k`` was taken at ``t_start + k / rate`` in DAQ time), and the host receive
time from an injected :class:`vsccore.clock.Clock` only as a secondary stamp for the time-base
estimator. Samples lost to a buffer overflow are reported with their exact index range on the
first block after the gap, so no earlier sample is ever silently dropped or renumbered.

Like python-can's ``BusABC``, the public methods (:meth:`DaqBackend.configure`,
:meth:`DaqBackend.start`, :meth:`DaqBackend.read`, :meth:`DaqBackend.stop`) check their
arguments and state; a backend implements the small private hooks (``_configure``, ``_start``,
``_read``, ``_stop``, ``_close``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import TracebackType
from typing import Any, ClassVar, Self

import numpy as np
import numpy.typing as npt

from vsccore.clock import Clock, SystemClock
from vsccore.errors import ConfigError, DeviceError

FloatArray = npt.NDArray[np.float64]


class TerminalConfig(StrEnum):
    """Analog-input terminal configuration."""

    RSE = "rse"
    """Referenced single-ended (measured against the DAQ's analog ground)."""
    NRSE = "nrse"
    """Non-referenced single-ended (against a common AI SENSE line)."""
    DIFF = "diff"
    """Differential (the usual choice for sensor outputs in a vehicle: rejects ground offsets)."""
    PSEUDODIFF = "pseudodiff"
    """Pseudo-differential."""


@dataclass(frozen=True, slots=True)
class DaqChannelConfig:
    """One analog-input channel of the acquisition.

    ``name`` is the logical channel name used everywhere downstream (scalings, optical-sensor
    roles, recorded schemas); ``physical_channel`` is the DAQ terminal (``Dev1/ai0``); ``role``
    is free text for people and the recorder (``optical.body.vx``, ``sync``, ``pressure.master``).
    """

    name: str
    physical_channel: str
    min_v: float = -10.0
    max_v: float = 10.0
    terminal: TerminalConfig = TerminalConfig.DIFF
    role: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            raise ConfigError(f"DAQ channel on {self.physical_channel!r}: name is empty")
        if not self.physical_channel:
            raise ConfigError(f"DAQ channel {self.name!r}: physical_channel is empty")
        if not (math.isfinite(self.min_v) and math.isfinite(self.max_v) and self.min_v < self.max_v):
            raise ConfigError(
                f"DAQ channel {self.name!r}: input range must satisfy min_v < max_v, got [{self.min_v}, {self.max_v}] V"
            )

    @classmethod
    def from_config(cls, d: Mapping[str, Any], where: str = "daq.channels") -> DaqChannelConfig:
        """From a session configuration ``[daq].channels`` entry (``DaqChannelConfig.model_dump()`` of
        ``rig.core.config``): ``name``, ``physical``, ``range_v = (min, max)``, ``terminal``, optional ``role``.

        Raises:
            ConfigError: a missing or invalid key (the message names ``where`` and the channel).
        """
        try:
            name = str(d["name"])
            lo, hi = d.get("range_v", (-10.0, 10.0))
            return cls(
                name=name,
                physical_channel=str(d["physical"]),
                min_v=float(lo),
                max_v=float(hi),
                terminal=TerminalConfig(str(d.get("terminal", "diff"))),
                role=str(d.get("role", "")),
            )
        except KeyError as exc:
            raise ConfigError(f"{where}: missing key {exc.args[0]!r} in {dict(d)!r}") from None
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: invalid DAQ channel {dict(d)!r}: {exc}") from None


@dataclass(frozen=True, slots=True)
class LostSamples:
    """A gap in the sample stream: samples ``start_index`` … ``stop_index − 1`` were overwritten."""

    start_index: int
    stop_index: int

    def __post_init__(self) -> None:
        if self.stop_index <= self.start_index:
            raise ValueError(f"lost sample range must be non-empty, got [{self.start_index}, {self.stop_index})")

    @property
    def count(self) -> int:
        return self.stop_index - self.start_index


@dataclass(frozen=True, slots=True)
class DaqBlock:
    """A contiguous block of samples of every configured channel.

    ``data[i, j]`` is channel ``channels[i]`` at DAQ sample index ``first_sample_index + j`` (volts).
    ``lost_before`` is set on the first block after an overflow: those samples immediately precede
    this block and are gone. ``segment`` counts acquisitions (it increases when a
    :class:`drivers.daq.link.DaqLink` restarts a disconnected device, and sample indices
    restart at 0 with it).
    """

    first_sample_index: int
    rate_hz: float
    data: FloatArray
    host_time_ns: int
    channels: tuple[str, ...]
    lost_before: LostSamples | None = None
    segment: int = 0

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[1])

    @property
    def next_sample_index(self) -> int:
        """Index of the sample that follows this block."""
        return self.first_sample_index + self.n_samples

    def sample_indices(self) -> npt.NDArray[np.int64]:
        """DAQ sample index of every column."""
        return np.arange(self.first_sample_index, self.next_sample_index, dtype=np.int64)

    def channel(self, name: str) -> FloatArray:
        """Volts of one channel (a view).

        Raises:
            ConfigError: the block has no channel of that name (the message lists the ones it has).
        """
        try:
            i = self.channels.index(name)
        except ValueError:
            raise ConfigError(f"DAQ block has no channel {name!r}; channels: {list(self.channels)}") from None
        return self.data[i]


class DaqEventKind(StrEnum):
    """What a :class:`DaqEvent` reports."""

    STARTED = "started"
    STOPPED = "stopped"
    OVERFLOW = "overflow"
    DISCONNECTED = "disconnected"
    RECONNECTED = "reconnected"
    CONNECT_FAILED = "connect_failed"
    SATURATION = "saturation"
    SATURATION_CLEARED = "saturation_cleared"
    STUCK = "stuck"
    STUCK_CLEARED = "stuck_cleared"
    FLOATING = "floating"
    FLOATING_CLEARED = "floating_cleared"
    SYNC_EDGE = "sync_edge"
    ERROR = "error"


@dataclass(frozen=True, slots=True)
class DaqEvent:
    """Something the recorder should put on ``/rig/events``.

    ``sample_index`` is the DAQ sample index where it was detected (when there is one), ``lost``
    the overflowed range for :attr:`DaqEventKind.OVERFLOW`, ``count`` a number of samples
    (saturated samples in an episode, …). For :attr:`DaqEventKind.SYNC_EDGE`, ``edge_index`` is the
    fractional sample index of the edge (``sample_index`` its floor) within ``segment``.
    """

    kind: DaqEventKind
    host_time_ns: int
    message: str
    channel: str | None = None
    sample_index: int | None = None
    segment: int = 0
    lost: LostSamples | None = None
    count: int | None = None
    edge_index: float | None = None


def validate_channels(channels: Sequence[DaqChannelConfig], device: str) -> tuple[DaqChannelConfig, ...]:
    """Check a channel list (non-empty, unique names and physical channels); return it as a tuple."""
    chans = tuple(channels)
    if not chans:
        raise ConfigError(f"{device}: no DAQ channels configured")
    for attr in ("name", "physical_channel"):
        values = [getattr(c, attr) for c in chans]
        dup = sorted({v for v in values if values.count(v) > 1})
        if dup:
            raise ConfigError(f"{device}: DAQ channel {attr}s must be unique, repeated: {dup}")
    return chans


class DaqBackend(ABC):
    """One continuous, hardware-timed analog-input acquisition.

    Life cycle: :meth:`configure` → :meth:`start` → :meth:`read` … → :meth:`stop` → (configure /
    start again) … → :meth:`close`. Not thread-safe: one thread reads (the
    :class:`~drivers.daq.link.DaqLink`).
    """

    name: ClassVar[str] = "daq"
    """Registry name of the backend (``sim``, ``nidaqmx``, …)."""

    def __init__(self, *, clock: Clock | None = None, device: str | None = None) -> None:
        """Backends are constructed by :func:`~drivers.daq.registry.create_backend` with keyword
        arguments only; every backend accepts ``clock`` (host clock for receive stamps) and
        ``device`` (the configuration's ``[daq].device``), plus its own options."""
        self._clock: Clock = clock if clock is not None else SystemClock()
        self._device = device or self.name
        self._channels: tuple[DaqChannelConfig, ...] = ()
        self._rate_hz: float | None = None
        self._buffer_size: int = 0
        self._running = False
        self._closed = False

    # -- public API ---------------------------------------------------------------------------

    @property
    def device(self) -> str:
        """Human-readable device name for messages (``sim``, ``Dev1``, …)."""
        return self._device

    @property
    def clock(self) -> Clock:
        return self._clock

    @property
    def channels(self) -> tuple[DaqChannelConfig, ...]:
        return self._channels

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self._channels)

    @property
    def rate_hz(self) -> float | None:
        """Sample rate of the running (or last) acquisition (Hz)."""
        return self._rate_hz

    @property
    def buffer_size(self) -> int:
        """Samples per channel the acquisition buffer holds."""
        return self._buffer_size

    @property
    def running(self) -> bool:
        return self._running

    def configure(self, channels: Sequence[DaqChannelConfig]) -> None:
        """Set the channels of the next acquisition.

        Raises:
            ConfigError: empty list, repeated names or physical channels, or a channel the
                backend cannot provide.
            DeviceError: the backend is running or closed.
        """
        self._check_open()
        if self._running:
            raise DeviceError(f"DAQ {self._device}: stop the acquisition before reconfiguring")
        chans = validate_channels(channels, f"DAQ {self._device}")
        self._configure(chans)
        self._channels = chans

    def start(self, rate_hz: float, buffer_size: int | None = None) -> None:
        """Start continuous acquisition at ``rate_hz``; sample indices start at 0.

        ``buffer_size`` is the number of samples per channel the acquisition buffer holds
        (default: 10 s of samples, at least 1000).

        Raises:
            ConfigError: no channels configured, or a non-positive rate or buffer.
            DeviceError: the device cannot start.
        """
        self._check_open()
        if self._running:
            raise DeviceError(f"DAQ {self._device}: acquisition already running")
        if not self._channels:
            raise ConfigError(f"DAQ {self._device}: configure channels before start()")
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"DAQ {self._device}: sample rate must be > 0 Hz, got {rate_hz}")
        size = buffer_size if buffer_size is not None else max(1000, round(10.0 * rate_hz))
        if size < 2:
            raise ConfigError(f"DAQ {self._device}: buffer size must be at least 2 samples, got {size}")
        self._start(rate_hz, size)
        self._rate_hz = rate_hz
        self._buffer_size = size
        self._running = True

    def read(self, n_samples: int, timeout_s: float = 1.0) -> DaqBlock:
        """Block until ``n_samples`` samples per channel are available and return them.

        The block follows the previous one without a gap unless samples were overwritten, in
        which case ``lost_before`` names the missing index range.

        Raises:
            DeviceTimeoutError: the samples did not arrive within ``timeout_s`` (nothing consumed).
            DeviceError: the device failed or disappeared, or the acquisition is not running.
        """
        if not self._running:
            raise DeviceError(f"DAQ {self._device}: read() without a running acquisition")
        if n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        first, data, lost = self._read(n_samples, timeout_s)
        host_ns = self._clock.now_ns()
        assert self._rate_hz is not None
        if data.shape != (len(self._channels), n_samples):
            raise DeviceError(
                f"DAQ {self._device}: backend returned data of shape {data.shape}, "
                f"expected {(len(self._channels), n_samples)}"
            )
        return DaqBlock(
            first_sample_index=first,
            rate_hz=self._rate_hz,
            data=data,
            host_time_ns=host_ns,
            channels=self.channel_names,
            lost_before=lost,
        )

    def available(self) -> int:
        """Samples per channel acquired and not yet read (0 when not running or the backend cannot tell).

        A reader that fell behind takes them in one :meth:`read` instead of block by block (see
        :class:`~drivers.daq.link.DaqLink`), so it catches up with one call's overhead. Never
        raises for a device that has gone: the next :meth:`read` reports that.
        """
        if not self._running:
            return 0
        return max(0, min(self._available(), self._buffer_size))

    def stop(self) -> None:
        """Stop the acquisition (idempotent); unread samples are discarded."""
        if self._running:
            self._running = False
            self._stop()

    def close(self) -> None:
        """Stop and release the device (idempotent)."""
        if self._closed:
            return
        try:
            self.stop()
        finally:
            self._closed = True
            self._close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceError(f"DAQ {self._device}: backend is closed")

    # -- hooks for backends -------------------------------------------------------------------

    @abstractmethod
    def _configure(self, channels: tuple[DaqChannelConfig, ...]) -> None:
        """Check that the backend can provide these channels (raise ConfigError if not)."""

    @abstractmethod
    def _start(self, rate_hz: float, buffer_size: int) -> None:
        """Start hardware-timed continuous acquisition of ``self.channels``."""

    @abstractmethod
    def _read(self, n_samples: int, timeout_s: float) -> tuple[int, FloatArray, LostSamples | None]:
        """Return (first sample index, volts of shape (n_channels, n_samples), lost range or None)."""

    @abstractmethod
    def _stop(self) -> None:
        """Stop the acquisition."""

    def _available(self) -> int:
        """Samples per channel waiting in the acquisition buffer (optional hook; 0: unknown)."""
        return 0

    def _close(self) -> None:  # noqa: B027 - optional hook, most backends hold nothing after stop
        """Release the device."""
