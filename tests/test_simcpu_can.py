"""The CAN reader's per-frame work made cheaper: bus time measured only for frames still in the load
window, message counting on the status board without a record per message."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.bus import BusLoadMeter, frame_bit_times
from rig.record.status import DeviceState, StatusBoard

BITRATE = 500_000


def _frames(n: int, seed: int) -> list[tuple[int, bool, bytes]]:
    rng = np.random.default_rng(seed)
    ids = rng.choice([0x86, 0xB2, 0xFD, 0x101, 0x106, 0x5A0], n)
    return [(int(i), False, rng.integers(0, 256, 8, dtype=np.uint8).tobytes()) for i in ids]


def test_deferred_bus_time_equals_the_eager_one_and_is_computed_only_in_the_window() -> None:
    calls = 0

    def duration(frame: tuple[int, bool, bytes]) -> float:
        nonlocal calls
        calls += 1
        return frame_bit_times(*frame)[0] / BITRATE

    frames = _frames(10_000, 1)
    lazy = BusLoadMeter(1.0, duration)
    eager = BusLoadMeter(1.0)
    t = 0
    for k, f in enumerate(frames):  # 10 s at 1000 frames/s, one error frame in 50
        t += 1_000_000
        is_error = k % 50 == 0
        if is_error:
            lazy.add(t, 0.0, True)
            eager.add(t, 0.0, True)
        else:
            lazy.add_frame(t, f)
            eager.add(t, frame_bit_times(*f)[0] / BITRATE)
    got, want = lazy.rates(), eager.rates()
    assert got[0] == pytest.approx(want[0], rel=1e-12) and got[1] == pytest.approx(want[1], rel=1e-12)
    assert got[2] == pytest.approx(want[2], rel=1e-9)  # the same sum, in one pass instead of a running one
    assert 0.2 < got[2] < 0.3  # ~125 bits per frame at 1000 frames/s on 500 kbit/s
    assert calls <= 1000  # only the last second's frames were measured, not all 10 000
    assert lazy.rates() == got and calls <= 1000  # measured once


def test_deferred_meter_restarts_when_the_clock_steps_back() -> None:
    meter = BusLoadMeter(1.0, lambda f: 1e-4)
    for k in range(10):
        meter.add_frame(1_000_000_000 + k * 10_000_000, None)
    meter.add_frame(5_000_000, None)  # adapter reset: a new window
    assert meter.rates() == (0.0, 0.0, 0.0)
    meter.add_frame(15_000_000, None)
    rate, errors, busy = meter.rates()
    assert rate == pytest.approx(100.0) and errors == 0.0 and busy == pytest.approx(1e-4 * 100.0)


def test_add_frame_needs_a_duration_function() -> None:
    with pytest.raises(ValueError, match="duration_of"):
        BusLoadMeter(1.0).add_frame(0, None)


def test_status_board_counts_messages_and_reports_them_in_the_snapshot() -> None:
    s = 1_000_000_000
    board = StatusBoard("unit", now_ns=0)
    board.add_device("can.vsc", "can")
    assert board.snapshot(0).devices[0].state is DeviceState.STARTING
    for k in range(100):
        board.message("can.vsc", s + k * s // 100)  # 100 Hz for a second
    board.update("can.vsc", detail="360 fr/s")
    board.error("can.vsc")
    d = board.snapshot(2 * s).devices[0]
    assert (d.messages, d.last_host_ns, d.state, d.detail, d.errors) == (100, s + 99 * s // 100, DeviceState.OK,
                                                                       "360 fr/s", 1)
    assert d.rate_hz == pytest.approx(100.0)
    board.update("can.vsc", state=DeviceState.LOST)
    assert board.snapshot(2 * s).devices[0].state is DeviceState.LOST
    board.message("can.vsc", 3 * s)  # a lost device that sends again is OK
    d = board.snapshot(3 * s).devices[0]
    assert d.state is DeviceState.OK and d.messages == 101 and d.last_host_ns == 3 * s
    board.update("can.vsc", state=DeviceState.DEGRADED)
    board.message("can.vsc", 4 * s)  # a degraded one stays degraded
    assert board.snapshot(4 * s).devices[0].state is DeviceState.DEGRADED
