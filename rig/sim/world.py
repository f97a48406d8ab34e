"""The simulated car of a session configuration's ``[simulation]`` table, with every device running.

:class:`SimWorld` simulates the drive (ground truth), then, on one
:class:`~vsccore.clock.ScaledClock` running ``simulation.speed`` times real time, starts:

- a :class:`~sim_devices.gnss.SimBase` and :class:`~sim_devices.gnss.SimRover` per receiver whose
  port is ``sim://NAME`` (each on its own pseudo-terminals; the rovers' roof antennas at the
  configured lever arms ``[antennas].a`` / ``.b``; MARK1 wired to the sync switch);
- the simulated VSC ECU (:class:`~sim_devices.vsc_ecu.VscEcu`) on a python-can virtual bus per
  ``[[can]]`` table with ``interface = "virtual"`` (on the configured channel); it sends until the
  world stops, the car standing where the drive ended, as the receivers show it (a real car's bus
  runs until the recorder stops);
- the simulated DAQ (:class:`~sim_devices.daq.SimDaqBackend`), made by :meth:`SimWorld.daq_session`
  for the recording session: the optical sensors' outputs (with the *true* zero offset of
  ``simulation.true_optical_zero_deg``), brake-pressure transducers and the sync switch, whose
  edges are the same :class:`~sim_devices.gnss.SyncSchedule` as the rovers' MARKPOS/MARKTIME.

The clock starts ``lead_s`` before truth ``t = 0``: the car stands at its start while the recorder
connects and the rovers reach an RTK fix. :class:`SimWorld` is also the session's port resolver
(``sim://NAME`` → the pseudo-terminal's stable path) and a session plug-in that records the ground
truth on ``/sim/truth`` as simulated time passes, plus the simulated DAQ's true sample timing as a
``/rig/events`` entry (source ``sim``), so a file carries what is needed to score its time base.
:meth:`SimWorld.stop` stops and joins everything.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import multiprocessing
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.analog import AnalogChannelSpec
from drivers.can.bus import CanBusConfig, TimestampSource, open_bus
from drivers.daq import (
    ChannelHealth,
    DaqBlock,
    DaqChannelConfig,
    DaqEvent,
    DaqLink,
    EdgePolarity,
    HealthLimits,
    SyncEdgeDetector,
)
from drivers.optical import OpticalSensorSpec
from rig.core.config import AntennaConfig, CanConfig, DaqConfig, ReceiverConfig, SessionConfig, SimulationConfig
from rig.core.topics import EventKind, Severity
from rig.record.recording import Recording
from sim_devices.daq import (
    FloatingInput,
    SimDaqBackend,
    SimDaqLink,
    SimOpticalSensor,
    SyncPulseOutput,
    sim_daq_sources,
)
from sim_devices.gnss import (
    DEFAULT_SOLUTION_NOISE,
    GnssErrorParams,
    RtkParams,
    SimBase,
    SimReceiver,
    SimRover,
    SimTimeBase,
    SolutionNoise,
    SyncSchedule,
)
from sim_devices.gnss.receiver import LATENCY_RANGE_S
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from sim_devices.vehicle import Drive, GroundTruth, Scenario, VehicleParams, demo_drive, make_scenario, simulate
from sim_devices.vsc_ecu import RUN_ON_STRETCH_S, EcuOutputs, VscEcu, VscEcuConfig, simulate_ecu
from vsccore.clock import (
    UNBOUNDED_NS,
    Clock,
    ClockGovernor,
    GovernorStats,
    Participant,
    ReleaseReason,
    ScaledClock,
    participant,
)
from vsccore.errors import ConfigError, DeviceError, SimulationError
from vsccore.gpstime import NS_PER_S, gps_ns_to_unix_ns

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.process import BaseProcess

    from rig.store import Source

__all__ = [
    "SIM_PREFIX",
    "DaqTiming",
    "SimCanLink",
    "SimWorld",
    "drive_from_name",
    "true_antenna_lever_arms",
]

log = logging.getLogger(__name__)

SIM_PREFIX = "sim://"
"""Port scheme of simulated receivers: ``sim://NAME`` (main port) or ``sim://NAME/COM2`` (another port)."""



class SimCanLink:
    """The cable between the simulated car's CAN bus and the host's adapter: unplug it to make the
    interface vanish (reads fail, the adapter cannot be opened) and replug it to bring it back."""

    def __init__(self) -> None:
        self._unplugged = threading.Event()

    @property
    def connected(self) -> bool:
        return not self._unplugged.is_set()

    def unplug(self) -> None:
        self._unplugged.set()

    def replug(self) -> None:
        self._unplugged.clear()


class _LinkedBus(can.BusABC):
    """A python-can bus behind a :class:`SimCanLink`: a USB adapter whose cable can be pulled."""

    def __init__(self, inner: can.BusABC, link: SimCanLink, reader: Participant | None = None) -> None:
        super().__init__(channel=getattr(inner, "channel_info", "sim"))
        self._inner = inner
        self._link = link
        self._reader = reader
        self._taken: int | None = None
        self.channel_info = f"simulated adapter on {inner.channel_info}"

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._report_taken()
        if not self._link.connected:
            self._not_reading()
            raise can.CanOperationError("simulated CAN adapter unplugged")
        msg = self._inner.recv(timeout)
        if not self._link.connected:
            self._not_reading()
            raise can.CanOperationError("simulated CAN adapter unplugged")
        if msg is not None and self._reader is not None:
            # reported as taken when the reader comes back for the next frame, i.e. once it has stamped
            # and handled this one: until then the governed clock holds (from the reader's first frame
            # on; what was sent before it was connected is not owed)
            self._taken = round(msg.timestamp * 1e9)
        return msg, False

    def _report_taken(self) -> None:
        if self._taken is not None and self._reader is not None:
            self._reader.took(self._taken)
            self._taken = None

    def _not_reading(self) -> None:
        self._taken = None
        if self._reader is not None:
            self._reader.not_reading()  # owes nothing: the clock must not wait for it

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._link.connected:
            raise can.CanOperationError("simulated CAN adapter unplugged")
        self._inner.send(msg, timeout)

    def shutdown(self) -> None:
        self._not_reading()
        super().shutdown()
        self._inner.shutdown()


