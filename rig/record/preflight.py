"""Pre-flight check: every device of a session configuration opened with the recorder's drivers, judged GO / NO-GO.

:func:`run_preflight` opens what :class:`~rig.record.recording.Recording` would open — each NovAtel receiver
(:class:`~drivers.novatel.receiver.NovatelReceiver` with :func:`~rig.record.gnss.receiver_commands`), the
correction relay, each CAN bus (:class:`~drivers.can.bus.CanBusLink` with the role map), the DAQ (its
:class:`~drivers.daq.DaqLink`) — through the same port resolver and factories (a simulated world passes its
own, as for a recording), watches them for up to ``wait_s`` of the session clock and returns one
:class:`DeviceResult` per device: each check with what was seen and, when it fails, what to do. Nothing is
recorded; the receivers keep the configuration they were sent (the recorder sends it again).

Besides the recorder's own commands a receiver is asked for ``RXSTATUSB ONCHANGED`` (the port-overrun bits)
and a base that logs no BESTPOS for ``BESTPOSB ONTIME 1`` (its solution status says whether its fixed position
agrees with what it measures). The thresholds and why are beside their constants; what is not checked is in
:attr:`PreflightReport.not_checked`.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import can
import numpy as np
import pymap3d

from drivers.can.bus import (
    BusEvent,
    BusState,
    BusStateChanged,
    CanBusConfig,
    CanBusLink,
    CanFrame,
    CanFrameFlag,
    open_bus,
)
from drivers.can.checks import FrameFlag
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap
from drivers.daq import DaqBlock, DaqEvent, DaqEventKind, DaqLink
from drivers.novatel import BestPos, FrameKind, MarkPos, MarkTime, PositionType, SolutionStatus, TimeStatus
from drivers.novatel.commands import LogRequest, LogTrigger, log_command
from drivers.novatel.layouts import decode_version
from drivers.novatel.messages import LOG_IDS, BodyFormat, Header, Log, RawBody, VersionComponent
from drivers.novatel.receiver import (
    NovatelReceiver,
    ReceivedChunk,
    ReceiverEvent,
    ReceiverEventKind,
    ReceiverSettings,
)
from drivers.relay import PushSource, Relay, RelayStats, Sink, open_sink, open_source
from drivers.relay import Source as RelaySource
from drivers.relay.endpoints import RedactedEndpoint, Secret
from rig.core.config import CanConfig, DaqConfig, ReceiverConfig, SessionConfig
from rig.core.config import LogTrigger as ConfigTrigger
from rig.core.timebase import align_sync_pulses
from rig.record.can import roles_table
from rig.record.daq import DaqFactory
from rig.record.gnss import receiver_commands, silence_reconfigure_s
from rig.record.recording import DirectPorts, PortResolver
from vsccore.clock import Clock, SystemClock
from vsccore.errors import AnalysisError, ConfigError, DeviceError, RigError
from vsccore.gpstime import NS_PER_S

__all__ = [
    "DEFAULT_DURATION_MIN",
    "DEFAULT_WAIT_S",
    "Check",
    "DeviceResult",
    "PreflightReport",
    "Verdict",
    "run_preflight",
]

log = logging.getLogger(__name__)

DEFAULT_WAIT_S = 60.0
"""How long (session clock) the check waits for every device to be GO."""
DEFAULT_DURATION_MIN = 60.0
"""Planned recording time the free disk must hold."""

RATE_TOLERANCE = 0.20
"""A periodic receiver log counts as on rate within ±20 % of 1/period: the receiver schedules its logs on GPS
time, so a log off by more than a fifth is being dropped (port overrun, a busy receiver) or was requested
at another rate, never timing jitter (at least 3 arrivals are measured)."""
MAX_CORRECTION_AGE_S = 5.0
"""Largest BESTPOS differential age that counts as corrections flowing: five intervals of the usual 1 Hz
RTCM messages; an RTK engine fed older corrections falls back from a fixed solution."""
CAN_RATE_RANGE = (0.5, 1.5)
"""A CAN role's rate, as a fraction of its message's DBC cycle rate (``GenMsgCycleTime``, per page of a
multiplexed message), that is plausible: cyclic messages keep their period to a few per cent, so under half
means frames lost or only some forwarded (a gateway), over one and a half a second sender of the identifier."""
CAN_MIN_RATE_HZ = 1.0
"""Lowest plausible rate of a role whose message has no cycle time in the DBC."""
_CAN_MIN_SPAN_S = 2.0
"""Seconds of frames before role rates are judged."""
DAQ_FLOATING_NOISE_V = 0.05
"""Median sample-to-sample change (V) above which a DAQ input is taken as floating: a sensor output is smooth at
the sample rate (a 0.05 V median step is 160 steps of a 16-bit converter over ±10 V), an open input picks up
wide-band noise and hum (the same threshold as :class:`drivers.daq.HealthLimits`)."""
DAQ_RAIL_MARGIN_V = 0.01
DAQ_PINNED_FRACTION = 0.5
"""A channel with at least half its samples within :data:`DAQ_RAIL_MARGIN_V` of a range end is pinned at the
rail (the low end of a unipolar input excepted: 0 V is a sensor at rest there)."""
ASSUMED_ADC_BITS = 16
"""Converter resolution assumed to express noise in quantisation steps (the configuration does not give it)."""
SYNC_TOLERANCE_NS = 1_000_000
"""A sync-switch edge on the DAQ and its MARK event must agree within 1 ms once the DAQ clock is fitted."""
SYNC_MIN_PAIRS = 3
"""Edge/mark pairs needed: two fix the DAQ clock's offset and rate, the third tests them."""
MIN_OBSERVE_S = 3.0
"""Shortest watch (session clock) before an all-GO ends the check early (rates need three arrivals)."""
_TICK_S = 0.1
"""How often (wall s) the check looks whether every device is GO."""

# Approximate sizes for the data-rate estimate (binary NovAtel logs with their 28-byte header and CRC, RTCM3
# frames of a base with about ten satellites per system); a log seen during the check is taken at its measured
# size instead.
_NOMINAL_LOG_BYTES = {
    "BESTPOS": 104, "BESTVEL": 76, "TIME": 76, "MARKPOS": 104, "MARKTIME": 72, "MARK1TIME": 72,
    "HEADING": 76, "HEADING2": 80, "BESTXYZ": 144, "PSRDOP": 100, "RANGECMP": 1000, "RANGE": 1800,
    "GPSEPHEM": 256, "GLOEPHEMERIS": 176, "RXSTATUS": 120, "VERSION": 144,
    "RTCM1005": 25, "RTCM1006": 27, "RTCM1033": 50, "RTCM1074": 200, "RTCM1077": 300, "RTCM1084": 180,
    "RTCM1087": 260, "RTCM1230": 15,
}
_ASCII_FACTOR = 2.2
"""An ASCII log (``…A``) is about this much longer than its binary form."""
_DEFAULT_LOG_BYTES = 150
_MCAP_MESSAGE_BYTES = 31
"""MCAP message record overhead (opcode, length, channel, sequence, two times)."""
_DECODED_GNSS_BYTES = 700
"""A decoded GNSS log as its JSON record (about 25 fields with their names)."""
_LOCATION_FIX_BYTES = 350
_CAN_FRAME_BYTES = 31
"""One CAN frame in a raw frame block: two times, identifier, flags, length (+ its payload)."""
_CAN_ROLES_BYTES = 140
_CAN_ROLE_BYTES = 30
"""A decoded CAN frame on the roles topic: the record, plus this per role it carries."""
_OPTICAL_BYTES = 250
_OPTICAL_HZ = 100.0
_BITS_PER_BYTE = 10
"""On an asynchronous serial port: a start bit, eight data bits, a stop bit."""

_COM_TX_OVERRUN = 0x0000_0100
"""Receiver status word: COM port transmit buffer overrun (RXSTATUS, Receiver Status)."""
_PORT_OVERRUN_BITS: dict[tuple[int, int], str] = {
    (1, 0x100): "USB1", (1, 0x200): "USB2", (1, 0x400): "USB3", (1, 0x8_0000): "ICOM1",
    (2, 0x200): "COM1", (2, 0x400): "COM2", (2, 0x800): "COM3",
}
"""(auxiliary status word, bit) → the port whose buffer overran (RXSTATUS, Auxiliary 1/2 Status)."""
_DIFFERENTIAL = frozenset({
    PositionType.PSRDIFF, PositionType.L1_FLOAT, PositionType.IONOFREE_FLOAT, PositionType.NARROW_FLOAT,
    PositionType.L1_INT, PositionType.WIDE_INT, PositionType.NARROW_INT, PositionType.RTK_DIRECT_INS,
    PositionType.INS_PSRDIFF, PositionType.INS_RTKFLOAT, PositionType.INS_RTKFIXED,
})
_BASELINE_EPOCHS = 5
"""Epochs with both rovers fixed whose median baseline length is judged."""
_SYNC_LOGS = frozenset({"BESTPOS", "BESTVEL", "TIME"})
_MARK_LOGS = frozenset({"MARKPOS", "MARKTIME", "MARK1TIME"})


