"""Simulated NovAtel GNSS receivers speaking the real wire protocol on pseudo-terminals.

Typical session wiring::

    from sim_devices.gnss import SimBase, SimRover, SimTimeBase, SyncSchedule

    tb = SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)
    clock = tb.make_clock(speed=10.0)                  # ScaledClock: 10x real time
    sync = SyncSchedule.for_truth(tb, 1.0, truth.t[-1], period_s=1.0)
    base = SimBase("base", position=(lat, lon, h), timebase=tb, clock=clock)
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=tb, clock=clock, sync=sync)
    base.start(); rover.start()
    # base.port_path, rover.port_path, rover.correction_port_path: open with pyserial
    ...
    rover.stop(); base.stop()

Modules: ``timebase`` (host ↔ GPS ↔ truth time, sync schedule), ``error_model`` (noise by
solution type, RTK state machine), ``antenna`` (antenna kinematics from the truth),
``constellation`` / ``observations`` (synthetic satellites and raw observations), ``rtcm``
(RTCM3 encoders), ``solution`` / ``rawlogs`` / ``bodies`` (log bodies), ``commands`` (command parser), ``pty``
(pseudo-terminal ports), ``geoid`` (the EGM96 undulation of a site), ``receiver`` (the engine: ports,
interface modes, overruns, resets as on an OEM7), ``rover`` and ``base``.
"""

from sim_devices.gnss.base import RTCM_LOGS, SimBase
from sim_devices.gnss.error_model import (
    DEFAULT_SOLUTION_NOISE,
    GnssErrorModel,
    GnssErrorParams,
    RtkParams,
    RtkState,
    RtkStateMachine,
    SolutionNoise,
)
from sim_devices.gnss.receiver import PortSettings, SimReceiver, StartupTiming
from sim_devices.gnss.rover import SimRover
from sim_devices.gnss.solution import Solution
from sim_devices.gnss.timebase import SimTimeBase, SyncSchedule

__all__ = [
    "DEFAULT_SOLUTION_NOISE",
    "RTCM_LOGS",
    "GnssErrorModel",
    "GnssErrorParams",
    "PortSettings",
    "RtkParams",
    "RtkState",
    "RtkStateMachine",
    "SimBase",
    "SimReceiver",
    "SimRover",
    "SimTimeBase",
    "Solution",
    "SolutionNoise",
    "StartupTiming",
    "SyncSchedule",
]
