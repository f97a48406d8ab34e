"""A bus-off of the simulated ECU's bus, recorded by the rig's CAN device (rig.record.can.CanDevice over
CanBusLink): the state changes and the bus-off as events, the span as a gap, and the recovery."""

from __future__ import annotations

import queue
import threading
import time
from typing import Any

import can
import pytest

from drivers.can.bus import (
    BusGap,
    BusLost,
    BusOpened,
    BusState,
    BusStats,
    CanBusConfig,
    CanBusLink,
    CanFrame,
    CanFrameFlag,
    FrameTime,
    TimestampSource,
)
from rig.core.config import CanConfig
from rig.core.timebase import Timebase
from rig.core.topics import EventKind, Severity
from rig.record.can import CanDevice
from rig.record.device import Reconnect
from rig.record.status import StatusBoard
from sim_devices.vsc_ecu import SimulatedVscBus, VscEcu, simulate_ecu, vsc_sim_dbc_path
from tests.can_live.truth_builders import steady_circle
from vsccore.clock import ScaledClock
from vsccore.errors import SimulationError

T0_NS = 1_700_000_000_000_000_000


class FakeSource:
    """A recorder source that keeps what the device puts, its events and gaps."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.events: list[tuple[EventKind, str, Severity, dict[str, Any]]] = []
        self.gaps: list[tuple[int, int, str, dict[str, Any]]] = []
        self.puts: list[tuple[str, int]] = []
        self.gap_seen = threading.Event()

    def put(self, topic: str, log_time_ns: int, publish_ns: int, payload: object) -> bool:
        with self.lock:
            self.puts.append((topic, log_time_ns))
        return True

    def event(self, kind: EventKind, text: str, *, severity: Severity = Severity.INFO, log_time_ns: int | None = None,
              **details: Any) -> bool:
        with self.lock:
            self.events.append((kind, text, severity, details))
        return True

    def gap(self, start_ns: int, end_ns: int, text: str, **details: Any) -> bool:
        with self.lock:
            self.gaps.append((start_ns, end_ns, text, details))
        self.gap_seen.set()
        return True

    def error(self, text: str, exc: BaseException | None = None, **details: Any) -> bool:
        raise AssertionError(f"device error: {text}") from exc


class FakeContext:
    """The narrow DeviceContext a device gets from the recording."""

    def __init__(self, clock: ScaledClock) -> None:
        self.clock = clock
        self.timebase = Timebase()
        self.board = StatusBoard("test", now_ns=clock.now_ns())
        self.reconnect = Reconnect(0.05, 0.2)
        self.src = FakeSource()

    def source(self, name: str, maxsize: int) -> FakeSource:
        return self.src

    def on_lateral_accel(self, t_ns: int, ay_mps2: float) -> None:
        pass


def _wait(predicate: Any, timeout: float = 5.0) -> None:
    done = threading.Event()
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not met in time"
        done.wait(0.01)


def test_the_rig_records_a_bus_off_of_the_simulated_bus_and_its_recovery(channel: str) -> None:
    truth = steady_circle(15.0, 100.0, 6.0)
    outputs = simulate_ecu(truth)
    clock = ScaledClock(T0_NS - 200_000_000)
    ctx = FakeContext(clock)
    cc = CanConfig(name="vsc", interface="virtual", channel=channel, dbc=vsc_sim_dbc_path())
    dev = CanDevice(ctx, cc)  # type: ignore[arg-type]
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as ecu_bus:
        ecu = VscEcu(truth, ecu_bus, clock, T0_NS, outputs=outputs, max_lag_s=60.0)
        dev.start()
        assert dev.started
        try:
            with ecu:
                _wait(lambda: dev.bus.stats().frames_total > 50)
                back = ecu.bus_off(0.4)
                with pytest.raises(SimulationError, match="already pending"):
                    ecu.bus_off(0.1)
                assert back.wait(5.0)
                assert ctx.src.gap_seen.wait(5.0)
                after = dev.bus.stats().frames_total
                _wait(lambda: dev.bus.stats().frames_total > after + 20)  # frames again
                assert dev.bus.state is BusState.ACTIVE
        finally:
            dev.stop()
    assert ecu.failure is None
    assert ecu.frames_lost_bus_off > 50  # ~0.4 s of the ECU's ~360 frames/s
    events = ctx.src.events
    texts = [text for _kind, text, _sev, _d in events]
    warnings = [text for kind, text, sev, _d in events if kind is EventKind.WARNING and sev is Severity.WARNING]
    assert "controller unknown → warning" in warnings  # as SocketCAN reports the counters rising
    assert "controller warning → passive" in warnings
    assert "controller passive → bus_off" in warnings
    lost = [text for kind, text, _s, _d in events if kind is EventKind.DISCONNECT]
    assert lost == ["controller is bus-off"]
    assert "controller bus_off → active" in texts  # the restart (CAN_ERR_RESTARTED)
    (start, end, text, details), = ctx.src.gaps
    assert "controller is bus-off" in text
    assert details == {"recovered": True, "reopen_attempts": 0}  # waited out, not reopened
    assert 0.3e9 < end - start < 1.5e9
    assert [kind for kind, *_ in events].count(EventKind.CONNECT) == 1  # the interface stayed open
    assert dev.bus.stats().error_frames_total == 4  # warning, passive, bus-off, restarted


def _stamped_frame(device_ns: int, host_ns: int) -> CanFrame:
    return CanFrame(device_ns, host_ns, 0x7FF, False, False, 0, b"", CanFrameFlag.NONE, TimestampSource.HARDWARE, "x")


@pytest.mark.parametrize(("source", "uses_device"), [(None, True), ("interface", True), ("host", False)])
def test_timestamp_source_decides_which_map_times_the_frames(source: str | None, uses_device: bool) -> None:
    """timestamp_source = "host": frames are timed by the host → UTC map although they carry a stamp
    (kept as their device time); otherwise the interface clock's estimate times them."""
    ctx = FakeContext(ScaledClock(T0_NS))
    cc = CanConfig(name="pt", interface="pcan", channel="PCAN_USBBUS1", dbc=vsc_sim_dbc_path(),
                   timestamp_source=source)  # type: ignore[arg-type]
    dev = CanDevice(ctx, cc)  # type: ignore[arg-type]
    assert dev.bus.config.time_from is (FrameTime.INTERFACE if uses_device else FrameTime.HOST)
    used: list[str] = []
    tb = ctx.timebase
    device_map, host_map = tb.device_to_utc, tb.live_host_to_utc
    tb.device_to_utc = lambda *a, **k: used.append("device") or device_map(*a, **k)  # type: ignore[method-assign]
    tb.live_host_to_utc = lambda *a, **k: used.append("host") or host_map(*a, **k)  # type: ignore[method-assign]
    dev._on_frame(_stamped_frame(5_000_000_000, T0_NS))
    dev.flush()
    assert used == ["device" if uses_device else "host"]


