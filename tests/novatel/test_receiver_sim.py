"""The receiver session against the simulated rover (sim_devices.gnss) at the wire level: the
standard configuration is accepted, logs stream on GPS time with the reported leap seconds, the
session survives an unplug, and baud detection finds a receiver set to another rate."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from drivers.novatel import BestPos, Time
from drivers.novatel.commands import LogRequest, LogTrigger, standard_configuration
from drivers.novatel.receiver import NovatelReceiver, ReceiverEventKind, ReceiverSettings
from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.vehicle import GroundTruth, make_scenario, simulate
from tests.novatel.test_receiver import WAIT, Consumer
from vsccore.clock import ScaledClock

SPEED = 5.0
COMMANDS = standard_configuration(
    "COM1",
    [LogRequest("BESTPOSB", LogTrigger.ONTIME, 0.05), LogRequest("TIMEB", LogTrigger.ONTIME, 1.0),
     LogRequest("MARKPOSB", LogTrigger.ONNEW)],
    interface_modes=[("COM2", "RTCMV3", "NONE")],
    mark_inputs=["MARK1"],
)


@pytest.fixture(scope="module")
def truth() -> GroundTruth:
    return simulate(make_scenario("straight", speed_kmh=50.0, duration_s=40.0), rate_hz=50.0)


@pytest.fixture
def timebase() -> SimTimeBase:
    return SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)


@pytest.fixture
def clock(timebase: SimTimeBase) -> ScaledClock:
    return timebase.make_clock(speed=SPEED)


@pytest.fixture
def rover(truth: GroundTruth, timebase: SimTimeBase, clock: ScaledClock) -> Iterator[SimRover]:
    sim = SimRover("rover_a", truth=truth, lever_arm=(0.6, 0.0, 1.0), timebase=timebase, clock=clock,
                   baud=230400, enforce_baud=True)
    sim.start()
    yield sim
    sim.stop()


def test_session_configures_the_simulated_rover_and_survives_an_unplug(rover: SimRover, clock: ScaledClock,
                                                                        timebase: SimTimeBase) -> None:
    consumer = Consumer()
    settings = ReceiverSettings("rover_a", rover.port_path, 230400, COMMANDS, command_timeout_s=2.0,
                                reconnect_first_s=0.05, reconnect_max_s=0.2)
    rx = NovatelReceiver(settings, on_data=consumer.on_data, on_event=consumer.on_event, clock=clock)
    try:
        rx.start()
        rx.wait_configured(WAIT)
        chunks = consumer.frames("BESTPOS", 5)
        consumer.frames("TIME", 1)
        for chunk in chunks:
            for frame in chunk.frames:
                if frame.log is not None and isinstance(frame.log.body, BestPos):
                    # delivered after the receiver's GPS time of the log (positive latency)
                    assert timebase.gps_ns(chunk.host_ns) >= frame.log.header.gps_ns
        assert rx.health().leap_seconds == 18
        rover.unplug()
        consumer.event(ReceiverEventKind.DISCONNECTED)
        rover.replug()
        back = consumer.event(ReceiverEventKind.CONNECTED)
        assert back.gap_ns is not None and back.gap_ns > 0
        consumer.event(ReceiverEventKind.CONFIGURED)
        consumer.frames("BESTPOS", 3)
    finally:
        rx.stop()
    times = [f.log.body for c in consumer.all_chunks for f in c.frames
             if f.log is not None and isinstance(f.log.body, Time)]
    assert times and all(t.leap_seconds == 18 for t in times)


def test_baud_detection_on_the_simulated_rover(rover: SimRover, clock: ScaledClock) -> None:
    consumer = Consumer()
    settings = ReceiverSettings("rover_a", rover.port_path, 115200, ("UNLOGALL", "LOG COM1 BESTPOSB ONTIME 0.1"),
                                autobaud=True, autobaud_rates=(115200, 230400), autobaud_probe_s=0.4)
    rx = NovatelReceiver(settings, on_data=consumer.on_data, on_event=consumer.on_event, clock=clock)
    try:
        rx.start()
        rx.wait_configured(WAIT)
        assert consumer.event(ReceiverEventKind.BAUD_DETECTED).baud == 230400
        consumer.frames("BESTPOS", 2)
    finally:
        rx.stop()
