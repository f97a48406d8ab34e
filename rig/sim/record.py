"""Recording a simulated session: the simulated world's devices behind the real recording, faults at truth
times, the truth on ``/sim/truth``."""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from rig.core.config import SessionConfig
from rig.record.recording import Recording, RecordingSummary
from rig.sim.world import GOVERNED_SWITCH_INTERVAL_S, SimWorld
from rig.store import RecorderOptions
from sim_devices.gnss import RtkParams
from sim_devices.vehicle import Drive, GroundTruth, Scenario
from vsccore.clock import GovernorStats
from vsccore.gpstime import NS_PER_S

__all__ = ["FAST_SPEED", "Action", "SimRecording", "record_simulated"]

log = logging.getLogger(__name__)

if TYPE_CHECKING:

    pass


FAST_SPEED = 3.0
"""Clock speed of ``--fast`` simulated sessions (every device keeps up at this rate on a laptop)."""


Action = tuple[float, Callable[["SimWorld", "Recording"], None]]
"""Something to do to the world or the session at a truth time (s), e.g. unplug a rover."""


@dataclass(frozen=True, slots=True)
class SimRecording:
    """A finished simulated recording."""

    summary: RecordingSummary
    world: SimWorld
    """The (stopped) world: its truth, time base, sync schedule and DAQ timing."""
    completed: bool
    """The drive ran to its end (False: stopped early)."""
    wall_s: float
    governor: GovernorStats | None = None
    """How much the governed clock slowed (None: not governed)."""
    governor_text: str = ""


def record_simulated(
    cfg: SessionConfig,
    out_dir: Path | str,
    *,
    name: str | None = None,
    drive: Drive | Scenario | None = None,
    speed: float | None = None,
    lead_s: float | None = None,
    rtk: RtkParams | None = None,
    stop: threading.Event | None = None,
    tick: Callable[[Recording], None] | None = None,
    actions: Sequence[Action] = (),
    config_path: Path | str | None = None,
    options: RecorderOptions | None = None,
    on_started: Callable[[Recording], None] | None = None,
    truth: GroundTruth | None = None,
    device_process: bool = False,
    governed: bool | None = None,
    floating: Collection[str] = (),
) -> SimRecording:
    """Run a :class:`SimWorld` and record it with a :class:`~rig.record.recording.Recording` until the
    drive ends (or ``stop`` is set, or the recording fails); return what was recorded.

    ``actions`` run at their truth times on this thread; ``tick`` every 0.25 s of real time (a
    dashboard); ``on_started`` once the session records. ``device_process``, ``governed``: see
    :class:`SimWorld`; the governed clock is released once the session has stopped. ``floating``: DAQ channels
    left open (:mod:`rig.sim.faults`).
    """
    t0 = time.monotonic()
    stop = stop or threading.Event()
    world = SimWorld(cfg, drive=drive, speed=speed, lead_s=lead_s, rtk=rtk, truth=truth,
                     device_process=device_process, governed=governed, floating=floating)
    switch = sys.getswitchinterval()
    if world.governed:
        # readers that wake for their data must get the interpreter soon (see _device_host_main)
        sys.setswitchinterval(min(switch, GOVERNED_SWITCH_INTERVAL_S))
    world.start()
    completed = False
    try:
        assert world.clock is not None
        clock = world.clock
        session = Recording(
            cfg, out_dir=out_dir, name=name, clock=world.clock, ports=world, daq_factory=world.daq_session,
            can_factory=world.can_bus, plugins=[world], config_path=config_path, options=options,
        )
        session.start()
        try:
            if world.truth_time_s() > -1.0:
                log.warning("sim world: the recording started only %.1f s before the drive (lead %.1f s at %g×); "
                            "give a longer lead", -world.truth_time_s(), world.lead_s, world.speed)
            if on_started is not None:
                on_started(session)
            pending = sorted(actions, key=lambda a: a[0])
            while not (stop.is_set() or session.failed.is_set()):
                world.report_governor_releases()
                world.report_device_losses()
                now = clock.now_ns()
                while pending and now >= world.timebase.truth_start_ns + round(pending[0][0] * NS_PER_S):
                    pending.pop(0)[1](world, session)
                if now >= world.end_ns:
                    completed = True
                    break
                if tick is not None:
                    tick(session)
                due = world.end_ns
                if pending:
                    due = min(due, world.timebase.truth_start_ns + round(pending[0][0] * NS_PER_S))
                stop.wait(min(0.25, max(0.0, (due - now) / world.speed / NS_PER_S)))
        finally:
            # the clock stays governed while the session stops (a reader that closes its end owes
            # nothing): released first, it ran freely at full speed while the readers closed, and the
            # session's stop took seconds of simulated time under load
            try:
                summary = session.stop()
            finally:
                if clock.governor is not None:
                    clock.governor.release()
    finally:
        governor_text = world.governor_summary() if world.clock is not None else ""
        sys.setswitchinterval(switch)
        world.stop()
    return SimRecording(summary, world, completed, time.monotonic() - t0, world.governor_stats(), governor_text)