def drive_from_name(text: str, *, heading_deg: float = 0.0) -> Drive | Scenario:
    """The drive named in ``simulation.drive``: ``demo`` or a scenario, optionally ``NAME:key=value,…``.

    Raises:
        SimulationError: unknown scenario or parameter (with a "did you mean" hint), bad syntax.
    """
    name, _, args = text.partition(":")
    params: dict[str, object] = {}
    for item in filter(None, (a.strip() for a in args.split(","))):
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise SimulationError(f"simulation.drive {text!r}: parameter {item!r} is not KEY=VALUE")
        params[key.strip()] = value.strip()
    name = name.strip()
    if name == "demo":
        if params:
            raise SimulationError(f"simulation.drive {text!r}: the demo drive takes no parameters")
        return demo_drive(heading_deg=heading_deg)
    if "heading_deg" not in params and name == "straight":
        params["heading_deg"] = heading_deg
    return make_scenario(name, **params)


@dataclass(frozen=True, slots=True)
class DaqTiming:
    """True sample timing of one acquisition (segment) of the simulated DAQ."""

    device: str
    segment: int
    sample0_gps_ns: int
    """True GPS time (ns) of sample index 0 of the segment."""
    true_rate_hz: float
    """Samples per second of true time (the nominal rate with the sample clock's ppm error)."""

    def gps_ns(self, sample_index: Any) -> Any:
        """True GPS time (ns, float for arrays) of sample indices of this segment."""
        return self.sample0_gps_ns + sample_index * (1e9 / self.true_rate_hz)


