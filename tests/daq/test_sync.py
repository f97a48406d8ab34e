"""Sync-pulse edges: sub-sample accuracy against analytic edges with noise, hysteresis, streaming."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import erf

from drivers.daq import EdgePolarity, SyncEdgeDetector, find_edges
from vsccore.errors import ConfigError

RATE = 1000.0  # Hz: indices below are in samples of a 1 kHz DAQ


def erf_pulse_train(n: int, rises: np.ndarray, width: float, rise_10_90: float, high: float = 5.0) -> np.ndarray:
    """Pulses whose edges are Gaussian-filtered steps (an input filter's rounding), 50 % at the given indices.

    ``rise_10_90`` in samples; for an erf edge the 10–90 % time is 2.563 σ.
    """
    k = np.arange(n, dtype=float)
    sigma = rise_10_90 / 2.563
    x = np.zeros(n)
    for r in rises:
        x += 0.5 * (erf((k - r) / (sigma * np.sqrt(2))) - erf((k - r - width) / (sigma * np.sqrt(2))))
    return high * x


def test_erf_edges_with_noise_are_located_far_better_than_one_sample() -> None:
    rng = np.random.default_rng(1)
    # 200 pulses at random sub-sample positions, 3 ms 10–90 % rise at 1 kHz, 20 mV rms noise on 5 V
    rises = 50.0 + np.cumsum(rng.uniform(80.0, 120.0, 200))
    x = erf_pulse_train(int(rises[-1]) + 200, rises, width=30.0, rise_10_90=3.0)
    x += rng.normal(0.0, 0.020, x.size)
    found = find_edges(x, low=1.0, high=4.0)
    assert found.size == rises.size
    err = found - rises
    assert np.max(np.abs(err)) < 0.05
    assert np.sqrt(np.mean(err**2)) < 0.02
    falling = find_edges(x, low=1.0, high=4.0, polarity=EdgePolarity.FALLING)
    assert np.max(np.abs(falling - (rises + 30.0))) < 0.05


def test_linear_ramp_edge_is_exact_without_noise() -> None:
    # trapezoid: 0 V until 100.3, linear to 5 V over 4 samples → 2.5 V crossing at 102.3
    k = np.arange(300, dtype=float)
    x = np.clip((k - 100.3) / 4.0, 0.0, 1.0) * 5.0
    assert find_edges(x, low=1.0, high=4.0) == pytest.approx([102.3], abs=1e-12)
    # a different level moves the crossing along the ramp as geometry says (an 8-sample ramp, so
    # the four samples around the crossing are all on the straight part)
    x8 = np.clip((k - 100.3) / 8.0, 0.0, 1.0) * 5.0
    assert find_edges(x8, low=0.5, high=4.5, level=1.25) == pytest.approx([102.3], abs=1e-12)
    assert find_edges(x8, low=1.0, high=4.0) == pytest.approx([104.3], abs=1e-12)


@pytest.mark.parametrize("rise_samples", [3.0, 4.0, 6.0])
def test_smooth_edges_at_any_sample_phase_need_the_cubic(rise_samples: float) -> None:
    """Raised-cosine edges (the simulated sync line's shape) at 50 sub-sample phases, no noise.

    Linear interpolation between the two bracketing samples is off by up to ~1 % of a sample on
    such an edge (10 µs at 1 kHz); the cubic through four samples stays far below that.
    """
    phases = np.linspace(0.0, 1.0, 50, endpoint=False)
    rises = 40.0 + 60.0 * np.arange(phases.size) + phases
    k = np.arange(int(rises[-1]) + 60, dtype=float)
    x = np.zeros(k.size)
    half = rise_samples / 2.0
    for r in rises:
        tau = np.clip(k - r, -half, half)
        tau_fall = np.clip(k - r - 20.0, -half, half)
        x += 0.5 * (np.sin(np.pi * tau / rise_samples) - np.sin(np.pi * tau_fall / rise_samples))
    x *= 5.0
    found = find_edges(x, low=1.0, high=4.0)
    assert found.size == rises.size
    err = np.abs(found - rises)
    chord = []  # what a chord between the bracketing samples gives
    for r in rises:
        j = int(np.floor(r))
        a, b = x[j], x[j + 1]
        chord.append(abs(j + (2.5 - a) / (b - a) - r))
    print(f"rise {rise_samples} samples: cubic max {err.max():.5f}, chord max {max(chord):.5f} samples")
    assert err.max() < 0.5 * max(chord)
    if rise_samples >= 4.0:  # the four samples lie on the smooth part of the edge
        assert err.max() < 0.2 * max(chord)
        assert err.max() < 0.002


def test_first_sample_index_is_added() -> None:
    k = np.arange(50, dtype=float)
    x = np.clip((k - 20.0) / 2.0, 0.0, 1.0) * 5.0
    assert find_edges(x, low=1.0, high=4.0, first_sample_index=10_000) == pytest.approx([10_021.0])


def test_hysteresis_rejects_noise_around_the_threshold() -> None:
    rng = np.random.default_rng(2)
    # a signal sitting at mid level with 0.3 V noise: crosses 2.5 V hundreds of times
    x = 2.5 + rng.normal(0.0, 0.3, 20_000)
    assert np.count_nonzero(np.diff(np.sign(x - 2.5))) > 1000
    assert find_edges(x, low=1.0, high=4.0, polarity=EdgePolarity.BOTH).size == 0
    # a noisy pulse train gives exactly one rising edge per pulse
    rises = np.array([1000.25, 3000.5, 5000.75])
    y = erf_pulse_train(7000, rises, width=500.0, rise_10_90=2.0) + rng.normal(0.0, 0.3, 7000)
    got = find_edges(y, low=1.0, high=4.0)
    assert got.size == 3
    assert np.max(np.abs(got - rises)) < 0.5  # heavy noise: still the right edges, within half a sample


def test_edge_at_start_without_earlier_state_is_not_reported() -> None:
    x = np.concatenate((np.full(5, 5.0), np.zeros(10), np.full(10, 5.0)))
    assert find_edges(x, low=1.0, high=4.0, polarity=EdgePolarity.BOTH).size == 2


def test_bad_thresholds_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="low < high"):
        find_edges(np.zeros(3), low=4.0, high=1.0)
    with pytest.raises(ConfigError, match="within the hysteresis band"):
        find_edges(np.zeros(3), low=1.0, high=4.0, level=4.5)


def test_nan_samples_do_not_create_edges() -> None:
    k = np.arange(100, dtype=float)
    x = np.clip((k - 40.5) / 3.0, 0.0, 1.0) * 5.0
    x[10:20] = np.nan
    assert find_edges(x, low=1.0, high=4.0) == pytest.approx([42.0])


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_streaming_detector_matches_batch_for_any_block_split(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rises = 30.0 + np.cumsum(rng.uniform(40.0, 60.0, 50))
    x = erf_pulse_train(int(rises[-1]) + 100, rises, width=20.0, rise_10_90=3.0) + rng.normal(0, 0.02, 1)
    x += rng.normal(0.0, 0.02, x.size)
    batch = find_edges(x, low=1.0, high=4.0, polarity=EdgePolarity.BOTH, first_sample_index=500)
    det = SyncEdgeDetector(low=1.0, high=4.0, polarity=EdgePolarity.BOTH)
    got: list[float] = []
    pos = 0
    while pos < x.size:
        n = int(rng.integers(1, 40))  # blocks shorter than an edge split edges across blocks
        got.extend(e.index for e in det.process(x[pos : pos + n], 500 + pos))
        pos += n
    np.testing.assert_allclose(got, batch, atol=1e-12)
    assert len(got) == 2 * rises.size


def test_streaming_detector_does_not_bridge_lost_samples() -> None:
    k = np.arange(200, dtype=float)
    x = np.clip((k - 100.5) / 3.0, 0.0, 1.0) * 5.0
    det = SyncEdgeDetector(low=1.0, high=4.0)
    assert det.process(x[:95], 0) == []
    # samples 95..149 were lost: the rising edge inside them must not be invented from the far side
    assert det.process(x[150:], 150) == []
    # and the detector works again after the gap
    y = np.concatenate((np.zeros(20), np.clip((np.arange(30.0) - 5.25) / 6.0, 0.0, 1.0) * 5.0))
    assert [e.index for e in det.process(np.zeros(20), 200)] == []
    edges = det.process(y[20:], 220)
    assert [e.rising for e in edges] == [True]
    assert edges[0].index == pytest.approx(220 + 8.25, abs=1e-12)
