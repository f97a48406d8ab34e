"""The devices of a recording session: each one's driver, recorder source and status-board line.

Used by :class:`rig.session.RecordSession` (see there for what each device records): a NovAtel
receiver (:class:`GnssDevice`), the correction relay (:class:`RelayDevice`), a CAN bus
(:class:`CanDevice`), the DAQ with its optical sensors (:class:`DaqDevice`), and the live rollover
index of the dashboard (:class:`LiveLtr`). Callbacks run on the drivers' threads and never raise
into them: a failure is counted, logged and recorded as an event.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

import rig.topics as T  # noqa: N812 - topics used as a namespace
from drivers.can.bus import (
    BusEvent,
    BusGap,
    BusLost,
    BusOpened,
    BusState,
    BusStateChanged,
    BusStats,
    CanBusConfig,
    CanBusSession,
    CanFrame,
    CanFrameFlag,
    open_bus,
)
from drivers.can.checks import FrameFlag
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap
from drivers.daq import DaqBlock, DaqEvent, DaqEventKind, DaqSession
from drivers.novatel import BestPos, BestVel, Heading, Heading2, MarkPos, MarkTime, Time
from drivers.novatel.commands import LogRequest as NovatelLog
from drivers.novatel.commands import LogTrigger as NovatelTrigger
from drivers.novatel.commands import standard_configuration
from drivers.novatel.messages import LOG_IDS
from drivers.novatel.receiver import (
    NovatelReceiver,
    ReceivedChunk,
    ReceiverEvent,
    ReceiverEventKind,
    ReceiverSettings,
)
from drivers.optical import OpticalSensorSpec, convert_block
from drivers.relay import CallbackSink, CorrectionFrame, PushSource, Relay, Sink, open_sink, open_source
from drivers.relay import Source as RelaySource
from drivers.relay.endpoints import RedactedEndpoint, Secret
from rig.config import CanConfig, DaqConfig, ReceiverConfig, SessionConfig
from rig.recorder import Source
from rig.status import DeviceState
from rig.timebase import FitStatus, SyncFit, align_sync_pulses
from rig.topics import EventKind, Severity
from vsccore.errors import AnalysisError, RigError
from vsccore.gpstime import GPS_EPOCH_UNIX_NS, NS_PER_S

if TYPE_CHECKING:
    from rig.session import RecordSession

__all__ = [
    "CAN_BLOCK_AGE_NS",
    "CanDevice",
    "DaqDevice",
    "Device",
    "GnssDevice",
    "LiveLtr",
    "RelayDevice",
    "receiver_commands",
    "roles_table",
]

log = logging.getLogger(__name__)

_CORRECTION_RX = {"rtcmv3": "RTCMV3", "rtca": "RTCA", "cmr": "CMR", "novatel": "NOVATEL"}
_SYNC_LOGS = (BestPos, BestVel, Time)
"""Logs output on the receiver's solution schedule: their (GPS time, receive time) pairs feed the time base."""
_OPTICAL_MAX_HZ = 100.0
_CAN_BLOCK_FRAMES = 256
_RX = int(T.CanFlag.RX)
_EXTENDED = int(T.CanFlag.EXTENDED)
_FD = int(T.CanFlag.FD)
_NOT_DATA = CanFrameFlag.ERROR_FRAME | CanFrameFlag.REMOTE
CAN_BLOCK_AGE_NS = 100_000_000
_CAN_FLAGS: dict[int, T.CanFlag] = {}
"""``CanFlag(bits)`` by bits: an enum construction per frame is a measurable share of the CAN thread."""
_FLAG_NAMES: dict[int, list[str]] = {}
"""``FrameFlag(bits).names()`` by bits (copied on use: the lists go into records)."""

def receiver_commands(rc: ReceiverConfig) -> tuple[str, ...]:
    """The configuration commands a receiver gets at every (re)connect."""
    logs = tuple(
        NovatelLog(lr.name, NovatelTrigger(lr.trigger.value.upper()), lr.period_s) for lr in rc.logs
    )
    names = {_log_base_name(lr.name) for lr in rc.logs}
    modes: list[tuple[str, str, str]] = []
    if rc.role == "rover":
        modes.append((rc.correction_port, _CORRECTION_RX[rc.correction_format], "NONE"))
    return standard_configuration(
        rc.command_port,
        logs,
        interface_modes=modes,
        fix_position=rc.fix_position if rc.role == "base" else None,
        mark_inputs=["MARK1"] if names & {"MARKPOS", "MARKTIME"} else [],
        extra=rc.extra_commands,
    )


def _log_base_name(name: str) -> str:
    """``BESTPOSB`` → ``BESTPOS`` (the format suffix off, when what is left is a known log)."""
    if name[-1:] in ("A", "B", "S") and name[:-1] in LOG_IDS:
        return name[:-1]
    return name


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None

# ---------------------------------------------------------------------------------------------
# Decoded GNSS logs in the topics' schemas
# ---------------------------------------------------------------------------------------------


