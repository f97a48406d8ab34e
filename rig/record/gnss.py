"""The devices of a recording session: each one's driver, recorder source and status-board line.

Used by :class:`rig.record.recording.Recording` (see there for what each device records): a NovAtel
receiver (:class:`GnssDevice`), the correction relay (:class:`RelayDevice`), a CAN bus
(:class:`CanDevice`), the DAQ with its optical sensors (:class:`DaqDevice`), and the live rollover
index of the dashboard (:class:`LiveLtr`). Callbacks run on the drivers' threads and never raise
into them: a failure is counted, logged and recorded as an event.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.novatel import BestPos, BestVel, Heading, Heading2, MarkPos, MarkTime, Time
from drivers.novatel.commands import LogRequest as NovatelLog
from drivers.novatel.commands import LogTrigger as NovatelTrigger
from drivers.novatel.commands import standard_configuration
from drivers.novatel.enums import TimeStatus
from drivers.novatel.layouts import decode_version
from drivers.novatel.messages import LOG_IDS, RawBody, VersionComponent
from drivers.novatel.receiver import (
    NovatelReceiver,
    ReceivedChunk,
    ReceiverEvent,
    ReceiverEventKind,
    ReceiverSettings,
)
from drivers.relay import PushSource
from rig.core.config import LogTrigger, ReceiverConfig
from rig.core.topics import EventKind, Severity
from rig.record.device import Device, DeviceContext
from rig.record.status import DeviceState
from vsccore.errors import DecodeError
from vsccore.gpstime import NS_PER_S

if TYPE_CHECKING:
    pass


__all__ = ["GnssDevice", "receiver_commands"]

log = logging.getLogger(__name__)


_CORRECTION_RX = {"rtcmv3": "RTCMV3", "rtca": "RTCA", "cmr": "CMR", "novatel": "NOVATEL"}
_SYNC_LOGS = (BestPos, BestVel, Time)
"""Logs output on the receiver's solution schedule: their (GPS time, receive time) pairs feed the time base,
once the receiver's clock is steered to GPS time (FINESTEERING: before it, after power-up or a reset, a log's
GPS time is the receiver's coarse guess, OEM7 Commands and Logs Reference, "GPS Reference Time Status")."""
_SILENCE_PERIODS = 3.0
"""A receiver is configured again when its logs stop for this many of its longest log period (at least
:data:`_SILENCE_MIN_S`): an OEM7 reset behind an open port drops every unsaved log."""
_SILENCE_MIN_S = 3.0


def silence_reconfigure_s(rc: ReceiverConfig) -> float:
    """How long a receiver's logs may stop before the rig configures it again (see :data:`_SILENCE_PERIODS`)."""
    periods = [lr.period_s for lr in rc.logs if lr.trigger is LogTrigger.ONTIME and lr.period_s]
    return max(_SILENCE_MIN_S, _SILENCE_PERIODS * max(periods, default=0.0))

def receiver_commands(rc: ReceiverConfig) -> tuple[str, ...]:
    """The configuration commands a receiver gets at every (re)connect.

    Logs go to THISPORT (the port the commands come in on: over USB that is the laptop's USB port, while
    ``LOG COM1 …`` would go to the physical COM1). A rover's correction port receives RTCM3 at its own baud,
    set when the rig owns the cable to it; a base's fixed height is sent with the UNDULATION that says how to
    read it. ``LOG VERSIONB ONCE`` first: the receiver's serial number identifies it; then ``LOG TIMEB ONCE``: the
    leap seconds are known before the first position, so no record is put on the host clock while they are not.
    """
    requests = [NovatelLog("VERSIONB", NovatelTrigger.ONCE), NovatelLog("TIMEB", NovatelTrigger.ONCE), *(
        NovatelLog(lr.name, NovatelTrigger(lr.trigger.value.upper()), lr.period_s) for lr in rc.logs)]
    names = {_log_base_name(lr.name) for lr in rc.logs}
    modes: list[tuple[str, str, str]] = []
    serial: list[tuple[str, int]] = []
    if rc.role == "rover":
        modes.append((rc.correction_port, _CORRECTION_RX[rc.correction_format], "NONE"))
        if rc.correction_device is not None:
            serial.append((rc.correction_port, rc.correction_baud))
    return standard_configuration(
        "THISPORT",
        requests,
        interface_modes=modes,
        serial_configs=serial,
        fix_position=rc.fix_position if rc.role == "base" else None,
        fix_height_ellipsoidal=rc.fix_height == "ellipsoidal",
        mark_inputs=["MARK1"] if names & {"MARKPOS", "MARKTIME", "MARK1TIME"} else [],
        extra=rc.extra_commands,
    )


