"""Receiver session on a pseudo-terminal against a scripted peer: configuration with <OK / <ERROR /
no answer, streaming with host times and lossless raw bytes, garbage on the line, unplug and
replug (reconnect + reconfigure), baud detection, and stop() that returns at once and joins."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.novatel import BestPos, FrameKind, Response, SkipReason, Time
from drivers.novatel.commands import LogRequest, LogTrigger, standard_configuration
from drivers.novatel.receiver import (
    NovatelReceiver,
    ReceivedChunk,
    ReceiverEvent,
    ReceiverEventKind,
    ReceiverSettings,
)
from tests.novatel.fake_peer import FakePeer
from tests.novatel.gen import rtcm_1005
from vsccore.clock import ScaledClock
from vsccore.errors import CommandError, CommandTimeoutError, ConfigError, DeviceError, DeviceTimeoutError

WAIT = 10.0  # generous bound for waits on a loaded machine (tests wait on queues, never sleep)
START_NS = 1_700_000_000_000_000_000

ROVER_LOGS = (
    LogRequest("BESTPOSB", LogTrigger.ONTIME, 0.05),
    LogRequest("TIMEB", LogTrigger.ONTIME, 0.2),
    LogRequest("MARKPOSB", LogTrigger.ONNEW),
)


class Consumer:
    """Collects chunks and events on queues (as the recorder would, without blocking the I/O thread)."""

    def __init__(self) -> None:
        self.chunks: queue.Queue[ReceivedChunk] = queue.Queue()
        self.events: queue.Queue[ReceiverEvent] = queue.Queue()
        self.all_chunks: list[ReceivedChunk] = []
        self.all_events: list[ReceiverEvent] = []

    def on_data(self, chunk: ReceivedChunk) -> None:
        self.all_chunks.append(chunk)
        self.chunks.put(chunk)

    def on_event(self, event: ReceiverEvent) -> None:
        self.all_events.append(event)
        self.events.put(event)

    def event(self, kind: ReceiverEventKind, timeout_s: float = WAIT) -> ReceiverEvent:
        deadline = time.monotonic() + timeout_s
        while True:
            event = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
            if event.kind is kind:
                return event

    def frames(self, name: str, count: int, timeout_s: float = WAIT) -> list[ReceivedChunk]:
        """Wait until ``count`` more logs named ``name`` arrived; the chunks that held them."""
        deadline = time.monotonic() + timeout_s
        got: list[ReceivedChunk] = []
        seen = 0
        while seen < count:
            chunk = self.chunks.get(timeout=max(0.0, deadline - time.monotonic()))
            n = sum(1 for f in chunk.frames if f.log is not None and f.log.name == name)
            if n:
                got.append(chunk)
                seen += n
        return got


@pytest.fixture
def link(tmp_path: Path) -> Path:
    return tmp_path / "ttyNOVATEL0"


@pytest.fixture
def peer(link: Path) -> Iterator[FakePeer]:
    p = FakePeer(link)
    p.plug()
    yield p
    p.close()


def settings(link: Path, commands: tuple[str, ...], **kw: object) -> ReceiverSettings:
    values: dict[str, object] = {"command_timeout_s": 1.0, "reconnect_first_s": 0.05, "reconnect_max_s": 0.2}
    values.update(kw)
    return ReceiverSettings("rover_a", str(link), 115200, commands, **values)  # type: ignore[arg-type]


def session(link: Path, commands: tuple[str, ...], consumer: Consumer, **kw: object) -> NovatelReceiver:
    return NovatelReceiver(
        settings(link, commands, **kw),
        on_data=consumer.on_data,
        on_event=consumer.on_event,
        clock=ScaledClock(START_NS),
    )


ROVER_COMMANDS = standard_configuration(
    "COM1",
    ROVER_LOGS,
    interface_modes=[("COM2", "RTCMV3", "NONE")],
    serial_configs=[("COM2", 115200)],
    mark_inputs=["MARK1"],
)


def test_configuration_is_sent_in_order_and_acknowledged_then_logs_stream(peer: FakePeer, link: Path) -> None:
    consumer = Consumer()
    rx = session(link, ROVER_COMMANDS, consumer)
    rx.start()
    try:
        rx.wait_configured(WAIT)
        assert rx.configured and rx.connected
        assert [peer.next_command() for _ in ROVER_COMMANDS] == list(ROVER_COMMANDS)
        assert ROVER_COMMANDS[0] == "UNLOGALL"
        assert "LOG COM1 BESTPOSB ONTIME 0.05" in ROVER_COMMANDS
        assert "LOG COM1 MARKPOSB ONNEW" in ROVER_COMMANDS
        assert "INTERFACEMODE COM2 RTCMV3 NONE ON" in ROVER_COMMANDS
        connected = consumer.event(ReceiverEventKind.CONNECTED)
        assert connected.gap_ns is None and connected.connection == 1 and connected.baud == 115200
        consumer.event(ReceiverEventKind.CONFIGURED)
        chunks = consumer.frames("BESTPOS", 10)
        consumer.frames("TIME", 1)
        # a runtime command goes through the same thread
        assert rx.command("LOG COM1 BESTVELB ONTIME 0.1") == Response(True, "OK")
        consumer.frames("BESTVEL", 2)
        health = rx.health()
    finally:
        rx.stop()
    for chunk in chunks:
        assert chunk.receiver == "rover_a" and chunk.connection == 1
        for frame in chunk.frames:
            if frame.log is not None and frame.log.name == "BESTPOS":
                assert frame.kind is FrameKind.NOVATEL_BINARY and isinstance(frame.log.body, BestPos)
    # host receive times come from the injected clock and never go back
    times = [c.host_ns for c in consumer.all_chunks]
    assert times == sorted(times) and times[0] >= START_NS
    # lossless: the chunks' bytes are exactly what the peer sent
    assert b"".join(c.data for c in consumer.all_chunks) == peer.all_written
    assert health.position_type == "NARROW_INT" and health.num_svs == 20 and health.diff_age_s == 1.0
    assert health.leap_seconds == 18
    assert health.crc_failures == 0 and health.rejected_bytes == 0
    assert health.message_counts["RESPONSE"] == len(ROVER_COMMANDS) + 1
    assert 2.0 < health.rates_hz["BESTPOS"] < 40.0  # requested 20 Hz; loose: the machine is shared
    kinds = [e.kind for e in consumer.all_events]
    assert kinds[:2] == [ReceiverEventKind.CONNECTED, ReceiverEventKind.CONFIGURED]
    assert kinds[-1] is ReceiverEventKind.STOPPED


def test_error_response_names_receiver_port_and_command(link: Path) -> None:
    peer = FakePeer(link, errors={"LOG COM1 RANGECMPB": "Invalid Message ID", "FIX POSITION": "Invalid Value"})
    peer.plug()
    commands = ("UNLOGALL", "LOG COM1 RANGECMPB ONTIME 1", "LOG COM1 BESTPOSB ONTIME 0.05")
    consumer = Consumer()
    rx = session(link, commands, consumer)
    try:
        rx.start()
        with pytest.raises(CommandError) as excinfo:
            rx.wait_configured(WAIT)
        message = str(excinfo.value)
        assert "rover_a" in message and str(link) in message
        assert "LOG COM1 RANGECMPB ONTIME 1" in message and "Invalid Message ID" in message
        assert not isinstance(excinfo.value, TimeoutError)
        failed = consumer.event(ReceiverEventKind.COMMAND_FAILED)
        assert failed.command == "LOG COM1 RANGECMPB ONTIME 1"
        consumer.event(ReceiverEventKind.CONFIGURATION_FAILED)
        # the remaining commands were still sent, and the good log streams
        assert [peer.next_command() for _ in commands] == list(commands)
        consumer.frames("BESTPOS", 3)
        assert not rx.configured
        with pytest.raises(CommandError, match=r"FIX POSITION 51.*Invalid Value"):
            rx.command("FIX POSITION 51.0 -114.0 1000.0")
        assert rx.health().command_failures == 2
    finally:
        rx.stop()
        peer.close()


def test_no_answer_times_out_with_the_command_named(link: Path) -> None:
    peer = FakePeer(link, silent=("LOG COM1 RANGECMPB", "SAVECONFIG"))
    peer.plug()
    commands = ("UNLOGALL", "LOG COM1 RANGECMPB ONTIME 1", "LOG COM1 BESTPOSB ONTIME 0.05")
    consumer = Consumer()
    rx = session(link, commands, consumer, command_timeout_s=0.3)
    try:
        rx.start()
        t0 = time.monotonic()
        with pytest.raises(CommandTimeoutError, match=r"rover_a.*LOG COM1 RANGECMPB ONTIME 1") as excinfo:
            rx.wait_configured(WAIT)
        assert isinstance(excinfo.value, TimeoutError) and isinstance(excinfo.value, CommandError)
        assert time.monotonic() - t0 >= 0.3
        # a receiver that does not answer is not sent the rest of the list
        assert [peer.next_command(), peer.next_command()] == list(commands[:2])
        with pytest.raises(queue.Empty):
            peer.commands.get(timeout=0.2)
        t1 = time.monotonic()
        with pytest.raises(CommandTimeoutError, match="SAVECONFIG"):
            rx.command("SAVECONFIG", timeout_s=0.3)
        assert 0.3 <= time.monotonic() - t1 < 3.0
        assert rx.command("UNLOGALL") == Response(True, "OK")
    finally:
        rx.stop()
        peer.close()


def test_garbage_on_the_line_is_counted_and_the_session_carries_on(peer: FakePeer, link: Path) -> None:
    consumer = Consumer()
    rx = session(link, ("UNLOGALL", "LOG COM1 BESTPOSB ONTIME 0.05"), consumer)
    garbage = b"\x01\x02 line noise \x7f\x10" * 3
    try:
        rx.start()
        rx.wait_configured(WAIT)
        consumer.frames("BESTPOS", 2)
        peer.inject(garbage)
        # a corrupted log: a bit flipped in the body of a valid binary frame
        chunks = consumer.frames("BESTPOS", 1)
        good = next(f.raw for c in chunks for f in c.frames if f.kind is FrameKind.NOVATEL_BINARY)
        bad = bytearray(good)
        bad[40] ^= 0x01
        peer.inject(bytes(bad))
        consumer.frames("BESTPOS", 3)
        assert rx.command("UNLOGALL") == Response(True, "OK")
        health = rx.health()
    finally:
        rx.stop()
    assert health.framer.bytes_skipped[SkipReason.GARBAGE] == len(garbage)
    assert health.framer.crc_failures[FrameKind.NOVATEL_BINARY] == 1
    assert health.framer.bytes_skipped[SkipReason.CRC_FAILURE] == len(good)
    assert all(f.raw != bytes(bad) for c in consumer.all_chunks for f in c.frames)
    assert b"".join(c.data for c in consumer.all_chunks) == peer.all_written


def test_unplug_and_replug_reconnects_and_reconfigures(peer: FakePeer, link: Path) -> None:
    consumer = Consumer()
    commands = ("UNLOGALL", "LOG COM1 BESTPOSB ONTIME 0.05", "LOG COM1 TIMEB ONTIME 0.5")
    rx = session(link, commands, consumer)
    try:
        rx.start()
        rx.wait_configured(WAIT)
        consumer.frames("BESTPOS", 3)
        assert [peer.next_command() for _ in commands] == list(commands)
        peer.unplug()
        lost = consumer.event(ReceiverEventKind.DISCONNECTED)
        assert isinstance(lost.error, DeviceError) and str(link) in str(lost.error)
        assert not rx.connected
        consumer.event(ReceiverEventKind.CONNECT_FAILED)  # the link is gone: back-off begins
        with pytest.raises(DeviceError, match="not connected"):
            rx.send_raw(b"\xd3")
        peer.plug()
        back = consumer.event(ReceiverEventKind.CONNECTED)
        assert back.connection == 2 and back.gap_ns is not None and back.gap_ns > 0
        consumer.event(ReceiverEventKind.CONFIGURED)
        assert [peer.next_command() for _ in commands] == list(commands)  # configuration re-sent
        chunks = consumer.frames("BESTPOS", 3)
        assert all(c.connection == 2 for c in chunks)
        health = rx.health()
    finally:
        rx.stop()
    assert health.disconnects == 1 and health.connection == 2 and health.connected
    assert health.last_gap_ns == back.gap_ns and health.total_gap_ns == back.gap_ns
    # nothing lost on either side of the gap
    assert b"".join(c.data for c in consumer.all_chunks) == peer.all_written


def test_corrections_written_with_send_raw_reach_the_receiver(peer: FakePeer, link: Path) -> None:
    consumer = Consumer()
    rx = session(link, ("UNLOGALL",), consumer)
    frame = rtcm_1005(2003, 4_177_000.1, 855_000.2, 4_727_000.3)
    try:
        rx.start()
        rx.wait_configured(WAIT)
        rx.send_raw(frame)
        assert peer.corrections.get(timeout=WAIT) == frame
        assert rx.command("UNLOGALL") == Response(True, "OK")
    finally:
        rx.stop()


def test_baud_detection_finds_the_receiver_rate(link: Path) -> None:
    peer = FakePeer(link, baud=230400)
    peer.plug()
    consumer = Consumer()
    rx = session(link, ("UNLOGALL", "LOG COM1 TIMEB ONTIME 0.1"), consumer, autobaud=True,
                 autobaud_rates=(115200, 57600, 230400), autobaud_probe_s=0.3)
    try:
        rx.start()
        rx.wait_configured(WAIT)
        detected = consumer.event(ReceiverEventKind.BAUD_DETECTED)
        assert detected.baud == 230400
        chunks = consumer.frames("TIME", 2)
        times = [f.log.body for c in chunks for f in c.frames if f.log is not None and f.log.name == "TIME"]
        assert all(isinstance(t, Time) and t.leap_seconds == 18 for t in times)
        assert rx.health().baud == 230400 and rx.health().leap_seconds == 18
    finally:
        rx.stop()
        peer.close()


def test_absent_port_retries_until_it_appears(link: Path) -> None:
    consumer = Consumer()
    rx = session(link, ("UNLOGALL",), consumer)
    peer = FakePeer(link)
    try:
        rx.start()
        failed = consumer.event(ReceiverEventKind.CONNECT_FAILED)
        assert str(link) in failed.message
        with pytest.raises(DeviceTimeoutError, match="rover_a"):
            rx.wait_configured(0.2)
        peer.plug()
        rx.wait_configured(WAIT)
        assert peer.next_command() == "UNLOGALL"
    finally:
        rx.stop()
        peer.close()


def test_stop_returns_at_once_during_back_off(link: Path) -> None:
    consumer = Consumer()
    rx = session(link, ("UNLOGALL",), consumer, reconnect_first_s=30.0, reconnect_max_s=30.0)
    rx.start()
    consumer.event(ReceiverEventKind.CONNECT_FAILED)
    t0 = time.monotonic()
    rx.stop()
    assert time.monotonic() - t0 < 1.0
    assert not any(t.name == "novatel-rover_a" for t in threading.enumerate())
    consumer.event(ReceiverEventKind.STOPPED)


def test_stop_returns_at_once_while_a_command_waits(link: Path) -> None:
    peer = FakePeer(link, silent=("UNLOGALL",))
    peer.plug()
    consumer = Consumer()
    rx = session(link, ("UNLOGALL",), consumer, command_timeout_s=30.0)
    try:
        rx.start()
        assert peer.next_command() == "UNLOGALL"
        t0 = time.monotonic()
        rx.stop()
        assert time.monotonic() - t0 < 1.0
        with pytest.raises(DeviceError, match="not running"):
            rx.command("UNLOGALL")
    finally:
        peer.close()


def test_consumer_errors_are_reported_not_fatal(peer: FakePeer, link: Path) -> None:
    consumer = Consumer()
    calls = []

    def flaky(chunk: ReceivedChunk) -> None:
        calls.append(chunk)
        if len(calls) == 1:
            raise RuntimeError("consumer bug")
        consumer.on_data(chunk)

    rx = NovatelReceiver(settings(link, ("UNLOGALL", "LOG COM1 BESTPOSB ONTIME 0.05")), on_data=flaky,
                         on_event=consumer.on_event)
    try:
        rx.start()
        failed = consumer.event(ReceiverEventKind.CALLBACK_FAILED)
        assert "consumer bug" in failed.message
        rx.wait_configured(WAIT)
        consumer.frames("BESTPOS", 2)
        assert rx.health().callback_failures == 1
    finally:
        rx.stop()


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"rover_a.*command_timeout_s"):
        ReceiverSettings("rover_a", "/dev/null", command_timeout_s=0)
    with pytest.raises(ConfigError, match="line break"):
        ReceiverSettings("rover_a", "/dev/null", commands=("LOG COM1 BESTPOSB\r\nFRESET",))
