"""The live status board: rates, states and what the dashboard shows."""

from __future__ import annotations

import threading

from rich.console import Console

from rig.record.status import DeviceState, StatusBoard, render_status

S = 1_000_000_000


def test_rate_and_state_from_messages() -> None:
    board = StatusBoard("run1", now_ns=0)
    board.add_device("rover_a", "novatel")
    for k in range(41):  # 20 Hz for 2 s
        board.message("rover_a", 10 * S + k * S // 20)
    snap = board.snapshot(12 * S)
    (dev,) = snap.devices
    assert dev.state is DeviceState.OK
    assert dev.messages == 41
    assert abs(dev.rate_hz - 20.0) < 1e-6
    assert snap.elapsed_s == 12.0


def test_lost_device_is_red_and_rate_decays() -> None:
    board = StatusBoard("run1", now_ns=0)
    board.add_device("vsc", "can")
    board.message("vsc", 1 * S)
    board.message("vsc", 1 * S + S // 100)
    board.update("vsc", state=DeviceState.LOST, detail="interface gone")
    board.error("vsc")
    snap = board.snapshot(10 * S)
    (dev,) = snap.devices
    assert dev.state is DeviceState.LOST
    assert dev.rate_hz == 0.0  # no message inside the 2 s window
    console = Console(width=140, record=True)
    console.print(render_status(snap, 10 * S))
    text = console.export_text()
    assert "lost" in text
    assert "interface gone" in text
    assert "9.0 s" in text  # age of the last message


def test_concurrent_updates_are_all_counted() -> None:
    board = StatusBoard("run1", now_ns=0)
    names = [f"d{i}" for i in range(4)]
    for n in names:
        board.add_device(n, "x")

    def hammer(name: str) -> None:
        for k in range(2000):
            board.message(name, k)

    threads = [threading.Thread(target=hammer, args=(n,)) for n in names]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert all(d.messages == 2000 for d in board.snapshot(2000).devices)