class Verdict(StrEnum):
    GO = "GO"
    NO_GO = "NO-GO"


@dataclass(frozen=True, slots=True)
class Check:
    """One check of a device: whether it passed, what was seen, and what to do when it did not."""

    name: str
    ok: bool
    detail: str
    fix: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"check": self.name, "ok": self.ok, "detail": self.detail, "fix": self.fix}


@dataclass(frozen=True, slots=True)
class DeviceResult:
    """The checks of one device (a receiver, the relay, a CAN bus, the DAQ, the sync switch, the antenna
    baseline, the disk), most telling first: the first that failed is the reason."""

    device: str
    kind: str
    checks: tuple[Check, ...]
    figures: Mapping[str, Any] = field(default_factory=dict)

    @property
    def verdict(self) -> Verdict:
        return Verdict.GO if all(c.ok for c in self.checks) else Verdict.NO_GO

    @property
    def failed(self) -> Check | None:
        return next((c for c in self.checks if not c.ok), None)

    @property
    def reason(self) -> str:
        """Why it is NO-GO (the first failed check), or a summary of what was seen."""
        bad = self.failed
        if bad is not None:
            return f"{bad.name}: {bad.detail}"
        return "; ".join(c.detail for c in self.checks if c.detail)

    @property
    def fix(self) -> str:
        bad = self.failed
        return bad.fix if bad is not None else ""

    def to_json(self) -> dict[str, Any]:
        return {"device": self.device, "kind": self.kind, "verdict": self.verdict.value, "reason": self.reason,
                "fix": self.fix, "checks": [c.to_json() for c in self.checks], "figures": dict(self.figures)}


@dataclass(frozen=True, slots=True)
class PreflightReport:
    """What :func:`run_preflight` found."""

    config: str
    devices: tuple[DeviceResult, ...]
    wait_s: float
    watched_s: float
    """How long the devices were watched (session clock s)."""
    time_to_go_s: float | None
    """Session-clock seconds from the start until every device was GO (None: not within ``wait_s``)."""
    wall_s: float
    simulated: bool
    assumptions: tuple[str, ...] = ()
    not_checked: tuple[str, ...] = ()

    @property
    def go(self) -> bool:
        return bool(self.devices) and all(d.verdict is Verdict.GO for d in self.devices)

    def to_json(self) -> dict[str, Any]:
        return {
            "config": self.config, "verdict": (Verdict.GO if self.go else Verdict.NO_GO).value,
            "simulated": self.simulated, "wait_s": self.wait_s, "watched_s": round(self.watched_s, 3),
            "time_to_go_s": None if self.time_to_go_s is None else round(self.time_to_go_s, 3),
            "wall_s": round(self.wall_s, 3), "devices": [d.to_json() for d in self.devices],
            "assumptions": list(self.assumptions), "not_checked": list(self.not_checked),
        }


# ---------------------------------------------------------------------------------------------
# Receivers
# ---------------------------------------------------------------------------------------------


def _base_log_name(name: str) -> str:
    """``BESTPOSB`` → ``BESTPOS``; ``RTCM1077`` stays (raw RTCM3); ``RTCM1077B`` → ``RTCM1077``."""
    if name[-1:] in ("A", "B", "S") and (name[:-1] in LOG_IDS or name[:-1].startswith("RTCM")):
        return name[:-1]
    return name


def _rtcm_type(raw: bytes) -> int | None:
    return ((raw[3] << 4) | (raw[4] >> 4)) if len(raw) >= 5 else None


def _log_bytes(name: str) -> float:
    base = _base_log_name(name)
    size = float(_NOMINAL_LOG_BYTES.get(base, _DEFAULT_LOG_BYTES))
    return size * _ASCII_FACTOR if name.endswith("A") and base != name else size


def _rxstatus_words(body: RawBody) -> tuple[int, ...] | None:
    """Receiver status and auxiliary status words 1-4 of an RXSTATUS binary body (error word, count, then per
    status code its word and the priority, set and clear masks)."""
    if body.fmt is not BodyFormat.BINARY or len(body.data) < 8:
        return None
    _, count = struct.unpack_from("<II", body.data)
    if len(body.data) < 8 + 16 * count:
        return None
    return tuple(struct.unpack_from("<I", body.data, 8 + 16 * i)[0] for i in range(count))


class _ReceiverProbe:
    """A receiver opened as the recorder opens it, with everything its checks need gathered from its stream."""

    def __init__(self, rc: ReceiverConfig, port: str, clock: Clock) -> None:
        self.rc = rc
        self.port = port
        names = {_base_log_name(lr.name) for lr in rc.logs}
        extra = [log_command("THISPORT", LogRequest("RXSTATUSB", LogTrigger.ONCHANGED))]
        if rc.role == "base" and "BESTPOS" not in names:  # its solution status judges its fixed position
            extra.append(log_command("THISPORT", LogRequest("BESTPOSB", LogTrigger.ONTIME, 1.0)))
        self.commands = (*receiver_commands(rc), *extra)
        settings = ReceiverSettings(
            name=rc.name, port=port, baud=rc.baud, commands=self.commands, command_timeout_s=rc.command_timeout_s,
            autobaud=rc.autobaud, silence_reconfigure_s=silence_reconfigure_s(rc),
        )
        self.rx = NovatelReceiver(settings, on_data=self._on_data, on_event=self._on_event, clock=clock)
        self.push: PushSource | None = None
        self._lock = threading.Lock()
        self.connected = False
        self.connect_error: str | None = None
        self.config_errors: list[str] = []
        self.configured_at: int | None = None
        self.resets = 0
        self.identity: VersionComponent | None = None
        self.arrivals: dict[str, _Arrivals] = {}
        """Each log (or RTCM3 message) since the receiver was configured."""
        self.time_status: TimeStatus | None = None
        self.overrun_seen = False
        self.overrun_ports: set[str] = set()
        self.positions: deque[tuple[int, BestPos]] = deque(maxlen=200)
        """(GPS ns, BESTPOS) of the recent epochs."""
        self.marks: list[int] = []
        self.marks_from_time = False
        self.host_minus_gps: int | None = None
        """Lower envelope of (host receive − GPS time) of the synchronous logs: the host → GPS map (ns)."""

    def start(self) -> None:
        self.rx.start()

    def stop(self) -> None:
        self.rx.stop()

    def _on_event(self, ev: ReceiverEvent) -> None:
        k = ev.kind
        with self._lock:
            if k is ReceiverEventKind.CONNECTED:
                self.connected = True
                self.connect_error = None
            elif k is ReceiverEventKind.CONNECT_FAILED:
                self.connect_error = ev.message
            elif k is ReceiverEventKind.DISCONNECTED:
                self.connected = False
                self.connect_error = ev.message
            elif k is ReceiverEventKind.COMMAND_FAILED:
                self.config_errors.append(ev.message)
            elif k is ReceiverEventKind.CONFIGURED:
                self.config_errors.clear()
                self._configured(ev.host_ns)
            elif k is ReceiverEventKind.RESET:
                self.resets += 1

    def _configured(self, host_ns: int) -> None:
        """Called under the lock: what came before the configuration is not this configuration's output."""
        self.configured_at = host_ns
        self.arrivals.clear()
        self.overrun_seen = False
        self.overrun_ports.clear()

    def _on_data(self, chunk: ReceivedChunk) -> None:
        if self.push is not None and chunk.data:
            self.push.feed(chunk.data)
        host = chunk.host_ns
        with self._lock:
            counting = self.configured_at is not None  # arrivals count once the log set is this one
            for frame in chunk.frames:
                if frame.kind is FrameKind.RTCM3:
                    t = _rtcm_type(frame.raw)
                    if t is not None and counting:
                        self._arrived(f"RTCM{t}", host, len(frame.raw))
                    continue
                lg = frame.log
                if lg is None:
                    continue
                if counting:
                    self._arrived(lg.name, host, len(frame.raw))
                self._log(lg, host)  # VERSION answers while the later commands are still being sent

    def _arrived(self, key: str, host: int, size: int) -> None:
        a = self.arrivals.get(key)
        self.arrivals[key] = (_Arrivals(1, host, host, size) if a is None
                              else _Arrivals(a.n + 1, a.first_ns, host, a.bytes + size))

    def _log(self, lg: Log, host: int) -> None:
        header = lg.header
        body = lg.body
        if isinstance(header, Header):  # short headers carry no time status nor receiver status
            status = header.time_status
            self.time_status = status
            if header.receiver_status & _COM_TX_OVERRUN:
                self.overrun_seen = True
            if lg.name in _SYNC_LOGS and status is TimeStatus.FINESTEERING:
                d = host - header.gps_ns
                self.host_minus_gps = d if self.host_minus_gps is None else min(self.host_minus_gps, d)
        if lg.name == "VERSION" and isinstance(body, RawBody):
            try:
                card = decode_version(body).component()
            except RigError as exc:
                log.warning("preflight %s: VERSION does not decode: %s", self.rc.name, exc)
                return
            if card is not None:
                self.identity = card
        elif lg.name == "RXSTATUS" and isinstance(body, RawBody):
            words = _rxstatus_words(body)
            if words:
                if words[0] & _COM_TX_OVERRUN:
                    self.overrun_seen = True
                for (aux, bit), port in _PORT_OVERRUN_BITS.items():
                    if aux < len(words) and words[aux] & bit:
                        self.overrun_ports.add(port)
        elif isinstance(body, BestPos):
            self.positions.append((header.gps_ns, body))
        elif isinstance(body, MarkTime):  # MARKTIME and MARK1TIME: preferred to MARKPOS (as the recorder)
            if not self.marks_from_time:
                self.marks_from_time = True
                self.marks.clear()
            self.marks.append(body.event_gps_ns)
        elif isinstance(body, MarkPos) and not self.marks_from_time:
            self.marks.append(header.gps_ns)

    def snapshot(self) -> _ReceiverState:
        with self._lock:
            return _ReceiverState(
                connected=self.connected, connect_error=self.connect_error, config_errors=tuple(self.config_errors),
                configured_at=self.configured_at, resets=self.resets, identity=self.identity,
                arrivals=dict(self.arrivals),
                time_status=self.time_status, overrun_seen=self.overrun_seen,
                overrun_ports=tuple(sorted(self.overrun_ports)), positions=tuple(self.positions),
                marks=tuple(self.marks), host_minus_gps=self.host_minus_gps,
            )


