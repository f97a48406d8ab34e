"""Time base against synthetic clocks of known truth: GNSS↔host, CAN interface → GPS, DAQ sync pulses."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.daq.sync import find_edges
from rig.core.timebase import ClockEstimator, ClockMap, FitStatus, Timebase, align_sync_pulses, envelope_line
from vsccore.errors import AnalysisError
from vsccore.gpstime import gps_ns_to_unix_ns, gps_to_ns

G0 = gps_to_ns(2400, 345_600.0)
H0 = 1_750_000_000_123_456_789
DRIFT = 50e-6
DURATION_S = 600.0


def host_true(gps_ns: np.ndarray) -> np.ndarray:
    """The host clock at GPS time g: 50 ppm fast, plus a slow 200 µs thermal wander."""
    dt = (gps_ns - G0).astype(np.float64)
    wander = 200e3 * np.sin(2 * np.pi * dt / 900e9)
    return H0 + np.round(dt * (1 + DRIFT) + wander).astype(np.int64)


def latency(rng: np.random.Generator, n: int, mean_ns: float, tail_mean_ns: float, jitter_ns: float) -> np.ndarray:
    """Positive latency with an exponential body, a 5 % heavy exponential tail and a little symmetric jitter."""
    lat = rng.exponential(mean_ns, n)
    tail = rng.random(n) < 0.05
    lat[tail] += rng.exponential(tail_mean_ns, tail.sum())
    return np.round(lat + rng.normal(0, jitter_ns, n)).astype(np.int64)


@pytest.fixture(scope="module")
def gnss_pairs() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    gps = G0 + np.arange(int(DURATION_S * 20)) * 50_000_000  # 20 Hz logs
    host = host_true(gps) + latency(rng, gps.size, 3e6, 50e6, 20e3)
    # two glitches: stamps far *below* the envelope (a wrong header time, a host clock hiccup)
    host[3000] -= 20_000_000
    host[9000] -= 5_000_000
    return gps, host


def test_envelope_line_recovers_a_line_under_positive_noise() -> None:
    rng = np.random.default_rng(1)
    x = np.sort(rng.uniform(0, 1000, 5000))
    y = 3.0 + 0.02 * x + rng.exponential(1.0, x.size)
    a, b, used = envelope_line(x, y)
    assert a == pytest.approx(3.0, abs=0.01) and b == pytest.approx(0.02, abs=2e-5)
    assert np.all(y[used] >= a + b * x[used] - 1e-9)  # a lower envelope: nothing used lies under it
    y2 = y.copy()
    y2[100] -= 500.0  # a glitch far under the envelope is left out
    a2, b2, used2 = envelope_line(x, y2)
    assert not used2[np.argsort(x)[100]] and a2 == pytest.approx(a, abs=0.01) and b2 == pytest.approx(b, abs=1e-5)


def test_gnss_host_mapping_within_1ms(gnss_pairs: tuple[np.ndarray, np.ndarray]) -> None:
    gps, host = gnss_pairs
    est = ClockEstimator("gnss:rover_a")
    for g, h in zip(gps.tolist(), host.tolist(), strict=True):  # streaming, one pair at a time
        est.add(g, h)
    m = est.mapping()
    grid = np.linspace(G0, gps[-1], 5000).astype(np.int64)
    err = m(grid) - host_true(grid)
    print(f"GNSS→host: max |error| {np.max(np.abs(err)) / 1e3:.1f} µs, rms {np.sqrt(np.mean(err**2.0)) / 1e3:.1f} µs")
    assert np.max(np.abs(err)) < 1_000_000
    assert np.sqrt(np.mean(err**2.0)) < 200_000
    # host → GPS (what host-stamped streams use) is the exact inverse
    back = m.inverse_ns(host_true(grid))
    assert np.max(np.abs(back - grid)) < 1_000_000
    # the live (latest-window) fit, as the recorder uses it while recording
    g_last = int(gps[-1])
    live = est.to_ref(g_last)
    assert live is not None and abs(live - int(host_true(np.asarray([g_last]))[0])) < 1_000_000
    q = est.quality()
    assert q.status is FitStatus.OK and q.n == gps.size
    # reported drift: 50 ppm plus the wander's slope at the end (≤ 1.4 ppm)
    assert q.drift_ppm == pytest.approx(50.0, abs=2.0)
    # reported latency above the envelope matches the simulated one (median of exp(3 ms) ≈ 2.08 ms)
    assert q.latency_p50_ns == pytest.approx(3e6 * np.log(2), rel=0.15)
    assert q.jitter_ns is not None and q.jitter_ns > 1e6
    assert set(q.to_json()) >= {"clock", "method", "reference", "status", "n", "drift_ppm", "jitter_ns"}


def test_can_interface_clock_to_gps_within_1ms(gnss_pairs: tuple[np.ndarray, np.ndarray]) -> None:
    """CAN frames stamped by the interface's own crystal (−30 ppm vs host): interface → host → GPS."""
    gps, host = gnss_pairs
    tb = Timebase()
    tb.gnss_clock("rover_a").add_many(gps, host)
    tb.set_leap_seconds(18)
    rng = np.random.default_rng(3)
    g_ev = G0 + np.sort(rng.integers(0, int(DURATION_S * 1e9), 60_000))  # 100 frames/s, random instants
    h_ev = host_true(g_ev)
    iface = 5_000_000_000 + np.round((h_ev - H0) * (1 - 30e-6)).astype(np.int64)
    recv = h_ev + latency(rng, g_ev.size, 0.4e6, 5e6, 5e3)
    can_clock = tb.clock("can0")
    can_clock.add_many(iface, recv)
    gps_est = tb.host_to_gps_map()(can_clock.mapping()(iface))
    err = gps_est - g_ev
    print(f"CAN→GPS: max |error| {np.max(np.abs(err)) / 1e3:.1f} µs")
    assert np.max(np.abs(err)) < 1_000_000
    # live path, one frame
    k = g_ev.size - 1
    utc = tb.device_to_utc("can0", int(iface[k]), int(recv[k]))
    assert abs(utc - gps_ns_to_unix_ns(int(g_ev[k]), 18)) < 1_000_000
    assert {q.clock for q in tb.quality()} == {"gnss:rover_a", "can0"}


