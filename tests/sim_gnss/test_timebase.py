"""Time base and sync schedule: host clock ↔ GPS ↔ truth time against calendar arithmetic."""

from __future__ import annotations

import datetime as dt

import pytest

from sim_devices.gnss import SimTimeBase, SyncSchedule
from vsccore.errors import SimulationError

GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.UTC)


def test_gps_start_maps_to_utc_with_leap_seconds() -> None:
    tb = SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18)
    expected_utc = GPS_EPOCH + dt.timedelta(weeks=2400, seconds=345600 - 18)
    assert tb.truth_start_ns == int(expected_utc.timestamp()) * 1_000_000_000
    assert tb.truth_s(tb.truth_start_gps_ns) == 0.0
    gps = tb.gps_ns_of_truth(12.345)
    assert tb.truth_s(gps) == pytest.approx(12.345, abs=1e-9)
    assert tb.gps_ns(tb.clock_ns(gps)) == gps


def test_host_clock_offset_shifts_only_the_host_side() -> None:
    good = SimTimeBase.from_gps_start(2400, 0.0)
    off = SimTimeBase.from_gps_start(2400, 0.0, host_clock_offset_ns=250_000_000)
    assert off.truth_start_gps_ns == good.truth_start_gps_ns
    assert off.clock_ns(good.truth_start_gps_ns) - good.clock_ns(good.truth_start_gps_ns) == 250_000_000


def test_sync_schedule_queries() -> None:
    tb = SimTimeBase.from_gps_start(2400, 100.0)
    sched = SyncSchedule.for_truth(tb, 1.0, 5.0, period_s=1.0)
    assert sched.truth_times_s(tb) == pytest.approx((1.0, 2.0, 3.0, 4.0))
    p = sched.pulse_gps_ns
    assert sched.between(p[0], p[2]) == (p[1], p[2])
    assert sched.next_after(p[1]) == p[2]
    assert sched.next_after(p[-1]) is None
    with pytest.raises(SimulationError):
        SyncSchedule((3, 2))
