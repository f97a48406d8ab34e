"""Time in a simulated session: host clock ↔ GPS time ↔ truth time, and the sync-switch schedule.

Every simulated device of a session shares one :class:`SimTimeBase`: the injected
:class:`~vsccore.clock.Clock` gives host time (ns since the Unix epoch); truth time ``t`` (s since
the start of the simulated drive, as in :class:`~sim_devices.vehicle.truth.GroundTruth`) is 0 at
host time ``truth_start_ns``; true GPS time follows from true UTC with the leap-second count the
simulated receivers report. ``host_clock_offset_ns`` lets the host clock be wrong (host = true UTC
+ offset), so a time-base estimator has something to find.

:class:`SyncSchedule` holds the GPS times of the sync switch's edges. The simulated rovers turn them
into MARKPOS/MARKTIME events; the simulated DAQ puts the same edges on its sync channel
(``SyncPulseOutput(edge_times_s=schedule.truth_times_s(timebase))``).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from vsccore.clock import ClockGovernor, ScaledClock
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S, gps_ns_to_unix_ns, gps_to_ns, unix_ns_to_gps_ns

__all__ = ["SimTimeBase", "SyncSchedule"]


@dataclass(frozen=True, slots=True)
class SimTimeBase:
    """Host clock ↔ true GPS time ↔ truth time of one simulated session.

    Attributes:
        truth_start_ns: host-clock time (ns since the Unix epoch) of truth ``t = 0``.
        leap_seconds: GPS − UTC (s) that the simulated receivers report in TIME (18 since 2017).
        host_clock_offset_ns: host clock − true UTC (ns); 0 for a perfect host clock.
    """

    truth_start_ns: int
    leap_seconds: int = 18
    host_clock_offset_ns: int = 0

    @classmethod
    def from_gps_start(
        cls, week: int, seconds: float, *, leap_seconds: int = 18, host_clock_offset_ns: int = 0
    ) -> SimTimeBase:
        """Time base whose truth ``t = 0`` is the GPS time (``week``, ``seconds``)."""
        if week < 0 or not (0.0 <= seconds < 604800.0):
            raise SimulationError(f"sim time base: GPS start week {week} seconds {seconds} out of range")
        unix = gps_ns_to_unix_ns(gps_to_ns(week, seconds), leap_seconds)
        return cls(unix + host_clock_offset_ns, leap_seconds, host_clock_offset_ns)

    def make_clock(self, speed: float = 1.0, lead_s: float = 0.0, governor: ClockGovernor | None = None) -> ScaledClock:
        """A :class:`ScaledClock` that reads truth ``t = -lead_s`` now and runs ``speed`` times real time
        (governed by ``governor`` when given)."""
        return ScaledClock(self.truth_start_ns - round(lead_s * NS_PER_S), speed, governor=governor)

    @property
    def truth_start_gps_ns(self) -> int:
        """True GPS time (ns since the GPS epoch) of truth ``t = 0``."""
        return self.gps_ns(self.truth_start_ns)

    def gps_ns(self, clock_ns: int) -> int:
        """True GPS time (ns) at host-clock time ``clock_ns``."""
        return unix_ns_to_gps_ns(clock_ns - self.host_clock_offset_ns, self.leap_seconds)

    def clock_ns(self, gps_ns: int) -> int:
        """Host-clock time (ns) at true GPS time ``gps_ns``."""
        return gps_ns_to_unix_ns(gps_ns, self.leap_seconds) + self.host_clock_offset_ns

    def truth_s(self, gps_ns: int) -> float:
        """Truth time (s) at GPS time ``gps_ns``."""
        return (gps_ns - self.truth_start_gps_ns) / NS_PER_S

    def gps_ns_of_truth(self, t_s: float) -> int:
        """GPS time (ns) at truth time ``t_s``."""
        return self.truth_start_gps_ns + round(t_s * NS_PER_S)


@dataclass(frozen=True, slots=True)
class SyncSchedule:
    """GPS times (ns since the GPS epoch, strictly increasing) of the sync switch's active edges."""

    pulse_gps_ns: tuple[int, ...]

    def __post_init__(self) -> None:
        p = self.pulse_gps_ns
        if any(b <= a for a, b in zip(p, p[1:], strict=False)):
            raise SimulationError("sync schedule: pulse times must be strictly increasing")

    @classmethod
    def periodic(cls, start_gps_ns: int, period_s: float = 1.0, count: int = 3600) -> SyncSchedule:
        """``count`` pulses every ``period_s`` seconds from ``start_gps_ns`` on."""
        if not (math.isfinite(period_s) and period_s > 0.0) or count < 0:
            raise SimulationError(f"sync schedule: period {period_s} s and count {count} must be positive")
        step = round(period_s * NS_PER_S)
        return cls(tuple(start_gps_ns + k * step for k in range(count)))

    @classmethod
    def for_truth(
        cls, timebase: SimTimeBase, start_s: float, end_s: float, period_s: float = 1.0
    ) -> SyncSchedule:
        """Pulses every ``period_s`` from truth time ``start_s`` up to ``end_s`` (exclusive)."""
        count = max(0, math.ceil((end_s - start_s) / period_s - 1e-9))
        return cls.periodic(timebase.gps_ns_of_truth(start_s), period_s, count)

    def between(self, after_gps_ns: int, upto_gps_ns: int) -> tuple[int, ...]:
        """Pulses with ``after_gps_ns < t <= upto_gps_ns``."""
        p = self.pulse_gps_ns
        i = bisect.bisect_right(p, after_gps_ns)
        j = bisect.bisect_right(p, upto_gps_ns)
        return p[i:j]

    def next_after(self, gps_ns: int) -> int | None:
        """First pulse strictly after ``gps_ns`` (None when there is none)."""
        p = self.pulse_gps_ns
        i = bisect.bisect_right(p, gps_ns)
        return p[i] if i < len(p) else None

    def truth_times_s(self, timebase: SimTimeBase) -> tuple[float, ...]:
        """The pulse times as truth times (s), e.g. for the simulated DAQ's ``SyncPulseOutput``."""
        return tuple(timebase.truth_s(t) for t in self.pulse_gps_ns)