def _record(kind: str, header: Any, body: Any) -> dict[str, Any]:
    """One decoded GNSS record (:data:`rig.topics.GNSS_RECORD_FIELDS`); non-finite numbers become null,
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


class Device:
    """Common part: a recorder source, a status-board line and error counting."""

    def __init__(self, session: RecordSession, name: str, kind: str, maxsize: int) -> None:
        self.session = session
        self.name = name
        self.source: Source = session.recorder.source(name, maxsize=maxsize)
        self.errors = 0
        session.board.add_device(name, kind)

    def event(self, kind: EventKind, text: str, *, severity: Severity = Severity.INFO, host_ns: int | None = None,
              **details: Any) -> None:
        s = self.session
        t = s.timebase.host_to_utc(host_ns if host_ns is not None else s.clock.now_ns())
        self.source.event(kind, text, severity=severity, log_time_ns=t, **details)
        s.board.event(f"{self.name}: {text}")
        if severity is Severity.ERROR:
            self.errors += 1
            s.board.error(self.name)

    def failed_callback(self, what: str, exc: BaseException) -> None:
        """A callback of this device raised: count it, report the first ones (never re-raise into the driver)."""
        self.errors += 1
        if self.errors <= 5 or self.errors % 1000 == 0:
            log.exception("%s: %s failed", self.name, what)
            self.source.error(f"{what} failed ({self.errors} so far): {exc}", exc)
            self.session.board.error(self.name)


class GnssDevice(Device):
    """One NovAtel receiver."""

    def __init__(self, session: RecordSession, rc: ReceiverConfig, port: str) -> None:
        super().__init__(session, rc.name, "gnss", maxsize=20_000)
        self.rc = rc
        self.port = port
        self.push: PushSource | None = None
        """Set when this receiver's stream is the correction relay's source."""
        self.raw_only = {_log_base_name(lr.name) for lr in rc.logs if lr.raw_only}
        self.frame_id = f"antenna_{rc.antenna}" if rc.antenna is not None else rc.name
        self.latency_ns = (round(rc.output_latency_s * NS_PER_S) if rc.output_latency_s is not None
                           else session.gnss_output_latency_ns)
        self.ns_per_byte = 10 * NS_PER_S / rc.baud
        self.topics = {kind: fn(rc.name) for kind, fn in (
            ("raw", T.gnss_raw), ("bestpos", T.gnss_bestpos), ("fix", T.gnss_fix), ("markpos", T.gnss_markpos),
            ("bestvel", T.gnss_bestvel), ("marktime", T.gnss_marktime), ("time", T.gnss_time),
            ("heading", T.gnss_heading))}
        self.last_pos: tuple[int, BestPos] | None = None
        self.last_vel: tuple[int, BestVel] | None = None
        settings = ReceiverSettings(
            name=rc.name, port=port, baud=rc.baud, commands=receiver_commands(rc),
            command_timeout_s=rc.command_timeout_s, autobaud=rc.autobaud,
            reconnect_first_s=session.reconnect_first_s, reconnect_max_s=session.reconnect_max_s,
        )
        self.rx = NovatelReceiver(settings, on_data=self._on_data, on_event=self._on_event, clock=session.clock)

    def start(self) -> None:
        self.rx.start()

    def stop(self) -> None:
        self.rx.stop()

    def _log_time(self, gps_ns: int, host_ns: int) -> int:
        tb = self.session.timebase
        return tb.gps_to_utc(gps_ns) if tb.leap_seconds is not None else tb.host_to_utc(host_ns)

    def _on_data(self, chunk: ReceivedChunk) -> None:
        s = self.session
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
            if isinstance(body, _SYNC_LOGS):
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
                s.on_position(self, gps_ns, body)
            elif isinstance(body, MarkPos):
                self.source.put(self.topics["markpos"], t, host, _position(lg.header, body))
                s.on_mark(self, gps_ns, from_marktime=False)
            elif isinstance(body, BestVel):
                self.source.put(self.topics["bestvel"], t, host, _velocity(lg.header, body))
                self.last_vel = (gps_ns, body)
            elif isinstance(body, MarkTime):
                ev = body.event_gps_ns
                self.source.put(self.topics["marktime"], self._log_time(ev, host), host, _marktime(body))
                s.on_mark(self, ev, from_marktime=True)
            elif isinstance(body, Time):
                self.source.put(self.topics["time"], t, host, _time(lg.header, body))
            elif isinstance(body, Heading | Heading2):
                self.source.put(self.topics["heading"], t, host, _heading(lg.header, body))

    def _on_event(self, ev: ReceiverEvent) -> None:
        board = self.session.board
        k = ev.kind
        details: dict[str, Any] = {"port": ev.port, "connection": ev.connection}
        if ev.command is not None:
            details["command"] = ev.command
        if k is ReceiverEventKind.CONNECTED:
            self.event(EventKind.CONNECT, f"{ev.port}: {ev.message}", host_ns=ev.host_ns, **details)
            if ev.gap_ns is not None:
                tb = self.session.timebase
                start = tb.host_to_utc(ev.host_ns - ev.gap_ns)
                self.source.gap(start, tb.host_to_utc(ev.host_ns),
                                f"no data from {ev.port} for {ev.gap_ns / 1e9:.3f} s", **details)
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
        self.session.board.update(self.name, detail=detail)


class RelayDevice(Device):
    """The RTK correction relay."""

    def __init__(self, session: RecordSession) -> None:
        super().__init__(session, "relay", "relay", maxsize=20_000)
        cfg = session.cfg.relay
        assert cfg is not None
        self.cfg = cfg
        self.from_receiver = cfg.source.startswith("receiver:")
        source: RelaySource
        if self.from_receiver:
            rx = session.gnss_device(cfg.source.removeprefix("receiver:"), "relay.source")
            push = PushSource(cfg.source)
            rx.push = push
            source = push
        else:
            password = None if cfg.source_password is None else Secret(cfg.source_password.get_secret_value())
            source = open_source(
                RedactedEndpoint(cfg.source, password),
                env=os.environ, user_env=cfg.ntrip_user_env, password_env=cfg.ntrip_password_env,
                gga=session.gga_position, gga_period_s=cfg.gga_period_s, clock=session.clock,
            )
        sinks: list[Sink] = []
        for text in cfg.sinks:
            if text.startswith("receiver:"):
                rx = session.gnss_device(text.removeprefix("receiver:"), "relay.sinks")
                path = session.ports.correction_port(rx.rc)
                if path is None:
                    sinks.append(CallbackSink(text, rx.rx.send_raw, queue_frames=cfg.queue_frames))
                else:
                    url = path if ("://" in path or "@" in path) else f"{path}@{rx.rc.baud}"
                    sinks.append(open_sink(url, queue_frames=cfg.queue_frames))
            else:
                sinks.append(open_sink(text, queue_frames=cfg.queue_frames))
        self.relay = Relay(
            source, sinks,
            tap=None if self.from_receiver else self._on_tap,
            on_frame=self._on_frame if self.from_receiver else None,
            clock=session.clock,
        )
        self._reported_failure = False

    def _on_tap(self, host_ns: int, data: bytes) -> None:
        self.source.put(T.TOPIC_RELAY_RAW, self.session.timebase.live_host_to_utc(T.TOPIC_RELAY_RAW, host_ns), host_ns,
                        data)
        self.session.board.message(self.name, host_ns)

    def _on_frame(self, host_ns: int, frame: CorrectionFrame) -> None:
        self.source.put(T.TOPIC_RELAY_RAW, self.session.timebase.live_host_to_utc(T.TOPIC_RELAY_RAW, host_ns), host_ns,
                        frame.raw)
        self.session.board.message(self.name, host_ns)

    def start(self) -> None:
        self.relay.start()
        self.event(EventKind.CONNECT, f"relay {self.cfg.source} → {', '.join(self.cfg.sinks)} started")

    def stop(self) -> None:
        self.relay.stop(drain_s=0.0)

    def publish_stats(self) -> None:
        st = self.relay.stats()
        now = self.session.clock.now_ns()
        self.source.put(T.TOPIC_RELAY_STATS, self.session.timebase.host_to_utc(now), now, st.to_topic_dict())
        age = "-" if st.last_correction_age_s is None else f"{st.last_correction_age_s:.1f} s"
        self.session.board.update(
            self.name,
            detail=f"{st.state} {st.bytes_per_s / 1000:.2f} kB/s age {age} bad {st.rejected_frames} "
            f"drop {st.dropped_frames}",
        )
        if self.relay.error is not None and not self._reported_failure:
            self._reported_failure = True
            self.session.board.update(self.name, state=DeviceState.LOST, detail=f"FAILED: {self.relay.error}")
            self.event(EventKind.ERROR, f"relay stopped: {self.relay.error}", severity=Severity.ERROR)


class CanDevice(Device):
    """One CAN bus."""

    def __init__(self, session: RecordSession, cc: CanConfig) -> None:
        super().__init__(session, f"can.{cc.name}", "can", maxsize=50_000)
        self.cc = cc
        self.clock_name = f"can:{cc.name}"
        self._host_channel = f"{self.clock_name} host stamps"
        """The live map key of the frames without an interface stamp (``clock_name`` is the interface clock's)."""
        self.topic_frames = T.can_frames(cc.name)
        self.topic_roles = T.can_roles(cc.name)
        self.decoder: RoleDecoder | None = None
        if cc.roles:
            db = load_dbc(cc.dbc)
            rolemap = RoleMap.from_mapping(roles_table(cc), db, source=f"can.{cc.name}")
            self.decoder = RoleDecoder(db, rolemap)
        config = CanBusConfig.from_mapping(cc.model_dump(exclude={"dbc", "roles_file", "roles", "checks"}))
        self.bus = CanBusSession(config, self._on_frame, self._on_event, clock=session.clock,
                                 bus_factory=session.can_factory or open_bus,
                                 backoff_initial_s=session.reconnect_first_s, backoff_max_s=session.reconnect_max_s)
        self._lock = threading.Lock()
        self._flush_lock = threading.Lock()
        self._pending: list[T.CanFrameRecord] = []
        self._pending_since = 0
        self._pending_t = 0
        self.started = False
        self._next_try = 0.0

    def start(self) -> None:
        """Open the bus (a failure is an event; the session keeps retrying)."""
        try:
            self.bus.start()
        except RigError as exc:
            self._next_try = time.monotonic() + 2.0
            self.session.board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.ERROR, f"cannot open: {exc}", severity=Severity.ERROR)
            return
        self.started = True

    def retry(self) -> None:
        if not self.started and time.monotonic() >= self._next_try:
            self.start()

    def stop(self) -> None:
        if self.started:
            self.bus.stop()
        self.flush()

    def _on_frame(self, f: CanFrame) -> None:
        try:
            self._frame(f)
        except Exception as exc:  # never into the CAN session: it would stop reading
            self.failed_callback("frame handling", exc)

    def _frame(self, f: CanFrame) -> None:
        s = self.session
        ff = f.flags
        if ff is CanFrameFlag.NONE:  # the common case, without enum arithmetic
            flags = _RX | (_EXTENDED if f.is_extended else 0) | (_FD if f.is_fd else 0)
        else:
            flags = (
                (_EXTENDED if f.is_extended else 0) | (_FD if f.is_fd else 0)
                | (0 if ff & CanFrameFlag.TX_ECHO else _RX)
                | (int(T.CanFlag.ERROR) if ff & CanFrameFlag.ERROR_FRAME else 0)
                | (int(T.CanFlag.REMOTE) if ff & CanFrameFlag.REMOTE else 0)
                | (int(T.CanFlag.BRS) if ff & CanFrameFlag.BITRATE_SWITCH else 0)
                | (int(T.CanFlag.ESI) if ff & CanFrameFlag.ERROR_STATE_INDICATOR else 0)
            )
        can_flags = _CAN_FLAGS.get(flags)
        if can_flags is None:
            can_flags = _CAN_FLAGS.setdefault(flags, T.CanFlag(flags))
        rec = T.CanFrameRecord(f.device_ts_ns, f.host_ts_ns, f.arbitration_id, can_flags, f.dlc, f.data)
        tb = s.timebase
        if f.device_ts_ns is not None:  # every stamped frame feeds the interface clock's estimate
            t = tb.device_to_utc(self.clock_name, f.device_ts_ns, f.host_ts_ns)
        else:  # host receive times: the host → GPS map, which must not run back either
            t = tb.live_host_to_utc(self._host_channel, f.host_ts_ns)
        with self._lock:
            if not self._pending:
                self._pending_since = f.host_ts_ns
                self._pending_t = t
            self._pending.append(rec)
            full = len(self._pending) >= _CAN_BLOCK_FRAMES or f.host_ts_ns - self._pending_since >= CAN_BLOCK_AGE_NS
        if full:
            self.flush()
        s.board.message(self.name, f.host_ts_ns)
        if self.decoder is None or (ff is not CanFrameFlag.NONE and ff & _NOT_DATA):
            return
        dec = self.decoder.decode(f.arbitration_id, f.data, t, f.is_extended)
        if dec.message is None or not (dec.samples or dec.flags):
            return
        bits = int(dec.flags)
        roles: dict[str, float | None] = {}
        for sample in dec.samples:
            v = sample.value
            roles[sample.role] = v if v == v and abs(v) != math.inf else None
            bits |= int(sample.flags)
            if sample.role == "lat_accel" and not sample.flags and not dec.flags:
                s.ltr.add(t, v)
        if bits:
            names = _FLAG_NAMES.get(bits)
            if names is None:
                names = _FLAG_NAMES.setdefault(bits, FrameFlag(bits).names())
            bad = list(names)
        else:
            bad = []
        valid = not bits
        self.source.put(self.topic_roles, t, f.host_ts_ns, {
            "can_id": f.arbitration_id, "message": dec.message,
            "device_time": T.CAN_DEVICE_TIME.to_json(f.device_ts_ns), "roles": roles, "valid": valid, "flags": bad,
        })

    def flush(self, older_than_ns: int | None = None) -> None:
        """Put the pending frames as one block (only if the oldest is older than ``older_than_ns``).

        Called by the reader (a full block) and the session's housekeeping (an old one): taking the
        block and putting it is one step, or a block taken later could be put first (log_time back).
        Its log time is its first frame's live common time (monotonic: rig.timebase.Timebase).
        """
        with self._flush_lock:
            with self._lock:
                if not self._pending or (older_than_ns is not None and self._pending_since > older_than_ns):
                    return
                frames, self._pending, t = self._pending, [], self._pending_t
            self.source.put(self.topic_frames, t, frames[0].host_ts_ns, T.pack_can_block(frames))

    def _on_event(self, ev: BusEvent) -> None:
        try:
            self._event(ev)
        except Exception as exc:
            self.failed_callback("event handling", exc)

    def _event(self, ev: BusEvent) -> None:
        board = self.session.board
        if isinstance(ev, BusStats):
            load = "-" if ev.bus_load_pct is None else f"{ev.bus_load_pct:.1f} %"
            board.update(self.name, detail=f"{ev.frames_per_s:.0f} fr/s load {load} err {ev.error_frames_total} "
                         f"{ev.state.value}")
        elif isinstance(ev, BusOpened):
            board.update(self.name, state=DeviceState.OK)
            self.event(EventKind.CONNECT, f"{ev.interface} {ev.channel} open ({ev.timestamp_source.value} stamps)",
                       host_ns=ev.host_ts_ns, channel_info=ev.channel_info)
        elif isinstance(ev, BusLost):
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.DISCONNECT, ev.reason, severity=Severity.WARNING, host_ns=ev.host_ts_ns)
        elif isinstance(ev, BusGap):
            tb = self.session.timebase
            self.source.gap(tb.host_to_utc(ev.start_ns), tb.host_to_utc(ev.end_ns),
                            f"no frames for {(ev.end_ns - ev.start_ns) / 1e9:.3f} s: {ev.reason}",
                            recovered=ev.recovered, reopen_attempts=ev.reopen_attempts)
            if self.decoder is not None:
                self.decoder.reset()
        elif isinstance(ev, BusStateChanged):
            bad = ev.state in (BusState.WARNING, BusState.PASSIVE, BusState.BUS_OFF)
            if not bad and ev.previous in (BusState.DISCONNECTED, BusState.UNKNOWN):
                return  # opening (reported as a connect) or a state the interface cannot tell
            self.event(EventKind.WARNING if bad else EventKind.INFO,
                       f"controller {ev.previous.value} → {ev.state.value}",
                       severity=Severity.WARNING if bad else Severity.INFO, host_ns=ev.host_ts_ns)


