"""Controller state per interface (drivers.can.controller) through CanBusLink, on fakes that behave as
python-can's PCAN, Vector and Kvaser buses do, and on the virtual bus with SocketCAN error frames."""

from __future__ import annotations

import queue
import threading
from typing import Any

import can
import pytest
from can.interfaces.vector import xlclass

from drivers.can.bus import (
    BusGap,
    BusLost,
    BusOpened,
    BusState,
    CanBusConfig,
    CanBusLink,
)
from drivers.can.controller import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_RX_PASSIVE,
    CAN_ERR_RESTARTED,
    PCAN_ERROR_BUSHEAVY,
    PCAN_ERROR_BUSOFF,
    PCAN_ERROR_BUSPASSIVE,
    XL_CAN_EV_TAG_CHIP_STATE,
    XL_CHIP_STATE,
    XL_CHIPSTAT_BUSOFF,
    XL_CHIPSTAT_ERROR_ACTIVE,
    XL_CHIPSTAT_ERROR_PASSIVE,
    XL_CHIPSTAT_ERROR_WARNING,
    KvaserStatus,
    VectorChipState,
    controller_monitor_for,
    socketcan_error_frame,
)
from tests.can_live.collect import Collector
from vsccore.clock import ScaledClock

T0_NS = 1_700_000_000_000_000_000


def _link(config: CanBusConfig, events: Collector, factory: Any, **kw: Any) -> CanBusLink:
    kw.setdefault("state_poll_s", 0.02)
    return CanBusLink(config, events.frame, events.event, clock=ScaledClock(T0_NS), bus_factory=factory,
                      backoff_initial_s=0.05, **kw)


# --- PCAN -------------------------------------------------------------------------------------------------


class PcanAdapter:
    """A PCAN adapter's controller: ``status`` is what CAN_GetStatus answers."""

    def __init__(self) -> None:
        self.status = 0
        self.opens = 0
        self.rx: queue.Queue[can.Message] = queue.Queue()


class FakePcanBus(can.BusABC):
    """As python-can's PcanBus: ``status()`` is CAN_GetStatus; ``state`` is the listen-only switch
    (PASSIVE = listen-only), not the error state; ``recv`` raises while error passive or bus-off
    (``_recv_internal`` raises PcanCanOperationError for every result but OK, QRCVEMPTY, BUSLIGHT,
    BUSHEAVY and ILLDATA); opening the channel again (CAN_Initialize) restarts a bus-off controller."""

    def __init__(self, channel: str, adapter: PcanAdapter, state: can.BusState = can.BusState.ACTIVE) -> None:
        adapter.opens += 1
        adapter.status &= ~PCAN_ERROR_BUSOFF
        self._adapter = adapter
        self._mode = state
        super().__init__(channel=channel)

    @property
    def state(self) -> can.BusState:
        return self._mode

    def status(self) -> int:
        return self._adapter.status

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        status = self._adapter.status
        if status & (PCAN_ERROR_BUSOFF | PCAN_ERROR_BUSPASSIVE):
            raise can.CanOperationError(f"PCAN bus error {status:#x}")
        try:
            return self._adapter.rx.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("listen-only")


def _pcan_factory(adapter: PcanAdapter):
    def open_fake(config: CanBusConfig) -> can.BusABC:
        mode = can.BusState.PASSIVE if config.listen_only else can.BusState.ACTIVE
        return FakePcanBus(str(config.channel), adapter, mode)

    return open_fake


def test_a_listen_only_pcan_is_not_reported_error_passive() -> None:
    """python-can's PcanBus.state says PASSIVE for a listen-only channel; the state comes from status()."""
    adapter = PcanAdapter()
    events = Collector()
    with _link(CanBusConfig("pcan", "PCAN_USBBUS1", name="pt"), events, _pcan_factory(adapter)) as link:
        assert events.wait_event(BusOpened).listen_only is True
        assert events.state(BusState.ACTIVE)
        adapter.rx.put(can.Message(arbitration_id=0x101, data=b"\x01", is_extended_id=False))
        events.frames.get(timeout=5.0)
        assert link.state is BusState.ACTIVE


def test_pcan_warning_passive_and_bus_off_from_its_status() -> None:
    adapter = PcanAdapter()
    events = Collector()
    with _link(CanBusConfig("pcan", "PCAN_USBBUS1", name="pt"), events, _pcan_factory(adapter)) as link:
        events.state(BusState.ACTIVE)
        adapter.status = PCAN_ERROR_BUSHEAVY  # = PCAN_ERROR_BUSWARNING
        events.state(BusState.WARNING)
        adapter.status = PCAN_ERROR_BUSPASSIVE  # recv now raises: read on, do not reopen
        events.state(BusState.PASSIVE)
        assert adapter.opens == 1
        adapter.status = PCAN_ERROR_BUSOFF
        events.state(BusState.BUS_OFF)
        lost = events.wait_event(BusLost)
        assert "bus-off" in lost.reason
        gap = events.wait_event(BusGap)  # re-initialising the channel restarts the controller
        assert gap.recovered and gap.reopen_attempts >= 1
        assert adapter.opens >= 2
        assert link.state is BusState.ACTIVE  # reported on reopening, before the gap
        assert link.stats().gaps_total == 1


