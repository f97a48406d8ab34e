"""GNSS log bytes a simulated receiver drops because its reader is behind reach ``/rig/events``.

The pty of a simulated port holds only so much; when the reader that has it open falls behind, the
receiver drops what does not fit. The sim world reads the per-port figure (from the device process
too, over its pipe) and writes a warning event naming the receiver, the port and the bytes, when it
first sees it and with the total at the end; :meth:`SimWorld.health` counts it as ``bytes_dropped``.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import pytest

from rig.core.topics import EventKind, Severity
from rig.sim.world import SimWorld
from tests.session.recording import FAST_RTK, config


@dataclass
class _Source:
    events: list[tuple[EventKind, str, Severity, dict[str, Any]]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def put(self, topic: str, log_ns: int, publish_ns: int, payload: bytes) -> bool:
        return True

    def event(self, kind: EventKind, text: str, *, severity: Severity = Severity.INFO, **details: Any) -> bool:
        with self.lock:
            self.events.append((kind, text, severity, details))
        return True

    def losses(self) -> list[tuple[EventKind, str, Severity, dict[str, Any]]]:
        with self.lock:
            return [e for e in self.events if "bytes_dropped" in e[3]]


@dataclass
class _Recorder:
    src: _Source

    def source(self, name: str, maxsize: int = 0) -> _Source:
        return self.src


@dataclass
class _Session:
    recorder: _Recorder


@pytest.mark.parametrize("device_process", [False, True], ids=["in-process", "device-process"])
def test_log_bytes_lost_to_a_reader_that_is_behind_are_an_event_and_a_health_figure(device_process: bool) -> None:
    cfg = config("straight:duration_s=12", 4.0)
    world = SimWorld(cfg, rtk=FAST_RTK, lead_s=4.0, device_process=device_process, governed=False)
    src = _Source()
    world.start()
    try:
        world.attach(_Session(_Recorder(src)))  # type: ignore[arg-type]
        rc = next(r for r in cfg.receivers if r.name == "rover_a")
        fd = os.open(world.port(rc), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            # ask for plenty of logs, then never read: the pty fills and the receiver drops the rest
            os.write(fd, b"UNLOGALL\r\nLOG RANGEB ONTIME 0.05\r\nLOG BESTPOSB ONTIME 0.05\r\n")
            deadline = time.monotonic() + 30.0
            while not src.losses():
                assert time.monotonic() < deadline, "no event for the lost bytes within 30 s"
                world.report_device_losses()
                threading.Event().wait(0.05)  # bounded by the deadline above
            first = src.losses()
            assert len(first) == 1
            kind, text, severity, details = first[0]
            assert kind is EventKind.WARNING and severity is Severity.WARNING
            assert details["receiver"] == "rover_a" and details["port"] == "COM1" and details["bytes_dropped"] > 0
            assert text.startswith("simulated rover_a dropped ") and " bytes on COM1: the pty was full" in text
            world.report_device_losses()  # the same loss is not reported twice while it runs
            assert len(src.losses()) == 1
            # the loss goes on while the reader does not read: the total at the end is larger
            deadline = time.monotonic() + 30.0
            while world.health()["gnss:rover_a"]["bytes_dropped"] <= details["bytes_dropped"]:
                assert time.monotonic() < deadline, "no further loss within 30 s"
                world.report_device_losses()
                threading.Event().wait(0.05)
            world.detach(_Session(_Recorder(src)))  # type: ignore[arg-type]
        finally:
            os.close(fd)
    finally:
        world.stop()
    losses = src.losses()
    assert len(losses) == 2, [e[1] for e in losses]
    final = losses[1][3]
    assert (final["receiver"], final["port"]) == ("rover_a", "COM1")
    assert final["bytes_dropped"] > details["bytes_dropped"]
    health = world.health()
    assert health["gnss:rover_a"]["bytes_dropped"] == health["gnss:rover_a"]["bytes_dropped:COM1"]
    assert health["gnss:rover_a"]["bytes_dropped"] >= final["bytes_dropped"]
    # ports nobody opened drop bytes too, but no reader lost them: no figure, no event
    assert all(health[f"gnss:{rx}"]["bytes_dropped"] == 0 for rx in ("base", "rover_b"))