def roles_table(cc: CanConfig) -> dict[str, Any]:
    """The ``roles``/``checks`` tables of a bus (what its ``<bus>.roles.toml`` attachment holds)."""
    return {
        "roles": {k: v.model_dump(exclude_none=True) for k, v in cc.roles.items()},
        "checks": {k: v.model_dump(exclude_none=True) for k, v in cc.checks.items()},
    }


class DaqDevice(Device):
    """The DAQ and the optical sensors it reads."""

    def __init__(self, session: RecordSession, dc: DaqConfig) -> None:
        super().__init__(session, f"daq.{dc.device}", "daq", maxsize=20_000)
        self.dc = dc
        self.clock_name = f"daq:{dc.device}"
        self.topic_samples = T.daq_samples(dc.device)
        self.ns_per_sample = NS_PER_S / dc.rate_hz
        cal = session.cfg.profile.calibration
        names = {c.name for c in dc.channels}
        self.optical: list[OpticalSensorSpec] = []
        for o in session.cfg.profile.optical:
            chans = [ch.daq_channel for ch in o.channels.values() if ch.daq_channel is not None]
            if chans and all(c in names for c in chans):
                self.optical.append(OpticalSensorSpec.from_config(
                    o.model_dump(), zero_offset_deg=cal.optical_zero_deg.get(o.name, 0.0), where=f"optical.{o.name}"))
        self.step = max(1, round(dc.rate_hz / _OPTICAL_MAX_HZ))
        self._lock = threading.Lock()
        self._segment = 0
        self._base = 0
        self._next_index = 0
        self._last_host = 0
        self.segments: dict[int, DaqSegmentTiming] = {}
        """Per acquisition (the DAQ's segment number): its own sync fit or host mapping."""
        self._latency_ns = 0
        self.lost = 0
        factory = session.daq_factory
        if factory is not None:
            self.daq = factory(dc, session.clock, self._on_block, self._on_event)
        else:
            self.daq = DaqSession.from_config(dc.model_dump(), on_block=self._on_block, on_event=self._on_event,
                                              clock=session.clock)

    def start(self) -> None:
        self.daq.start()

    def stop(self) -> None:
        self.daq.stop()

    def _index_base(self, segment: int, host_ns: int) -> int:
        """File sample index of index 0 of ``segment``: indices stay unique across reconnects.

        A new segment starts after the last index seen plus the samples the host time says were
        missed (its true position comes from the sync pulse; the estimate only keeps the order).
        """
        with self._lock:
            if segment != self._segment:
                if self._segment:
                    gap = max(0, round((host_ns - self._last_host) / self.ns_per_sample))
                    self._base = self._next_index + gap
                self._segment = segment
                self.segments[segment] = DaqSegmentTiming(segment, self._base)
            return self._base

    def _on_block(self, block: DaqBlock) -> None:
        try:
            self._block(block)
        except Exception as exc:  # an exception here would end the DAQ session
            self.failed_callback("block handling", exc)

    def _block(self, block: DaqBlock) -> None:
        s = self.session
        host = block.host_time_ns
        base = self._index_base(block.segment, host)
        first = base + block.first_sample_index
        n = block.n_samples
        with self._lock:
            self._next_index = first + n
            self._last_host = host
            seg = self._segment_of(block.segment, base)
            # lower envelope of the receive times: host time of the segment's index 0, at the nominal rate
            off = host - round((first + n - 1 - base) * self.ns_per_sample)
            seg.host_offset_ns = off if seg.host_offset_ns is None else min(seg.host_offset_ns, off)
        if block.lost_before is not None:
            self.lost += block.lost_before.count
        s.timebase.clock(self.clock_name).add(round((first + n - 1) * self.ns_per_sample), host)
        payload = T.pack_daq_block(T.DaqBlock(first, block.rate_hz, block.channels,
                                              np.asarray(block.data, dtype=np.float32)))
        t = self.sample_utc(np.asarray([first], dtype=np.float64), seg)
        self.source.put(self.topic_samples, int(t[0]), host, payload)
        s.board.message(self.name, host)
        for spec in self.optical:
            sample = convert_block(spec, block)
            sel = np.arange((-first) % self.step, n, self.step)
            if sel.size == 0:
                continue
            times = self.sample_utc((first + sel).astype(np.float64), seg)
            records = sample.records()
            topic = T.optical(spec.name)
            for i, ti in zip(sel.tolist(), times.tolist(), strict=True):
                rec = records[i]
                rec["sample_index"] = first + i
                self.source.put(topic, ti, host, rec)

    def _segment_of(self, number: int, base: int) -> DaqSegmentTiming:
        seg = self.segments.get(number)
        if seg is None:  # the driver's first segment (or an index_base call raced us)
            seg = self.segments[number] = DaqSegmentTiming(number, base)
        return seg

    def current_segment(self) -> DaqSegmentTiming | None:
        with self._lock:
            return self.segments.get(self._segment)

    @property
    def fit(self) -> SyncFit | None:
        """The sync fit of the current acquisition (None until it has enough edges matched to marks)."""
        seg = self.current_segment()
        return None if seg is None else seg.fit

    def sample_utc(self, index: np.ndarray, seg: DaqSegmentTiming | None = None) -> np.ndarray:
        """Common-time-base times (int64 ns) of file sample indices of one acquisition (default: the current).

        Each acquisition is timed on its own (the sample index restarts with a reconnect and the
        file's index after one is only an estimate): from its own sync fit once two or more of its
        edges match marks; before that from the host mapping (:meth:`host_utc`), and marked so.
        """
        tb = self.session.timebase
        seg = seg if seg is not None else self.current_segment()
        if seg is None:
            return np.round(index * self.ns_per_sample).astype(np.int64)
        fit = seg.fit
        if fit is not None and tb.leap_seconds is not None:
            return fit.gps_ns(index) + (GPS_EPOCH_UNIX_NS - tb.leap_seconds * NS_PER_S)
        return self.host_utc(index, seg)

    def _period_ns(self) -> float:
        """Sample period: from a synchronised acquisition (one oscillator), else the host estimate, else nominal."""
        with self._lock:
            fits = [s.fit for s in self.segments.values() if s.fit is not None]
        if fits:
            return float(fits[-1].map.slope)
        f = self.session.timebase.clock(self.clock_name).fit()
        if f is not None and self.session.timebase.clock(self.clock_name).status() is FitStatus.OK:
            return self.ns_per_sample * f[2]
        return self.ns_per_sample

    def host_utc(self, index: np.ndarray, seg: DaqSegmentTiming) -> np.ndarray:
        """Host-clock times of ``seg``'s samples on the common base: the lower envelope of its blocks'
        receive times less the DAQ's delivery latency measured on a synchronised acquisition (as the
        offline reader, :meth:`rig.dataset.Session.daq`, does for a segment without sync edges)."""
        tb = self.session.timebase
        off = seg.host_offset_ns
        if off is None:
            return np.round(index * self.ns_per_sample).astype(np.int64)
        host = off + np.round((np.asarray(index, dtype=np.float64) - seg.base) * self._period_ns()).astype(np.int64)
        return np.asarray([tb.host_to_utc(int(h)) for h in host], dtype=np.int64) - self._latency_ns

    def _on_event(self, ev: DaqEvent) -> None:
        try:
            self._event(ev)
        except Exception as exc:
            self.failed_callback("event handling", exc)

    def _event(self, ev: DaqEvent) -> None:
        k = ev.kind
        board = self.session.board
        if k is DaqEventKind.SYNC_EDGE:
            if ev.edge_index is not None:
                base = self._index_base(ev.segment, ev.host_time_ns)
                with self._lock:
                    self._segment_of(ev.segment, base).edges.append(base + ev.edge_index)
            return
        details: dict[str, Any] = {"segment": ev.segment}
        if ev.channel is not None:
            details["channel"] = ev.channel
        if ev.sample_index is not None:
            details["sample_index"] = ev.sample_index
        if ev.count is not None:
            details["count"] = ev.count
        if k in (DaqEventKind.STARTED, DaqEventKind.RECONNECTED):
            board.update(self.name, state=DeviceState.OK)
            details["time_source"] = "host"  # until this acquisition's own sync edges are matched
            self.event(EventKind.CONNECT, ev.message, host_ns=ev.host_time_ns, **details)
        elif k is DaqEventKind.DISCONNECTED:
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.DISCONNECT, ev.message, severity=Severity.WARNING, host_ns=ev.host_time_ns,
                       **details)
        elif k in (DaqEventKind.CONNECT_FAILED, DaqEventKind.ERROR):
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.ERROR, ev.message, severity=Severity.ERROR, host_ns=ev.host_time_ns, **details)
        elif k is DaqEventKind.OVERFLOW:
            self.event(EventKind.OVERFLOW, ev.message, severity=Severity.WARNING, host_ns=ev.host_time_ns, **details)
        elif k in (DaqEventKind.SATURATION, DaqEventKind.STUCK, DaqEventKind.FLOATING):
            board.update(self.name, state=DeviceState.DEGRADED)
            self.event(EventKind.WARNING, ev.message, severity=Severity.WARNING, host_ns=ev.host_time_ns, **details)
        elif k in (DaqEventKind.SATURATION_CLEARED, DaqEventKind.STUCK_CLEARED, DaqEventKind.FLOATING_CLEARED):
            self.event(EventKind.INFO, ev.message, host_ns=ev.host_time_ns, **details)
        elif k is DaqEventKind.STOPPED:
            board.update(self.name, state=DeviceState.STOPPED)

    def refresh(self) -> None:
        """Status-board detail: rate, channels, lost samples, and the current acquisition's sync fit."""
        detail = f"{self.dc.rate_hz:g} Hz × {len(self.dc.channels)} ch, lost {self.lost}"
        seg = self.current_segment()
        if seg is not None and seg.fit is None and len(seg.edges) >= 2 and len(seg.edges) != seg.fit_counts[0]:
            # a fresh acquisition (start, reconnect) gets its own fit as soon as it has two edges,
            # not at the next time-base period
            self.session._align_daq()  # the session owns the marks
            seg = self.current_segment()
        fit = None if seg is None else seg.fit
        if seg is not None and fit is not None:
            detail += (f", sync {fit.matched_edges.size} edges rms {fit.rms_ns / 1e3:.1f} µs "
                       f"drift {fit.drift_ppm:+.1f} ppm")
        else:
            n = 0 if seg is None else len(seg.edges)
            detail += f", {n} sync edges, not aligned yet (host clock)"
        if seg is not None and seg.number > 1:
            detail += f", acquisition {seg.number}"
        self.session.board.update(self.name, detail=detail)

    def align(self, marks: Sequence[int]) -> None:
        """Refit each acquisition's sample index → GPS time from its own sync edges and the marks (when
        there is something new). An acquisition without two matched edges yet keeps the host mapping."""
        tb = self.session.timebase
        marks_a = np.asarray(marks, dtype=np.int64)
        with self._lock:
            todo = [(seg, np.asarray(seg.edges, dtype=np.float64)) for seg in self.segments.values()]
        latest: SyncFit | None = None
        for seg, edges in todo:
            counts = (edges.size, marks_a.size)
            if edges.size >= 2 and marks_a.size >= 2 and counts != seg.fit_counts:
                self._align_segment(seg, edges, marks_a)
                seg.fit_counts = counts
            if seg.fit is not None:
                latest = seg.fit
        if latest is not None:
            tb.set_daq(latest)

    def _align_segment(self, seg: DaqSegmentTiming, edges: np.ndarray, marks: np.ndarray) -> None:
        tb = self.session.timebase
        approx: np.ndarray | None = None
        if seg.fit is not None:
            approx = seg.fit.gps_ns(edges)
        elif tb.leap_seconds is not None and seg.host_offset_ns is not None:
            approx = self.host_utc(edges, seg) - (GPS_EPOCH_UNIX_NS - tb.leap_seconds * NS_PER_S)
        # the fit's clock name says which acquisition it is (the first keeps the device's name)
        name = self.dc.device if seg.number <= 1 else f"{self.dc.device}#{seg.number}"
        try:
            fit = align_sync_pulses(name, edges, marks, self.dc.rate_hz, approx_gps_ns=approx)
        except AnalysisError as exc:
            log.debug("DAQ %s acquisition %d: no sync fit yet: %s", self.dc.device, seg.number, exc)
            return
        first = seg.fit is None
        if first and tb.leap_seconds is not None and seg.host_offset_ns is not None:
            # the DAQ's delivery latency (host receive − true time), for acquisitions without a fit
            utc0 = int(fit.gps_ns(np.asarray([seg.base], dtype=np.float64))[0]) + (
                GPS_EPOCH_UNIX_NS - tb.leap_seconds * NS_PER_S)
            self._latency_ns = tb.host_to_utc(seg.host_offset_ns) - utc0
        seg.fit = fit
        if first:
            self.event(EventKind.INFO, f"acquisition {seg.number} synchronised to the sync pulse "
                       f"({fit.matched_edges.size} edges, rms {fit.rms_ns / 1e3:.1f} µs); its times before this "
                       "were from the host clock", segment=seg.number, time_source="sync_pulse")


