"""The CAN controller's error state (error active, warning, passive, bus-off) as each interface reports it.

Interfaces report it in different ways, and python-can passes most of them up unchanged:

- SocketCAN sends *error frames* (``linux/can/error.h``): the error class in the identifier
  (``CAN_ERR_CRTL``, ``CAN_ERR_BUSOFF``, ``CAN_ERR_RESTARTED``), the controller status in
  ``data[1]`` and, with ``CAN_ERR_CNT``, the counters in ``data[6..7]``. socketcand forwards the
  class only (``< error CLASS … >``: no data, so bus-off and restart are seen, warning and passive
  are not); the simulated devices use the same encoding on the virtual bus.
- PCAN's error frames carry PCAN's own error codes, not SocketCAN's: the state comes from
  ``PcanBus.status()`` (``CAN_GetStatus``: ``PCAN_ERROR_BUSWARNING``, ``…_BUSPASSIVE``,
  ``…_BUSOFF``), and ``recv`` raises while the controller is error passive or bus-off.
  ``PcanBus.state`` is *not* the error state: it is the listen-only switch (PASSIVE = listen-only).
- Vector reports chip-state events (``XL_CHIP_STATE`` / ``XL_CAN_EV_TAG_CHIP_STATE``: bus status and
  both counters) that python-can hands to ``VectorBus.handle_can_event`` / ``handle_canfd_event``
  and otherwise drops; the rig hooks them and asks for one with ``xlCanRequestChipState``.
- Kvaser: python-can wraps no status call; CANlib's ``canReadStatus`` (``canSTAT_*`` flags) and
  ``canReadErrorCounters`` are called on the bus's handle.

A :class:`ControllerMonitor` per interface turns these into :class:`ControllerReport`s.
"""

from __future__ import annotations

import ctypes
import enum
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

__all__ = [
    "CAN_ERR_BUSOFF",
    "CAN_ERR_CNT",
    "CAN_ERR_CRTL",
    "CAN_ERR_CRTL_ACTIVE",
    "CAN_ERR_CRTL_RX_PASSIVE",
    "CAN_ERR_CRTL_RX_WARNING",
    "CAN_ERR_CRTL_TX_PASSIVE",
    "CAN_ERR_CRTL_TX_WARNING",
    "CAN_ERR_RESTARTED",
    "BusState",
    "ControllerMonitor",
    "ControllerReport",
    "KvaserStatus",
    "NoControllerState",
    "PcanStatus",
    "SocketcanErrorFrames",
    "VectorChipState",
    "controller_monitor_for",
    "error_counters_from_error_frame",
    "socketcan_error_frame",
    "state_from_error_frame",
]

log = logging.getLogger(__name__)


class BusState(enum.Enum):
    """Controller state as far as the interface lets us see it."""

    UNKNOWN = "unknown"
    """The interface reports no state (an interface the rig does not know, or none reported yet)."""
    ACTIVE = "active"
    WARNING = "warning"
    """Error counters above 96: still error active, but the bus is in trouble."""
    PASSIVE = "passive"
    BUS_OFF = "bus_off"
    DISCONNECTED = "disconnected"
    """The interface is closed: being reopened after a failure, or the session is stopped."""


@dataclass(frozen=True, slots=True)
class ControllerReport:
    """What one report of the controller said (None: not said)."""

    state: BusState | None
    tx_errors: int | None = None
    rx_errors: int | None = None

    @property
    def counters(self) -> tuple[int, int] | None:
        """``(TEC, REC)`` when both were reported."""
        if self.tx_errors is None or self.rx_errors is None:
            return None
        return self.tx_errors, self.rx_errors


class ControllerMonitor:
    """Reads the controller state of one kind of interface; the base reports nothing."""

    name = "none"
    restarts_itself = False
    """After bus-off the controller comes back by itself (SocketCAN with ``restart-ms``): wait for it."""
    note: str | None = None
    """What the rig cannot see on this interface (shown when the bus opens)."""

    def attach(self, bus: can.BusABC) -> None:
        """Called with every newly opened bus."""

    def from_error_frame(self, msg: can.Message) -> ControllerReport | None:
        """The report an error frame carries (None: it carries none)."""
        return None

    def poll(self, bus: can.BusABC) -> ControllerReport | None:
        """The state now, asked of the interface (None: it cannot be asked)."""
        return None

    def on_receive_error(self, bus: can.BusABC, exc: BaseException) -> ControllerReport | None:
        """The state behind a failed ``recv`` (None: the failure is not a controller state)."""
        return None