class SimWorld:
    """A simulated car with all its devices (see the module docstring).

    Args:
        cfg: session configuration with a ``[simulation]`` table.
        drive: the drive (default: ``simulation.drive``).
        speed: clock speed factor (default ``simulation.speed``).
        lead_s: simulated time before the drive starts (default: long enough for an RTK fix).
        rtk: timing of the simulated rovers' RTK engine.
        sync_period_s: interval of the sync switch's pulses.
        truth_rate_hz: rate of the ground truth (and of ``/sim/truth``).
        truth: the drive's ground truth when it has been simulated already (with this configuration).
        device_process: run the simulated receivers and ECUs in processes of their own (see
            :class:`_DeviceHost`), as real devices run on their own hardware: the receivers in
            one, the ECUs in another, so neither waits for the interpreter while the other works
            and the recording process has its own to itself. The DAQ and the truth topic stay in
            this process; faults (unplugging) of receivers and ECUs are only available with the
            devices in this process.
        governed: run a governed clock (default ``simulation.governed``): simulated time waits,
            in both processes (:class:`~vsccore.clock.ClockGovernor`): it stands still at each ECU
            frame and GNSS write until it is sent, at each GNSS write until it is read, and at most
            ``simulation.governor_budget_ms`` past a CAN frame the reader has not taken yet (and
            past the DAQ's and the truth writer's progress), so a busy host makes the session slower,
            not late. False: the host's scheduling delays show, magnified by the speed factor.
    """

    def __init__(
        self,
        cfg: SessionConfig,
        *,
        drive: Drive | Scenario | None = None,
        speed: float | None = None,
        lead_s: float | None = None,
        rtk: RtkParams | None = None,
        sync_period_s: float = 1.0,
        truth_rate_hz: float = 1000.0,
        truth: GroundTruth | None = None,
        device_process: bool = False,
        governed: bool | None = None,
        floating: Collection[str] = (),
        _part: DevicePart | None = None,
    ) -> None:
        if cfg.simulation is None:
            raise ConfigError("simulation: a simulated session needs a [simulation] table in its configuration")
        self.cfg = cfg
        self.floating = frozenset(floating)
        """DAQ channels left open (a fault: noise and mains hum instead of their signal)."""
        self.sim: SimulationConfig = cfg.simulation
        sim = self.sim
        self.speed = float(speed if speed is not None else sim.speed)
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ConfigError(f"simulation.speed: must be > 0, got {self.speed}")
        self.governed = sim.governed if governed is None else governed
        self.rtk = rtk or RtkParams()
        params = VehicleParams.from_mapping(cfg.profile.vehicle.model_dump(), section="vehicle")
        self.drive = drive if drive is not None else drive_from_name(sim.drive, heading_deg=sim.initial_heading_deg)
        self.truth: GroundTruth = truth if truth is not None else simulate(
            self.drive,
            params,
            rate_hz=truth_rate_hz,
            origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
            initial_heading_deg=sim.initial_heading_deg,
            seed=sim.seed,
        )
        self.timebase = SimTimeBase.from_gps_start(
            sim.start_gps_week, sim.start_gps_seconds, leap_seconds=sim.gnss.leap_seconds
        )
        self._sim_receivers = [r for r in cfg.receivers if r.port.startswith(SIM_PREFIX)]
        self._virtual_can = [c for c in cfg.can if c.interface == "virtual"]
        has_rover = any(r.role == "rover" for r in self._sim_receivers)
        self.lead_s = float(lead_s if lead_s is not None else (self.rtk.time_to_fix_s + 4.0 if has_rover else 1.0))
        self.duration_s = float(self.truth.t[-1])
        self.sync_period_s = sync_period_s
        self.sync = SyncSchedule.for_truth(self.timebase, -self.lead_s + 0.5, self.duration_s, sync_period_s)
        self.truth_t0_utc_ns = gps_ns_to_unix_ns(self.timebase.truth_start_gps_ns, sim.gnss.leap_seconds)
        self._ecu_config = VscEcuConfig(seed=sim.seed, swa_offset_rad=math.radians(sim.true_swa_offset_deg))
        self._rx_host = (_DeviceHost(self, DevicePart(receivers=True, ecus=False))
                         if device_process and self._sim_receivers else None)
        self._ecu_host = (_DeviceHost(self, DevicePart(receivers=False, ecus=True))
                          if device_process and self._virtual_can else None)
        self._hosts = [h for h in (self._rx_host, self._ecu_host) if h is not None]
        if _part is not None and not device_process:  # this world is one device process's part of the recording's world
            self._sim_receivers = self._sim_receivers if _part.receivers else []
            self._virtual_can = self._virtual_can if _part.ecus else []
        # Computed before the clock starts, so the ECU is on time from its first frame (and past the
        # drive's end: the ECU runs on until the world stops).
        self._ecu_outputs: EcuOutputs | None = (
            simulate_ecu(self.truth, self._ecu_config, t_end_s=float(self.truth.t[-1]) + RUN_ON_STRETCH_S)
            if self._virtual_can and not self._hosts else None
        )
        self.clock: ScaledClock | None = None
        self.receivers: dict[str, SimReceiver] = {}
        self.ecus: dict[str, VscEcu] = {}
        self._buses: list[can.BusABC] = []
        self.daq_link = SimDaqLink()
        self.can_link = SimCanLink()
        self.daq_backends: list[SimDaqBackend] = []
        self._dir: Path | None = None
        self._truth_thread: threading.Thread | None = None
        self._truth_stop = threading.Event()
        self._truth_source: Source | None = None
        self._truth_next = 0
        self._truth_lock = threading.Lock()
        self._session: Recording | None = None
        self._final_health: dict[str, dict[str, int]] = {}
        self._releases_seen = 0
        self._losses_reported: dict[tuple[str, str], int] = {}
        self._losses_polled = -math.inf

    # --- life cycle ----------------------------------------------------------------------------

    @property
    def end_ns(self) -> int:
        """Clock time at which the drive has ended (plus time for the last outputs to arrive).

        On the governed clock the last GNSS epoch's logs are written and read before the clock passes
        them, so 0.1 s past its output latency is enough. The free-running clock keeps 0.5 s for
        readers that fall behind. Every device (the ECU too) goes on until the world stops."""
        latency = self.sim.gnss.output_latency_s
        tail_s = (0.1 if self.governed else 0.5) + (LATENCY_RANGE_S[1] if latency is None else latency)
        return self.timebase.truth_start_ns + round((self.duration_s + tail_s) * NS_PER_S)

    def start(self, clock: ScaledClock | None = None) -> None:
        """Start the clock (or take ``clock``) and every simulated device (stopped again if one fails)."""
        if self.clock is not None:
            raise SimulationError("sim world already started")
        try:
            # the device processes import and build their devices (side by side) before the clock starts
            for host in self._hosts:
                host.launch()
            for host in self._hosts:
                host.load()
            if clock is None:
                governor = (ClockGovernor.create(round(self.sim.governor_budget_ms * 1e6))
                            if self.governed else None)
                clock = self.timebase.make_clock(self.speed, self.lead_s, governor)
            self.clock = clock
            for host in self._hosts:
                host.start(self.clock)
            if not self._hosts:
                self._dir = Path(tempfile.mkdtemp(prefix="vsc-simworld-"))
                for rc in self._sim_receivers:
                    self._start_receiver(rc, self.clock, self._dir)
                for cc in self._virtual_can:
                    self._start_ecu(cc, self.clock)
        except BaseException:
            self.stop()
            raise
        log.info(
            "sim world: %.1f s drive at %g× real time, %.1f s lead, %d receivers, %d CAN buses",
            self.duration_s, self.speed, self.lead_s, len(self.receivers), len(self.ecus),
        )

    def health(self) -> dict[str, dict[str, int]]:
        """What the simulated devices could not deliver: ECU frames skipped (late), receiver log
        bytes dropped because the port's baud rate could not carry them (``bytes_overrun``) or because
        the pty was full while a reader had it open (``bytes_dropped``, and ``bytes_dropped:<port>``
        for each port that lost any), DAQ segments started. Kept after :meth:`stop`; with the devices
        in their own process, their figures as of the last :meth:`report_device_losses` (or stop)."""
        out = dict(self._final_health)
        for host in self._hosts:
            out.update(host.health)
        for channel, ecu in self.ecus.items():
            out[f"ecu:{channel}"] = {"frames_sent": ecu.frames_sent, "frames_skipped": ecu.frames_skipped}
        for name, rx in self.receivers.items():
            out[f"gnss:{name}"] = _receiver_health(rx)
        out["daq"] = {"segments": len(self.daq_backends)}
        return out

    def stop(self) -> None:
        """Stop every device and join its thread; remove the port links (idempotent)."""
        errors: list[BaseException] = []
        self._stop_truth()
        for host in self._hosts:
            try:
                host.stop()
            except SimulationError as exc:
                errors.append(exc)
        if self.ecus or self.receivers:
            self._final_health = self.health()
        for ecu in self.ecus.values():
            try:
                ecu.stop()
            except SimulationError as exc:
                errors.append(exc)
        self.ecus.clear()
        for bus in self._buses:
            bus.shutdown()
        self._buses.clear()
        for rx in self.receivers.values():
            try:
                rx.stop()
            except Exception as exc:  # keep stopping the others
                errors.append(exc)
        self.receivers.clear()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None
        if self.clock is not None and self.clock.governor is not None:
            self.clock.governor.close()  # statistics stay readable
        if errors:
            raise SimulationError(f"sim world: {len(errors)} devices failed to stop: {errors[0]}") from errors[0]

    def __enter__(self) -> SimWorld:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def governor_stats(self) -> GovernorStats | None:
        """How much the governed clock had to hold simulated time back (None: not governed)."""
        if self.clock is None or self.clock.governor is None:
            return None
        return self.clock.governor.stats()

    def governor_summary(self) -> str:
        """One line: how much the clock slowed, and for whom."""
        stats = self.governor_stats()
        if stats is None or self.clock is None:
            return "clock not governed (the host's latency shows in simulated time)"
        wall = self.clock.wall_ns()
        text = (f"governed clock: paused {stats.paused_wall_ns / 1e9:.1f} s of {wall / 1e9:.1f} s wall "
                f"({stats.pauses} pauses, budget {stats.budget_ns / 1e6:.0f} ms), effective speed "
                f"{stats.effective_speed(self.speed, wall):.2f}× of {self.speed:g}×")
        worst = sorted(stats.blamed_wall_ns.items(), key=lambda kv: -kv[1])[:3]
        if worst:
            text += "; waited for " + ", ".join(f"{n} {v / 1e9:.1f} s" for n, v in worst)
        if stats.ignored:
            text += f"; {stats.ignored} participants released ({stats.safety_releases} alive, at the safety limit)"
        return text

    def report_governor_releases(self) -> None:
        """Write every participant the governed clock stopped waiting for since the last call to
        ``/rig/events`` with its reason (an error event for a live one released at the safety limit)."""
        if self.clock is None or self.clock.governor is None or self._truth_source is None:
            return
        releases, self._releases_seen = self.clock.governor.releases(self._releases_seen)
        for rel in releases:
            safety = rel.reason is ReleaseReason.SAFETY_LIMIT
            self._truth_source.event(
                EventKind.ERROR if safety else EventKind.INFO, rel.text,
                severity=Severity.ERROR if safety else Severity.INFO, simulation=True,
                participant=rel.participant, reason=rel.reason.name.lower(), detail=rel.detail,
                held_wall_s=rel.held_wall_ns / 1e9,
            )

    def report_device_losses(self, *, final: bool = False) -> None:
        """Write a warning to ``/rig/events`` for each simulated receiver port whose pty dropped bytes
        while a reader had it open (the reader was behind: GNSS logs lost): once when it is first
        seen, and with ``final`` (at the end) again for every port whose total grew since. Looks at
        most every :data:`DEVICE_LOSS_POLL_S` (the devices in their own process are asked over
        their pipe) unless ``final``."""
        if self._truth_source is None:
            return
        now = time.monotonic()
        if not final and now < self._losses_polled + DEVICE_LOSS_POLL_S:
            return
        self._losses_polled = now
        for host in self._hosts:
            host.poll_health()
        for key, figures in sorted(self.health().items()):
            if not key.startswith("gnss:"):
                continue
            rx = key.partition(":")[2]
            for name, n in sorted(figures.items()):
                if not name.startswith("bytes_dropped:"):
                    continue
                port = name.partition(":")[2]
                seen = self._losses_reported.get((rx, port))
                if n <= (seen or 0) or (seen is not None and not final):
                    continue
                self._losses_reported[(rx, port)] = n
                self._truth_source.event(
                    EventKind.WARNING,
                    f"simulated {rx} dropped {n:,} bytes on {port}".replace(",", " ")
                    + ": the pty was full (reader behind) — GNSS logs lost",
                    severity=Severity.WARNING, simulation=True, receiver=rx, port=port, bytes_dropped=n,
                )

    def wait_end(self, stop: threading.Event | None = None) -> bool:
        """Wait until the drive has ended on the clock; False if ``stop`` was set first."""
        if self.clock is None:
            raise SimulationError("sim world not started")
        return self.clock.sleep_until_ns(self.end_ns, stop)

    def wait_truth_time(self, t_s: float, stop: threading.Event | None = None) -> bool:
        """Wait until the clock reaches truth time ``t_s``; False if ``stop`` was set first."""
        if self.clock is None:
            raise SimulationError("sim world not started")
        return self.clock.sleep_until_ns(self.timebase.truth_start_ns + round(t_s * NS_PER_S), stop)

    def truth_time_s(self) -> float:
        """Truth time (s) now."""
        if self.clock is None:
            raise SimulationError("sim world not started")
        return (self.clock.now_ns() - self.timebase.truth_start_ns) / NS_PER_S

    # --- devices -------------------------------------------------------------------------------

    def _error_params(self) -> GnssErrorParams:
        g = self.sim.gnss
        noise = dict(DEFAULT_SOLUTION_NOISE)
        from drivers.novatel import PositionType

        fixed = noise[PositionType.NARROW_INT]
        noise[PositionType.NARROW_INT] = SolutionNoise(
            g.position_noise_m,
            fixed.vertical_sigma_m * g.position_noise_m / max(fixed.horizontal_rms_m, 1e-9),
            g.velocity_noise_mps,
            fixed.vertical_velocity_sigma_mps * g.velocity_noise_mps / max(fixed.velocity_sigma_mps, 1e-9),
        )
        # one sky, one base: the part of the error every rover shares (same seed for all of them)
        return GnssErrorParams(noise=noise, correlation_time_s=g.correlation_time_s,
                               common_fraction=g.common_fraction, common_seed=self.sim.seed)

    def _start_receiver(self, rc: ReceiverConfig, clock: Clock, link_dir: Path) -> None:
        name, port = _sim_target(rc.port)
        if port is not None:
            raise ConfigError(f"receivers.{rc.name}.port: {rc.port!r} must name the main port (sim://NAME)")
        if name in self.receivers:
            raise ConfigError(f"receivers.{rc.name}.port: simulated receiver {name!r} is used twice")
        g = self.sim.gnss
        seed = self.sim.seed * 101 + len(self.receivers) * 13
        rx: SimReceiver
        if rc.role == "base":
            # the base antenna stands where the survey put it: the simulated car's fix_position is its true
            # position, height above the ellipsoid. fix_height only says how the rig tells the receiver to read
            # it, so fix_height = "msl" here is the 48 m mistake of a real day (the base flags its fix)
            lat, lon, h = rc.fix_position or (self.sim.origin_lat_deg, self.sim.origin_lon_deg, self.sim.origin_h_m)
            rx = SimBase(
                name, position=(lat, lon, h), timebase=self.timebase, clock=clock,
                port_name=rc.command_port, link_dir=link_dir, baud=rc.baud, output_latency_s=g.output_latency_s,
                seed=seed, error_params=self._error_params(),
            )
        else:
            arm = self.antenna_lever_arms()[rc.antenna or "a"]
            _, cable = _sim_target(rc.correction_device) if rc.correction_device else (None, None)
            rx = SimRover(
                name, truth=self.truth, lever_arm=arm, timebase=self.timebase, clock=clock,
                sync=self.sync, correction_port_name=cable or rc.correction_port, rtk=self.rtk,
                error_params=self._error_params(), port_name=rc.command_port, link_dir=link_dir, baud=rc.baud,
                output_latency_s=g.output_latency_s, seed=seed,
            )
        rx.start()
        self.receivers[name] = rx

    def antenna_lever_arms(self) -> dict[str, tuple[float, float, float]]:
        """True antenna positions of this car (see :func:`true_antenna_lever_arms`)."""
        return true_antenna_lever_arms(self.cfg.profile.antennas, self.sim.true_mount_offset_deg)

    def _start_ecu(self, cc: CanConfig, clock: Clock) -> None:
        if cc.channel in self.ecus:
            raise ConfigError(f"can.{cc.name}.channel: virtual channel {cc.channel!r} is used twice")
        bus = can.Bus(interface="virtual", channel=cc.channel, preserve_timestamps=True)
        self._buses.append(bus)
        # A frame is late only because this host was busy (the simulated ECU never is): send it late
        # with its true time stamp rather than drop it, unless the host fell seconds behind.
        ecu = VscEcu(self.truth, bus, clock, self.timebase.truth_start_ns, self._ecu_config,
                     outputs=self._ecu_outputs, max_lag_s=max(0.5, 2.0 * self.speed),
                     reader=can_reader_name(cc.channel), name=f"ecu:{cc.channel}", run_on=True)
        ecu.start()
        self.ecus[cc.channel] = ecu

    # --- port resolution (rig.record.recording.PortResolver) --------------------------------------------

    def _receiver_for(self, url: str, key: str) -> tuple[SimReceiver, str | None]:
        name, port = _sim_target(url)
        rx = self.receivers.get(name)
        if rx is None:
            raise ConfigError(f"{key}: no simulated receiver {name!r} (simulated: {sorted(self.receivers)})")
        return rx, port

    def port(self, receiver: ReceiverConfig) -> str:
        """The device path of a receiver's command port (its pty for ``sim://NAME``)."""
        if not receiver.port.startswith(SIM_PREFIX):
            return receiver.port
        if self._rx_host is not None:
            return self._rx_host.ports(receiver)[0]
        rx, _ = self._receiver_for(receiver.port, f"receivers.{receiver.name}.port")
        return rx.port_path

    def correction_port(self, receiver: ReceiverConfig) -> str | None:
        """The device path cabled to a receiver's correction port (``correction_device``; None without one)."""
        if self._rx_host is not None:
            return self._rx_host.ports(receiver)[1]
        if receiver.correction_device is None:  # no cable: nothing routed behind the configuration's back
            return None
        if not receiver.correction_device.startswith(SIM_PREFIX):
            return receiver.correction_device
        rx, port = self._receiver_for(receiver.correction_device, f"receivers.{receiver.name}.correction_device")
        return str(rx.port(port).path)

    # --- the host's CAN adapter ------------------------------------------------------------------

    def can_bus(self, config: CanBusConfig) -> can.BusABC:
        """Open a CAN interface through the simulated adapter (``bus_factory`` of the CAN session).

        Raises:
            DeviceError: the adapter is unplugged, or the interface cannot be opened.
        """
        if not self.can_link.connected:
            raise DeviceError(f"{config.describe()}: simulated CAN adapter unplugged")
        reader = None
        if config.interface == "virtual" and self.clock is not None:
            reader = participant(self.clock, can_reader_name(config.channel), progress_ns=UNBOUNDED_NS, reuse=True,
                                 value=UNBOUNDED_NS)
        if self._ecu_host is not None and config.interface == "virtual":
            config = self._ecu_host.can_config(config)
        return _LinkedBus(open_bus(config), self.can_link, reader)

    # --- the simulated DAQ -----------------------------------------------------------------------

    def daq_session(
        self,
        daq: DaqConfig,
        clock: Clock,
        on_block: Callable[[DaqBlock], None],
        on_event: Callable[[DaqEvent], None],
    ) -> DaqLink:
        """A DAQ session on the simulated DAQ (the factory :class:`rig.record.recording.Recording` calls)."""
        if daq.backend != "sim":
            raise ConfigError(f"daq.backend: the simulated car has a 'sim' DAQ, not {daq.backend!r}")
        channels = [DaqChannelConfig.from_config(c.model_dump(), f"daq.channels[{i}]")
                    for i, c in enumerate(daq.channels)]
        cal = self.cfg.profile.calibration
        daq_names = {c.name for c in channels}
        sensors = []
        for k, o in enumerate(self.cfg.profile.optical):
            if not all(ch.daq_channel in daq_names for ch in o.channels.values() if ch.daq_channel is not None):
                continue
            spec = OpticalSensorSpec.from_config(
                o.model_dump(), zero_offset_deg=cal.optical_zero_deg.get(o.name, 0.0), where=f"optical.{o.name}"
            )
            zero = math.radians(self.sim.true_optical_zero_deg.get(o.name, 0.0))
            sensors.append(SimOpticalSensor(spec, zero_offset_rad=zero, seed=self.sim.seed * 31 + k))
        analog = [AnalogChannelSpec.from_config(a.model_dump(), f"daq.analog.{a.name}") for a in daq.analog]
        sync = SyncPulseOutput.from_gps(self.sync, self.timebase) if daq.sync_channel is not None else None
        sources = sim_daq_sources(channels, optical=sensors, analog=analog, sync_channel=daq.sync_channel, sync=sync)
        physical = {c.name: c.physical_channel for c in channels}
        sources.update((physical[name], FloatingInput()) for name in self.floating if name in physical)

        def factory() -> SimDaqBackend:
            backend = SimDaqBackend(
                clock=clock, truth=self.truth, sources=sources, timebase=self.timebase,
                clock_ppm=self.sim.daq_clock_ppm, seed=self.sim.seed, link=self.daq_link, device=daq.device,
            )
            self.daq_backends.append(backend)
            return backend

        detector = None
        if daq.sync_channel is not None:
            level = daq.sync_threshold_v
            detector = SyncEdgeDetector(low=level - 1.0, high=level + 1.0, level=level, polarity=EdgePolarity.RISING)
        quiet = {daq.sync_channel} if daq.sync_channel is not None else set()
        limits = {c.name: HealthLimits(check_stuck=False, check_low_end=False) for c in channels if c.min_v >= 0}
        limits.update({n: HealthLimits(check_saturation=False, check_stuck=False) for n in quiet})
        health = ChannelHealth(channels, limits=limits, default=HealthLimits(check_stuck=False), clock=clock)
        return DaqLink(
            factory, channels, daq.rate_hz, on_block=on_block, on_event=on_event, clock=clock,
            block_size=daq.block_size, buffer_size=daq.buffer_samples, health=health, sync=detector,
            sync_channel=daq.sync_channel, name=daq.device,
        )

    def daq_timing(self) -> list[DaqTiming]:
        """True sample timing of every acquisition the simulated DAQ has started (in order)."""
        out = []
        for seg, b in enumerate(self.daq_backends):
            if b.rate_hz is None:
                continue  # made but never started
            out.append(DaqTiming(b.device, seg + 1, int(b.sample_gps_ns(0)), b.true_rate_hz))
        return out

    # --- session plug-in (rig.record.recording.RecordingPlugin) ---------------------------------------------

    def attach(self, session: Recording) -> None:
        """Record the ground truth on ``/sim/truth`` as simulated time passes."""
        if self.clock is None:
            raise SimulationError("sim world: start() before attaching a recording session")
        self._session = session
        self._truth_source = session.recorder.source("sim", maxsize=100_000)
        self._truth_stop.clear()
        self._truth_thread = threading.Thread(target=self._truth_loop, name="sim-truth")
        self._truth_thread.start()

    def detach(self, session: Recording) -> None:
        """Write the truth up to now and the DAQ's true timing, and stop the truth thread."""
        self._stop_truth()
        if self.clock is not None and self._truth_source is not None:
            self._write_truth_until(self.clock.now_ns())
            self.report_governor_releases()
            self.report_device_losses(final=True)
            stats = self.governor_stats()
            if stats is not None:
                self._truth_source.event(
                    EventKind.INFO, "simulation: " + self.governor_summary(), simulation=True,
                    governor=stats.as_dict(), speed=self.speed, wall_ns=self.clock.wall_ns(),
                )
            latencies = {name.removeprefix("gnss:"): h["output_latency_ns"] for name, h in self.health().items()
                         if name.startswith("gnss:") and "output_latency_ns" in h}
            if latencies:  # the truth the recording measures (or was told): for scoring only
                self._truth_source.event(
                    EventKind.INFO, "simulation: receivers' output latency " + ", ".join(
                        f"{k} {v / 1e6:.2f} ms" for k, v in sorted(latencies.items())),
                    gnss_output_latency_ns=latencies, simulation=True,
                )
            for timing in self.daq_timing():
                self._truth_source.event(
                    EventKind.INFO,
                    f"simulation: DAQ {timing.device} segment {timing.segment} sample 0 at GPS "
                    f"{timing.sample0_gps_ns} ns, true rate {timing.true_rate_hz:.6f} Hz",
                    sample0_gps_ns=timing.sample0_gps_ns, true_rate_hz=timing.true_rate_hz,
                    segment=timing.segment, device=timing.device, simulation=True,
                )
        self._truth_source = None
        self._session = None

    def _stop_truth(self) -> None:
        self._truth_stop.set()
        if self._truth_thread is not None:
            self._truth_thread.join(5.0)
            if self._truth_thread.is_alive():
                log.error("sim world: truth thread did not stop within 5 s")
            self._truth_thread = None

    def _truth_loop(self) -> None:
        clock = self.clock
        assert clock is not None
        block = max(1, round(1.0 / self.truth.dt))  # one second of truth per message
        n = len(self.truth)
        with participant(clock, "truth") as me:
            while not self._truth_stop.is_set():
                with self._truth_lock:
                    nxt = self._truth_next
                if nxt >= n:
                    return
                end = min(n, nxt + block)
                due = self.timebase.truth_start_ns + round(float(self.truth.t[end - 1]) * NS_PER_S)
                me.at(due)
                if not clock.sleep_until_ns(due, self._truth_stop):
                    return
                self._write_truth_until(clock.now_ns())

    def _write_truth_until(self, now_ns: int) -> None:
        """Put every truth block whose first sample is at or before clock time ``now_ns``."""
        src = self._truth_source
        if src is None:
            return
        truth = self.truth
        block = max(1, round(1.0 / truth.dt))
        with self._truth_lock:
            while self._truth_next < len(truth):
                i0 = self._truth_next
                if self.timebase.truth_start_ns + round(float(truth.t[i0]) * NS_PER_S) > now_ns:
                    break
                i1 = min(len(truth), i0 + block)
                payload = T.pack_truth_block(truth, i0, i1, self.truth_t0_utc_ns)
                log_ns = self.truth_t0_utc_ns + round(float(truth.t[i0]) * NS_PER_S)
                if not src.put(T.TOPIC_SIM_TRUTH, log_ns, now_ns, payload):
                    log.warning("sim world: truth block %d..%d not recorded (recorder refused it)", i0, i1)
                self._truth_next = i1