@dataclass(frozen=True, slots=True)
class _ReceiverState:
    connected: bool
    connect_error: str | None
    config_errors: tuple[str, ...]
    configured_at: int | None
    resets: int
    identity: VersionComponent | None
    arrivals: dict[str, _Arrivals]
    time_status: TimeStatus | None
    overrun_seen: bool
    overrun_ports: tuple[str, ...]
    positions: tuple[tuple[int, BestPos], ...]
    marks: tuple[int, ...]
    host_minus_gps: int | None

    @property
    def last_pos(self) -> BestPos | None:
        return self.positions[-1][1] if self.positions else None


@dataclass(frozen=True, slots=True)
class _Arrivals:
    """One log's arrivals: how many, the first and last host times, their bytes."""

    n: int
    first_ns: int
    last_ns: int
    bytes: int

    @property
    def rate_hz(self) -> float | None:
        """Arrivals per second from the first to the last (None below three arrivals)."""
        if self.n < 3 or self.last_ns <= self.first_ns:
            return None
        return (self.n - 1) / ((self.last_ns - self.first_ns) / NS_PER_S)


def _periodic_logs(rc: ReceiverConfig) -> list[tuple[str, float]]:
    return [(lr.name, lr.period_s) for lr in rc.logs if lr.trigger is ConfigTrigger.ONTIME and lr.period_s]


def _budget_bps(rc: ReceiverConfig, st: _ReceiverState | None) -> float:
    """Bits per second the configured periodic logs need on the command port (measured sizes where seen)."""
    bits = 0.0
    for name, period in _periodic_logs(rc):
        a = st.arrivals.get(_base_log_name(name)) if st is not None else None
        size = a.bytes / a.n if a is not None else _log_bytes(name)
        bits += size * _BITS_PER_BYTE / period
    return bits


def _port_load(st: _ReceiverState, now: int) -> tuple[float, list[tuple[str, float]]]:
    """Bits per second the port carried since the receiver was configured (10 bits a byte), and each log's
    bytes per second, largest first."""
    if st.configured_at is None or now <= st.configured_at:
        return 0.0, []
    span = (now - st.configured_at) / NS_PER_S
    per = sorted(((k, a.bytes / span) for k, a in st.arrivals.items()), key=lambda kv: -kv[1])
    return sum(v for _, v in per) * _BITS_PER_BYTE, per


def _serial_port(rc: ReceiverConfig) -> bool:
    return rc.command_port.startswith("COM")


def _judge_receiver(
    p: _ReceiverProbe, st: _ReceiverState, now: int, watched_s: float, relay: _RelayState | None,
) -> DeviceResult:
    rc = p.rc
    checks: list[Check] = []
    figures: dict[str, Any] = {"port": p.port, "baud": rc.baud, "role": rc.role}
    # 1. the port answers and takes every command
    if st.configured_at is None:
        if st.config_errors:
            first = st.config_errors[0]
            timeout = "no <OK or <ERROR" in first
            checks.append(Check(
                "answers", False, first,
                (f"nothing answered at {rc.baud} Bd on {p.port}: is it the receiver's {rc.command_port}, at that "
                 f"baud (receivers.{rc.name}.baud, or autobaud = true)?") if timeout else
                "the receiver refused a command: check the receiver model and firmware, and extra_commands"))
        elif st.connect_error is not None and not st.connected:
            checks.append(Check("answers", False, f"cannot open {p.port}: {st.connect_error}",
                                "check the cable and the port path (/dev/serial/by-id/…), and that you are in the "
                                "dialout group"))
        else:
            checks.append(Check("answers", False, f"{p.port} open, the configuration not yet answered",
                                "wait, or check that the port is the receiver's command port"))
        return DeviceResult(rc.name, "gnss", tuple(checks), figures)
    if not st.connected:
        checks.append(Check("answers", False, f"{p.port} lost during the check: {st.connect_error}",
                            "check the cable and the receiver's power (a USB adapter that drops out, a loose plug)"))
        return DeviceResult(rc.name, "gnss", tuple(checks), figures)
    checks.append(Check("answers", True, f"{len(p.commands)} commands <OK on {p.port}"
                        + (f"; reconfigured after {st.resets} resets" if st.resets else "")))
    configured_s = (now - st.configured_at) / NS_PER_S
    # 2. the port carries the log set
    need = _budget_bps(rc, st)
    carried, per_log = _port_load(st, now)
    serial = _serial_port(rc)
    if serial:
        figures["port_load_pct"] = round(100.0 * need / rc.baud, 1)
        figures["measured_load_pct"] = round(100.0 * carried / rc.baud, 1)

    def share(bps: float) -> str:
        return f" ({100.0 * bps / rc.baud:.0f} % of {rc.baud} Bd)" if serial else ""

    top = ", ".join(f"{k} {v / 1000:.1f} kB/s" for k, v in per_log[:3])
    budget = (f"the configured logs need ≈ {need / 1000:.0f} kbit/s{share(need)}, the port carried "
              f"≈ {carried / 1000:.0f} kbit/s{share(carried)}" + (f": {top}" if top else ""))
    if st.overrun_seen:
        ports = f" ({', '.join(st.overrun_ports)})" if st.overrun_ports else ""
        checks.append(Check(
            "port overrun", False, f"the receiver drops logs: COM transmit buffer overrun{ports}; {budget}",
            f"raise the baud (receivers.{rc.name}.baud and the port's SERIALCONFIG, e.g. 460800 or 921600) or "
            "log less (RANGECMPB at 1 Hz, fewer logs; logs asked for in extra_commands count too)"))
    else:
        checks.append(Check("port overrun", True, f"no overrun; {budget}"))
    # 3. the receiver it is supposed to be
    card = st.identity
    if card is None:
        checks.append(Check("identity", False, "no VERSION log answered LOG VERSIONB ONCE",
                            "check that this port is a NovAtel receiver's command port"))
    else:
        figures.update(model=card.model, serial_number=card.psn.strip(), firmware=card.sw_version)
        want = rc.serial_number
        if want is not None and card.psn.strip() != want.strip():
            checks.append(Check(
                "identity", False,
                f"{p.port} answers as PSN {card.psn.strip()}, not {rc.name}'s {want}: ports swapped?",
                "swap the port paths (or fix serial_number); use /dev/serial/by-id/… paths, which stay put"))
        else:
            psn = card.psn.strip()
            note = "" if want is not None else f" (set receivers.{rc.name}.serial_number = \"{psn}\")"
            checks.append(Check("identity", True, f"{card.model} PSN {psn} firmware {card.sw_version}{note}"))
    # 4. GPS time
    ts = st.time_status
    figures["time_status"] = None if ts is None else ts.name
    if ts is TimeStatus.FINESTEERING:
        checks.append(Check("time", True, "FINESTEERING"))
    else:
        checks.append(Check("time", False, f"time status {'none yet' if ts is None else ts.name}, not FINESTEERING",
                            "wait for the receiver to converge (a few minutes after power-up); check the antenna "
                            "cable and its view of the sky"))
    pos = st.last_pos
    if pos is not None:
        figures.update(position_type=pos.pos_type.name, solution_status=pos.sol_status.name,
                       satellites=pos.num_soln_svs,
                       diff_age_s=round(pos.diff_age_s, 2) if math.isfinite(pos.diff_age_s) else None)
    if rc.role == "base":
        checks.append(_base_position(rc, pos))
    else:
        checks.append(_corrections(rc, pos, relay))
        if pos is not None and pos.pos_type is PositionType.NARROW_INT:
            checks.append(Check("RTK", True, f"NARROW_INT, {pos.num_soln_svs} satellites"))
        else:
            what = "no BESTPOS yet" if pos is None else f"{pos.pos_type.name}"
            checks.append(Check("RTK", False, f"{what} after {configured_s:.0f} s (needs NARROW_INT)",
                                "wait longer (--wait) once corrections flow; check the antenna's view of the sky"))
    checks.append(_rates(rc, st, configured_s, now))
    return DeviceResult(rc.name, "gnss", tuple(checks), figures)


