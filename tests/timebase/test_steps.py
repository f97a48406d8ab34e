"""The time base's one deliberate jump — the host-time estimate replaced by GPS-derived UTC when the leap
seconds become known — is decided in Timebase.set_leap_seconds and recorded as a step."""

from __future__ import annotations

import numpy as np

from rig.core.timebase import ClockEstimator, Timebase
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


def test_a_device_clocks_live_map_never_runs_back_while_its_envelope_finds_the_latency_floor() -> None:
    """A CAN reader busy for the first 0.4 s (every frame 5 ms late): when the first 0.5 s bin closes, the
    refit moves the live map back ~5 ms, more than the 1 ms between frames. The old map stepped back
    (log_time of /can/vsc/roles ran back 2.1 ms in a demo); now it slews and records the slew."""
    rng = np.random.default_rng(8)
    device = np.arange(0, 10 * NS, MS, dtype=np.int64)  # 1 kHz of frames, interface clock
    true_host = device + H0  # the interface clock runs on the host's rate here: truth is an offset
    latency = rng.exponential(0.1 * MS, device.size).astype(np.int64)
    latency[device < 400 * MS] += 5 * MS
    tb = Timebase()  # no GNSS clock: the common time is the host time, so only the CAN map moves
    live = np.asarray([tb.device_to_utc("can:vsc", int(d), int(h + lat))
                       for d, h, lat in zip(device, true_host, latency, strict=True)], dtype=np.int64)
    back = np.diff(live)
    assert back.min() >= 0, f"live map ran back {-back.min() / MS:.3f} ms at frame {int(np.argmin(back)) + 1}"
    err = live - true_host
    converged = device >= 1 * NS
    assert np.abs(err[converged]).max() < 0.05 * MS  # on the latency floor once the slew is done
    assert err.max() < 5.8 * MS  # never later than the old map was (5 ms + its first frame's latency)
    (slew,) = [s for s in tb.steps() if s.slew_ns]
    assert -5.6 * MS < slew.step_ns < -4.4 * MS
    assert 8 * MS < slew.slew_ns < 12 * MS  # absorbed at half the device time's rate
    assert "can:vsc" in slew.reason and "monotonic" in slew.reason
    done = device > 520 * MS
    assert np.abs(err[done]).max() < 0.5 * MS  # caught up within ~ 2·5 ms of the move


def test_a_device_clock_that_restarts_is_not_held_at_its_old_time() -> None:
    tb = Timebase()
    for k in range(100):
        tb.device_to_utc("can:vsc", 50 * NS + k * MS, H0 + k * MS + 100_000)
    # the interface reset its clock (a reconnect): device time starts again near 0, the host time runs on
    t = tb.device_to_utc("can:vsc", 10 * MS, H0 + 100 * MS + 100_000)
    assert t < H0  # no floor across a device clock that went back: the map's own (wrong) answer, no hold


def test_a_host_timed_channel_never_runs_back_when_the_reference_receivers_map_is_refitted() -> None:
    """A host clock 500 ppm fast: until the reference receiver's pairs span 2 s its map is offset only
    (the lowest pair), then the drift comes in and the host → GPS map moves back ~1 ms. A raw channel
    stamped on the host clock every 0.5 ms (serial chunks) ran back with it; now it slews."""
    rng = np.random.default_rng(5)
    tb = Timebase()
    tb.set_leap_seconds(18)
    gnss = tb.gnss_clock("rover_a")
    gps = G0 + np.arange(0, 4 * NS, 50 * MS, dtype=np.int64)
    host_of = H0 + np.round((gps - G0) * (1 + 500e-6)).astype(np.int64)
    rx = host_of + rng.exponential(0.05 * MS, gps.size).astype(np.int64)
    chunks = H0 + np.arange(0, 4 * NS, MS // 2, dtype=np.int64)
    chunks = chunks[chunks > rx[0]]  # from the first log on: before it the host time is its own estimate
    events = sorted([(int(h), 0, int(g)) for h, g in zip(rx, gps, strict=True)] + [(int(h), 1, 0) for h in chunks])
    live: list[int] = []
    raw: list[int] = []
    for host, is_chunk, g in events:
        if is_chunk:
            live.append(tb.live_host_to_utc("/gnss/rover_a/raw", host))
            raw.append(tb.host_to_utc(host))
        else:
            gnss.add(g, host)
    assert np.diff(raw).min() < 0  # the map itself did move back
    assert np.diff(live).min() >= 0
    (slew,) = [s for s in tb.steps() if s.slew_ns]
    assert slew.step_ns < -0.5 * MS and "/gnss/rover_a/raw" in slew.reason
    assert np.array_equal(np.asarray(live)[-100:], np.asarray(raw)[-100:])  # caught up: the map itself


def test_a_step_of_the_time_base_beyond_the_slew_limit_is_not_slewed() -> None:
    """The first TIME log replaces a host clock that is far off (here years): the channel's time follows the
    step at once (the recorder clamps what runs back), it is not held for twice the step."""
    tb = Timebase()
    _feed(tb)
    host = H0 + 199 * 50 * MS + 408 * MS
    before = tb.live_host_to_utc("/relay/raw", host)
    tb.set_leap_seconds(18)
    after = tb.live_host_to_utc("/relay/raw", host + MS)
    assert after == tb.host_to_utc(host + MS) and after < before
    assert not [s for s in tb.steps() if s.slew_ns]