# ---------------------------------------------------------------------------------------------
# The simulated devices in a process of their own
# ---------------------------------------------------------------------------------------------

_HOST_START_TIMEOUT_S = 120.0
"""Longest wait for the device process to import, build its world and start its devices."""
_HOST_STOP_TIMEOUT_S = 15.0
_HOST_HEALTH_TIMEOUT_S = 2.0
"""Longest wait for the device process to report its figures while it runs."""
DEVICE_LOSS_POLL_S = 1.0
"""How often (wall s) a recording looks whether a simulated device lost bytes
(:meth:`SimWorld.report_device_losses`)."""


@dataclass(frozen=True, slots=True)
class DevicePart:
    """Which of a world's simulated devices one device process runs."""

    receivers: bool
    """The simulated GNSS receivers (all of them: one may be wired to another's port)."""
    ecus: bool
    """The simulated ECUs of the virtual CAN buses, served by socketcand."""

    @property
    def label(self) -> str:
        return "+".join(n for n, on in (("receivers", self.receivers), ("ECUs", self.ecus)) if on)


@dataclass(frozen=True, slots=True)
class _HostSpec:
    """What the device process needs to build the same world (pickled to it)."""

    part: DevicePart
    cfg: SessionConfig
    truth: GroundTruth
    speed: float
    lead_s: float
    rtk: RtkParams
    sync_period_s: float


