"""The receiver's message rates: a periodic stream's rate from its intervals, not from the time since its first
message (which read a 10 Hz log as 7.8 Hz at the end of a 1.5 s monitor run, CI 2026-12-08)."""

from __future__ import annotations

import pytest

from drivers.novatel.receiver import _RateMeter

NS = 1_000_000_000


def test_a_periodic_stream_reads_its_rate_however_long_ago_its_last_message_came() -> None:
    meter = _RateMeter(5 * NS)
    for k in range(11):
        meter.add("BESTPOS", k * NS // 10)
    assert meter.rates(1 * NS)["BESTPOS"] == pytest.approx(10.0)
    assert meter.rates(1_400_000_000)["BESTPOS"] == pytest.approx(10.0)  # old figure: 11 / 1.4 s = 7.9 Hz
    assert meter.rates(7 * NS)["BESTPOS"] == 0.0  # gone from the window: no rate


def test_one_message_reads_one_over_its_age() -> None:
    meter = _RateMeter(5 * NS)
    meter.add("TIME", 0)
    assert meter.rates(2 * NS)["TIME"] == pytest.approx(0.5)