def _base_position(rc: ReceiverConfig, pos: BestPos | None) -> Check:
    if pos is None:
        return Check("base position", False, "no BESTPOS from the base", "check the base's command port")
    if pos.sol_status in (SolutionStatus.INTEGRITY_WARNING, SolutionStatus.INVALID_FIX):
        how = ("ellipsoidal (UNDULATION USER 0 before FIX)" if rc.fix_height == "ellipsoidal"
               else "above mean sea level (UNDULATION EGM96 before FIX)")
        return Check(
            "base position", False,
            f"BESTPOS {pos.sol_status.name}: the fixed position disagrees with what the base measures "
            f"(25-50 m off: INTEGRITY_WARNING, more: INVALID_FIX); the base sends no corrections",
            f"check receivers.{rc.name}.fix_position and fix_height: now {rc.fix_height!r}, sent as {how}, and no "
            "other UNDULATION in extra_commands; a height read on the wrong datum is off by the local geoid height "
            "(tens of metres: about 48 m around Stuttgart)")
    if pos.pos_type is not PositionType.FIXEDPOS:
        return Check("base position", False, f"BESTPOS {pos.pos_type.name} {pos.sol_status.name}, not FIXEDPOS",
                     f"give receivers.{rc.name}.fix_position (the surveyed antenna position)")
    return Check("base position", True, f"FIXEDPOS {pos.sol_status.name}")


def _corrections(rc: ReceiverConfig, pos: BestPos | None, relay: _RelayState | None) -> Check:
    sent = relay.sent_to.get(rc.name) if relay is not None else None
    cable = f"{rc.correction_device} @ {rc.correction_baud} Bd" if rc.correction_device else "no correction_device"
    relayed = "" if sent is None else f"; relay wrote {sent} frames to {cable}"
    age = pos.diff_age_s if pos is not None and math.isfinite(pos.diff_age_s) else 0.0
    if pos is not None and pos.pos_type in _DIFFERENTIAL and 0.0 < age <= MAX_CORRECTION_AGE_S:
        return Check("corrections", True, f"RTCM age {age:.1f} s{relayed}")
    if pos is not None and pos.pos_type in _DIFFERENTIAL:
        return Check("corrections", False, f"corrections {age:.1f} s old (> {MAX_CORRECTION_AGE_S:g} s){relayed}",
                     "check the radio link or the relay source's rate")
    seen = "no BESTPOS yet" if pos is None else f"{pos.pos_type.name}, no correction age"
    if relay is not None and (relay.frames_in == 0
                              or (relay.stats.last_correction_age_s or 0.0) > MAX_CORRECTION_AGE_S):
        return Check("corrections", False, f"{seen}; the relay has no corrections from {relay.source}",
                     "see the base (or the relay source) above")
    if sent:
        return Check(
            "corrections", False, f"{seen}, though the relay wrote {sent} frames to {cable}",
            f"the corrections do not reach {rc.correction_port}, the port set to RTCMV3: is correction_device "
            f"cabled to the receiver's {rc.correction_port} (not another COM port), at correction_baud?")
    if relay is None:
        return Check("corrections", False, f"{seen}; no relay configured",
                     "configure [relay] or a radio into the rover's correction port")
    return Check("corrections", False, f"{seen}; nothing relayed to {rc.name} yet",
                 f"check relay.sinks includes receiver:{rc.name} and its correction_device opens")


def _rates(rc: ReceiverConfig, st: _ReceiverState, configured_s: float, now: int) -> Check:
    off: list[str] = []
    ok: list[str] = []
    pending = False
    for name, period in _periodic_logs(rc):
        key = _base_log_name(name)
        a = st.arrivals.get(key)
        rate = None if a is None else a.rate_hz
        want = 1.0 / period
        if rate is None:
            if configured_s < 3 * period:
                pending = True
                off.append(f"{name} waiting (period {period:g} s)")
            else:
                off.append(f"{name} {0 if a is None else a.n} in {configured_s:.0f} s (want {want:g} Hz)")
            continue
        assert a is not None
        silent_s = (now - a.last_ns) / NS_PER_S
        if silent_s > max(3.0 * period, 1.0):
            off.append(f"{name} stopped {silent_s:.1f} s ago")
        elif abs(rate / want - 1.0) > RATE_TOLERANCE:
            off.append(f"{name} {rate:.2f} Hz (want {want:g} Hz)")
        else:
            ok.append(f"{key} {rate:.3g} Hz")
    if off:
        return Check("log rates", False, "; ".join(off),
                     "wait" if pending and len(off) == 1 else
                     "a log below its rate is being dropped (port overrun above) or not logged: check the logs "
                     "requested and the port's baud")
    return Check("log rates", True, ", ".join(ok) if ok else "no periodic logs")


def _baseline(cfg: SessionConfig, states: Mapping[str, _ReceiverState]) -> DeviceResult | None:
    ant = cfg.profile.antennas
    by_antenna = {r.antenna: r.name for r in cfg.receivers if r.role == "rover" and r.antenna is not None}
    if "a" not in by_antenna or "b" not in by_antenna:
        return None
    sa, sb = states.get(by_antenna["a"]), states.get(by_antenna["b"])
    figures: dict[str, Any] = {"nominal_m": ant.baseline_length_m, "tolerance_m": ant.baseline_tolerance_m}
    pa = {t: p for t, p in (sa.positions if sa else ()) if p.pos_type is PositionType.NARROW_INT}
    pairs = [(pa[t], p) for t, p in (sb.positions if sb else ()) if t in pa and p.pos_type is PositionType.NARROW_INT]
    if len(pairs) < _BASELINE_EPOCHS:
        check = Check("length", False, f"needs both rovers RTK fixed (NARROW_INT) at {_BASELINE_EPOCHS} epochs, "
                      f"has {len(pairs)}", "see the rovers above")
        return DeviceResult("baseline A-B", "baseline", (check,), figures)
    lengths = []
    for a, b in pairs[-20:]:
        e, n, u = pymap3d.geodetic2enu(b.lat_deg, b.lon_deg, b.hgt_m + b.undulation_m,
                                       a.lat_deg, a.lon_deg, a.hgt_m + a.undulation_m)
        lengths.append(math.sqrt(e * e + n * n + u * u))
    length = float(np.median(lengths))
    figures["measured_m"] = round(length, 4)
    diff = length - ant.baseline_length_m
    text = (f"{length:.3f} m over {len(lengths)} fixed epochs, nominal {ant.baseline_length_m:.3f} ± "
            f"{ant.baseline_tolerance_m:.3f} m")
    if abs(diff) > ant.baseline_tolerance_m:
        check = Check("length", False, f"{text} ({diff:+.3f} m)",
                      "measure the antennas again ([antennas] a, b and baseline_length_m); a few metres off is the "
                      "wrong receiver on an antenna (see identity)")
    else:
        check = Check("length", True, text)
    return DeviceResult("baseline A-B", "baseline", (check,), figures)


# ---------------------------------------------------------------------------------------------
# Correction relay
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _RelayState:
    source: str
    frames_in: int
    sent_to: dict[str, int]
    """Frames written to each ``receiver:NAME`` sink, by receiver name."""
    stats: RelayStats
    error: str | None