def test_host_time_falls_back_until_gps_and_leap_seconds_known() -> None:
    tb = Timebase()
    assert tb.host_to_utc(H0) == H0
    with pytest.raises(AnalysisError, match="leap seconds"):
        tb.gps_to_utc(G0)
    tb.gnss_clock("a").add(G0, H0 + 1_000_000)
    assert tb.host_to_utc(H0) == H0  # leap seconds still unknown
    tb.set_leap_seconds(18)
    assert tb.host_to_utc(H0 + 1_000_000) == gps_ns_to_unix_ns(G0, 18)
    assert tb.gnss_clock("a").quality().status is FitStatus.CONVERGING


def _daq_signal(edge_idx_true: np.ndarray, n: int, rng: np.random.Generator, rise_samples: float = 4.0) -> np.ndarray:
    """0/5 V pulses (100 samples wide) with raised-cosine edges centred on fractional sample indices, 5 mV noise."""
    k = np.arange(n, dtype=np.float64)
    i = np.searchsorted(edge_idx_true - rise_samples / 2, k, side="right") - 1
    tau = np.where(i >= 0, k - edge_idx_true[np.clip(i, 0, None)], -np.inf)

    def ramp(x: np.ndarray) -> np.ndarray:
        xc = np.clip(x, -rise_samples / 2, rise_samples / 2)
        return 0.5 * (1 + np.sin(np.pi * xc / rise_samples))

    return 5.0 * (ramp(tau) - ramp(tau - 100.0)) + rng.normal(0, 0.005, n)


@pytest.fixture(scope="module")
def daq_case() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(11)
    rate = 1000.0
    true_rate = rate * (1 + DRIFT)
    g_start = G0 + 123_456_789  # GPS time of sample 0
    pulse_gps = G0 + 1_000_000_000 + np.cumsum(rng.uniform(1.0, 3.0, 150) * 1e9).astype(np.int64)
    edge_true = (pulse_gps - g_start) / 1e9 * true_rate
    n = int(edge_true[-1]) + 500
    extra_edge = np.asarray([edge_true[40] + 600.0])  # a switch bounce the GNSS did not see
    all_edges = np.sort(np.concatenate([edge_true, extra_edge]))
    signal = _daq_signal(all_edges, n, rng)
    edges = find_edges(signal, low=1.0, high=4.0)
    keep = rng.random(pulse_gps.size) > 0.1  # 10 % of the MARKTIME logs lost
    marks = np.sort(np.concatenate([pulse_gps[keep], pulse_gps[5] + np.asarray([700_000_000, 1_300_000_000])]))
    return {"edges": edges, "marks": marks, "g_start": np.asarray([g_start]), "n": np.asarray([n]),
            "true_rate": np.asarray([true_rate]), "edge_true": edge_true, "n_kept": np.asarray([keep.sum()])}