class NoControllerState(ControllerMonitor):
    """An interface the rig does not know: no state is decoded (python-can's ``BusABC.state`` means
    different things on different backends, and error-frame encodings differ)."""

    def __init__(self, interface: str) -> None:
        self.name = interface
        self.note = (f"controller state is not decoded for interface {interface!r} "
                     "(known: socketcan, socketcand, virtual, pcan, vector, kvaser)")


# --- SocketCAN error frames (linux/can/error.h) ----------------------------------------------------

CAN_ERR_CRTL = 0x004
"""Error class: controller problem, status in ``data[1]``."""
CAN_ERR_BUSOFF = 0x040
CAN_ERR_RESTARTED = 0x100
"""The controller was restarted after bus-off (SocketCAN's ``restart-ms`` or ``ip link … restart``)."""
CAN_ERR_CNT = 0x200
"""``data[6]`` = TX error counter, ``data[7]`` = RX error counter."""
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
_CRTL_WARNING = CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING
_CRTL_PASSIVE = CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE


def socketcan_error_frame(error_class: int, *, status: int = 0, tx_errors: int | None = None,
                          rx_errors: int | None = None, timestamp: float = 0.0) -> can.Message:
    """A SocketCAN error frame (8 bytes) of ``error_class``, with the controller ``status`` in
    ``data[1]`` and, when given, the counters in ``data[6..7]`` (``CAN_ERR_CNT`` then set)."""
    data = bytearray(8)
    data[1] = status
    if tx_errors is not None and rx_errors is not None:
        error_class |= CAN_ERR_CNT
        data[6], data[7] = min(tx_errors, 255), min(rx_errors, 255)
    return can.Message(timestamp=timestamp, arbitration_id=error_class, is_error_frame=True, is_extended_id=False,
                       data=bytes(data), dlc=8)


def state_from_error_frame(msg: can.Message) -> BusState | None:
    """Controller state that a SocketCAN-style error frame announces (None if it announces none)."""
    cls = msg.arbitration_id
    if cls & CAN_ERR_BUSOFF:
        return BusState.BUS_OFF
    if cls & CAN_ERR_RESTARTED:
        return BusState.ACTIVE
    if cls & CAN_ERR_CRTL and len(msg.data) > 1:
        status = msg.data[1]
        if status & _CRTL_PASSIVE:
            return BusState.PASSIVE
        if status & _CRTL_WARNING:
            return BusState.WARNING
        if status & CAN_ERR_CRTL_ACTIVE:
            return BusState.ACTIVE
    return None


def error_counters_from_error_frame(msg: can.Message) -> tuple[int, int] | None:
    """``(TEC, REC)`` reported by a SocketCAN-style error frame (None if it carries no counters)."""
    if msg.arbitration_id & CAN_ERR_CNT and len(msg.data) >= 8:
        return int(msg.data[6]), int(msg.data[7])
    return None


class SocketcanErrorFrames(ControllerMonitor):
    """SocketCAN's error frames (also forwarded by socketcand, and used by the simulated devices)."""

    restarts_itself = True

    def __init__(self, interface: str = "socketcan") -> None:
        self.name = interface
        if interface == "socketcand":
            self.note = ("socketcand forwards the error class without its data: bus-off and restarts are "
                         "reported, error warning and passive are not")

    def from_error_frame(self, msg: can.Message) -> ControllerReport | None:
        state = state_from_error_frame(msg)
        counters = error_counters_from_error_frame(msg)
        if state is None and counters is None:
            return None
        tx, rx = counters if counters is not None else (None, None)
        return ControllerReport(state, tx, rx)


# --- PCAN -------------------------------------------------------------------------------------------