class _RelayProbe:
    """The correction relay as the recorder builds it (``receiver:NAME`` ends through the port resolver)."""

    def __init__(self, cfg: SessionConfig, probes: Mapping[str, _ReceiverProbe], ports: PortResolver,
                 clock: Clock) -> None:
        rcfg = cfg.relay
        assert rcfg is not None
        self.cfg = rcfg
        by_name = {r.name: r for r in cfg.receivers}
        source: RelaySource
        if rcfg.source.startswith("receiver:"):
            probe = probes[rcfg.source.removeprefix("receiver:")]
            push = PushSource(rcfg.source)
            probe.push = push
            source = push
        else:
            password = None if rcfg.source_password is None else Secret(rcfg.source_password.get_secret_value())
            source = open_source(RedactedEndpoint(rcfg.source, password), env=os.environ, user_env=rcfg.ntrip_user_env,
                                 password_env=rcfg.ntrip_password_env, gga=None, gga_period_s=rcfg.gga_period_s,
                                 clock=clock)
        sinks: list[Sink] = []
        self.sink_receivers: list[str | None] = []
        for text in rcfg.sinks:
            if text.startswith("receiver:"):
                rc = by_name[text.removeprefix("receiver:")]
                path = ports.correction_port(rc)
                if path is None:
                    raise ConfigError(f"relay.sinks: {text}: no correction_device cabled to its {rc.correction_port}")
                url = path if ("://" in path or "@" in path) else f"{path}@{rc.correction_baud}"
                sinks.append(open_sink(url, queue_frames=rcfg.queue_frames))
                self.sink_receivers.append(rc.name)
            else:
                sinks.append(open_sink(text, queue_frames=rcfg.queue_frames))
                self.sink_receivers.append(None)
        self.relay = Relay(source, sinks, clock=clock)

    def start(self) -> None:
        self.relay.start()

    def stop(self) -> None:
        self.relay.stop(drain_s=0.0)

    def snapshot(self) -> _RelayState:
        st = self.relay.stats()
        sent = {rx: s.frames_out for rx, s in zip(self.sink_receivers, st.sinks, strict=True) if rx is not None}
        error = None if self.relay.error is None else str(self.relay.error)
        return _RelayState(self.cfg.source, st.frames_in, sent, st, error)


def _judge_relay(p: _RelayProbe, st: _RelayState) -> DeviceResult:
    s = st.stats
    figures: dict[str, Any] = {"frames_in": s.frames_in, "bytes_per_s": round(s.bytes_per_s, 1),
                               "frames_by_type": dict(s.frames_by_type),
                               "sinks": {k.name: k.frames_out for k in s.sinks}}
    checks: list[Check] = []
    if st.error is not None:
        checks.append(Check("source", False, f"relay stopped: {st.error}", "check relay.source"))
    elif s.frames_in == 0 or s.last_correction_age_s is None or s.last_correction_age_s > MAX_CORRECTION_AGE_S:
        since = ("" if s.frames_in == 0 or s.last_correction_age_s is None
                 else f" for {s.last_correction_age_s:.0f} s ({s.frames_in} before)")
        checks.append(Check("source", False, f"no correction frames from {st.source}{since} ({s.state})",
                            "see the base: its fixed position and RTCM logs" if st.source.startswith("receiver:")
                            else "check the source (radio port, NTRIP caster and mount point)"))
    else:
        types = ", ".join(sorted(s.frames_by_type))
        checks.append(Check("source", True, f"{s.frames_in} frames from {st.source} ({types})"
                            + (f", {s.rejected_frames} rejected" if s.rejected_frames else "")))
    bad = [k for k in s.sinks if k.frames_out == 0]
    if bad:
        errs = "; ".join(f"{k.name}: {k.last_error or ('not connected' if not k.connected else 'nothing written')}"
                         for k in bad)
        checks.append(Check("sinks", False, errs, "check each correction_device path and that it opens"))
    else:
        checks.append(Check("sinks", True, ", ".join(f"{k.frames_out} frames to {k.name}" for k in s.sinks)))
    return DeviceResult("relay", "relay", tuple(checks), figures)


# ---------------------------------------------------------------------------------------------
# CAN
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _RoleExpect:
    role: str
    message: str
    frame_id: int
    rate_hz: float | None
    """Expected samples per second (None: the DBC gives no cycle time)."""


class _CanProbe:
    def __init__(self, cc: CanConfig, clock: Clock, factory: Callable[[CanBusConfig], can.BusABC] | None) -> None:
        self.cc = cc
        self._clock = clock
        self.decoder: RoleDecoder | None = None
        self.expect: list[_RoleExpect] = []
        db = load_dbc(cc.dbc)
        if cc.roles:
            rolemap = RoleMap.from_mapping(roles_table(cc), db, source=f"can.{cc.name}")
            self.decoder = RoleDecoder(db, rolemap)
            for spec in rolemap.roles:
                msg = db.get_message_by_name(spec.message)
                rate = None if not msg.cycle_time else 1000.0 / msg.cycle_time
                sig = msg.get_signal_by_name(spec.signal)
                if rate is not None and sig.multiplexer_ids:
                    pages = {i for s in msg.signals for i in (s.multiplexer_ids or ())}
                    rate *= len(sig.multiplexer_ids) / max(1, len(pages))
                self.expect.append(_RoleExpect(spec.role, spec.message, msg.frame_id, rate))
        self.config = CanBusConfig.from_mapping(cc.model_dump(exclude={"dbc", "roles_file", "roles", "checks"}))
        self.link = CanBusLink(self.config, self._on_frame, self._on_event, clock=clock,
                               bus_factory=factory or open_bus)
        self._lock = threading.Lock()
        self.open_error: str | None = None
        self.started = False
        self.frames = 0
        self.error_frames = 0
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.role_counts: dict[str, int] = {}
        self.message_counts: dict[int, int] = {}
        self.message_flags: dict[int, dict[str, int]] = {}
        self.worst = BusState.UNKNOWN
        self.callback_errors = 0

    def start(self) -> None:
        try:
            self.link.start()
        except RigError as exc:
            self.open_error = str(exc)
            return
        self.started = True

    def stop(self) -> None:
        if self.started:
            self.link.stop()

    def _on_event(self, ev: BusEvent) -> None:
        if isinstance(ev, BusStateChanged):
            with self._lock:
                if _state_rank(ev.state) > _state_rank(self.worst):
                    self.worst = ev.state

    def _on_frame(self, f: CanFrame) -> None:
        try:
            self._frame(f)
        except Exception:  # never into the bus session: it would stop reading
            self.callback_errors += 1
            if self.callback_errors <= 3:
                log.exception("preflight CAN %s: frame handling failed", self.cc.name)

    def _frame(self, f: CanFrame) -> None:
        with self._lock:
            if f.flags is not CanFrameFlag.NONE and f.flags & CanFrameFlag.ERROR_FRAME:
                self.error_frames += 1
                return
            self.frames += 1
            if self.first_ns is None:
                self.first_ns = f.host_ts_ns
            self.last_ns = f.host_ts_ns
            self.message_counts[f.arbitration_id] = self.message_counts.get(f.arbitration_id, 0) + 1
            if self.decoder is None or (f.flags is not CanFrameFlag.NONE and f.flags & CanFrameFlag.REMOTE):
                return
            dec = self.decoder.decode(f.arbitration_id, f.data, f.host_ts_ns, f.is_extended)
            if dec.message is None:
                return
            if dec.flags is not FrameFlag.OK and not dec.samples:
                flags = self.message_flags.setdefault(f.arbitration_id, {})
                for name in FrameFlag(dec.flags).names():
                    flags[name] = flags.get(name, 0) + 1
            for sample in dec.samples:
                self.role_counts[sample.role] = self.role_counts.get(sample.role, 0) + 1

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            return {"frames": self.frames, "error_frames": self.error_frames, "first_ns": self.first_ns,
                    "last_ns": self.last_ns, "roles": dict(self.role_counts), "messages": dict(self.message_counts),
                    "flags": {k: dict(v) for k, v in self.message_flags.items()}, "worst": self.worst,
                    "state": self.link.state if self.started else BusState.DISCONNECTED}


_STATE_RANK = {BusState.UNKNOWN: 0, BusState.DISCONNECTED: 0, BusState.ACTIVE: 1, BusState.WARNING: 2,
               BusState.PASSIVE: 3, BusState.BUS_OFF: 4}


def _state_rank(state: BusState) -> int:
    return _STATE_RANK.get(state, 0)


