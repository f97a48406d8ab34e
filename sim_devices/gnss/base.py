"""Simulated NovAtel base station: a fixed antenna that sends RTCM3 corrections on its port.

At power-up its saved configuration fixes its position (``FIX POSITION`` at the true antenna
position, the height above MSL under the factory EGM96 undulation of the site) and logs the RTCM
messages given by ``rtcm_messages`` every ``rtcm_period_s`` on its port, so it streams corrections
without being configured; a driver that sends ``UNLOGALL`` and its own ``LOG … RTCM1006 ONTIME 10``
/ ``FIX POSITION lat lon hgt`` commands gets what it asks for, including a fixed position off the
antenna: 25-50 m off is INTEGRITY_WARNING, worse INVALID_FIX (BESTPOS solution status), and then no
RTCM goes out (OEM7 Commands and Logs Reference, FIX). ``RTCM1077B`` / ``RTCM1077A`` put the message
in a NovAtel header, for a port left in NOVATEL mode.

RTCM messages (log names as on an OEM7): RTCM1005, RTCM1006 (ARP from the FIX POSITION, height
above MSL + undulation), RTCM1033, RTCM1074, RTCM1077, RTCM1084, RTCM1087 (observations of the
synthetic constellation; within one epoch every MSM but the last carries the multiple-message
bit), RTCM1230. Without a fixed position a base sends no station or observation messages (as a
real base in that state would not). It also answers BESTPOS (FIXEDPOS), BESTXYZ, TIME, PSRDOP,
VERSION, GPGGA.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pymap3d

from drivers.novatel import Body, SolutionStatus, TimeStatus
from sim_devices.gnss.antenna import AntennaState, FixedAntenna
from sim_devices.gnss.commands import LogFormat
from sim_devices.gnss.constellation import Constellation, GnssSystem
from sim_devices.gnss.error_model import GnssErrorParams
from sim_devices.gnss.geoid import egm96_undulation_m
from sim_devices.gnss.observations import ObservationGenerator, SignalObservation
from sim_devices.gnss.receiver import SimReceiver, StartupTiming
from sim_devices.gnss.rtcm import (
    MsmSatellite,
    MsmSignal,
    encode_1005,
    encode_1006,
    encode_1033,
    encode_1230,
    encode_msm,
    frame,
)
from sim_devices.gnss.timebase import SimTimeBase
from vsccore.clock import Clock
from vsccore.errors import SimulationError

__all__ = ["RTCM_LOGS", "SimBase"]

#: RTCM log names a simulated base accepts.
RTCM_LOGS = frozenset({"RTCM1005", "RTCM1006", "RTCM1033", "RTCM1074", "RTCM1077", "RTCM1084", "RTCM1087",
                       "RTCM1230"})
_MSM = {"RTCM1074": (4, GnssSystem.GPS), "RTCM1077": (7, GnssSystem.GPS), "RTCM1084": (4, GnssSystem.GLONASS),
        "RTCM1087": (7, GnssSystem.GLONASS)}


class SimBase(SimReceiver):
    """A simulated base receiver (see module docstring and :class:`SimReceiver` for the engine).

    Args:
        name: device name (``base``).
        position: true antenna position (lat deg, lon deg, ellipsoidal height m).
        timebase: the session's :class:`SimTimeBase`.
        clock: injected host clock.
        station_id: RTCM reference station ID (0..4095).
        rtcm_messages: message numbers logged at power-up (saved configuration).
        rtcm_period_s: their period.
        antenna_height_m: DF028 of 1006.
        Other keyword arguments go to :class:`SimReceiver`.
    """

    def __init__(
        self,
        name: str,
        *,
        position: tuple[float, float, float],
        timebase: SimTimeBase,
        clock: Clock | None = None,
        station_id: int = 0,
        rtcm_messages: Sequence[int] = (1006, 1033, 1077, 1087, 1230),
        rtcm_period_s: float = 1.0,
        antenna_height_m: float = 0.0,
        port_name: str = "COM1",
        extra_ports: Sequence[str] = (),
        link_dir: Path | str | None = None,
        baud: int | None = 115200,
        output_latency_s: float | None = None,
        latency_jitter_s: float = 0.002,
        startup_commands: Sequence[str] | None = None,
        seed: int = 0,
        enforce_baud: bool = False,
        undulation_m: float | None = None,
        error_params: GnssErrorParams | None = None,
        constellation: Constellation | None = None,
        serial_number: str | None = None,
        lenient_corrections: bool = False,
        startup: StartupTiming | None = None,
        cold_start: bool = False,
    ) -> None:
        if not 0 <= station_id <= 4095:
            raise SimulationError(f"sim base {name}: station_id {station_id} out of 0..4095")
        lat, lon, h = position
        if undulation_m is None:
            undulation_m = egm96_undulation_m(lat, lon)
        if startup_commands is None:
            cmds = [f"FIX POSITION {lat:.11f} {lon:.11f} {h - undulation_m:.4f}"]
            for number in rtcm_messages:
                if f"RTCM{number}" not in RTCM_LOGS:
                    raise SimulationError(f"sim base {name}: RTCM message {number} is not simulated")
                cmds.append(f"LOG {port_name} RTCM{number} ONTIME {rtcm_period_s:g}")
            startup_commands = cmds
        super().__init__(
            name,
            timebase=timebase,
            clock=clock,
            port_name=port_name,
            extra_ports=extra_ports,
            link_dir=link_dir,
            baud=baud,
            output_latency_s=output_latency_s,
            latency_jitter_s=latency_jitter_s,
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
        self.antenna = FixedAntenna(lat, lon, h)
        self.station_id = station_id
        self.antenna_height_m = antenna_height_m
        self.observations = ObservationGenerator(self.constellation, seed + 1)
        self._obs_cache: tuple[int, list[SignalObservation]] | None = None

    def known_logs(self) -> frozenset[str]:
        return super().known_logs() | RTCM_LOGS

    def antenna_state(self, t_gps_ns: int) -> AntennaState:
        return self.antenna.state(0.0)

    def arp_ecef(self) -> tuple[float, float, float] | None:
        """ECEF (m) of the fixed reference position the station messages carry (None when not fixed)."""
        fix = self._fix
        if fix is None or fix.kind != "POSITION":
            return None
        lat, lon, hgt = fix.values
        x, y, z = pymap3d.geodetic2ecef(lat, lon, hgt + self.undulation_m)
        return float(x), float(y), float(z)

    def _epoch_obs(self, t_ns: int) -> list[SignalObservation]:
        if self._obs_cache is None or self._obs_cache[0] != t_ns:
            self._obs_cache = (t_ns, self.observations.epoch(self.antenna_state(t_ns), t_ns))
        return self._obs_cache[1]

    def message(self, entry_name: str, fmt: LogFormat, t_gps_ns: int, batch: Sequence[str]) -> Body | bytes | None:
        if entry_name not in RTCM_LOGS:
            return self._common_message(entry_name, fmt, t_gps_ns)
        arp = self.arp_ecef()
        if arp is None or self.time_status_at(t_gps_ns) is not TimeStatus.FINESTEERING:
            return None
        if self.fix_status(t_gps_ns) is not SolutionStatus.SOL_COMPUTED:
            return None  # a fixed position the integrity monitor flags stops the corrections (FIX)
        sid = self.station_id
        if entry_name == "RTCM1005":
            return frame(encode_1005(sid, arp))
        if entry_name == "RTCM1006":
            return frame(encode_1006(sid, arp, self.antenna_height_m))
        if entry_name == "RTCM1033":
            return frame(encode_1033(sid))
        if entry_name == "RTCM1230":
            return frame(encode_1230(sid))
        msm, system = _MSM[entry_name]
        msm_in_batch = [n for n in batch if n in _MSM]
        more = msm_in_batch.index(entry_name) < len(msm_in_batch) - 1
        sats: dict[int, list[SignalObservation]] = {}
        for o in self._epoch_obs(t_gps_ns):
            if o.sat.system is system:
                sats.setdefault(o.sat.prn, []).append(o)
        msm_sats = [
            MsmSatellite(
                prn,
                tuple(
                    MsmSignal(o.msm_signal_id, o.pseudorange_m, o.phaserange_m, o.range_rate_mps, o.cnr_dbhz,
                              o.lock_time_s)
                    for o in obs
                ),
                obs[0].pseudorange_m,  # rough range from the receiver's own pseudorange (clocks included)
                obs[0].range_rate_mps,
                obs[0].sat.fcn,
            )
            for prn, obs in sorted(sats.items())
        ]
        return frame(
            encode_msm(msm, system, sid, t_gps_ns, msm_sats, leap_seconds=self._leap_seconds, multiple_message=more)
        )