def _log_base_name(name: str) -> str:
    """``BESTPOSB`` → ``BESTPOS`` (the format suffix off, when what is left is a known log)."""
    if name[-1:] in ("A", "B", "S") and name[:-1] in LOG_IDS:
        return name[:-1]
    return name


# ---------------------------------------------------------------------------------------------
# Decoded GNSS logs in the topics' schemas
# ---------------------------------------------------------------------------------------------


def _record(kind: str, header: Any, body: Any) -> dict[str, Any]:
    """One decoded GNSS record (:data:`rig.core.topics.GNSS_RECORD_FIELDS`); non-finite numbers become null,
    an enum a short header does not carry ``UNKNOWN``."""
    out: dict[str, Any] = {}
    for f in T.GNSS_RECORD_FIELDS[kind]:
        v = getattr(header if f.header else body, f.name, None)
        if f.enum is not None:
            out[f.key] = v.name if v is not None else "UNKNOWN"
        elif f.ns is not None:
            out[f.ns.key] = f.ns.to_json(v)
        else:
            out[f.key] = _finite(v) if isinstance(v, float) else v
    return out


def _position(header: Any, b: BestPos | MarkPos) -> dict[str, Any]:
    return _record("position", header, b)


def _velocity(header: Any, b: BestVel) -> dict[str, Any]:
    return _record("velocity", header, b)


def _marktime(b: MarkTime) -> dict[str, Any]:
    return {**_record("marktime", None, b), "event_input": "MARK1"}


def _time(header: Any, b: Time) -> dict[str, Any]:
    sec, ms = divmod(b.utc_ms, 1000)
    iso = f"{b.utc_year:04d}-{b.utc_month:02d}-{b.utc_day:02d}T{b.utc_hour:02d}:{b.utc_min:02d}:{sec:02d}.{ms:03d}Z"
    return {**_record("time", header, b), "utc_iso": iso}


def _heading(header: Any, b: Heading | Heading2) -> dict[str, Any]:
    return _record("heading", header, b)


# ---------------------------------------------------------------------------------------------
# Devices
# ---------------------------------------------------------------------------------------------