def _judge_can(p: _CanProbe, s: dict[str, Any], now: int, watched_s: float) -> DeviceResult:
    cc = p.cc
    name = f"can.{cc.name}"
    figures: dict[str, Any] = {"interface": cc.interface, "channel": cc.channel, "bitrate": cc.bitrate}
    if p.open_error is not None:
        return DeviceResult(name, "can", (Check(
            "open", False, p.open_error,
            f"check the adapter and the interface ({cc.interface} {cc.channel}); SocketCAN: ip link set {cc.channel} "
            f"up type can bitrate {cc.bitrate} restart-ms 100"),), figures)
    checks = [Check("open", True, f"{cc.interface} {cc.channel} open")]
    frames = s["frames"]
    span = 0.0 if s["first_ns"] is None else (now - s["first_ns"]) / NS_PER_S
    figures.update(frames=frames, error_frames=s["error_frames"], state=s["state"].value, worst_state=s["worst"].value)
    if frames:
        figures["frames_per_s"] = round(frames / max(span, 1e-9), 1)
    worst: BusState = s["worst"]
    if worst in (BusState.PASSIVE, BusState.BUS_OFF):
        checks.append(Check("bus state", False, f"controller went {worst.value} (now {s['state'].value}), "
                            f"{s['error_frames']} error frames",
                            f"check the bitrate ({cc.bitrate}), the termination and the tap; record listen-only"))
    else:
        more = f", {s['error_frames']} error frames" if s["error_frames"] else ""
        state: BusState = s["state"]
        text = ("controller state not reported by this interface" if state is BusState.UNKNOWN
                else f"controller {state.value}")
        checks.append(Check("bus state", True, f"{text}{more}"))
    if frames == 0:
        checks.append(Check("frames", False, f"no frames in {watched_s:.0f} s",
                            "wrong bus or bitrate, the adapter not up, or the car's ignition off; tap the "
                            "powertrain CAN, not the OBD port behind the gateway"))
        return DeviceResult(name, "can", tuple(checks), figures)
    checks.append(Check("frames", True, f"{frames} frames, {frames / max(span, 1e-9):.0f}/s"))
    if not p.expect:
        return DeviceResult(name, "can", tuple(checks), figures)
    dead: list[str] = []
    slow: list[str] = []
    good: list[str] = []
    rates: dict[str, float] = {}
    if span < _CAN_MIN_SPAN_S:
        checks.append(Check("roles", False, f"measuring ({span:.1f} s of frames)", "wait"))
        return DeviceResult(name, "can", tuple(checks), figures)
    for e in p.expect:
        n = s["roles"].get(e.role, 0)
        rate = n / span if span > 0 else 0.0
        rates[e.role] = round(rate, 1)
        if n == 0:
            seen = s["messages"].get(e.frame_id, 0)
            flags = s["flags"].get(e.frame_id)
            if seen and flags:
                dead.append(f"{e.role} ({e.message}): {seen} frames, all flagged "
                            f"{', '.join(f'{k} {v}' for k, v in sorted(flags.items()))}")
            else:
                dead.append(f"{e.role} ({e.message}, 0x{e.frame_id:X}) never seen")
            continue
        if e.rate_hz is not None:
            lo, hi = CAN_RATE_RANGE
            if not lo * e.rate_hz <= rate <= hi * e.rate_hz:
                slow.append(f"{e.role} {rate:.1f}/s (DBC cycle {e.rate_hz:.1f}/s)")
                continue
        elif e.rate_hz is None and rate < CAN_MIN_RATE_HZ:
            slow.append(f"{e.role} {rate:.1f}/s")
            continue
        good.append(e.role)
    figures["role_rates_hz"] = rates
    if dead:
        checks.append(Check("roles", False, "; ".join(dead),
                            "the message is not on this bus (another bus, or behind the gateway) or the roles map "
                            "the wrong message/DBC: check [[can]] roles against the car's DBC"))
    elif slow:
        checks.append(Check("role rates", False, "; ".join(slow),
                            "frames are lost or forwarded in part (gateway), or another sender uses the identifier"))
    else:
        checks.append(Check("roles", True, f"{len(good)} roles at plausible rates"))
    return DeviceResult(name, "can", tuple(checks), figures)


# ---------------------------------------------------------------------------------------------
# DAQ and the sync switch
# ---------------------------------------------------------------------------------------------


class _DaqProbe:
    def __init__(self, dc: DaqConfig, clock: Clock, factory: DaqFactory | None) -> None:
        self.dc = dc
        self.ranges = {c.name: c.range_v for c in dc.channels}
        self.window = max(int(dc.rate_hz), 2 * dc.block_size)
        self._lock = threading.Lock()
        self.buffers: dict[str, np.ndarray] = {}
        self.samples = 0
        self.blocks = 0
        self.segment = 0
        self.host_offset: dict[int, int] = {}
        """Per acquisition: lower envelope of (block receive time − its last sample's nominal time), host ns."""
        self.edges: dict[int, list[float]] = {}
        self.errors: list[str] = []
        self.lost = 0
        self.started = False
        self.ns_per_sample = NS_PER_S / dc.rate_hz
        self.link: DaqLink | None = None
        try:
            if factory is not None:
                self.link = factory(dc, clock, self._on_block, self._on_event)
            else:
                self.link = DaqLink.from_config(dc.model_dump(), on_block=self._on_block, on_event=self._on_event,
                                                clock=clock)
        except DeviceError as exc:  # the backend's package or driver is missing: this device is NO-GO
            self.errors.append(str(exc))

    def start(self) -> None:
        if self.link is None:
            return
        try:
            self.link.start()
        except RigError as exc:
            self.errors.append(str(exc))
            return
        self.started = True

    def stop(self) -> None:
        if self.started and self.link is not None:
            self.link.stop()

    def _on_block(self, block: DaqBlock) -> None:
        with self._lock:
            self.blocks += 1
            self.samples += block.n_samples
            self.segment = block.segment
            if block.lost_before is not None:
                self.lost += block.lost_before.count
            last = block.next_sample_index - 1
            off = block.host_time_ns - round(last * self.ns_per_sample)
            prev = self.host_offset.get(block.segment)
            self.host_offset[block.segment] = off if prev is None else min(prev, off)
            for i, name in enumerate(block.channels):
                x = np.asarray(block.data[i], dtype=np.float64)
                old = self.buffers.get(name)
                self.buffers[name] = x[-self.window:] if old is None else np.concatenate((old, x))[-self.window:]

    def _on_event(self, ev: DaqEvent) -> None:
        with self._lock:
            if ev.kind is DaqEventKind.SYNC_EDGE and ev.edge_index is not None:
                self.edges.setdefault(ev.segment, []).append(float(ev.edge_index))
            elif ev.kind in (DaqEventKind.CONNECT_FAILED, DaqEventKind.ERROR, DaqEventKind.DISCONNECTED):
                self.errors.append(ev.message)

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            seg = self.segment
            return {"samples": self.samples, "blocks": self.blocks, "segment": seg, "lost": self.lost,
                    "buffers": {k: v.copy() for k, v in self.buffers.items()}, "errors": list(self.errors),
                    "edges": list(self.edges.get(seg, ())), "host_offset": self.host_offset.get(seg)}


def _judge_channel(name: str, x: np.ndarray, rng: tuple[float, float], rate_hz: float) -> tuple[Check, dict[str, Any]]:
    lo, hi = rng
    lsb = (hi - lo) / 2**ASSUMED_ADC_BITS
    step = float(np.median(np.abs(np.diff(x)))) if x.size > 1 else 0.0
    figures = {"mean_v": round(float(np.mean(x)), 4), "std_v": round(float(np.std(x)), 4),
               "min_v": round(float(np.min(x)), 4), "max_v": round(float(np.max(x)), 4),
               "median_step_v": round(step, 5)}
    at_top = float(np.mean(x >= hi - DAQ_RAIL_MARGIN_V))
    at_bottom = float(np.mean(x <= lo + DAQ_RAIL_MARGIN_V)) if lo < 0 else 0.0
    span = f"[{lo:g}, {hi:g}] V"
    if step > DAQ_FLOATING_NOISE_V:
        return Check(name, False,
                     f"floating: median sample-to-sample step {step:.3f} V ({step / lsb:.0f} steps of a "
                     f"{ASSUMED_ADC_BITS}-bit converter over {span}), std {np.std(x):.3f} V",
                     f"an open input: check its connector and wiring, and the terminal mode (DIFF needs both "
                     f"wires, RSE one against AI GND) of daq channel {name!r}"), figures
    if max(at_top, at_bottom) >= DAQ_PINNED_FRACTION:
        rail = hi if at_top >= at_bottom else lo
        return Check(name, False, f"pinned at the rail {rail:g} V ({100 * max(at_top, at_bottom):.0f} % of samples) "
                     f"of its range {span}",
                     f"the signal is outside range_v {span} or the input floats to a rail: check the sensor's "
                     "supply and output range"), figures
    return Check(name, True, f"{figures['mean_v']:+.3f} V ± {figures['std_v']:.3f} within {span}"), figures