class _DeviceHost:
    """A part of the simulated devices of a :class:`SimWorld` (:class:`DevicePart`: its receivers, or its
    ECUs), run in a child process.

    Protocol on a :func:`multiprocessing.Pipe` (pickled tuples): child → ``("loaded",)`` once it has
    imported and built its world (before the clock starts, so its start-up costs no simulated
    time); parent → ``("start", clock)`` with the shared :class:`ScaledClock` (CLOCK_MONOTONIC is
    system-wide, so both processes read the same simulated time); child → ``("ready", ports,
    can_port)``: each receiver's (command port, correction port) paths and the TCP port of a
    socketcand server on 127.0.0.1 serving the virtual CAN channels; parent → ``("health", n)``, child
    → ``("health", n, health)`` as often as asked (:meth:`poll_health`); parent → ``("stop",)``; child →
    ``("stopped", health)``. A failure in the child arrives as ``("error", text)``; the child also
    stops when the pipe closes (the parent died).
    """

    def __init__(self, world: SimWorld, part: DevicePart) -> None:
        self._world = world
        self.part = part
        self._proc: BaseProcess | None = None
        self._conn: Connection | None = None
        self._ports: dict[str, tuple[str, str | None]] = {}
        self._can_port: int | None = None
        self.health: dict[str, dict[str, int]] = {}
        self._health_asked = 0

    def launch(self) -> None:
        """Start the process (it imports while the parent goes on)."""
        ctx = multiprocessing.get_context("spawn")  # never fork a process that runs threads
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_device_host_main, args=(child,), name=f"vsc-sim-{self.part.label}", daemon=True)
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent

    def load(self) -> None:
        """Send the world's spec and wait until the process has built its devices."""
        w = self._world
        proc, conn = self._proc, self._conn
        assert proc is not None and conn is not None
        spec = _HostSpec(self.part, w.cfg, w.truth, w.speed, w.lead_s, w.rtk, w.sync_period_s)
        # The spec (tens of MB of truth) goes over our pipe, not in the spawn arguments: a child that
        # dies while starting then breaks the pipe instead of leaving the parent blocked on a write.
        try:
            conn.send(spec)
        except OSError as exc:
            proc.join(1.0)
            raise SimulationError(f"simulated devices ({self.part.label}): their process ended while starting "
                                  f"(exit code {proc.exitcode}): {exc}") from exc
        self._expect("loaded")

    def start(self, clock: ScaledClock) -> None:
        assert self._conn is not None
        self._conn.send(("start", clock))
        _, self._ports, self._can_port = self._expect("ready")
        log.info("sim world: %s in process %s (socketcand port %s)", self.part.label,
                 self._proc.pid if self._proc else None, self._can_port)

    def _expect(self, what: str) -> tuple[Any, ...]:
        conn, proc = self._conn, self._proc
        assert conn is not None and proc is not None
        deadline = time.monotonic() + _HOST_START_TIMEOUT_S
        while True:
            if conn.poll(0.2):
                try:
                    msg = conn.recv()
                except EOFError:
                    proc.join(1.0)
                    raise SimulationError(f"simulated devices ({self.part.label}): their process ended "
                                      f"(exit code {proc.exitcode}) "
                                          f"before it was {what}") from None
                if msg[0] == what:
                    return tuple(msg)
                if msg[0] == "error":
                    raise SimulationError(f"simulated devices ({self.part.label}): {msg[1]}")
            elif not proc.is_alive():
                raise SimulationError(f"simulated devices ({self.part.label}): their process exited with code "
                                      f"{proc.exitcode} "
                                      f"before it was {what}")
            if time.monotonic() > deadline:
                raise SimulationError(f"simulated devices ({self.part.label}): not {what} within "
                                      f"{_HOST_START_TIMEOUT_S:.0f} s")

    def ports(self, receiver: ReceiverConfig) -> tuple[str, str | None]:
        try:
            return self._ports[receiver.name]
        except KeyError:
            raise ConfigError(f"receivers.{receiver.name}: no simulated ports for it "
                              f"(simulated: {sorted(self._ports)})") from None

    def can_config(self, config: CanBusConfig) -> CanBusConfig:
        """``config`` (a virtual bus) as the socketcand bus the device process serves it on; the
        ECU's frame stamps are the shared clock's, as on the in-process virtual bus."""
        if self._can_port is None:
            raise ConfigError(f"{config.describe()}: the simulated devices serve no CAN bus")
        options = {**config.options, "host": "127.0.0.1", "port": self._can_port}
        return dataclasses.replace(config, interface="socketcand", options=options,
                                   timestamp_source=TimestampSource.HOST)

    def poll_health(self, timeout_s: float = _HOST_HEALTH_TIMEOUT_S) -> None:
        """Update :attr:`health` with the devices' figures now (kept as they were if the process
        does not answer within ``timeout_s``; a late answer is skipped by the next poll)."""
        conn, proc = self._conn, self._proc
        if conn is None or proc is None:
            return
        self._health_asked += 1
        try:
            conn.send(("health", self._health_asked))
            deadline = time.monotonic() + timeout_s
            while conn.poll(max(0.0, deadline - time.monotonic())):
                msg = conn.recv()
                if msg[0] == "health" and msg[1] == self._health_asked:
                    self.health = msg[2]
                    return
                if msg[0] == "error":
                    log.error("sim world: device process: %s", msg[1])
        except (OSError, EOFError) as exc:
            log.warning("sim world: cannot ask the device process for its figures: %s", exc)
            return
        log.warning("sim world: the device process did not report its figures within %.1f s", timeout_s)

    def stop(self) -> None:
        proc, conn = self._proc, self._conn
        if proc is None or conn is None:
            return
        self._proc = self._conn = None
        error: str | None = None
        try:
            with contextlib.suppress(OSError):
                conn.send(("stop",))
            deadline = time.monotonic() + _HOST_STOP_TIMEOUT_S
            while time.monotonic() < deadline and (proc.is_alive() or conn.poll(0)):
                if not conn.poll(0.2):
                    continue
                try:
                    msg = conn.recv()
                except EOFError:
                    break
                if msg[0] == "stopped":
                    self.health = msg[1]
                    break
                if msg[0] == "error":
                    error = msg[1]
        finally:
            proc.join(_HOST_STOP_TIMEOUT_S)
            if proc.is_alive():
                log.error("sim world: device process %s did not stop; terminating it", proc.pid)
                proc.terminate()
                proc.join(5.0)
            conn.close()
            with contextlib.suppress(ValueError):
                proc.close()
        if error is not None:
            raise SimulationError(f"simulated devices ({self.part.label}): {error}")


