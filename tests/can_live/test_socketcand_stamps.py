"""The socketcand server stamps a frame a client sends with its arrival, not with the time its command thread
gets round to it (the HIL replay's 1x timing is measured on these stamps by a receiving recorder)."""

from __future__ import annotations

import sys
import threading
import time

import can
import pytest

from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from tests.waiting import wait_until


def _queued_at(port: int) -> bool:
    """Bytes wait unread in an established TCP socket of local port ``port`` (Linux's /proc/net/tcp rx_queue)."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for line in f.readlines()[1:]:
                fields = line.split()
                local, state, queues = fields[1], fields[3], fields[4]
                if int(local.rsplit(":", 1)[1], 16) == port and state == "01" and int(queues.split(":")[1], 16) > 0:
                    return True
    return False


@pytest.mark.skipif(sys.platform != "linux", reason="the kernel's TCP receive stamps (SO_TIMESTAMPNS) are Linux's")
def test_a_sent_frame_is_stamped_at_its_arrival_while_the_server_thread_is_held_up(channel: str) -> None:
    """The command thread is held in its bus's ``send`` of frame A (as a busy process holds it from the CPU or
    the interpreter lock) while the client sends B: B is stamped when it reached the server (before the thread
    was let go), not after. The frame's bytes are what the client sent."""
    entered, release = threading.Event(), threading.Event()
    base = virtual_channel_opener({"vcan0": channel})

    def opener(name: str) -> can.BusABC:
        bus = base(name)
        send = bus.send

        def held_send(msg: can.Message, timeout: float | None = None) -> None:
            if not entered.is_set():
                entered.set()
                release.wait(5.0)
            send(msg, timeout)

        bus.send = held_send  # type: ignore[method-assign]
        return bus

    with SocketcandServer(opener, rawmode_settle_s=0.0) as server, \
            can.Bus(interface="virtual", channel=channel) as ecu:
        host, port = server.address
        with can.Bus(interface="socketcand", host=host, port=port, channel="vcan0", tcp_tune=True) as client:
            try:
                client.send(can.Message(arbitration_id=0x0A1, data=b"\x01", is_extended_id=False))
                assert entered.wait(5.0), "the server did not take frame A"
                before_b = time.time()
                client.send(can.Message(arbitration_id=0x0B2, data=b"\x02\x03", is_extended_id=False))
                # B has reached the server once its bytes wait in the server's socket (a busy host may take
                # the loopback delivery past the client's send by milliseconds): only then let the thread go
                assert wait_until(lambda: _queued_at(port), every_s=0.001), "frame B never reached the server's socket"
                let_go = time.time()
            finally:
                release.set()
            a, b = ecu.recv(5.0), ecu.recv(5.0)
    assert a is not None and b is not None, "frames not on the bus"
    assert (a.arbitration_id, bytes(a.data), b.arbitration_id, bytes(b.data)) == (0x0A1, b"\x01", 0x0B2, b"\x02\x03")
    assert before_b - 1e-6 <= b.timestamp < let_go, (b.timestamp - before_b, let_go - before_b)
    assert a.timestamp <= b.timestamp