@dataclass(slots=True)
class DaqSegmentTiming:
    """Live timing state of one DAQ acquisition (a segment: the sample index restarts with a reconnect)."""

    number: int
    """The DAQ driver's segment number (1 for the first acquisition)."""
    base: int
    """File sample index of the segment's index 0."""
    edges: list[float] = field(default_factory=list)
    """File sample indices of its sync edges."""
    host_offset_ns: int | None = None
    """Lower envelope of the host receive times, as the host time of index ``base`` (nominal rate)."""
    fit: SyncFit | None = None
    """Its own sync fit (None: too few edges matched yet; times come from the host clock)."""
    fit_counts: tuple[int, int] = (0, 0)

    @property
    def time_source(self) -> str:
        """``sync_pulse`` or ``host`` (not synchronised yet)."""
        return "sync_pulse" if self.fit is not None else "host"


class LiveLtr:
    """The live rollover index for the dashboard: LTR from the CAN lateral acceleration (role
    ``lat_accel``, body-fixed) through the roll model of the vehicle profile, and its AR prediction
    (:mod:`rig.analysis.rollover`) over the last few seconds."""

    def __init__(self, cfg: SessionConfig, history_s: float = 4.0, rate_hz: float = 50.0) -> None:
        v = cfg.profile.vehicle
        self._vehicle = v
        self._history_ns = round(history_s * NS_PER_S)
        self._rate_hz = rate_hz
        self._lock = threading.Lock()
        self._samples: deque[tuple[int, float]] = deque()
        self._model: Any = None
        self._failed = False
        self._last: tuple[tuple[int, int], dict[str, float | bool]] | None = None  # ((newest stamp, samples), figures)

    def add(self, t_ns: int, ay_body: float) -> None:
        with self._lock:
            self._samples.append((t_ns, ay_body))
            while self._samples and self._samples[0][0] < t_ns - self._history_ns:
                self._samples.popleft()

    def figures(self) -> dict[str, float | bool]:
        """``ltr``, ``ltr_predicted`` (the largest predicted magnitude, signed) and ``ltr_warning``; {} without data.

        Computed again only when samples came since the last call (the dashboard asks at its own pace
        in wall time; a slowed or paused simulated clock brings none), and only the newest epochs' AR
        prediction (``predict_ltr``'s ``tail_s``: the same figures for a fraction of the fits)."""
        with self._lock:
            if len(self._samples) < 2 or self._failed:
                return {}
            key = (self._samples[-1][0], len(self._samples))
            if self._last is not None and self._last[0] == key:
                return dict(self._last[1])
            data = list(self._samples)
        figures = self._compute(data)
        self._last = (key, figures)
        return dict(figures)

    def _compute(self, data: list[tuple[int, float]], *, whole_window: bool = False) -> dict[str, float | bool]:
        """The figures of ``data``; ``whole_window``: the AR prediction over the whole window, not only its
        newest epochs (the same figures, for checking)."""
        from rig.analysis.rollover import CONFIRM_S, RollModel, horizontal_ay, ltr_from_lateral, predict_ltr

        v = self._vehicle
        try:
            if self._model is None:
                self._model = RollModel.from_vehicle(v)
            t_ns = np.asarray([d[0] for d in data], dtype=np.int64)
            t = (t_ns - t_ns[0]) / 1e9
            grid = np.arange(0.0, t[-1], 1.0 / self._rate_hz)
            if grid.size < 2 * self._rate_hz:
                return {}
            ay = np.interp(grid, t, np.asarray([d[1] for d in data], dtype=np.float64))
            roll, _acc = self._model.roll_from_body_ay(grid, ay)
            track = 0.5 * (v.track_front_m + v.track_rear_m)
            ltr = ltr_from_lateral(horizontal_ay(ay, roll), roll, cg_height_m=v.cg_height_m,
                                   roll_axis_height_m=v.roll_axis_height_m, track_m=track)
            recent = grid >= grid[-1] - 3.5
            pred = predict_ltr(grid[recent], ltr[recent], window_s=3.0, tail_s=None if whole_window else CONFIRM_S)
        except (AnalysisError, ValueError, np.linalg.LinAlgError) as exc:
            self._failed = True  # a model the profile cannot give: no live LTR rather than noise
            log.warning("live LTR switched off: %s", exc)
            return {}
        last = pred.predicted[-1]
        worst = float(last[np.nanargmax(np.abs(last))]) if np.any(np.isfinite(last)) else math.nan
        return {"ltr": float(ltr[-1]), "ltr_predicted": worst, "ltr_warning": bool(pred.warning[-1])}