# PCAN-Basic status codes (python-can's can/interfaces/pcan/basic.py)
PCAN_ERROR_BUSLIGHT = 0x00004
PCAN_ERROR_BUSHEAVY = 0x00008  # = PCAN_ERROR_BUSWARNING: an error counter reached the warning limit
PCAN_ERROR_BUSOFF = 0x00010
PCAN_ERROR_BUSPASSIVE = 0x40000


def _int(value: Any) -> int:
    """A ctypes status (``TPCANStatus``) or a plain int as int."""
    return int(getattr(value, "value", value))


def pcan_state(status: int) -> BusState:
    """:class:`BusState` of a ``CAN_GetStatus`` result."""
    if status & PCAN_ERROR_BUSOFF:
        return BusState.BUS_OFF
    if status & PCAN_ERROR_BUSPASSIVE:
        return BusState.PASSIVE
    if status & (PCAN_ERROR_BUSHEAVY | PCAN_ERROR_BUSLIGHT):
        return BusState.WARNING
    return BusState.ACTIVE


class PcanStatus(ControllerMonitor):
    """PCAN: ``PcanBus.status()`` polled, and asked again when ``recv`` fails (it raises while error
    passive or bus-off). Error frames carry PCAN error codes: counted, not decoded."""

    name = "pcan"

    def poll(self, bus: can.BusABC) -> ControllerReport | None:
        status = getattr(bus, "status", None)
        if status is None:
            return None
        try:
            return ControllerReport(pcan_state(_int(status())))
        except (can.CanError, OSError, ValueError, TypeError) as exc:
            log.debug("pcan: status() failed: %s", exc)
            return None

    def on_receive_error(self, bus: can.BusABC, exc: BaseException) -> ControllerReport | None:
        return self.poll(bus)


# --- Vector -----------------------------------------------------------------------------------------

# xldefine.py: XL_EventTags.XL_CHIP_STATE, XL_CANFD_RX_EventTags.XL_CAN_EV_TAG_CHIP_STATE, XL_BusStatus
XL_CHIP_STATE = 4
XL_CAN_EV_TAG_CHIP_STATE = 1033
XL_CHIPSTAT_BUSOFF = 0x01
XL_CHIPSTAT_ERROR_PASSIVE = 0x02
XL_CHIPSTAT_ERROR_WARNING = 0x04
XL_CHIPSTAT_ERROR_ACTIVE = 0x08


def _state_of_flags(flags: int, bits: tuple[int, int, int, int]) -> BusState | None:
    """The worst state whose bit is set, given the (bus-off, passive, warning, active) bits of a status word."""
    states = (BusState.BUS_OFF, BusState.PASSIVE, BusState.WARNING, BusState.ACTIVE)
    return next((state for bit, state in zip(bits, states, strict=True) if flags & bit), None)


def vector_state(bus_status: int) -> BusState | None:
    """:class:`BusState` of a Vector chip state's ``busStatus``."""
    return _state_of_flags(bus_status, (XL_CHIPSTAT_BUSOFF, XL_CHIPSTAT_ERROR_PASSIVE, XL_CHIPSTAT_ERROR_WARNING,
                                        XL_CHIPSTAT_ERROR_ACTIVE))


class VectorChipState(ControllerMonitor):
    """Vector: the chip-state events python-can passes to ``handle_can_event``/``handle_canfd_event``
    (hooked on each opened bus), asked for with ``xlCanRequestChipState`` at every poll."""

    name = "vector"

    def __init__(self) -> None:
        self._pending: ControllerReport | None = None

    def attach(self, bus: can.BusABC) -> None:
        # python-can documents these two methods as the place for non-message events (subclasses
        # implement them); the instance attributes take precedence over the class's empty methods
        bus.handle_can_event = self._can_event  # type: ignore[attr-defined]
        bus.handle_canfd_event = self._canfd_event  # type: ignore[attr-defined]

    def _can_event(self, event: Any) -> None:
        if int(event.tag) == XL_CHIP_STATE:
            self._chip(event.tagData.chipState)

    def _canfd_event(self, event: Any) -> None:
        if int(event.tag) == XL_CAN_EV_TAG_CHIP_STATE:
            self._chip(event.tagData.canChipState)

    def _chip(self, chip: Any) -> None:
        self._pending = ControllerReport(vector_state(int(chip.busStatus)), int(chip.txErrorCounter),
                                         int(chip.rxErrorCounter))

    def poll(self, bus: can.BusABC) -> ControllerReport | None:
        report, self._pending = self._pending, None
        driver = getattr(bus, "xldriver", None)
        if driver is not None:
            try:  # the answer comes as an event through recv, reported at the next poll
                driver.xlCanRequestChipState(bus.port_handle, bus.mask)  # type: ignore[attr-defined]
            except (can.CanError, OSError, AttributeError) as exc:
                log.debug("vector: xlCanRequestChipState failed: %s", exc)
        return report


