"""DaqLink: thread start/stop/join, contiguous blocks, overflow and health events, reconnect, errors."""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
import pytest

from drivers.daq import (
    ChannelHealth,
    DaqBackend,
    DaqBlock,
    DaqChannelConfig,
    DaqEvent,
    DaqEventKind,
    DaqLink,
    HealthLimits,
    ReconnectPolicy,
)
from drivers.optical import OpticalSensorSpec, SensorKind, correvit_channels
from sim_devices.daq import ConstantInput, SimDaqBackend, SimDaqLink, SimOpticalSensor
from tests.daq.helpers import T0_NS, ManualClock, optical_channels, optical_wiring, steady_circle
from vsccore.clock import ScaledClock
from vsccore.errors import ConfigError, DeviceError

RATE = 1000.0
CHANS = [DaqChannelConfig("a", "sim/ai0"), DaqChannelConfig("b", "sim/ai1")]
SOURCES = {"sim/ai0": ConstantInput(1.0), "sim/ai1": ConstantInput(-2.0)}


class Collector:
    """Blocks and events from the session thread, with events to wait on."""

    def __init__(self, want_blocks: int = 10**9) -> None:
        self.blocks: list[DaqBlock] = []
        self.events: queue.Queue[DaqEvent] = queue.Queue()
        self.all_events: list[DaqEvent] = []
        self.enough = threading.Event()
        self.want = want_blocks

    def on_block(self, block: DaqBlock) -> None:
        self.blocks.append(block)
        if len(self.blocks) >= self.want:
            self.enough.set()

    def on_event(self, event: DaqEvent) -> None:
        self.all_events.append(event)
        self.events.put(event)

    def wait_for(self, kind: DaqEventKind, timeout: float = 10.0) -> DaqEvent:
        deadline = time.monotonic() + timeout
        while True:
            ev = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
            if ev.kind is kind:
                return ev


def assert_contiguous(blocks: list[DaqBlock]) -> None:
    for prev, blk in zip(blocks, blocks[1:], strict=False):
        if blk.segment == prev.segment:
            expected = prev.next_sample_index if blk.lost_before is None else blk.lost_before.stop_index
            assert blk.first_sample_index == expected
            if blk.lost_before is not None:
                assert blk.lost_before.start_index == prev.next_sample_index
        else:
            assert blk.segment == prev.segment + 1
            assert blk.first_sample_index == 0


def test_session_delivers_contiguous_blocks_and_stops_promptly() -> None:
    clock = ScaledClock(T0_NS, speed=20.0)
    col = Collector(want_blocks=15)
    session = DaqLink(
        lambda: SimDaqBackend(clock=clock, sources=SOURCES, truth_start_ns=T0_NS),
        CHANS, RATE, on_block=col.on_block, on_event=col.on_event, clock=clock, block_size=100,
    )
    with session:
        assert session.is_running
        assert col.enough.wait(10.0)
        t0 = time.monotonic()
    assert time.monotonic() - t0 < 2.0  # one 100-sample block at 20× is 5 ms of wall time
    assert not session.is_running and session.join(0.0)
    assert session.error is None
    # whole blocks; more than one only when the reader was behind (a busy machine)
    assert len(col.blocks) >= 15 and all(b.n_samples % 100 == 0 for b in col.blocks)
    assert col.blocks[0].first_sample_index == 0
    assert_contiguous(col.blocks)
    assert {b.segment for b in col.blocks} == {1}
    kinds = [e.kind for e in col.all_events]
    assert kinds[0] is DaqEventKind.STARTED and kinds[-1] is DaqEventKind.STOPPED
    np.testing.assert_allclose(col.blocks[3].channel("a"), 1.0, atol=0.002)
    # host receive stamps come from the injected clock and never precede the data
    assert all(b.host_time_ns >= T0_NS + b.next_sample_index * 1e6 - 1e6 for b in col.blocks)