class GnssDevice(Device):
    """One NovAtel receiver."""

    def __init__(self, ctx: DeviceContext, rc: ReceiverConfig, port: str, *, output_latency_ns: int) -> None:
        super().__init__(ctx, rc.name, "gnss", maxsize=20_000)
        self.rc = rc
        self.port = port
        self.push: PushSource | None = None
        """Set when this receiver's stream is the correction relay's source."""
        self.raw_only = {_log_base_name(lr.name) for lr in rc.logs if lr.raw_only}
        self.frame_id = f"antenna_{rc.antenna}" if rc.antenna is not None else rc.name
        self.latency_ns = (round(rc.output_latency_s * NS_PER_S) if rc.output_latency_s is not None
                           else output_latency_ns)
        self.ns_per_byte = 10 * NS_PER_S / rc.baud
        self.topics = {kind: fn(rc.name) for kind, fn in (
            ("raw", T.gnss_raw), ("bestpos", T.gnss_bestpos), ("fix", T.gnss_fix), ("markpos", T.gnss_markpos),
            ("bestvel", T.gnss_bestvel), ("marktime", T.gnss_marktime), ("time", T.gnss_time),
            ("heading", T.gnss_heading))}
        self.last_pos: tuple[int, BestPos] | None = None
        self.last_vel: tuple[int, BestVel] | None = None
        self.identity: VersionComponent | None = None
        """The receiver's GNSS card as its VERSION log gave it (model, PSN, firmware)."""
        self.refused: str | None = None
        """Why this port's receiver is not taken as ours (another serial number than configured)."""
        settings = ReceiverSettings(
            name=rc.name, port=port, baud=rc.baud, commands=receiver_commands(rc),
            command_timeout_s=rc.command_timeout_s, autobaud=rc.autobaud,
            reconnect_first_s=ctx.reconnect.first_s, reconnect_max_s=ctx.reconnect.max_s,
            silence_reconfigure_s=silence_reconfigure_s(rc),
        )
        self.rx = NovatelReceiver(settings, on_data=self._on_data, on_event=self._on_event, clock=ctx.clock)

    def start(self) -> None:
        self.rx.start()

    def stop(self) -> None:
        self.rx.stop()

    def _log_time(self, gps_ns: int, host_ns: int) -> int:
        tb = self.ctx.timebase
        return tb.gps_to_utc(gps_ns) if tb.leap_seconds is not None else tb.host_to_utc(host_ns)

    def _on_data(self, chunk: ReceivedChunk) -> None:
        s = self.ctx
        tb = s.timebase
        host = chunk.host_ns
        if chunk.data:
            self.source.put(self.topics["raw"], tb.live_host_to_utc(self.topics["raw"], host), host, chunk.data)
            if self.push is not None:
                self.push.feed(chunk.data)
        for frame in chunk.frames:
            s.board.message(self.name, host)
            lg = frame.log
            if lg is None:
                continue
            body = lg.body
            gps_ns = lg.header.gps_ns
            name = lg.name
            if name == "VERSION" and isinstance(body, RawBody):
                self._identify(body, host)
                continue
            if self.refused is not None:
                continue  # another receiver on this port: its raw bytes are kept, nothing is taken as ours
            if isinstance(body, _SYNC_LOGS) and getattr(lg.header, "time_status", None) is TimeStatus.FINESTEERING:
                # first byte left the receiver output_latency after the data time; the read returns
                # once the last byte is in: take both known parts of the latency off
                tx_ns = round(len(frame.raw) * self.ns_per_byte)
                tb.gnss_clock(self.name).add(gps_ns, host - tx_ns - self.latency_ns)
            if isinstance(body, Time) and body.utc_status.name == "VALID" and tb.leap_seconds != body.leap_seconds:
                tb.set_leap_seconds(body.leap_seconds)
                self.event(EventKind.TIMEBASE, f"GPS − UTC = {body.leap_seconds} s (TIME log)", host_ns=host,
                           leap_seconds=body.leap_seconds)
            if name in self.raw_only:
                continue
            t = self._log_time(gps_ns, host)
            if isinstance(body, BestPos):
                self.source.put(self.topics["bestpos"], t, host, _position(lg.header, body))
                self.source.put(
                    self.topics["fix"], t, host,
                    T.location_fix(t, self.frame_id, body.lat_deg, body.lon_deg, body.hgt_m + body.undulation_m,
                                   body.lat_sigma_m, body.lon_sigma_m, body.hgt_sigma_m),
                )
                self.last_pos = (gps_ns, body)
                s.on_position(self.rc, gps_ns, body)
            elif isinstance(body, MarkPos):
                self.source.put(self.topics["markpos"], t, host, _position(lg.header, body))
                s.on_mark(self.name, gps_ns, from_marktime=False)
            elif isinstance(body, BestVel):
                self.source.put(self.topics["bestvel"], t, host, _velocity(lg.header, body))
                self.last_vel = (gps_ns, body)
            elif isinstance(body, MarkTime):
                ev = body.event_gps_ns
                self.source.put(self.topics["marktime"], self._log_time(ev, host), host, _marktime(body))
                s.on_mark(self.name, ev, from_marktime=True)
            elif isinstance(body, Time):
                self.source.put(self.topics["time"], t, host, _time(lg.header, body))
            elif isinstance(body, Heading | Heading2):
                self.source.put(self.topics["heading"], t, host, _heading(lg.header, body))

    def _identify(self, body: RawBody, host: int) -> None:
        """The receiver's VERSION: record who answered on this port; refuse another than the configured one."""
        try:
            card = decode_version(body).component()
        except DecodeError as exc:
            self.event(EventKind.WARNING, f"VERSION log does not decode: {exc}", severity=Severity.WARNING,
                       host_ns=host)
            return
        if card is None:
            return
        self.identity = card
        want = self.rc.serial_number
        details: dict[str, Any] = {"model": card.model, "serial_number": card.psn, "firmware": card.sw_version,
                                   "port": self.port}
        if want is not None and card.psn.strip() != want.strip():
            self.refused = (f"{self.port} answers as receiver PSN {card.psn}, not {self.rc.name}'s {want}: "
                            "ports swapped? (use /dev/serial/by-id paths)")
            self.ctx.board.update(self.name, state=DeviceState.LOST, detail=f"REFUSED: wrong receiver {card.psn}")
            self.event(EventKind.ERROR, self.refused, severity=Severity.ERROR, host_ns=host, **details)
            return
        self.refused = None
        self.event(EventKind.INFO, f"receiver {card.model} PSN {card.psn}, firmware {card.sw_version}",
                   host_ns=host, **details)

    def _on_event(self, ev: ReceiverEvent) -> None:
        board = self.ctx.board
        k = ev.kind
        details: dict[str, Any] = {"port": ev.port, "connection": ev.connection}
        if ev.command is not None:
            details["command"] = ev.command
        if k is ReceiverEventKind.CONNECTED:
            self.event(EventKind.CONNECT, f"{ev.port}: {ev.message}", host_ns=ev.host_ns, **details)
            if ev.gap_ns is not None:
                tb = self.ctx.timebase
                start = tb.host_to_utc(ev.host_ns - ev.gap_ns)
                self.source.gap(start, tb.host_to_utc(ev.host_ns),
                                f"no data from {ev.port} for {ev.gap_ns / 1e9:.3f} s", **details)
        elif k is ReceiverEventKind.RESET:
            board.update(self.name, state=DeviceState.DEGRADED, detail=ev.message)
            self.event(EventKind.WARNING, f"receiver reset? {ev.message}", severity=Severity.WARNING,
                       host_ns=ev.host_ns, **details)
        elif k is ReceiverEventKind.CONFIGURED:
            board.update(self.name, state=DeviceState.OK)
            self.event(EventKind.INFO, f"configured: {ev.message}", host_ns=ev.host_ns, **details)
        elif k is ReceiverEventKind.DISCONNECTED:
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.DISCONNECT, ev.message, severity=Severity.WARNING, host_ns=ev.host_ns, **details)
        elif k is ReceiverEventKind.CONNECT_FAILED:
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.ERROR, ev.message, severity=Severity.ERROR, host_ns=ev.host_ns, **details)
        elif k in (ReceiverEventKind.COMMAND_FAILED, ReceiverEventKind.CONFIGURATION_FAILED,
                   ReceiverEventKind.CALLBACK_FAILED):
            board.update(self.name, state=DeviceState.DEGRADED)
            self.event(EventKind.ERROR, ev.message, severity=Severity.ERROR, host_ns=ev.host_ns, **details)
        elif k is ReceiverEventKind.BAUD_DETECTED:
            self.event(EventKind.INFO, ev.message, host_ns=ev.host_ns, baud=ev.baud, **details)
        elif k is ReceiverEventKind.STOPPED:
            board.update(self.name, state=DeviceState.STOPPED)

    def refresh(self) -> None:
        """Status-board detail from the receiver's health."""
        h = self.rx.health()
        if h.position_type is not None:
            diff = "-" if h.diff_age_s is None else f"{h.diff_age_s:.1f} s"
            detail = f"{h.position_type} {h.num_soln_svs}/{h.num_svs} sv diff {diff}"
        else:
            detail = f"{h.baud or '-'} Bd, {h.bytes_in} B"
        if h.crc_failures:
            detail += f" crc {h.crc_failures}"
        self.ctx.board.update(self.name, detail=detail)


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
