"""Cost of one ``now_ns()`` of the governed scaled clock (issue 15 §4: called once per CAN frame).

Sets up the participants of a ``rig demo --fast`` recording (three receivers, an ECU feeding its CAN
reader, the DAQ reader, the truth writer) well ahead of the clock, so nothing holds it, and times:
the free-running clock; the governed clock with nothing changed between calls; and the governed clock
when a participant has published new progress since the last call (the CAN path: a frame sent or
taken between two stamps; the publish alone is timed and subtracted). Times are the thread's CPU time
(best of five rounds), so a loaded host does not inflate them.

Usage: .venv/bin/python benchmarks/bench_clock_now.py [CALLS]
"""

from __future__ import annotations

import sys
import time

from vsccore.clock import UNBOUNDED_NS, ClockGovernor, ScaledClock, participant

MS = 1_000_000
HOUR_NS = 3_600_000 * MS


def _per_call(fn: object, n: int) -> float:
    best = float("inf")
    for _ in range(5):
        t0 = time.thread_time_ns()
        for _ in range(n):
            fn()  # type: ignore[operator]
        best = min(best, (time.thread_time_ns() - t0) / n)
    return best


def main(n: int) -> None:
    free = ScaledClock(0, 8.0)
    gov = ClockGovernor.create(1 * MS)
    try:
        clock = ScaledClock(0, 8.0, governor=gov)
        parts = [participant(clock, name, progress_ns=HOUR_NS)
                 for name in ("gnss:base", "gnss:rover_a", "gnss:rover_b", "daq:SimDAQ", "truth")]
        rx = participant(clock, "canrx:vsc-sim", progress_ns=UNBOUNDED_NS, value=UNBOUNDED_NS)
        ecu = participant(clock, "ecu:vsc-sim", progress_ns=HOUR_NS)
        ecu.feeds("canrx:vsc-sim")
        ecu.sent(1 * MS)
        rx.took(1 * MS)
        k = [HOUR_NS]

        def publish() -> None:
            k[0] += 1
            parts[1].at(k[0])

        def publish_and_now() -> None:
            k[0] += 1
            parts[1].at(k[0])
            clock.now_ns()

        t_free = _per_call(free.now_ns, n)
        t_steady = _per_call(clock.now_ns, n)
        t_pub = _per_call(publish, n)
        t_both = _per_call(publish_and_now, n)
        print(f"free-running ScaledClock.now_ns: {t_free:8.0f} ns/call")
        print(f"governed now_ns, nothing changed: {t_steady:8.0f} ns/call (7 participants, one producer/consumer pair)")
        print(f"governed now_ns after a publish: {t_both - t_pub:8.0f} ns/call (publish alone {t_pub:.0f} ns)")
    finally:
        gov.close()


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 100_000)