def _judge_daq(p: _DaqProbe, s: dict[str, Any], watched_s: float) -> DeviceResult:
    dc = p.dc
    name = f"daq.{dc.device}"
    figures: dict[str, Any] = {"backend": dc.backend, "rate_hz": dc.rate_hz, "samples": s["samples"],
                               "lost": s["lost"], "sync_edges": len(s["edges"])}
    if not s["samples"]:
        why = s["errors"][0] if s["errors"] else f"no samples in {watched_s:.0f} s"
        return DeviceResult(name, "daq", (Check("acquisition", False, why,
                                                f"check the DAQ device {dc.device!r} (backend {dc.backend}) and its "
                                                "driver"),), figures)
    checks = [Check("acquisition", True, f"{s['samples']} samples at {dc.rate_hz:g} Hz"
                    + (f", {s['lost']} lost" if s["lost"] else ""))]
    channels: dict[str, Any] = {}
    bad: list[Check] = []
    for c in dc.channels:
        x = s["buffers"].get(c.name)
        if x is None or x.size < 2:
            bad.append(Check(c.name, False, "no samples", "check the channel list"))
            continue
        check, fig = _judge_channel(c.name, x, c.range_v, dc.rate_hz)
        channels[c.name] = fig
        if not check.ok:
            bad.append(check)
    figures["channels"] = channels
    if bad:
        checks.extend(Check(f"channel {b.name}", False, b.detail, b.fix) for b in bad)
    else:
        checks.append(Check("channels", True, f"{len(dc.channels)} channels in range, none floating"))
    return DeviceResult(name, "daq", tuple(checks), figures)


def _judge_sync(p: _DaqProbe, s: dict[str, Any], mark_rx: _ReceiverProbe, st: _ReceiverState) -> DeviceResult:
    dc = p.dc
    edges = np.asarray(s["edges"], dtype=np.float64)
    marks = np.asarray(st.marks, dtype=np.int64)
    src = f"DAQ channel {dc.sync_channel!r}"
    figures: dict[str, Any] = {"daq_edges": int(edges.size), "marks": int(marks.size), "receiver": mark_rx.rc.name}
    if edges.size == 0 or marks.size == 0:
        missing = []
        if edges.size == 0:
            missing.append(f"no edge on {src}")
        if marks.size == 0:
            missing.append(f"no MARK event from {mark_rx.rc.name}")
        return DeviceResult("sync switch", "sync", (Check(
            "edges", False, f"{'; '.join(missing)} ({edges.size} edges, {marks.size} marks)",
            f"press the sync switch {SYNC_MIN_PAIRS} times or more during the check; check the MARK1 input wiring "
            f"(3.3 V, pull-up) and the DAQ channel (sync_threshold_v {dc.sync_threshold_v:g} V)"),), figures)
    approx = None
    off, gnss_off = s["host_offset"], st.host_minus_gps
    if off is not None and gnss_off is not None:
        approx = (off + np.round(edges * p.ns_per_sample) - gnss_off).astype(np.int64)
    try:
        fit = align_sync_pulses(dc.device, edges, marks, dc.rate_hz, approx_gps_ns=approx,
                                tolerance_ns=SYNC_TOLERANCE_NS)
    except AnalysisError as exc:
        return DeviceResult("sync switch", "sync", (Check(
            "pairing", False, f"{edges.size} edges, {marks.size} marks, not paired within 1 ms: {exc}",
            "the DAQ edge and the MARK must come from the same switch: check the wiring of both"),), figures)
    worst = float(np.max(np.abs(fit.residual_ns))) if fit.residual_ns.size else math.nan
    n = int(fit.matched_edges.size)
    figures.update(pairs=n, max_residual_us=round(worst / 1e3, 1), drift_ppm=round(fit.drift_ppm, 1))
    text = (f"{n} edge/mark pairs of {edges.size} edges and {marks.size} marks agree within {worst / 1e3:.1f} µs "
            f"once the DAQ clock is fitted ({fit.drift_ppm:+.1f} ppm)")
    if n < SYNC_MIN_PAIRS:
        return DeviceResult("sync switch", "sync", (Check(
            "pairing", False, text + f" (needs {SYNC_MIN_PAIRS})",
            f"press the sync switch {SYNC_MIN_PAIRS} times or more during the check"),), figures)
    if not worst <= SYNC_TOLERANCE_NS:
        return DeviceResult("sync switch", "sync", (Check(
            "pairing", False, text + " (more than 1 ms)", "check the sync switch's wiring to both inputs"),), figures)
    return DeviceResult("sync switch", "sync", (Check("pairing", True, text),), figures)


# ---------------------------------------------------------------------------------------------
# Disk
# ---------------------------------------------------------------------------------------------


def _data_rate(cfg: SessionConfig, rx: Mapping[str, _ReceiverState], can_states: Mapping[str, dict[str, Any]],
               can_probes: Sequence[_CanProbe]) -> tuple[float, dict[str, float]]:
    """Bytes per second the recorder will write (uncompressed), by device."""
    parts: dict[str, float] = {}
    for rc in cfg.receivers:
        st = rx.get(rc.name)
        raw = _budget_bps(rc, st) / _BITS_PER_BYTE
        decoded = 0.0
        for name, period in _periodic_logs(rc):
            key = _base_log_name(name)
            if key in {"BESTPOS", "BESTVEL", "TIME", "HEADING", "HEADING2"} and not _raw_only(rc, name):
                per = _DECODED_GNSS_BYTES + (_LOCATION_FIX_BYTES if key == "BESTPOS" else 0)
                decoded += (per + 2 * _MCAP_MESSAGE_BYTES) / period
        parts[rc.name] = raw + decoded + _MCAP_MESSAGE_BYTES * 20
    if cfg.relay is not None and cfg.relay.enabled:
        base = cfg.relay.source.removeprefix("receiver:")
        base_rc = next((r for r in cfg.receivers if r.name == base), None)
        parts["relay"] = (_budget_bps(base_rc, rx.get(base)) / _BITS_PER_BYTE) if base_rc is not None else 1000.0
    for probe in can_probes:
        s = can_states.get(probe.cc.name, {})
        first, last, frames = s.get("first_ns"), s.get("last_ns"), s.get("frames", 0)
        if first is not None and last is not None and last > first and frames > 1:
            fps = frames / ((last - first) / NS_PER_S)
        else:
            fps = sum(e.rate_hz or 0.0 for e in probe.expect) or 100.0
        roles_per_frame = max(1.0, len(probe.expect) / max(1, len({e.message for e in probe.expect})))
        decoded = (_CAN_ROLES_BYTES + _CAN_ROLE_BYTES * roles_per_frame + _MCAP_MESSAGE_BYTES) if probe.expect else 0
        parts[f"can.{probe.cc.name}"] = fps * (_CAN_FRAME_BYTES + 8 + decoded)
    if cfg.daq is not None:
        dc = cfg.daq
        optical = len(cfg.profile.optical) * min(_OPTICAL_HZ, dc.rate_hz) * (_OPTICAL_BYTES + _MCAP_MESSAGE_BYTES)
        parts[f"daq.{dc.device}"] = dc.rate_hz * len(dc.channels) * 4 + optical
    return sum(parts.values()), parts


def _raw_only(rc: ReceiverConfig, name: str) -> bool:
    return any(lr.raw_only for lr in rc.logs if lr.name == name)


def _existing(path: Path) -> Path:
    p = path.resolve()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _judge_disk(cfg: SessionConfig, out_dir: Path, duration_min: float, rate_bps: float,
                parts: Mapping[str, float]) -> DeviceResult:
    where = _existing(out_dir)
    try:
        free = shutil.disk_usage(where).free
    except OSError as exc:
        return DeviceResult("disk", "disk", (Check("free space", False, f"{out_dir}: {exc}",
                                                   "give a writable --out folder"),))
    need = rate_bps * duration_min * 60.0 + cfg.output.min_free_disk_mb * 1e6
    figures = {"folder": str(out_dir), "free_mb": round(free / 1e6, 1), "needed_mb": round(need / 1e6, 1),
               "rate_kb_per_s": round(rate_bps / 1e3, 1), "duration_min": duration_min,
               "rate_kb_per_s_by_device": {k: round(v / 1e3, 1) for k, v in parts.items()}}
    text = (f"{free / 1e9:.1f} GB free at {where}; {duration_min:g} min at ≈ {rate_bps / 1e3:.0f} kB/s "
            f"(uncompressed) + the {cfg.output.min_free_disk_mb:g} MB reserve need {need / 1e9:.2f} GB")
    if free < need:
        return DeviceResult("disk", "disk", (Check("free space", False, text,
                                                   "free space, record to another disk (--out), or plan shorter "
                                                   "sessions (--duration-min)"),), figures)
    return DeviceResult("disk", "disk", (Check("free space", True, text),), figures)


