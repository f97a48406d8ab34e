"""A stalled stream is a live alarm: the session marks its device DEGRADED, the dashboard shows an ALARM line."""

from __future__ import annotations

import io

from rich.console import Console

from rig.live.dashboard import Dashboard, alarm_lines
from rig.record.status import DeviceState, StatusBoard
from tests.recorder.helpers import T0, ManualClock


def test_a_degraded_device_is_an_alarm_line_with_its_latest_event() -> None:
    board = StatusBoard("run", now_ns=T0)
    board.add_device("can.vsc", "can")
    board.add_device("rover_a", "gnss")
    board.message("can.vsc", T0)
    assert alarm_lines(board.snapshot(T0)) == []
    board.update("can.vsc", state=DeviceState.DEGRADED, detail="812 fr/s")
    board.event("can.vsc: STALLED: no /can/vsc/roles for 3.2 s")
    assert alarm_lines(board.snapshot(T0)) == [
        "ALARM can.vsc degraded — STALLED: no /can/vsc/roles for 3.2 s (812 fr/s)"]
    board.update("can.vsc", state=DeviceState.OK)
    assert alarm_lines(board.snapshot(T0)) == []


def test_the_plain_dashboard_prints_the_alarm_before_the_status_line() -> None:
    board = StatusBoard("run", now_ns=T0)
    board.add_device("can.vsc", "can")
    board.update("can.vsc", state=DeviceState.DEGRADED)
    board.event("can.vsc: STALLED: no /can/vsc/frames for 1.0 s")
    buf = io.StringIO()
    dash = Dashboard(board, ManualClock(), on_mark=lambda m: None, console=Console(file=buf, width=200),
                     keys=io.StringIO(), plain_period_s=60.0)
    dash.start()
    dash.stop()
    lines = buf.getvalue().splitlines()
    assert lines[0] == "ALARM can.vsc degraded — STALLED: no /can/vsc/frames for 1.0 s"
    assert "can.vsc=degraded" in lines[1]