def test_overflow_is_reported_and_no_earlier_sample_is_lost() -> None:
    clock = ManualClock()
    col = Collector(want_blocks=30)
    stalled: list[bool] = []

    def slow_consumer(block: DaqBlock) -> None:
        if block.first_sample_index == 500 and not stalled:
            stalled.append(True)
            clock.advance(3.0)  # the consumer takes 3 s of DAQ time on this block: the 1 s buffer overflows
        col.on_block(block)

    session = DaqLink(
        lambda: SimDaqBackend(clock=clock, sources=SOURCES, truth_start_ns=T0_NS),
        CHANS, RATE, on_block=slow_consumer, on_event=col.on_event, clock=clock, block_size=100, buffer_size=1000,
    )
    with session:
        ev = col.wait_for(DaqEventKind.OVERFLOW)
        assert col.enough.wait(10.0)
    assert ev.lost is not None
    assert ev.lost.start_index == 600
    # after the stall the clock stood at sample 599's instant + 3 s: samples up to index 3599 existed
    assert ev.lost.stop_index == 3600 - 1000
    assert ev.count == ev.lost.count and "samples lost" in ev.message
    assert_contiguous(col.blocks)
    firsts = [b.first_sample_index for b in col.blocks]
    assert firsts[:7] == [0, 100, 200, 300, 400, 500, 2600]


def test_reader_that_fell_behind_catches_up_in_one_read_without_loss() -> None:
    clock = ManualClock()
    col = Collector(want_blocks=12)
    stalled: list[bool] = []

    def slow_consumer(block: DaqBlock) -> None:
        if block.first_sample_index == 300 and not stalled:
            stalled.append(True)
            clock.advance(0.65)  # 650 samples pile up in the 1000-sample buffer: no overflow
        col.on_block(block)

    session = DaqLink(
        lambda: SimDaqBackend(clock=clock, sources=SOURCES, truth_start_ns=T0_NS),
        CHANS, RATE, on_block=slow_consumer, on_event=col.on_event, clock=clock, block_size=100, buffer_size=1000,
        catch_up_s=0.5,
    )
    with session:
        assert col.enough.wait(10.0)
    assert not [e for e in col.all_events if e.kind is DaqEventKind.OVERFLOW]
    assert_contiguous(col.blocks)
    sizes = [(b.first_sample_index, b.n_samples) for b in col.blocks]
    # block 300..399 ended at sample 399's instant; the stall made samples up to 1049 available:
    # 650 waiting = 6 whole blocks, capped at catch_up_s = 500 samples, then 100 more, then one at a time
    assert sizes[:7] == [(0, 100), (100, 100), (200, 100), (300, 100), (400, 500), (900, 100), (1000, 100)]
    np.testing.assert_allclose(col.blocks[4].channel("a"), 1.0, atol=0.002)


def test_reconnects_after_the_device_disappears() -> None:
    clock = ScaledClock(T0_NS, speed=20.0)
    link = SimDaqLink()
    col = Collector()
    made: list[DaqBackend] = []
    unplugged = threading.Event()

    def factory() -> DaqBackend:
        b = SimDaqBackend(clock=clock, sources=SOURCES, truth_start_ns=T0_NS, link=link)
        made.append(b)
        return b

    def on_block(block: DaqBlock) -> None:
        col.on_block(block)
        if len(col.blocks) == 5:
            link.unplug()
            unplugged.set()
        if block.segment == 2 and block.first_sample_index >= 300:
            col.enough.set()

    session = DaqLink(
        factory, CHANS, RATE, on_block=on_block, on_event=col.on_event, clock=clock, block_size=100,
        reconnect=ReconnectPolicy(initial_s=0.01, max_s=0.05),
    )
    with session:
        assert unplugged.wait(10.0)
        disc = col.wait_for(DaqEventKind.DISCONNECTED)
        assert "disappeared" in disc.message
        col.wait_for(DaqEventKind.CONNECT_FAILED)  # still unplugged: retried with back-off
        link.replug()
        rec = col.wait_for(DaqEventKind.RECONNECTED)
        assert col.enough.wait(10.0)
    assert rec.segment == 2 and session.segment == 2
    assert len(made) >= 3 and all(b.running is False for b in made)  # every backend was closed
    assert [b.segment for b in col.blocks[:5]] == [1] * 5
    assert_contiguous(col.blocks)
    seg2 = [b for b in col.blocks if b.segment == 2]
    assert seg2[0].first_sample_index == 0