def test_a_bus_off_is_seen_over_socketcand_as_on_a_remote_socketcan_bus(channel: str) -> None:
    """socketcand forwards the error class only: the bus-off and the restart come through (warning and
    passive do not), and the link waits the bus-off out as on SocketCAN."""
    truth = steady_circle(15.0, 100.0, 6.0)
    clock = ScaledClock(T0_NS - 200_000_000)
    events: queue.Queue[Any] = queue.Queue()

    def wait(kind: type) -> Any:
        while True:
            event = events.get(timeout=5.0)
            if isinstance(event, kind):
                return event

    with SimulatedVscBus(truth, clock=clock, t0_ns=T0_NS, channel=channel, port=0) as sim:
        assert sim.address is not None
        host, port = sim.address
        config = CanBusConfig("socketcand", "vsc0", name="remote", options={"host": host, "port": port})
        with CanBusLink(config, lambda f: None, lambda e: None if isinstance(e, BusStats) else events.put(e),
                        clock=clock) as link:
            opened = wait(BusOpened)
            assert any("socketcand forwards the error class" in n for n in opened.notes)
            assert any("server's interface setting" in n for n in opened.notes)  # listen-only not checkable
            _wait(lambda: link.stats().frames_total > 50)
            assert sim.bus_off(0.3).wait(5.0)
            assert "bus-off" in wait(BusLost).reason
            gap = wait(BusGap)
            assert gap.recovered and gap.reopen_attempts == 0
            assert link.state is BusState.ACTIVE
