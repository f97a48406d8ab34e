"""What a CAN link delivers, collected in queues that the tests wait on with timeouts."""

from __future__ import annotations

import queue
import time
from typing import Any

from drivers.can.bus import BusState, BusStateChanged, BusStats, CanFrame


class Collector:
    """Frames and events from a session, in queues to wait on with timeouts."""

    def __init__(self) -> None:
        self.frames: queue.Queue[CanFrame] = queue.Queue()
        self.events: queue.Queue[Any] = queue.Queue()

    def frame(self, f: CanFrame) -> None:
        self.frames.put(f)

    def event(self, e: Any) -> None:
        if not isinstance(e, BusStats):
            self.events.put(e)

    def wait_event(self, kind: type, timeout: float = 5.0, where: Any = None) -> Any:
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"no {kind.__name__} event within {timeout} s")
            e = self.events.get(timeout=remaining)
            if isinstance(e, kind) and (where is None or where(e)):
                return e

    def wait_frames(self, n: int, timeout: float = 5.0) -> list[CanFrame]:
        return [self.frames.get(timeout=timeout) for _ in range(n)]

    def state(self, state: BusState, timeout: float = 5.0) -> BusStateChanged:
        return self.wait_event(BusStateChanged, timeout, lambda e: e.state is state)
