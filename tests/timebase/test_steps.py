"""The time base's one deliberate jump — the host-time estimate replaced by GPS-derived UTC when the leap
seconds become known — is decided in Timebase.set_leap_seconds and recorded as a step."""

from __future__ import annotations

import numpy as np

from rig.timebase import ClockEstimator, Timebase
from vsccore.gpstime import GPS_EPOCH_UNIX_NS

MS = 1_000_000
NS = 1_000_000_000
G0 = 1_400_000_000 * NS  # GPS ns
H0 = 1_750_000_000 * NS  # host ns (the host clock is not on UTC: 408 ms and a few years off)


def _feed(tb: Timebase, n: int = 200) -> None:
    est = tb.gnss_clock("rover_a")
    for k in range(n):
        est.add(G0 + k * 50 * MS, H0 + k * 50 * MS + 408 * MS)


def test_the_first_leap_seconds_are_one_step_with_its_size_and_reason() -> None:
    tb = Timebase()
    _feed(tb)
    host = H0 + 199 * 50 * MS + 408 * MS
    before = tb.host_to_utc(host)
    assert before == host  # no leap seconds: the host time itself
    tb.set_leap_seconds(18)
    after = tb.host_to_utc(host)
    assert after == G0 + 199 * 50 * MS + GPS_EPOCH_UNIX_NS - 18 * NS
    (step,) = tb.steps()
    assert (step.host_ns, step.at_ns, step.step_ns) == (host, after, after - before)
    assert "replaces the host-clock estimate" in step.reason
    tb.set_leap_seconds(18)  # every TIME log repeats it: not a step
    tb.set_leap_seconds(18)
    assert len(tb.steps()) == 1
    tb.set_leap_seconds(19)
    assert [s.step_ns for s in tb.steps()][1] == -NS and "18 → 19" in tb.steps()[1].reason


def test_without_gnss_pairs_the_leap_seconds_are_no_step() -> None:
    tb = Timebase()
    tb.set_leap_seconds(18)
    assert tb.steps() == [] and tb.leap_seconds == 18


def test_envelope_error_is_the_latency_floor_scatter_clean_and_the_backlog_starved() -> None:
    rng = np.random.default_rng(3)
    x = np.arange(0, 60 * NS, 10 * MS, dtype=np.int64)
    lat = rng.exponential(0.3 * MS, x.size).astype(np.int64)
    clean = ClockEstimator("can:clean")
    clean.add_many(x, x + lat)
    e_clean = clean.envelope_error_ns()
    assert e_clean is not None and e_clean < 0.1 * MS
    backlog = np.clip((x - 20 * NS) // 2, 0, None) * ((x > 20 * NS) & (x < 30 * NS))  # up to 5 s behind, drained
    starved = ClockEstimator("can:starved")
    starved.add_many(x, x + lat + backlog)
    e_starved = starved.envelope_error_ns()
    assert e_starved is not None and e_starved > 1 * NS