def _device_host_main(conn: Connection) -> None:
    """Entry point of the device process (see :class:`_DeviceHost`)."""
    # Ctrl-C reaches the whole process group: the recording process decides when the devices stop.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # a device thread that wakes at its time must get the interpreter soon: a governed clock stands
    # still until it has acted (the default 5 ms switch interval is 40 ms of simulated time at 8x)
    sys.setswitchinterval(GOVERNED_SWITCH_INTERVAL_S)
    world: SimWorld | None = None
    server: SocketcandServer | None = None
    try:
        spec = conn.recv()
        if not isinstance(spec, _HostSpec):  # stopped before it got its part (another device process failed)
            return
        world = SimWorld(spec.cfg, speed=spec.speed, lead_s=spec.lead_s, rtk=spec.rtk,
                         sync_period_s=spec.sync_period_s, truth=spec.truth, _part=spec.part)
        conn.send(("loaded",))
        msg = conn.recv()
        if msg[0] != "start":
            return
        world.start(clock=msg[1])
        ports = {rc.name: (world.port(rc), world.correction_port(rc))
                 for rc in spec.cfg.receivers
                 if spec.part.receivers
                 and (rc.port.startswith(SIM_PREFIX) or (rc.correction_device or "").startswith(SIM_PREFIX))}
        can_port = None
        if world.ecus:
            server = SocketcandServer(virtual_channel_opener({ch: ch for ch in world.ecus}), host="127.0.0.1")
            server.start()
            can_port = server.address[1]
        conn.send(("ready", ports, can_port))
        while (msg := conn.recv())[0] != "stop":
            if msg[0] == "health":
                conn.send(("health", msg[1], world.health()))
    except EOFError:
        log.warning("sim device process: the recording process went away; stopping")
    except BaseException as exc:
        with contextlib.suppress(OSError):
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        health: dict[str, dict[str, int]] = {}
        try:
            if server is not None:
                server.stop()
            if world is not None:
                world.stop()
                health = world.health()
        finally:
            with contextlib.suppress(OSError):
                conn.send(("stopped", health))
            conn.close()