def test_a_pcan_error_frame_is_not_read_as_a_socketcan_one() -> None:
    """PCAN error frames carry PCAN's error type in the identifier (4: stuff error) — the SocketCAN
    reading would take the identifier for CAN_ERR_CRTL and data[1] 0x10 for RX error passive."""
    adapter = PcanAdapter()
    events = Collector()
    with _link(CanBusConfig("pcan", "PCAN_USBBUS1", name="pt"), events, _pcan_factory(adapter),
               state_poll_s=60.0) as link:
        events.state(BusState.ACTIVE)
        adapter.rx.put(can.Message(arbitration_id=0x4, is_error_frame=True, data=bytes([1, 0x10, 5, 0])))
        events.frames.get(timeout=5.0)
        assert link.state is BusState.ACTIVE
        assert link.stats().error_frames_total == 1


# --- Vector -----------------------------------------------------------------------------------------------


class FakeXlDriver:
    """The part of python-can's xldriver the monitor uses: a chip-state request answered as an event."""

    def __init__(self, bus: FakeVectorBus) -> None:
        self.bus = bus
        self.requests = 0

    def xlCanRequestChipState(self, port_handle: Any, mask: int) -> None:
        self.requests += 1
        self.bus.events.put(self.bus.chip_event())


class FakeVectorBus(can.BusABC):
    """As python-can's VectorBus: ``recv`` hands every non-message event (a chip state among them) to
    ``handle_can_event`` and returns nothing for it."""

    def __init__(self, channel: str, chip: dict[str, int]) -> None:
        self.xldriver = FakeXlDriver(self)
        self.port_handle = 1
        self.mask = 1
        self.chip = chip
        self.events: queue.Queue[Any] = queue.Queue()
        super().__init__(channel=channel)

    def chip_event(self) -> xlclass.XLevent:
        event = xlclass.XLevent()
        event.tag = XL_CHIP_STATE
        event.tagData.chipState.busStatus = self.chip["status"]
        event.tagData.chipState.txErrorCounter = self.chip["tx"]
        event.tagData.chipState.rxErrorCounter = self.chip["rx"]
        return event

    def handle_can_event(self, event: xlclass.XLevent) -> None:
        """python-can's hook: does nothing unless replaced."""

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            event = self.events.get(timeout=timeout)
        except queue.Empty:
            return None, False
        if isinstance(event, can.Message):
            return event, False
        self.handle_can_event(event)
        return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


def test_vector_chip_states_are_reported_with_their_counters() -> None:
    chip = {"status": XL_CHIPSTAT_ERROR_ACTIVE, "tx": 0, "rx": 0}
    buses: list[FakeVectorBus] = []

    def factory(config: CanBusConfig) -> can.BusABC:
        buses.append(FakeVectorBus(str(config.channel), chip))
        return buses[-1]

    events = Collector()
    with _link(CanBusConfig("vector", "0", name="pt"), events, factory) as link:
        events.state(BusState.ACTIVE)
        chip.update(status=XL_CHIPSTAT_ERROR_WARNING, tx=0, rx=100)
        events.state(BusState.WARNING)
        chip.update(status=XL_CHIPSTAT_ERROR_PASSIVE, tx=0, rx=130)
        events.state(BusState.PASSIVE)
        assert (link.stats().tx_error_counter, link.stats().rx_error_counter) == (0, 130)
        chip.update(status=XL_CHIPSTAT_BUSOFF, tx=255, rx=0)
        events.state(BusState.BUS_OFF)
        chip.update(status=XL_CHIPSTAT_ERROR_ACTIVE, tx=0, rx=0)  # re-activating the channel restarts it
        assert events.wait_event(BusGap).recovered
        events.state(BusState.ACTIVE)  # the chip state comes as an event after the reopen
    assert buses[0].xldriver.requests > 0 and len(buses) >= 2


