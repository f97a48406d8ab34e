"""Channel health over DAQ blocks: saturation, stuck (constant) and floating (disconnected) inputs.

Each condition is reported as a pair of events, when it begins and when it clears, so a recorder
gets a handful of events for a long episode rather than one per block. The checker only looks at
the volts; it never modifies or drops a sample.

- saturation: samples at (within ``saturation_margin_v`` of) the input range limits, or non-finite
  (so a signal resting at 0 V on a 0–10 V input counts: give such channels a bipolar range or
  ``check_low_end=False``, which :meth:`DaqLink.from_config` does for unipolar inputs);
- stuck: the standard deviation over the trailing ``window_s`` is at most ``stuck_std_v``, i.e.
  nothing but the converter's own noise (a channel pulled to a constant, or a frozen sensor
  output). Channels that are legitimately constant for long (sync, status, brake pressure while
  cruising) should have ``check_stuck=False`` or a longer window;
- floating: the median absolute sample-to-sample difference over the window exceeds
  ``floating_noise_v`` (an open input picks up wide-band noise and hum; a real sensor output is
  smooth at the sample rate, and a median ignores the few large steps of a legitimate edge).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from vsccore.clock import Clock, SystemClock
from vsccore.errors import ConfigError

from .base import DaqBlock, DaqChannelConfig, DaqEvent, DaqEventKind

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class HealthLimits:
    """Per-channel thresholds of :class:`ChannelHealth` (volts, seconds)."""

    saturation_margin_v: float = 0.01
    window_s: float = 1.0
    stuck_std_v: float = 0.001
    floating_noise_v: float = 0.05
    check_saturation: bool = True
    check_low_end: bool = True
    """Count samples at the range minimum as saturated (off for unipolar inputs whose signal rests at 0 V)."""
    check_stuck: bool = True
    check_floating: bool = True

    def __post_init__(self) -> None:
        for name in ("saturation_margin_v", "window_s", "stuck_std_v", "floating_noise_v"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"health limit {name} must be a finite number >= 0, got {v}")
        if self.window_s == 0:
            raise ConfigError("health limit window_s must be > 0")


@dataclass(slots=True)
class ChannelStats:
    """Running counters of one channel (mutable, owned by the checker)."""

    saturated_samples: int = 0
    saturated: bool = False
    episode_saturated: int = 0
    stuck: bool = False
    floating: bool = False
    window: FloatArray = field(default_factory=lambda: np.empty(0, dtype=np.float64))


class ChannelHealth:
    """Watches every channel of a stream of :class:`DaqBlock` and returns health events."""

    def __init__(
        self,
        channels: Sequence[DaqChannelConfig],
        limits: Mapping[str, HealthLimits] | None = None,
        default: HealthLimits | None = None,
        clock: Clock | None = None,
    ) -> None:
        self._channels = {c.name: c for c in channels}
        lim = dict(limits or {})
        unknown = sorted(set(lim) - set(self._channels))
        if unknown:
            raise ConfigError(f"health limits name unknown DAQ channels {unknown}; channels: {sorted(self._channels)}")
        base = default if default is not None else HealthLimits()
        self._limits = {name: lim.get(name, base) for name in self._channels}
        self._stats = {name: ChannelStats() for name in self._channels}
        self._clock: Clock = clock if clock is not None else SystemClock()
        self._next_index: int | None = None

    @property
    def stats(self) -> Mapping[str, ChannelStats]:
        return self._stats

    def check(self, block: DaqBlock) -> list[DaqEvent]:
        """Update the state with one block; return the events that began or cleared in it."""
        now = self._clock.now_ns()
        events: list[DaqEvent] = []
        if self._next_index is not None and block.first_sample_index != self._next_index:
            for st in self._stats.values():  # the window must not bridge a gap or a restart
                st.window = np.empty(0, dtype=np.float64)
        self._next_index = block.next_sample_index
        for i, name in enumerate(block.channels):
            if name in self._channels:
                events.extend(self._check_channel(name, block.data[i], block, now))
        return events

    def _check_channel(self, name: str, x: FloatArray, block: DaqBlock, now: int) -> list[DaqEvent]:
        cfg = self._channels[name]
        lim = self._limits[name]
        st = self._stats[name]
        events: list[DaqEvent] = []

        def ev(kind: DaqEventKind, msg: str, index: int, count: int | None = None) -> DaqEvent:
            return DaqEvent(kind, now, msg, channel=name, sample_index=index, segment=block.segment, count=count)

        if lim.check_saturation:
            with np.errstate(invalid="ignore"):
                bad = ~np.isfinite(x) | (x >= cfg.max_v - lim.saturation_margin_v)
                if lim.check_low_end:
                    bad |= x <= cfg.min_v + lim.saturation_margin_v
            n_bad = int(np.count_nonzero(bad))
            st.saturated_samples += n_bad
            if n_bad and not st.saturated:
                st.saturated = True
                st.episode_saturated = 0
                where = f"[{cfg.min_v}, {cfg.max_v}] V" if lim.check_low_end else f"maximum {cfg.max_v} V"
                msg = f"DAQ channel {name!r} ({cfg.physical_channel}) at its input range {where} or non-finite"
                events.append(ev(DaqEventKind.SATURATION, msg, block.first_sample_index + int(np.argmax(bad))))
            if st.saturated:
                st.episode_saturated += n_bad
                if n_bad == 0:
                    st.saturated = False
                    msg = f"DAQ channel {name!r} back within range after {st.episode_saturated} saturated samples"
                    events.append(
                        ev(DaqEventKind.SATURATION_CLEARED, msg, block.first_sample_index, st.episode_saturated)
                    )
        if not (lim.check_stuck or lim.check_floating):
            return events
        n_win = max(2, round(lim.window_s * block.rate_hz))
        win = np.concatenate((st.window, x))[-n_win:]
        st.window = win
        if win.size < n_win:
            return events
        end_index = block.next_sample_index - 1
        if lim.check_stuck:
            stuck = bool(np.all(np.isfinite(win))) and float(np.std(win)) <= lim.stuck_std_v
            if stuck != st.stuck:
                st.stuck = stuck
                if stuck:
                    msg = (
                        f"DAQ channel {name!r} ({cfg.physical_channel}) constant at {float(win[-1]):.4f} V "
                        f"for {lim.window_s} s (stuck or disconnected)"
                    )
                    events.append(ev(DaqEventKind.STUCK, msg, end_index - n_win + 1))
                else:
                    events.append(ev(DaqEventKind.STUCK_CLEARED, f"DAQ channel {name!r} moving again", end_index))
        if lim.check_floating:
            d = np.abs(np.diff(win))
            d = d[np.isfinite(d)]
            noise = float(np.median(d)) if d.size else 0.0
            floating = noise > lim.floating_noise_v
            if floating != st.floating:
                st.floating = floating
                if floating:
                    msg = (
                        f"DAQ channel {name!r} ({cfg.physical_channel}) looks floating: median sample-to-sample "
                        f"change {noise:.3f} V > {lim.floating_noise_v} V (open input?)"
                    )
                    events.append(ev(DaqEventKind.FLOATING, msg, end_index - n_win + 1))
                else:
                    msg = f"DAQ channel {name!r} no longer floating"
                    events.append(ev(DaqEventKind.FLOATING_CLEARED, msg, end_index))
        return events
