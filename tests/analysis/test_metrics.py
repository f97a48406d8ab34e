"""Validation metrics on signals with known errors, delays and acceleration bins."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from rig.analysis.metrics import Tolerances, compare, error_series, estimate_lag
from vsccore.errors import AnalysisError


def _random_signal(n: int, dt: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    b, a = signal.butter(4, 1.0 * 2 * dt)  # band-limited to 1 Hz, like a sideslip record
    x = signal.filtfilt(b, a, rng.standard_normal(n)) * 0.02
    return np.arange(n) * dt, x


@pytest.mark.parametrize("delay", [0.137, -0.061, 0.0, 0.5])
def test_lag_recovers_subsample_delay(delay: float) -> None:
    dt = 0.05
    t, ref = _random_signal(4000, dt, seed=3)
    est = np.interp(t - delay, t, ref)  # est(t) = ref(t − d): late by d
    lag, corr = estimate_lag(t, est, ref, max_lag_s=1.0)
    assert lag == pytest.approx(delay, abs=0.1 * dt)
    assert corr > 0.99


def test_lag_ignores_invalid_samples_and_needs_uniform_time() -> None:
    dt = 0.01
    t, ref = _random_signal(6000, dt, seed=5)
    est = np.interp(t - 0.083, t, ref)
    valid = np.ones(t.size, bool)
    valid[1000:1500] = False
    est[1000:1500] = 99.0  # garbage where the reference is invalid
    lag, _ = estimate_lag(t, est, ref, valid=valid)
    assert lag == pytest.approx(0.083, abs=0.002)
    t2 = t.copy()
    t2[10:] += 0.5
    with pytest.raises(AnalysisError, match="uniform"):
        estimate_lag(t2, est, ref)


def test_error_statistics_known_values() -> None:
    n = 1001
    t = np.arange(n) * 0.01
    ref = np.radians(np.sin(t))
    e = np.radians(np.linspace(-1.0, 2.0, n))  # uniform errors from −1° to 2°
    m = compare(t, ref + e, ref, tolerances=Tolerances(min_valid_fraction=None))
    assert math.degrees(m.bias_rad) == pytest.approx(0.5, abs=1e-9)
    assert math.degrees(m.max_abs_rad) == pytest.approx(2.0, abs=1e-9)
    # RMS of a uniform ramp from a to b: sqrt((a² + ab + b²)/3) (continuous limit)
    assert math.degrees(m.rmse_rad) == pytest.approx(math.sqrt((1 - 2 + 4) / 3), rel=2e-3)
    # |e| > x for x in (1, 2): (2 − x)/3 of the samples; 5 % at x = 1.85°
    assert math.degrees(m.p95_abs_rad) == pytest.approx(1.85, abs=0.005)
    assert not m.passed
    assert any(f.startswith("RMSE") for f in m.failures) and any(f.startswith("max |error|") for f in m.failures)
    assert any(f.startswith("|bias|") for f in m.failures)
    d = m.to_dict()
    assert d["bias_deg"] == pytest.approx(0.5) and d["passed"] is False


def test_validity_wrap_and_pass() -> None:
    t = np.arange(100) * 0.05
    ref = np.full(100, math.pi - 0.001)
    est = np.full(100, -math.pi + 0.001)  # 0.002 rad apart across the ±π seam
    valid = np.ones(100, bool)
    valid[:30] = False
    est[:30] = 0.0  # large errors where the reference is invalid do not count
    m = compare(t, est, ref, reference_valid=valid, reference_sigma=np.full(100, math.radians(0.05)))
    assert m.n_compared == 70 and m.valid_fraction == pytest.approx(0.7)
    assert m.rmse_rad == pytest.approx(0.002, abs=1e-12)
    assert m.passed and not m.failures
    assert math.degrees(m.reference_sigma_rms_rad) == pytest.approx(0.05)
    m2 = compare(t, est, ref, reference_valid=valid, tolerances=Tolerances(min_valid_fraction=0.8))
    assert not m2.passed and "valid 70.0 %" in m2.failures[0]
    np.testing.assert_allclose(error_series(est[30:], ref[30:]), 0.002, atol=1e-12)
    with pytest.raises(AnalysisError, match="no common valid sample"):
        compare(t, est, ref, reference_valid=np.zeros(100, bool))


def test_ay_bins() -> None:
    t = np.arange(1000) * 0.01
    ay = np.linspace(-9.9, 9.9, 1000)
    ref = np.zeros(1000)
    est = np.radians(0.1 * np.abs(ay))  # error grows with |a_y|
    m = compare(t, est, ref, ay=ay)
    assert [b.lo_mps2 for b in m.bins] == [0.0, 2.0, 4.0, 6.0, 8.0]
    assert sum(b.n for b in m.bins) == 1000
    for b in m.bins:
        hi = min(b.hi_mps2, 9.9)
        assert math.degrees(b.max_abs_rad) == pytest.approx(0.1 * hi, abs=0.003)
        assert b.lo_mps2 * 0.1 <= math.degrees(b.bias_rad) <= 0.1 * hi
    assert m.bins[-1].to_dict()["ay_hi_mps2"] is None
    with pytest.raises(AnalysisError, match="must increase"):
        compare(t, est, ref, ay=ay, ay_bins=(0.0, 4.0, 2.0))


def test_lag_tolerance() -> None:
    dt = 0.02
    t, ref = _random_signal(3000, dt, seed=9)
    est = np.interp(t - 0.2, t, ref)
    m = compare(t, est, ref, tolerances=Tolerances(rmse_rad=None, max_abs_rad=None, bias_rad=None, max_lag_s=0.1))
    assert m.lag_s == pytest.approx(0.2, abs=0.005)
    assert m.failures == ("|lag| 0.200 s > 0.100 s",) or m.failures[0].startswith("|lag| 0.2")
