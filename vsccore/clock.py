"""Injectable clocks: the host wall clock, and a scaled clock shared by a simulated session.

Everything that stamps host receive times takes a :class:`Clock`, so simulated sessions can run
faster than real time and tests never depend on the machine's wall clock.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    """A source of host time in integer ns since the Unix epoch."""

    def now_ns(self) -> int:
        """Current host time (ns since the Unix epoch)."""
        ...

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        """Wait until ``now_ns() >= t_ns``; return False early if ``stop`` is set."""
        ...


class SystemClock:
    """The host's wall clock (``time.time_ns``)."""

    def now_ns(self) -> int:
        return time.time_ns()

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        delay = (t_ns - time.time_ns()) / 1e9
        if delay <= 0:
            return not (stop is not None and stop.is_set())
        if stop is None:
            time.sleep(delay)
            return True
        return not stop.wait(delay)


class ScaledClock:
    """A clock that runs ``speed`` times faster than the wall clock from a chosen start time.

    Shared by simulated devices and the recorder in a fast simulated session, so host receive
    times and device times stay consistent while the session takes less wall time.
    """

    def __init__(self, start_ns: int, speed: float = 1.0) -> None:
        if speed <= 0:
            raise ValueError(f"clock speed must be > 0, got {speed}")
        self._start_ns = start_ns
        self._speed = speed
        self._mono0 = time.monotonic_ns()

    @property
    def speed(self) -> float:
        return self._speed

    def now_ns(self) -> int:
        return self._start_ns + int((time.monotonic_ns() - self._mono0) * self._speed)

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        delay = (t_ns - self.now_ns()) / self._speed / 1e9
        if delay <= 0:
            return not (stop is not None and stop.is_set())
        if stop is None:
            time.sleep(delay)
            return True
        return not stop.wait(delay)
