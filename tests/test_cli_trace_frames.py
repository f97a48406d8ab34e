"""`--debug` shows debug logs but not every CAN frame; `--trace-frames` adds the frames.

A real `rig can monitor` process reads a socketcand server (python-can's socketcand interface logs
each received frame at DEBUG level) while this test puts frames on the served virtual bus.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator

import can
import pytest

from sim_devices.socketcand import SocketcandServer, virtual_channel_opener

FRAME_LINE = "Received Ascii Message"


@pytest.fixture
def served() -> Iterator[tuple[SocketcandServer, str]]:
    channel = f"trace-{uuid.uuid4().hex}"
    server = SocketcandServer(virtual_channel_opener({"vcan0": channel}))
    server.start()
    try:
        yield server, channel
    finally:
        server.stop()


def _monitor(server: SocketcandServer, channel: str, *global_options: str) -> subprocess.CompletedProcess[str]:
    host, port = server.address
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
    stop = threading.Event()

    def send() -> None:
        with can.Bus(interface="virtual", channel=channel) as ecu:
            ident = 0
            while not stop.wait(0.01):  # 100 frames/s until the monitor ends
                ecu.send(can.Message(arbitration_id=0x100 + ident % 16, data=bytes([ident % 256] * 8)))
                ident += 1

    sender = threading.Thread(target=send, name="trace-frames-sender")
    sender.start()
    try:
        return subprocess.run(
            [sys.executable, "-m", "rig", *global_options, "can", "monitor", "--interface", "socketcand",
             "--host", host, "--port", str(port), "--channel", "vcan0", "--duration", "2", "--interval", "0.5"],
            capture_output=True, text=True, timeout=120, env=env, check=False,
        )
    finally:
        stop.set()
        sender.join(5)


def test_debug_does_not_log_every_frame(served: tuple[SocketcandServer, str]) -> None:
    proc = _monitor(*served, "--debug")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert " DEBUG " in proc.stderr  # debug logging is on
    assert FRAME_LINE not in proc.stderr
    assert "frames" in proc.stdout.lower()  # frames did arrive


def test_trace_frames_logs_them(served: tuple[SocketcandServer, str]) -> None:
    proc = _monitor(*served, "--trace-frames")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stderr.count(FRAME_LINE) >= 20
