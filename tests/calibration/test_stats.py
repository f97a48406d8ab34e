"""Robust location, AR(1) variance of a block mean, φ bias correction and interval coverage."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as sps

from calibration import stats
from tests.calibration.synth import ar1
from vsccore.errors import CalibrationError


@pytest.mark.parametrize(("n", "phi"), [(1, 0.5), (2, 0.3), (20, 0.0), (50, 0.9), (300, 0.99)])
def test_ar1_mean_variance_factor_matches_covariance_sum(n: int, phi: float) -> None:
    # Var(mean) = 1ᵀ Σ 1 / n² with Σ_ij = φ^|i−j| for a unit-variance AR(1)
    i = np.arange(n)
    brute = float(np.sum(phi ** np.abs(i[:, None] - i[None, :]))) / n**2
    assert stats.ar1_mean_variance_factor(n, phi) == pytest.approx(brute, rel=1e-12)
    assert float(stats.ar1_mean_variance_factors(n, np.array([phi]))[0]) == pytest.approx(brute, rel=1e-9)


def test_huber_location_resists_outliers() -> None:
    rng = np.random.default_rng(4)
    x = rng.standard_normal(400) * 0.1 + 2.0
    x[:20] += 50.0  # 5 % gross errors
    loc, scale = stats.huber_location(x)
    assert loc == pytest.approx(2.0, abs=0.03)
    assert scale == pytest.approx(0.1, rel=0.2)
    assert np.mean(x) > 4.0  # the plain mean is ruined
    # symmetric data: the M-estimate is the centre of symmetry
    assert stats.huber_location(np.array([1.0, 2.0, 3.0, 4.0, 100.0, -95.0]))[0] == pytest.approx(2.5)
    assert stats.huber_location(np.array([3.0, 3.0, 3.0, 7.0])) == (3.0, 0.0)
    with pytest.raises(CalibrationError, match="no samples"):
        stats.huber_location(np.array([]))


def test_pooled_ar1_is_median_unbiased() -> None:
    """Two 6 s runs at 20 Hz with τ = 1 s: the raw pooled φ̂ is far too low, the corrected one is not."""
    dt, tau, n = 0.05, 1.0, 120
    phi_true = math.exp(-dt / tau)
    table = stats.Ar1BiasTable([n, n])
    rng = np.random.default_rng(11)
    raw, corrected = [], []
    for _ in range(200):
        blocks = [ar1(rng, n, 1.0, tau, dt) for _ in range(2)]
        raw.append(stats.pooled_lag1(blocks))
        corrected.append(stats.pooled_ar1(blocks, table=table))
    assert np.median(raw) < phi_true - 0.03
    assert np.median(corrected) == pytest.approx(phi_true, abs=0.01)
    # white noise stays near zero; the upper bound lies above the median-unbiased value
    white = [rng.standard_normal(n) for _ in range(2)]
    assert stats.pooled_ar1(white, table=table) < 0.2
    assert float(table.upper(0.8)) > float(table.correct(0.8))


def test_combine_weights_and_birge_inflation() -> None:
    a = stats.LocationEstimate(1.0, 0.1, 50.0, 100, 30.0)
    b = stats.LocationEstimate(1.2, 0.2, 50.0, 100, 30.0)
    c = stats.combine([a, b])
    w = np.array([1 / 0.01, 1 / 0.04])
    assert c.value == pytest.approx(float(np.sum(w * [1.0, 1.2]) / np.sum(w)))
    assert c.birge_ratio < 1.0 and c.std_error == pytest.approx(math.sqrt(1 / np.sum(w)))
    # blocks 10 σ apart: the uncertainty grows with the scatter
    far = stats.combine([a, stats.LocationEstimate(3.0, 0.1, 50.0, 100, 30.0)])
    assert far.birge_ratio > 10.0 and far.chi2_p_value < 1e-6
    assert far.std_error == pytest.approx(math.sqrt(0.005) * far.birge_ratio)
    assert far.dof == 1.0


def test_interval_coverage_with_estimated_correlation() -> None:
    """The bootstrap-t interval keeps ≈ 95 % coverage where a Student-t with n_eff − 1 dof falls short.

    Two 6 s blocks (20 Hz) of AR(1) noise with τ = 1 s, combined by their mean, as the
    direction-balanced mounting offset is. 160 replications: the binomial standard error of the
    coverage is ≈ 1.7 %.
    """
    dt, tau, n = 0.05, 1.0, 120
    table = stats.Ar1BiasTable([n, n])
    rng = np.random.default_rng(2024)
    hit_boot, hit_t = [], []
    for _ in range(160):
        blocks = [ar1(rng, n, 1.0, tau, dt) for _ in range(2)]
        res = [stats.block_residuals(b) for b in blocks]
        phi = stats.pooled_ar1(res, table=table)
        phi_up = max(phi, float(table.upper(stats.pooled_lag1(res))))
        ests = [stats.combine([stats.correlated_location(b, phi)]) for b in blocks]
        tot = stats.average_of_two(*ests)
        sq = stats.studentized_quantiles([n, n], [[0], [1]], phi_up, 0.95, table=table)
        hit_boot.append(abs(tot.value) <= sq.total * tot.std_error)
        lo, hi = tot.interval(0.95)
        hit_t.append(lo <= 0.0 <= hi)
    cov_boot, cov_t = float(np.mean(hit_boot)), float(np.mean(hit_t))
    print(f"coverage: bootstrap-t {cov_boot:.3f}, Student-t {cov_t:.3f}")
    assert cov_boot >= 0.92
    assert cov_boot >= cov_t


def test_studentized_quantiles_reduce_to_normal_for_white_noise() -> None:
    table = stats.Ar1BiasTable([400, 400])
    sq = stats.studentized_quantiles([400, 400], [[0], [1]], 0.0, 0.95, table=table)
    z = sps.norm.ppf(0.975)
    assert sq.total == pytest.approx(z, rel=0.06)
    assert all(q == pytest.approx(z, rel=0.08) for q in sq.blocks)
    assert sq.difference == pytest.approx(z, rel=0.06)
    with pytest.raises(CalibrationError, match="confidence"):
        stats.studentized_quantiles([400], [[0]], 0.0, 1.5, table=table)