GOVERNED_SWITCH_INTERVAL_S = 0.0005
"""Interpreter switch interval (s) of the processes of a governed simulated recording."""


def _receiver_health(rx: SimReceiver) -> dict[str, int]:
    """A simulated receiver's part of :meth:`SimWorld.health`."""
    lost = rx.bytes_lost()
    out = {"bytes_overrun": rx.bytes_overrun(), "errors": int(rx.error is not None),
           "bytes_dropped": sum(lost.values()), "output_latency_ns": round(rx.output_latency_s * NS_PER_S)}
    out.update((f"bytes_dropped:{port}", n) for port, n in sorted(lost.items()) if n > 0)
    return out


def can_reader_name(channel: str) -> str:
    """The governed clock's name for the reader of the simulated ECU's CAN channel ``channel``."""
    return f"canrx:{channel}"


def true_antenna_lever_arms(antennas: AntennaConfig, mount_offset_deg: float) -> dict[str, tuple[float, float, float]]:
    """True antenna positions (x, y, z) m from the CG: the configured lever arms with the baseline
    turned by ``mount_offset_deg`` (``simulation.true_mount_offset_deg``) about antenna A.

    The mounting offset is the azimuth of the baseline B → A minus the car's heading (clockwise
    positive, as in :mod:`calibration.mount`): B moves so that B → A points that far to the right
    of the x axis, which in ISO 8855 axes (y left) is a rotation by −offset.
    """
    a, b = antennas.a, antennas.b
    delta = -math.radians(mount_offset_deg)
    dx, dy = a.x_m - b.x_m, a.y_m - b.y_m
    c, s = math.cos(delta), math.sin(delta)
    rx, ry = c * dx - s * dy, s * dx + c * dy
    return {"a": (a.x_m, a.y_m, a.z_m), "b": (a.x_m - rx, a.y_m - ry, b.z_m)}


def _sim_target(url: str) -> tuple[str, str | None]:
    """``sim://NAME`` → (NAME, None); ``sim://NAME/COM2`` → (NAME, "COM2")."""
    rest = url.removeprefix(SIM_PREFIX)
    name, _, port = rest.partition("/")
    if not name:
        raise ConfigError(f"port {url!r}: a simulated port is sim://NAME or sim://NAME/PORT")
    return name, port or None




