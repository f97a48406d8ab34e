"""A device of the recording: the narrow context it may ask the recording for, and the common base."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from drivers.novatel import BestPos
from rig.core.config import ReceiverConfig
from rig.core.timebase import Timebase
from rig.core.topics import EventKind, Severity
from rig.record.status import StatusBoard
from rig.store import Source
from vsccore.clock import Clock

if TYPE_CHECKING:
    pass

__all__ = ["Device", "DeviceContext", "Reconnect"]

log = logging.getLogger(__name__)




@dataclass(frozen=True, slots=True)
class Reconnect:
    """Back-off of a device's reconnects: the first wait, doubling up to the longest."""

    first_s: float = 0.1
    max_s: float = 2.0


class DeviceContext(Protocol):
    """What a device may ask of the recording: its source, the clock, the time base, the status board, and
    the few things the recording joins across devices (positions, marks, the DAQ alignment, the live LTR)."""

    @property
    def clock(self) -> Clock: ...
    @property
    def timebase(self) -> Timebase: ...
    @property
    def board(self) -> StatusBoard: ...
    @property
    def reconnect(self) -> Reconnect: ...

    def source(self, name: str, maxsize: int) -> Source:
        """The device's own recorder source."""
        ...

    def on_position(self, receiver: ReceiverConfig, gps_ns: int, pos: BestPos) -> None:
        """A BESTPOS of a receiver (the live baseline, the relay's view of the differential age)."""
        ...

    def on_mark(self, receiver: str, gps_ns: int, *, from_marktime: bool) -> None:
        """A sync-switch event seen by a receiver."""
        ...

    def on_lateral_accel(self, t_ns: int, ay_mps2: float) -> None:
        """A valid body-fixed lateral acceleration from CAN (the live LTR)."""
        ...

    def align_daq(self) -> None:
        """Align the DAQ to the sync-switch marks gathered so far."""
        ...


class Device:
    """Common part: a recorder source, a status-board line and error counting."""

    def __init__(self, ctx: DeviceContext, name: str, kind: str, maxsize: int) -> None:
        self.ctx = ctx
        self.name = name
        self.source: Source = ctx.source(name, maxsize=maxsize)
        self.errors = 0
        ctx.board.add_device(name, kind)

    def event(self, kind: EventKind, text: str, *, severity: Severity = Severity.INFO, host_ns: int | None = None,
              **details: Any) -> None:
        s = self.ctx
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
            self.ctx.board.error(self.name)


