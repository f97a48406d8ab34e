"""Dashboard: operator marks from keys, live view on a terminal, plain lines off a terminal."""

from __future__ import annotations

import io
import os
import queue

from rich.console import Console

from rig.live.dashboard import Dashboard, Mark, MarkInput
from rig.record.status import StatusBoard
from vsccore.clock import SystemClock


def test_mark_time_is_the_key_press_not_the_enter() -> None:
    keys = MarkInput()
    assert keys.feed("x", 1) is None  # other keys do nothing outside a mark
    assert not keys.editing
    assert keys.feed("m", 100) is None
    assert keys.editing
    for i, ch in enumerate("cone 3 hitt"):
        assert keys.feed(ch, 200 + i) is None
    keys.feed("\x7f", 300)  # backspace
    assert "cone 3 hit" in keys.prompt
    assert keys.feed("\r", 900) == Mark(100, "cone 3 hit")
    assert not keys.editing
    keys.feed("m", 1000)
    assert keys.feed("\x1b", 1001) == Mark(1000, "")


def test_plain_lines_when_not_a_terminal() -> None:
    out = io.StringIO()
    clock = SystemClock()
    board = StatusBoard("run7", now_ns=clock.now_ns())
    board.add_device("rover_a", "novatel")
    board.message("rover_a", clock.now_ns())
    board.vehicle(speed_kmh=50.0, baseline_m=1.581, baseline_nominal_m=1.58, ltr=0.95, ltr_warning=True)
    dash = Dashboard(board, clock, on_mark=lambda m: None, console=Console(file=out), keys=io.StringIO(),
                     plain_period_s=0.05)
    assert not dash.interactive
    dash.start()
    dash.stop()
    text = out.getvalue()
    assert "rover_a=ok" in text
    assert "speed 50.0 km/h" in text
    assert "ROLLOVER WARNING" in text
    assert "\x1b[" not in text  # no cursor control or colours in plain output


def test_marks_typed_on_a_terminal_reach_the_session() -> None:
    master, slave = os.openpty()
    keys = os.fdopen(slave, "r", closefd=True)
    marks: queue.Queue[Mark] = queue.Queue()
    clock = SystemClock()
    board = StatusBoard("run8", now_ns=clock.now_ns())
    out = io.StringIO()
    dash = Dashboard(board, clock, on_mark=marks.put, console=Console(file=out, force_terminal=True, width=150),
                     keys=keys, refresh_hz=50.0)
    assert dash.interactive
    before = clock.now_ns()
    dash.start()
    try:
        os.write(master, b"mbrake test\r")
        mark = marks.get(timeout=10)
    finally:
        dash.stop()
        keys.close()
        os.close(master)
    assert mark.note == "brake test"
    assert mark.host_ns >= before
    assert "vsc-rig" in out.getvalue()