# ---------------------------------------------------------------------------------------------
# The check
# ---------------------------------------------------------------------------------------------


class _Probes:
    """Every device of the configuration, opened as the recorder opens them."""

    def __init__(self, cfg: SessionConfig, clock: Clock, ports: PortResolver, daq_factory: DaqFactory | None,
                 can_factory: Callable[[CanBusConfig], can.BusABC] | None) -> None:
        self.cfg = cfg
        self.receivers = {rc.name: _ReceiverProbe(rc, ports.port(rc), clock) for rc in cfg.receivers}
        self.relay = (_RelayProbe(cfg, self.receivers, ports, clock)
                      if cfg.relay is not None and cfg.relay.enabled else None)
        self.can = [_CanProbe(cc, clock, can_factory) for cc in cfg.can]
        self.daq = _DaqProbe(cfg.daq, clock, daq_factory) if cfg.daq is not None else None
        rovers = sorted((r for r in cfg.receivers if r.role == "rover"), key=lambda r: r.antenna or "z")
        marking = [r for r in rovers if {_base_log_name(lr.name) for lr in r.logs} & _MARK_LOGS]
        self.mark_rx = self.receivers[marking[0].name] if marking else None

    def start(self) -> None:
        for p in self.receivers.values():
            p.start()
        if self.relay is not None:
            self.relay.start()
        for c in self.can:
            c.start()
        if self.daq is not None:
            self.daq.start()

    def stop(self) -> None:
        """Stop and join everything (each one even when another fails)."""
        steps: list[tuple[str, Callable[[], None]]] = []
        if self.relay is not None:
            steps.append(("relay", self.relay.stop))
        steps += [(f"receiver {n}", p.stop) for n, p in self.receivers.items()]
        steps += [(f"CAN bus {c.cc.name}", c.stop) for c in self.can]
        if self.daq is not None:
            steps.append(("DAQ", self.daq.stop))
        for what, fn in steps:
            try:
                fn()
            except Exception:
                log.exception("preflight: stopping %s failed", what)

    def judge(self, now: int, watched_s: float, out_dir: Path, duration_min: float) -> list[DeviceResult]:
        states = {n: p.snapshot() for n, p in self.receivers.items()}
        relay = self.relay.snapshot() if self.relay is not None else None
        out: list[DeviceResult] = []
        for name, p in self.receivers.items():
            out.append(_judge_receiver(p, states[name], now, watched_s, relay))
        if self.relay is not None and relay is not None:
            out.append(_judge_relay(self.relay, relay))
        base = _baseline(self.cfg, states)
        if base is not None:
            out.append(base)
        can_states = {c.cc.name: c.snapshot() for c in self.can}
        out.extend(_judge_can(c, can_states[c.cc.name], now, watched_s) for c in self.can)
        if self.daq is not None:
            ds = self.daq.snapshot()
            out.append(_judge_daq(self.daq, ds, watched_s))
            if self.daq.dc.sync_channel is not None and self.mark_rx is not None:
                out.append(_judge_sync(self.daq, ds, self.mark_rx, states[self.mark_rx.rc.name]))
        rate, parts = _data_rate(self.cfg, states, can_states, self.can)
        out.append(_judge_disk(self.cfg, out_dir, duration_min, rate, parts))
        return out

    def min_observe_s(self) -> float:
        periods = [p for rc in self.cfg.receivers for _, p in _periodic_logs(rc)]
        return max(MIN_OBSERVE_S, 3.0 * max(periods, default=0.0))


def _not_checked(cfg: SessionConfig, probes: _Probes) -> tuple[str, ...]:
    out = []
    if cfg.daq is None:
        out.append("DAQ and sync switch: no [daq] table")
    elif cfg.daq.sync_channel is None:
        out.append("sync switch: no daq.sync_channel")
    elif probes.mark_rx is None:
        out.append("sync switch: no rover logs MARKPOS/MARK1TIME")
    if not cfg.can:
        out.append("CAN: no [[can]] table")
    out.append("receiver output latency: needs the sync switch against a known event, not measured here")
    out.append("USB vs COM: logs are requested on the port the commands come in on (THISPORT), so a receiver "
               "on USB is checked as it is wired; a cable to the wrong physical port shows as no answer")
    out.append("CAN bus state on socketcand and the virtual bus: only bus-off and restart are reported there, "
               "error warning and error passive are not")
    out.append("DAQ channel values against the sensors' physics (a plausible but wrong voltage is not caught)")
    out.append("sync switch: a constant delay between the DAQ edge and the MARK (both the same in every pair) "
               "goes into the fitted DAQ clock offset; only the pairing (host-time prior ±0.25 s) and the pairs' "
               "agreement within 1 ms are checked")
    return tuple(out)


def _assumptions(duration_min: float) -> tuple[str, ...]:
    return (
        (f"free disk: {duration_min:g} min at the estimated data rate, uncompressed (zstd chunks are typically "
         "3-5x smaller, so this is an upper bound), plus output.min_free_disk_mb"),
        ("data rate: receiver logs at their configured rates and measured sizes (nominal sizes for logs not "
         "seen), decoded GNSS logs ≈ 700 B of JSON each, CAN at the measured frame rate with ≈ 30 B per role "
         "decoded, DAQ 4 B per sample and channel, optical sensors at 100 Hz"),
        f"DAQ noise in quantisation steps of an assumed {ASSUMED_ADC_BITS}-bit converter over each channel's range",
        ("corrections: the rover's own BESTPOS differential age (RTCM age) and the relay's frames written to its "
         "correction_device"),
    )


def run_preflight(
    cfg: SessionConfig,
    *,
    config_name: str = "",
    wait_s: float = DEFAULT_WAIT_S,
    duration_min: float = DEFAULT_DURATION_MIN,
    out_dir: Path | str | None = None,
    clock: Clock | None = None,
    ports: PortResolver | None = None,
    daq_factory: DaqFactory | None = None,
    can_factory: Callable[[CanBusConfig], can.BusABC] | None = None,
    stop: threading.Event | None = None,
    simulated: bool = False,
    on_tick: Callable[[Sequence[DeviceResult], float], None] | None = None,
) -> PreflightReport:
    """Open every device of ``cfg`` as the recorder would and judge it GO / NO-GO (see the module docstring).

    Watches for up to ``wait_s`` of ``clock`` time (the session clock: a simulated world's runs faster than
    the wall) and ends early once every device is GO after :data:`MIN_OBSERVE_S` (or three of the longest log
    period). ``ports``, ``daq_factory``, ``can_factory`` and ``clock`` are what a :class:`Recording` takes
    (a simulated world passes its own). ``on_tick`` gets the device results and the watched seconds as they
    are judged (a live view). Every device is stopped and its thread joined before this returns.

    Raises:
        ConfigError: a device configuration the drivers refuse (before anything is opened for long).
    """
    if not (math.isfinite(wait_s) and wait_s > 0):
        raise ConfigError(f"preflight --wait: must be > 0 s, got {wait_s}")
    if not (math.isfinite(duration_min) and duration_min >= 0):
        raise ConfigError(f"preflight --duration-min: must be >= 0, got {duration_min}")
    clock = clock or SystemClock()
    stop = stop or threading.Event()
    out = Path(out_dir if out_dir is not None else cfg.output.directory)
    wall0 = time.monotonic()
    probes = _Probes(cfg, clock, ports or DirectPorts(), daq_factory, can_factory)
    min_observe = probes.min_observe_s()
    t0 = clock.now_ns()
    time_to_go: float | None = None
    results: list[DeviceResult] = []
    try:
        probes.start()
        while True:
            now = clock.now_ns()
            watched = (now - t0) / NS_PER_S
            results = probes.judge(now, watched, out, duration_min)
            if on_tick is not None:
                on_tick(results, watched)
            if all(r.verdict is Verdict.GO for r in results) and watched >= min_observe:
                time_to_go = watched
                break
            if watched >= wait_s or stop.wait(_TICK_S):
                break
    finally:
        probes.stop()
    watched = (clock.now_ns() - t0) / NS_PER_S
    return PreflightReport(
        config=config_name, devices=tuple(results), wait_s=wait_s, watched_s=watched, time_to_go_s=time_to_go,
        wall_s=time.monotonic() - wall0, simulated=simulated, assumptions=_assumptions(duration_min),
        not_checked=_not_checked(cfg, probes),
    )
