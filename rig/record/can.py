"""A CAN bus of a recording: every frame in blocks, the mapped roles decoded per frame, bus state as events."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import can

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.can.bus import (
    BusEvent,
    BusGap,
    BusLost,
    BusOpened,
    BusState,
    BusStateChanged,
    BusStats,
    CanBusConfig,
    CanBusLink,
    CanFrame,
    CanFrameFlag,
    FrameTime,
    open_bus,
)
from drivers.can.checks import FrameFlag
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap
from rig.core.config import CanConfig
from rig.core.topics import EventKind, Severity
from rig.record.device import Device, DeviceContext
from rig.record.status import DeviceState
from vsccore.errors import RigError

__all__ = ["CAN_BLOCK_AGE_NS", "CanDevice", "roles_table"]

log = logging.getLogger(__name__)


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


class CanDevice(Device):
    """One CAN bus."""

    def __init__(self, ctx: DeviceContext, cc: CanConfig,
                 bus_factory: Callable[[CanBusConfig], can.BusABC] | None = None) -> None:
        super().__init__(ctx, f"can.{cc.name}", "can", maxsize=50_000)
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
        self._interface_stamps = config.uses_interface_stamps
        """Interface stamps place the frames in time (``timestamp_source``); else the host receive times do."""
        self.bus = CanBusLink(config, self._on_frame, self._on_event, clock=ctx.clock,
                                 bus_factory=bus_factory or open_bus,
                                 backoff_initial_s=ctx.reconnect.first_s, backoff_max_s=ctx.reconnect.max_s)
        self._lock = threading.Lock()
        self._flush_lock = threading.Lock()
        self._pending: list[T.CanFrameRecord] = []
        self._pending_since = 0
        self._pending_t = 0
        self.started = False
        self._next_try = 0.0
        self._noted = False

    def start(self) -> None:
        """Open the bus (a failure is an event; the session keeps retrying)."""
        try:
            self.bus.start()
        except RigError as exc:
            self._next_try = time.monotonic() + 2.0
            self.ctx.board.update(self.name, state=DeviceState.LOST)
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
        s = self.ctx
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
        if f.device_ts_ns is not None and self._interface_stamps:  # feeds the interface clock's estimate
            t = tb.device_to_utc(self.clock_name, f.device_ts_ns, f.host_ts_ns)
        else:  # host receive times (no stamp, or timestamp_source = "host"): the host → GPS map, which
            # must not run back either; the interface's stamp stays in the record as its device time
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
                s.on_lateral_accel(t, v)
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
        Its log time is its first frame's live common time (monotonic: rig.core.timebase.Timebase).
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
        board = self.ctx.board
        if isinstance(ev, BusStats):
            load = "-" if ev.bus_load_pct is None else f"{ev.bus_load_pct:.1f} %"
            board.update(self.name, detail=f"{ev.frames_per_s:.0f} fr/s load {load} err {ev.error_frames_total} "
                         f"{ev.state.value}")
        elif isinstance(ev, BusOpened):
            board.update(self.name, state=DeviceState.OK)
            times = (f"{ev.timestamp_source.value} stamps" if ev.frame_time is FrameTime.INTERFACE
                     else f"host receive times; {ev.timestamp_source.value} stamps kept")
            mode = {True: ", listen-only", False: ", active", None: ""}[ev.listen_only]
            self.event(EventKind.CONNECT, f"{ev.interface} {ev.channel} open ({times}{mode})",
                       host_ns=ev.host_ts_ns, channel_info=ev.channel_info, timestamp_source=ev.frame_time.value,
                       listen_only=ev.listen_only)
            if not self._noted:  # the same on every reopen: once is enough
                self._noted = True
                for note in ev.notes:
                    self.event(EventKind.WARNING, note, severity=Severity.WARNING, host_ns=ev.host_ts_ns)
        elif isinstance(ev, BusLost):
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.DISCONNECT, ev.reason, severity=Severity.WARNING, host_ns=ev.host_ts_ns)
        elif isinstance(ev, BusGap):
            tb = self.ctx.timebase
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

