"""Simulated NovAtel rover: a roof antenna on the simulated car, RTK from the corrections it receives.

Ports: the command/log port (``port_name``, default COM1, at :attr:`SimRover.port_path`) and the
correction input (``correction_port_name``, default COM2, at :attr:`SimRover.correction_port_path`),
wired to ptys. Raw RTCM3 counts as corrections only on a port set to RTCMV3 (or AUTO) receive by
``INTERFACEMODE``, as on an OEM7 (the factory NOVATEL mode takes them only with a NovAtel header,
``RTCM1077B``; ``lenient_corrections=True`` brings back the old shortcut). The frames, CRC-checked,
feed the :class:`~sim_devices.gnss.error_model.RtkStateMachine`, which sets the solution type of
every position log; a frame whose CRC fails never counts.

Logs: BESTPOS, BESTVEL, BESTXYZ, TIME, PSRDOP, RXSTATUS, MARKPOS, MARK1TIME and the deprecated
MARKTIME (MARK1 events at the
:class:`~sim_devices.gnss.timebase.SyncSchedule`'s pulse times plus the EVENTINCONTROL time bias;
MARK2POS/MARK2TIME accepted, never fired), RANGECMP (raw observations,
:mod:`sim_devices.gnss.observations`), GPSEPHEM (one log per visible GPS satellite; ONCHANGED
sends a satellite's set when it is new to the receiver or its IODE changed, other triggers send all;
:mod:`sim_devices.gnss.ephemeris`), GLOEPHEMERIS (the same per visible GLONASS satellite, a new set
every 30 minutes), VERSION (its own PSN), GPGGA, and with a secondary antenna (a
dual-antenna receiver) HEADING and HEADING2.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from drivers.novatel import (
    Body,
    BodyFormat,
    ClockModelStatus,
    Heading,
    Heading2,
    Mark1Time,
    MarkTime,
    RawBody,
    TimeStatus,
)
from drivers.novatel.rawobs import encode_gloephemeris, encode_gpsephem
from sim_devices.gnss import bodies
from sim_devices.gnss.antenna import AntennaState, TruthAntenna
from sim_devices.gnss.commands import LogFormat, SimpleCommand
from sim_devices.gnss.constellation import Constellation, GnssSystem
from sim_devices.gnss.ephemeris import glonass_ephemeris, gps_ephemeris
from sim_devices.gnss.error_model import GnssErrorParams, RtkParams, RtkState, RtkStateMachine, carries_gps_epoch
from sim_devices.gnss.glonass import GlonassTruth
from sim_devices.gnss.observations import ObservationGenerator
from sim_devices.gnss.rawlogs import rangecmp_ascii, rangecmp_binary
from sim_devices.gnss.receiver import SimReceiver, StartupTiming
from sim_devices.gnss.rtcm import (
    frame_gps_epoch_ms,
    frame_message_number,
    frame_station_id,
    gps_epoch_from_tow_ms,
)
from sim_devices.gnss.solution import Solution
from sim_devices.gnss.timebase import SimTimeBase, SyncSchedule
from sim_devices.vehicle.truth import GroundTruth
from vsccore.angles import wrap_2pi
from vsccore.clock import Clock
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK

__all__ = ["SimRover"]


class SimRover(SimReceiver):
    """A simulated rover receiver (see module docstring and :class:`SimReceiver` for the engine).

    Args:
        name: device name (``rover_a``).
        truth: ground truth of the simulated drive.
        lever_arm: antenna phase centre (x, y, z) m from the CG in vehicle axes.
        timebase: the session's :class:`SimTimeBase`.
        clock: injected host clock (a ``ScaledClock`` to run faster than real time).
        sync: the sync-switch schedule wired to MARK1 (None: nothing on the event input).
        secondary_lever_arm: second antenna of a dual-antenna receiver (enables HEADING/HEADING2).
        rtk: RTK timing; error_params: noise by solution type.
        heading_sigma_deg_at_1m: heading 1σ for a 1 m baseline (scales as 1/length).
        velocity_latency_s: BESTVEL latency field; the velocity is taken that long before the log time.
        Other keyword arguments go to :class:`SimReceiver` (port_name, extra_ports, link_dir, baud,
        output_latency_s, solution_rate_hz, startup_commands, seed, undulation_m, serial_number,
        lenient_corrections, startup, cold_start, …).
    """

    def __init__(
        self,
        name: str,
        *,
        truth: GroundTruth,
        lever_arm: tuple[float, float, float],
        timebase: SimTimeBase,
        clock: Clock | None = None,
        sync: SyncSchedule | None = None,
        correction_port_name: str = "COM2",
        secondary_lever_arm: tuple[float, float, float] | None = None,
        rtk: RtkParams | None = None,
        error_params: GnssErrorParams | None = None,
        heading_sigma_deg_at_1m: float = 0.16,
        velocity_latency_s: float = 0.0,
        port_name: str = "COM1",
        extra_ports: Sequence[str] = (),
        link_dir: Path | str | None = None,
        baud: int | None = 115200,
        output_latency_s: float | None = None,
        latency_jitter_s: float = 0.002,
        solution_rate_hz: float = 20.0,
        startup_commands: Sequence[str] = (),
        seed: int = 0,
        enforce_baud: bool = False,
        undulation_m: float | None = None,
        constellation: Constellation | None = None,
        serial_number: str | None = None,
        lenient_corrections: bool = False,
        startup: StartupTiming | None = None,
        cold_start: bool = False,
    ) -> None:
        if correction_port_name == port_name:
            raise SimulationError(f"sim rover {name}: correction port must differ from {port_name}")
        super().__init__(
            name,
            timebase=timebase,
            clock=clock,
            port_name=port_name,
            extra_ports=(correction_port_name, *extra_ports),
            link_dir=link_dir,
            baud=baud,
            output_latency_s=output_latency_s,
            latency_jitter_s=latency_jitter_s,
            solution_rate_hz=solution_rate_hz,
            startup_commands=startup_commands,
            seed=seed,
            enforce_baud=enforce_baud,
            undulation_m=undulation_m,
            error_params=error_params,
            constellation=constellation,
            serial_number=serial_number,
            lenient_corrections=lenient_corrections,
            startup=startup,
            cold_start=cold_start,
        )
        self._rtk_params = rtk
        self.truth = truth
        self.antenna = TruthAntenna(truth, lever_arm)
        self.secondary = TruthAntenna(truth, secondary_lever_arm) if secondary_lever_arm is not None else None
        self.sync = sync
        self.correction_port_name = correction_port_name
        self.rtk = RtkStateMachine(rtk)
        self.heading_sigma_deg_at_1m = heading_sigma_deg_at_1m
        self.velocity_latency_s = velocity_latency_s
        self.observations = ObservationGenerator(self.constellation, seed + 1 if seed is not None else None)
        self.corrections_received = 0
        self._mark_time_ns: int | None = None
        self._last_mark_accepted: int | None = None
        self._ephemeris_sent: dict[int, int] = {}  # PRN -> IODE last sent ONCHANGED
        self._glo_ephemeris_sent: dict[int, int] = {}  # slot -> tb (GPS s) last sent ONCHANGED

    @property
    def correction_port_path(self) -> str:
        """Stable path of the correction input port (RTCM3 in)."""
        return str(self.port(self.correction_port_name).path)

    # --- hooks ----------------------------------------------------------------------------------

    def known_logs(self) -> frozenset[str]:
        names = set(super().known_logs()) | {"MARKPOS", "MARKTIME", "MARK1TIME", "MARK2POS", "MARK2TIME", "RANGECMP",
                                                "GPSEPHEM", "GLOEPHEMERIS"}
        if self.secondary is not None:
            names |= {"HEADING", "HEADING2"}
        return frozenset(names)

    def antenna_state(self, t_gps_ns: int) -> AntennaState:
        return self.antenna.state(self.timebase.truth_s(t_gps_ns))

    def rtk_state(self, t_gps_ns: int) -> RtkState:
        return self.rtk.state(t_gps_ns)

    def apply_simple(self, cmd: SimpleCommand) -> None:
        super().apply_simple(cmd)
        if cmd.name == "RTKTIMEOUT":
            p = self.rtk.params
            age = float(cmd.args[0])
            self.rtk.params = RtkParams(
                age, max(age, p.float_hold_s), max(age, p.psrdiff_timeout_s), p.time_to_float_s, p.time_to_fix_s
            )

    def on_reset(self) -> None:
        """A reset loses the RTK state and the ephemerides sent (the corrections must come in again)."""
        self.rtk = RtkStateMachine(self._rtk_params)
        self._ephemeris_sent.clear()
        self._glo_ephemeris_sent.clear()

    def on_correction_frame(self, raw: bytes, rx_gps_ns: int) -> None:
        number = frame_message_number(raw)
        epoch: int | None = None
        if carries_gps_epoch(number):
            epoch = gps_epoch_from_tow_ms(frame_gps_epoch_ms(raw), rx_gps_ns)
        self.rtk.on_frame(rx_gps_ns, number, frame_station_id(raw), epoch)
        self.corrections_received += 1

    def next_event_ns(self, after_ns: int) -> int | None:
        ev = self._events.get("MARK1")
        if self.sync is None or ev is None or not ev.enabled:
            return None
        bias = ev.t_bias_ns
        nxt = self.sync.next_after(after_ns - bias)
        while nxt is not None:
            t = nxt + bias
            last = self._last_mark_accepted
            if last is None or t - last >= ev.t_guard_ms * 1_000_000:
                return t
            nxt = self.sync.next_after(nxt)
        return None

    def on_event(self, t_gps_ns: int) -> list[str]:
        self._mark_time_ns = t_gps_ns
        self._last_mark_accepted = t_gps_ns
        return ["MARKPOS", "MARKTIME", "MARK1TIME"]

    def message(
        self, entry_name: str, fmt: LogFormat, t_gps_ns: int, batch: Sequence[str]
    ) -> Body | bytes | list[Body] | None:
        if entry_name == "BESTVEL" and self.velocity_latency_s > 0.0:
            return bodies.bestvel(self._delayed(t_gps_ns), self.velocity_latency_s)
        if entry_name in ("MARKPOS", "MARKTIME", "MARK1TIME"):
            t = self._mark_time_ns
            if t is None or self.time_status_at(t) is TimeStatus.UNKNOWN:
                return None  # no mark time nor position before the receiver knows the time
            if entry_name == "MARKPOS":
                return bodies.markpos(self.solution(t), self.undulation_m)
            cls = MarkTime if entry_name == "MARKTIME" else Mark1Time  # MARKTIME (231) is deprecated (MARK1TIME)
            return cls(
                t // NS_PER_WEEK, (t % NS_PER_WEEK) / NS_PER_S, 0.0, 1.0e-9, -float(self._leap_seconds),
                ClockModelStatus.VALID,
            )
        if entry_name in ("MARK2POS", "MARK2TIME"):
            return None
        if entry_name in ("HEADING", "HEADING2"):
            return self._heading(t_gps_ns, Heading if entry_name == "HEADING" else Heading2)
        if entry_name == "RANGECMP":
            obs = self.observations.epoch(self.antenna_state(t_gps_ns), t_gps_ns)
            if fmt is LogFormat.BINARY:
                return RawBody(rangecmp_binary(obs), BodyFormat.BINARY)
            return RawBody(rangecmp_ascii(obs), BodyFormat.ASCII)
        if entry_name == "GPSEPHEM":
            return self._ephemerides(fmt, t_gps_ns)
        if entry_name == "GLOEPHEMERIS":
            return self._glonass_ephemerides(fmt, t_gps_ns)
        return self._common_message(entry_name, fmt, t_gps_ns)

    def _ephemerides(self, fmt: LogFormat, t_gps_ns: int) -> list[Body]:
        out: list[Body] = []
        body_fmt = BodyFormat.BINARY if fmt is LogFormat.BINARY else BodyFormat.ASCII
        for geo in self.observations.geometry(self.antenna_state(t_gps_ns), t_gps_ns):
            if geo.sat.system is not GnssSystem.GPS:
                continue
            eph = gps_ephemeris(self.constellation, geo.sat, t_gps_ns)
            if self.emitting_on_change:
                if self._ephemeris_sent.get(eph.prn) == eph.iode1:
                    continue
                self._ephemeris_sent[eph.prn] = eph.iode1
            out.append(encode_gpsephem(eph, body_fmt))
        return out

    def _glonass_ephemerides(self, fmt: LogFormat, t_gps_ns: int) -> list[Body]:
        out: list[Body] = []
        body_fmt = BodyFormat.BINARY if fmt is LogFormat.BINARY else BodyFormat.ASCII
        for geo in self.observations.geometry(self.antenna_state(t_gps_ns), t_gps_ns):
            if geo.sat.system is not GnssSystem.GLONASS:
                continue
            if self.emitting_on_change:  # a new set every 30 min: tell before computing it
                tb = GlonassTruth.tb_s(t_gps_ns / NS_PER_S)
                if self._glo_ephemeris_sent.get(geo.sat.prn) == tb:
                    continue
                self._glo_ephemeris_sent[geo.sat.prn] = tb
            out.append(encode_gloephemeris(glonass_ephemeris(self.constellation, geo.sat, t_gps_ns), body_fmt))
        return out

    def _delayed(self, t_gps_ns: int) -> Solution:
        sol = self.solution(t_gps_ns)
        past = self.antenna.state(self.timebase.truth_s(t_gps_ns - round(self.velocity_latency_s * NS_PER_S)))
        dv = (sol.vel_enu_mps[0] - sol.truth.v_east_mps, sol.vel_enu_mps[1] - sol.truth.v_north_mps,
              sol.vel_enu_mps[2] - sol.truth.v_up_mps)
        return replace(sol, vel_enu_mps=(past.v_east_mps + dv[0], past.v_north_mps + dv[1], past.v_up_mps + dv[2]))

    def _heading(self, t_gps_ns: int, cls: type[Heading] | type[Heading2]) -> Heading | Heading2 | None:
        if self.secondary is None:
            return None
        t_s = self.timebase.truth_s(t_gps_ns)
        p = self.antenna.enu(t_s)
        s = self.secondary.enu(t_s)
        de, dn, du = s[0] - p[0], s[1] - p[1], s[2] - p[2]
        length = math.sqrt(de * de + dn * dn + du * du)
        if length < 0.1:
            return None
        sig_h = self.heading_sigma_deg_at_1m / length
        sig_p = 2.0 * sig_h
        hdg = math.degrees(wrap_2pi(math.atan2(de, dn) + math.radians(float(self._rng.normal(0.0, sig_h)))))
        pitch = math.degrees(math.atan2(du, math.hypot(de, dn))) + float(self._rng.normal(0.0, sig_p))
        sol = self.solution(t_gps_ns)
        return bodies.heading(
            length + float(self._rng.normal(0.0, 0.003)), hdg, pitch, sig_h, sig_p, len(sol.satellites),
            sol.num_soln_svs, cls,
        )