@pytest.mark.parametrize("with_prior", [True, False])
def test_daq_sync_pulses_within_0_1ms(daq_case: dict[str, np.ndarray], with_prior: bool) -> None:
    edges, marks = daq_case["edges"], daq_case["marks"]
    g_start, n, true_rate = int(daq_case["g_start"][0]), int(daq_case["n"][0]), float(daq_case["true_rate"][0])
    approx = None
    if with_prior:  # GPS time from the blocks' host receive times: 30 ms late, ±10 ms
        rng = np.random.default_rng(5)
        approx = g_start + np.round(edges / 1000.0 * 1e9).astype(np.int64) + 30_000_000
        approx += rng.integers(-10_000_000, 10_000_000, edges.size)
    fit = align_sync_pulses("daq1", edges, marks, 1000.0, approx_gps_ns=approx)
    k = np.arange(0, n, 997)
    truth = g_start + np.round(k / true_rate * 1e9).astype(np.int64)
    err = fit.gps_ns(k) - truth
    print(f"DAQ sync: max |error| {np.max(np.abs(err)) / 1e3:.2f} µs over {k.size} samples; rms residual "
          f"{fit.rms_ns / 1e3:.2f} µs; matched {fit.matched_edges.size}")
    assert np.max(np.abs(err)) < 100_000
    # every matched pair is a real pulse; the bounce and the two spurious marks stay unmatched
    n_kept = int(daq_case["n_kept"][0])
    assert edges.size == 151  # 150 pulses and the bounce, each found once
    assert fit.matched_edges.size == n_kept
    assert (fit.unmatched_edges, fit.unmatched_marks) == (151 - n_kept, 2)
    assert fit.drift_ppm == pytest.approx(50.0, abs=1.0)
    q = fit.quality(18)
    assert q.method == "sync_pulse" and q.rms_ns is not None and q.rms_ns < 100_000


def test_daq_sync_refuses_unrelated_pulses() -> None:
    with pytest.raises(AnalysisError, match="daq1"):
        align_sync_pulses("daq1", np.asarray([10.0]), np.asarray([G0]), 1000.0)


def test_clock_map_round_trips_and_extrapolates() -> None:
    m = ClockMap(G0, H0, np.asarray([0.0, 1e11, 2e11]), np.asarray([0.0, 1.00005e11, 2.0001e11]), (1.00005, 1.00005))
    x = G0 + np.asarray([-5e10, 0, 5e10, 1.5e11, 3e11]).astype(np.int64)
    y = m(x)
    assert np.all(np.diff(y) > 0)
    assert np.array_equal(m.inverse_ns(y), x)
    assert m.one(G0 + 100_000_000_000) == H0 + 100_005_000_000


def test_a_latency_learnt_later_moves_the_map_as_if_known_from_the_start() -> None:
    """ClockEstimator.add_min_latency: the pairs already seen are taken as if the latency had been known."""
    rng = np.random.default_rng(7)
    x = np.arange(0, 60_000_000_000, 50_000_000, dtype=np.int64) + 10**18
    ref = x + 3_000_000_000 + 45_000_000 + rng.integers(0, 2_000_000, x.size)
    learnt, known = ClockEstimator("learnt"), ClockEstimator("known", min_latency_ns=45_000_000)
    for est in (learnt, known):
        for xi, ri in zip(x[:600].tolist(), ref[:600].tolist(), strict=True):
            est.add(xi, ri)
    before = learnt.to_ref(int(x[599]))
    learnt.add_min_latency(45_000_000)
    assert before is not None and learnt.to_ref(int(x[599])) == before - 45_000_000
    for est in (learnt, known):
        est.add_many(x[600:], ref[600:])
    assert learnt.min_latency_ns == known.min_latency_ns == 45_000_000
    assert learnt.to_ref(int(x[-1])) == known.to_ref(int(x[-1]))
    assert np.array_equal(learnt.mapping()(x), known.mapping()(x))