def test_vector_fd_chip_state_event() -> None:
    monitor = VectorChipState()
    bus = FakeVectorBus("0", {"status": 0, "tx": 0, "rx": 0})
    monitor.attach(bus)
    event = xlclass.XLcanRxEvent()
    event.tag = XL_CAN_EV_TAG_CHIP_STATE
    event.tagData.canChipState.busStatus = XL_CHIPSTAT_ERROR_PASSIVE
    event.tagData.canChipState.txErrorCounter = 140
    event.tagData.canChipState.rxErrorCounter = 3
    bus.handle_canfd_event(event)  # type: ignore[attr-defined]
    report = monitor.poll(bus)
    assert report is not None and report.state is BusState.PASSIVE and report.counters == (140, 3)
    bus.shutdown()


# --- Kvaser -----------------------------------------------------------------------------------------------


class FakeKvaserBus(can.BusABC):
    """As python-can's KvaserBus: reads nothing on bus-off; keeps its CANlib handle in ``_read_handle``."""

    def __init__(self, channel: str, opens: list[int]) -> None:
        opens.append(1)
        self._read_handle = 42
        super().__init__(channel=channel)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        threading.Event().wait(timeout or 0.0)
        return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


def test_kvaser_status_flags_and_counters() -> None:
    status = {"flags": 0x08, "tx": 0, "rx": 0}
    handles: list[int] = []
    opens: list[int] = []

    def read_status(handle: int) -> tuple[int, int | None, int | None]:
        handles.append(handle)
        return status["flags"], status["tx"], status["rx"]

    def factory(config: CanBusConfig) -> can.BusABC:
        status.update(flags=0x08, tx=0, rx=0)  # canBusOn after canBusOff: error active again
        return FakeKvaserBus(str(config.channel), opens)

    events = Collector()
    with _link(CanBusConfig("kvaser", "0", name="pt"), events, factory,
               controller=KvaserStatus(read_status)) as link:
        events.state(BusState.ACTIVE)
        status.update(flags=0x04, tx=100, rx=2)  # canSTAT_ERROR_WARNING
        events.state(BusState.WARNING)
        assert (link.stats().tx_error_counter, link.stats().rx_error_counter) == (100, 2)
        status.update(flags=0x01, tx=130, rx=2)  # canSTAT_ERROR_PASSIVE
        events.state(BusState.PASSIVE)
        status.update(flags=0x02, tx=255, rx=2)  # canSTAT_BUS_OFF
        events.state(BusState.BUS_OFF)
        assert events.wait_event(BusGap).recovered
        assert link.state is BusState.ACTIVE
    assert set(handles) == {42} and len(opens) >= 2


# --- SocketCAN error frames on the virtual bus -------------------------------------------------------------


def test_socketcan_bus_off_is_waited_out_until_the_kernel_restarts_it(channel: str) -> None:
    """SocketCAN restarts a bus-off controller itself (restart-ms): the link keeps the interface open and
    reports the gap when CAN_ERR_RESTARTED comes, without reopening."""
    opens: list[CanBusConfig] = []

    def factory(config: CanBusConfig) -> can.BusABC:
        opens.append(config)
        return can.Bus(interface="virtual", channel=channel)

    events = Collector()
    with _link(CanBusConfig("virtual", channel, name="pt"), events, factory) as link, \
            can.Bus(interface="virtual", channel=channel) as tx:
        events.wait_event(BusOpened)
        tx.send(socketcan_error_frame(CAN_ERR_CRTL, status=CAN_ERR_CRTL_RX_PASSIVE, tx_errors=0, rx_errors=128))
        events.state(BusState.PASSIVE)
        tx.send(socketcan_error_frame(CAN_ERR_BUSOFF))
        events.state(BusState.BUS_OFF)
        assert "bus-off" in events.wait_event(BusLost).reason
        tx.send(socketcan_error_frame(CAN_ERR_RESTARTED))
        gap = events.wait_event(BusGap)
        assert gap.recovered and gap.reopen_attempts == 0
        assert link.state is BusState.ACTIVE
        tx.send(can.Message(arbitration_id=0x100, data=b"\x01", is_extended_id=False))
        while events.frames.get(timeout=5.0).arbitration_id != 0x100:
            pass
        assert link.stats().gaps_total == 1
    assert len(opens) == 1


def test_every_known_interface_has_a_state_reader() -> None:
    for name in ("socketcan", "socketcand", "virtual", "pcan", "vector", "kvaser"):
        assert controller_monitor_for(name).note is None or name == "socketcand"
    assert controller_monitor_for("socketcand").note is not None  # warning/passive not forwarded
    assert "not decoded" in (controller_monitor_for("ixxat").note or "")


@pytest.mark.parametrize(("flags", "state"), [(0x08, BusState.ACTIVE), (0x04, BusState.WARNING),
                                              (0x01 | 0x04, BusState.PASSIVE), (0x02 | 0x01, BusState.BUS_OFF)])
def test_kvaser_flags_map_to_states(flags: int, state: BusState) -> None:
    from drivers.can.controller import kvaser_state

    assert kvaser_state(flags) is state