# --- Kvaser -----------------------------------------------------------------------------------------

# canstat.h circuit status flags (python-can's kvaser/constants.py does not name them)
canSTAT_ERROR_PASSIVE = 0x01
canSTAT_BUS_OFF = 0x02
canSTAT_ERROR_WARNING = 0x04
canSTAT_ERROR_ACTIVE = 0x08

KvaserReader = Callable[[int], tuple[int, int | None, int | None]]
"""``handle → (canReadStatus flags, TEC, REC)``."""


def kvaser_state(flags: int) -> BusState | None:
    """:class:`BusState` of ``canReadStatus`` flags."""
    return _state_of_flags(flags, (canSTAT_BUS_OFF, canSTAT_ERROR_PASSIVE, canSTAT_ERROR_WARNING, canSTAT_ERROR_ACTIVE))


def _canlib_reader() -> KvaserReader | None:
    """``canReadStatus`` and ``canReadErrorCounters`` from Kvaser's CANlib (None when it is not installed)."""
    name = "canlib32" if sys.platform == "win32" else "libcanlib.so"
    try:
        lib = ctypes.WinDLL(name) if sys.platform == "win32" else ctypes.CDLL(name)  # type: ignore[attr-defined]
    except OSError:
        return None
    read_status = lib.canReadStatus
    read_status.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_ulong)]
    read_status.restype = ctypes.c_int
    read_counters = lib.canReadErrorCounters
    read_counters.argtypes = [ctypes.c_int] + [ctypes.POINTER(ctypes.c_uint)] * 3
    read_counters.restype = ctypes.c_int

    def read(handle: int) -> tuple[int, int | None, int | None]:
        flags = ctypes.c_ulong(0)
        if read_status(handle, ctypes.byref(flags)) < 0:
            raise OSError(f"canReadStatus failed on handle {handle}")
        tx, rx, overruns = ctypes.c_uint(0), ctypes.c_uint(0), ctypes.c_uint(0)
        if read_counters(handle, ctypes.byref(tx), ctypes.byref(rx), ctypes.byref(overruns)) < 0:
            return int(flags.value), None, None
        return int(flags.value), int(tx.value), int(rx.value)

    return read


class KvaserStatus(ControllerMonitor):
    """Kvaser: CANlib's ``canReadStatus`` and ``canReadErrorCounters`` on the bus's read handle, polled.
    ``reader`` replaces CANlib (tests)."""

    name = "kvaser"

    def __init__(self, reader: KvaserReader | None = None) -> None:
        self._reader = reader
        self._loaded = reader is not None

    def poll(self, bus: can.BusABC) -> ControllerReport | None:
        if not self._loaded:
            self._reader, self._loaded = _canlib_reader(), True
        handle = getattr(bus, "_read_handle", None)  # python-can's KvaserBus keeps its CANlib handle here
        if self._reader is None or handle is None:
            return None
        try:
            flags, tx, rx = self._reader(_int(handle))
        except OSError as exc:
            log.debug("kvaser: status read failed: %s", exc)
            return None
        return ControllerReport(kvaser_state(flags), tx, rx)


def controller_monitor_for(interface: str) -> ControllerMonitor:
    """A fresh monitor for python-can's ``interface`` (one per bus session: some keep state)."""
    name = interface.lower()
    if name in ("socketcan", "socketcand", "virtual"):
        return SocketcanErrorFrames(name)
    if name == "pcan":
        return PcanStatus()
    if name == "vector":
        return VectorChipState()
    if name == "kvaser":
        return KvaserStatus()
    return NoControllerState(interface)