def test_gives_up_after_max_attempts() -> None:
    calls = []

    def factory() -> DaqBackend:
        calls.append(1)
        raise DeviceError("DAQ Dev1: device not found")

    col = Collector()
    session = DaqLink(
        factory, CHANS, RATE, on_block=col.on_block, on_event=col.on_event,
        reconnect=ReconnectPolicy(initial_s=0.0, max_s=0.0, max_attempts=3),
    )
    session.start()
    assert session.join(10.0)
    assert len(calls) == 3
    kinds = [e.kind for e in col.all_events]
    assert kinds == [DaqEventKind.CONNECT_FAILED] * 3 + [DaqEventKind.ERROR]
    assert "Dev1" in col.all_events[0].message


def test_configuration_error_is_not_retried() -> None:
    calls = []
    spec = OpticalSensorSpec("body", SensorKind.BODY, (0.0, 0.0, 0.0), correvit_channels("body"))
    chans = optical_channels("body", 0)
    sources = optical_wiring(SimOpticalSensor(spec), chans)

    def factory() -> DaqBackend:
        calls.append(1)
        return SimDaqBackend(clock=ManualClock(), sources=sources)  # no truth: configure() fails

    col = Collector()
    session = DaqLink(factory, chans, RATE, on_block=col.on_block, on_event=col.on_event)
    session.start()
    assert session.join(10.0)
    assert len(calls) == 1
    assert isinstance(session.error, ConfigError)
    assert [e.kind for e in col.all_events] == [DaqEventKind.ERROR]
    assert "needs ground truth" in col.all_events[0].message


def test_consumer_exception_ends_the_session_visibly() -> None:
    clock = ManualClock()
    col = Collector()

    def bad_consumer(block: DaqBlock) -> None:
        if block.first_sample_index == 200:
            raise ValueError("consumer bug")
        col.on_block(block)

    session = DaqLink(
        lambda: SimDaqBackend(clock=clock, sources=SOURCES, truth_start_ns=T0_NS),
        CHANS, RATE, on_block=bad_consumer, on_event=col.on_event, clock=clock, block_size=100,
    )
    session.start()
    assert session.join(10.0)
    assert isinstance(session.error, ValueError)
    assert [b.first_sample_index for b in col.blocks] == [0, 100]
    last = col.all_events[-1]
    assert last.kind is DaqEventKind.ERROR and "consumer bug" in last.message


def test_health_events_flow_through_the_session() -> None:
    clock = ManualClock()
    truth = steady_circle(duration=5.0)
    chans = [DaqChannelConfig("railed", "sim/ai0"), DaqChannelConfig("open", "sim/ai1")]
    col = Collector(want_blocks=25)
    session = DaqLink(
        lambda: SimDaqBackend(clock=clock, truth=truth, sources={"sim/ai0": ConstantInput(-10.5)},
                              truth_start_ns=T0_NS),
        chans, RATE, on_block=col.on_block, on_event=col.on_event, clock=clock, block_size=100,
        health=ChannelHealth(chans, default=HealthLimits(check_stuck=False), clock=clock),
    )
    with session:
        sat = col.wait_for(DaqEventKind.SATURATION)
        flo = col.wait_for(DaqEventKind.FLOATING)
        assert col.enough.wait(10.0)
    assert sat.channel == "railed" and sat.segment == 1
    assert flo.channel == "open"
    assert_contiguous(col.blocks)


def test_constructor_checks() -> None:
    with pytest.raises(ConfigError, match="rate_hz"):
        DaqLink(lambda: SimDaqBackend(), CHANS, 0.0, on_block=lambda b: None)
    with pytest.raises(ConfigError, match="unique"):
        DaqLink(lambda: SimDaqBackend(), CHANS + CHANS, RATE, on_block=lambda b: None)
