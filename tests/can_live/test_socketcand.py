"""The socketcand server against python-can's own socketcand client (both directions, several clients)."""

from __future__ import annotations

import logging
import queue
import socket
import time
from collections.abc import Iterator

import can
import pytest
from can.interfaces.socketcand.socketcand import (
    convert_ascii_message_to_can_message,
    convert_can_message_to_ascii_message,
)

from drivers.can.bus import BusGap, BusLost, CanBusConfig, CanBusLink, CanFrame, open_bus
from sim_devices.socketcand import SocketcandServer, format_frame, parse_send, virtual_channel_opener
from vsccore.clock import SystemClock
from vsccore.errors import DeviceError


@pytest.fixture
def server(channel: str) -> Iterator[SocketcandServer]:
    srv = SocketcandServer(virtual_channel_opener({"vcan0": channel}))
    srv.start()
    try:
        yield srv
    finally:
        srv.stop()


def _client(srv: SocketcandServer) -> can.BusABC:
    host, port = srv.address
    return can.Bus(interface="socketcand", host=host, port=port, channel="vcan0")


def _until_forwarding(ecu: can.BusABC, client: can.BusABC, timeout: float = 3.0) -> can.Message:
    """Frames sent before a client's raw mode has settled are not forwarded: probe until one arrives."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ecu.send(can.Message(timestamp=1.0, arbitration_id=0x7FF, data=b"probe"))
        msg = client.recv(0.1)
        if msg is not None:
            return msg
    raise AssertionError(f"client not forwarding within {timeout} s")


def _recv(bus: can.BusABC, timeout: float = 3.0) -> can.Message:
    msg = bus.recv(timeout)
    assert msg is not None, "no frame within timeout"
    return msg


FRAMES = [
    can.Message(
        timestamp=12.345678, arbitration_id=0x101, data=bytes([0xA7, 0x70, 0, 1, 2, 3, 4, 5]), is_extended_id=False
    ),
    can.Message(timestamp=12.5, arbitration_id=0x18FEF100, data=b"\x01\xf1", is_extended_id=True),
    can.Message(timestamp=13.0, arbitration_id=0x00A, data=b"", is_extended_id=False),
]


# --- the line format against python-can's own converters --------------------------------------


@pytest.mark.parametrize("msg", FRAMES)
def test_frame_lines_parse_with_python_cans_client_code(msg: can.Message) -> None:
    back = convert_ascii_message_to_can_message(format_frame(msg))
    assert back.arbitration_id == msg.arbitration_id
    assert back.is_extended_id == msg.is_extended_id
    assert bytes(back.data) == bytes(msg.data)
    assert back.timestamp == pytest.approx(msg.timestamp, abs=1e-6)


def test_error_frames_parse_as_error_frames_with_their_class() -> None:
    line = format_frame(can.Message(timestamp=5.25, arbitration_id=0x040, is_error_frame=True, data=bytes(8)))
    assert line == "< error 040 5.250000 >"  # socketcand's own format: class, then time
    back = convert_ascii_message_to_can_message(line)
    assert back.is_error_frame
    assert back.arbitration_id == 0x040


@pytest.mark.parametrize("msg", FRAMES)
def test_send_commands_from_python_cans_client_parse(msg: can.Message) -> None:
    parsed = parse_send(convert_can_message_to_ascii_message(msg))
    assert parsed is not None
    assert (parsed.arbitration_id, parsed.is_extended_id, bytes(parsed.data)) == (
        msg.arbitration_id,
        msg.is_extended_id,
        bytes(msg.data),
    )


@pytest.mark.parametrize(
    "bad", ["< send 123 9 1 2 3 4 5 6 7 8 9 >", "< send 123 2 1 >", "< send XYZ 1 0 >", "< send 800 0 >", "< send >"]
)
def test_malformed_send_commands_are_rejected(bad: str) -> None:
    assert parse_send(bad) is None


# --- live, through python-can's socketcand interface -------------------------------------------


def test_client_receives_the_bus_frames_and_sends_back(server: SocketcandServer, channel: str) -> None:
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as ecu, _client(server) as client:
        assert server.wait_for_clients(1, 3.0)
        assert _until_forwarding(ecu, client).arbitration_id == 0x7FF
        while client.recv(0.05) is not None:  # drain further probes
            pass
        for m in FRAMES:
            ecu.send(m)
        got = [_recv(client) for _ in FRAMES]
        for sent, rx in zip(FRAMES, got, strict=True):
            assert (rx.arbitration_id, rx.is_extended_id, bytes(rx.data)) == (
                sent.arbitration_id,
                sent.is_extended_id,
                bytes(sent.data),
            )
            assert rx.timestamp == pytest.approx(sent.timestamp, abs=1e-6)
        client.send(can.Message(arbitration_id=0x1ABCDEF0, data=b"\x11\x22\x33", is_extended_id=True))
        client.send(can.Message(arbitration_id=0x321, data=bytes(range(8)), is_extended_id=False))
        a, b = _recv(ecu), _recv(ecu)
        assert (a.arbitration_id, a.is_extended_id, bytes(a.data)) == (0x1ABCDEF0, True, b"\x11\x22\x33")
        assert (b.arbitration_id, b.is_extended_id, bytes(b.data)) == (0x321, False, bytes(range(8)))


def _drain_until(bus: can.BusABC, ident: int, timeout: float = 3.0) -> can.Message:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = bus.recv(0.1)
        if msg is not None and msg.arbitration_id == ident:
            return msg
    raise AssertionError(f"no frame 0x{ident:X} within {timeout} s")


def test_two_clients_share_the_bus_and_one_disconnecting_leaves_the_other(
    server: SocketcandServer, channel: str
) -> None:
    with can.Bus(interface="virtual", channel=channel) as ecu:
        a = _client(server)
        b = _client(server)
        try:
            assert server.wait_for_clients(2, 3.0)
            for client in (a, b):
                _until_forwarding(ecu, client)
            ecu.send(can.Message(arbitration_id=0x555, data=b"\x55"))
            assert bytes(_drain_until(a, 0x555).data) == b"\x55"
            assert bytes(_drain_until(b, 0x555).data) == b"\x55"
            # a frame from client A reaches the ECU and client B
            a.send(can.Message(arbitration_id=0x0AA, data=b"\xaa", is_extended_id=False))
            assert bytes(_drain_until(ecu, 0x0AA).data) == b"\xaa"
            assert bytes(_drain_until(b, 0x0AA).data) == b"\xaa"
        finally:
            a.shutdown()
        assert server.wait_for_clients(1, 3.0)
        ecu.send(can.Message(arbitration_id=0x666, data=b"\x66"))
        assert bytes(_drain_until(b, 0x666).data) == b"\x66"
        b.shutdown()
        assert server.wait_for_clients(0, 3.0)


def test_unknown_bus_name_is_refused(server: SocketcandServer) -> None:
    with socket.create_connection(server.address, timeout=3.0) as sock:
        assert sock.recv(64) == b"< hi >"
        sock.sendall(b"< open can7 >")
        assert sock.recv(64) == b"< error could not open bus >"
        assert sock.recv(64) == b""  # and the server hangs up, as socketcand does
    assert server.wait_for_clients(0, 3.0)
    # the bus session's probe turns that into a DeviceError naming the bus (python-can's own client
    # would raise CanError and leak its socket)
    host, port = server.address
    config = CanBusConfig(interface="socketcand", channel="can7", name="chassis", options={"host": host, "port": port})
    with pytest.raises(DeviceError, match=r"chassis.*refused bus 'can7'"):
        open_bus(config)


def _raw_session(srv: SocketcandServer) -> socket.socket:
    sock = socket.create_connection(srv.address, timeout=3.0)
    assert sock.recv(64) == b"< hi >"
    sock.sendall(b"< open vcan0 >")
    assert sock.recv(64) == b"< ok >"
    sock.sendall(b"< rawmode >")
    assert sock.recv(64) == b"< ok >"
    return sock


def test_garbage_and_malformed_commands_do_not_break_the_server(server: SocketcandServer, channel: str) -> None:
    with can.Bus(interface="virtual", channel=channel) as ecu:
        sock = _raw_session(server)
        with sock:
            sock.sendall(b"\x00\xff junk >>> < send ZZZ 1 00 > < send 123 2 1 >" + b"x" * 300)
            sock.sendall(b"< send 12 2 0A ff >< echo >")
            msg = _drain_until(ecu, 0x12)
            assert bytes(msg.data) == b"\x0a\xff"
            # the reply to echo arrives, possibly after forwarded frames
            buf = b""
            deadline = time.monotonic() + 3.0
            while b"< echo >" not in buf and time.monotonic() < deadline:
                buf += sock.recv(4096)
            assert b"< echo >" in buf
            sock.sendall(b"< frobnicate >")
            while b"< error unknown command >" not in buf and time.monotonic() < deadline:
                buf += sock.recv(4096)
            assert b"< error unknown command >" in buf
        assert server.wait_for_clients(0, 3.0)


def test_stop_with_clients_connected_is_prompt(channel: str) -> None:
    srv = SocketcandServer(virtual_channel_opener({"vcan0": channel}))
    srv.start()
    sock = _raw_session(srv)
    client = _client(srv)
    try:
        assert srv.wait_for_clients(2, 3.0)
        t = time.monotonic()
        srv.stop()
        assert time.monotonic() - t < 1.0
        assert sock.recv(64) == b""  # the server hung up
    finally:
        sock.close()
        client.shutdown()


def _until_received(ecu: can.BusABC, frames: queue.Queue[CanFrame], ident: int, timeout: float = 5.0) -> CanFrame:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ecu.send(can.Message(arbitration_id=ident, data=b"\x01"))
        try:
            frame = frames.get(timeout=0.1)
        except queue.Empty:
            continue
        if frame.arbitration_id == ident:
            return frame
    raise AssertionError(f"frame 0x{ident:X} not received within {timeout} s")


def test_bus_session_over_socketcand_recovers_when_the_server_comes_back(channel: str) -> None:
    frames: queue.Queue[CanFrame] = queue.Queue()
    events: queue.Queue[object] = queue.Queue()
    srv = SocketcandServer(virtual_channel_opener({"vcan0": channel}))
    srv.start()
    port = srv.address[1]
    config = CanBusConfig(interface="socketcand", channel="vcan0", options={"host": "127.0.0.1", "port": port})
    session = CanBusLink(
        config,
        frames.put,
        events.put,
        clock=SystemClock(),
        silence_timeout_s=0.3,
        backoff_initial_s=0.05,
        backoff_max_s=0.2,
    )

    def wait_for(kind: type) -> object:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            e = events.get(timeout=deadline - time.monotonic())
            if isinstance(e, kind):
                return e
        raise AssertionError(f"no {kind.__name__}")

    with can.Bus(interface="virtual", channel=channel) as ecu:
        session.start()
        try:
            assert _until_received(ecu, frames, 0x101).arbitration_id == 0x101
            srv.stop()  # the remote bus disappears
            lost = wait_for(BusLost)
            srv = SocketcandServer(virtual_channel_opener({"vcan0": channel}), port=port)
            srv.start()
            gap = wait_for(BusGap)
            assert isinstance(gap, BusGap)
            assert gap.recovered
            assert gap.start_ns == lost.host_ts_ns
            assert _until_received(ecu, frames, 0x102).arbitration_id == 0x102
        finally:
            session.stop()
            srv.stop()


def test_open_bus_quiets_only_python_cans_split_frame_warning(server: SocketcandServer,
                                                             caplog: pytest.LogCaptureFixture) -> None:
    host, port = server.address
    bus = open_bus(CanBusConfig("socketcand", "vcan0", bitrate=None, options={"host": host, "port": port}))
    try:
        logger = logging.getLogger("can.interfaces.socketcand.socketcand")
        with caplog.at_level(logging.WARNING, logger=logger.name):
            logger.warning("Got incomplete message => waiting for more data")  # a frame split across reads
            logger.warning("Bad data: No opening < found => discarding entire buffer 'xx'")
        # warnings only: python-can's INFO lines (its "connected with address" on open) reach the
        # capture when an earlier test in this process ran the CLI, which sets python-can's level
        texts = [r.getMessage() for r in caplog.records if r.name == logger.name and r.levelno >= logging.WARNING]
        assert texts == ["Bad data: No opening < found => discarding entire buffer 'xx'"]
    finally:
        bus.shutdown()


def test_open_bus_sends_without_nagle_delay(server: SocketcandServer) -> None:
    """A small ``< send >`` must leave at once: with Nagle's algorithm on (python-can's default), a
    replayed frame could wait for the previous command's delayed ACK (up to 40 ms)."""
    import socket

    host, port = server.address
    bus = open_bus(CanBusConfig("socketcand", "vcan0", bitrate=None, options={"host": host, "port": port}))
    try:
        sock = bus._SocketCanDaemonBus__socket  # type: ignore[attr-defined]  # python-can's private socket
        assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
    finally:
        bus.shutdown()
