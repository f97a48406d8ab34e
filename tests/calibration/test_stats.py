"""Robust location, the white + Gauss–Markov REML fit, the mixture interval, against brute force and scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize
from scipy import stats as sps

from calibration import stats
from tests.calibration.synth import ar1
from vsccore.errors import CalibrationError


@pytest.mark.parametrize(("n", "phi"), [(1, 0.5), (2, 0.3), (20, 0.0), (50, 0.9), (300, 0.99)])
def test_ar1_mean_variance_factor_matches_covariance_sum(n: int, phi: float) -> None:
    # Var(mean) = 1ᵀ Σ 1 / n² with Σ_ij = φ^|i−j| for a unit-variance AR(1)
    i = np.arange(n)
    brute = float(np.sum(phi ** np.abs(i[:, None] - i[None, :]))) / n**2
    assert stats.ar1_mean_variance_factor(n, phi) == pytest.approx(brute, rel=1e-9)


def test_grid_mean_factor_matches_covariance_sum() -> None:
    grid = stats.NoiseGrid.make(0.05, 10.0)
    n = 37
    i = np.arange(n)
    for node in (0, 100, len(grid.phi) - 1, len(grid.phi) // 2):
        om, ph = grid.white_share[node], grid.phi[node]
        cov = om * np.eye(n) + (1.0 - om) * ph ** np.abs(i[:, None] - i[None, :])
        assert grid.mean_factor(n)[node] == pytest.approx(float(np.sum(cov)) / n**2, rel=1e-9)
    assert grid.tau_s.min() == pytest.approx(0.0125) and grid.tau_s.max() == pytest.approx(10.0)
    with pytest.raises(CalibrationError, match="max correlation time"):
        stats.NoiseGrid.make(0.05, 0.001)


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
    # the row-wise version agrees with the scalar one
    rows = rng.standard_t(3, (5, 60))
    locs, scales = stats.huber_locations(rows)
    for r in range(5):
        assert (locs[r], scales[r]) == pytest.approx(stats.huber_location(rows[r]), rel=1e-12)


def _dense_reml(blocks: list[np.ndarray], omega: float, phi: float) -> tuple[float, float]:
    """−2 log L_R (σ² profiled, up to a constant) and σ̂² by plain linear algebra."""
    m2ll, q, n_tot = 0.0, 0.0, 0
    for y in blocks:
        n = y.size
        i = np.arange(n)
        v = omega * np.eye(n) + (1.0 - omega) * phi ** np.abs(i[:, None] - i[None, :])
        vi = np.linalg.inv(v)
        one = np.ones(n)
        a = one @ vi @ one
        m2ll += np.linalg.slogdet(v)[1] + math.log(a)
        q += y @ vi @ y - (one @ vi @ y) ** 2 / a
        n_tot += n
    dof = n_tot - len(blocks)
    return m2ll + dof * math.log(q), q / dof


def test_reml_fit_matches_dense_linear_algebra() -> None:
    """The Kalman-filter restricted likelihood equals the textbook formula with the full covariance matrix."""
    rng = np.random.default_rng(3)
    blocks = [ar1(rng, 40, 1.0, 0.5, 0.05) + 0.5 * rng.standard_normal(40) + 3.0, ar1(rng, 25, 1.0, 0.5, 0.05)]
    omega = np.array([0.0, 0.2, 0.5, 0.9, 1.0, 0.3])
    phi = np.array([0.95, 0.9, 0.5, 0.99, 0.7, 0.0])
    grid = stats.NoiseGrid(omega, -0.05 / np.log(np.maximum(phi, 1e-300)), phi, 0.05, 10.0)
    fit = stats.fit_noise(blocks, grid)
    dense = [_dense_reml(blocks, float(o), float(p)) for o, p in zip(omega, phi, strict=True)]
    ll = np.array([-0.5 * d[0] for d in dense])
    w = np.exp(ll - ll.max())
    assert fit.weight[:, 0] == pytest.approx(w / w.sum(), rel=1e-8)
    assert fit.sigma2[:, 0] == pytest.approx([d[1] for d in dense], rel=1e-9)
    assert fit.dof == 63


def test_mixture_half_width_against_scipy() -> None:
    rng = np.random.default_rng(0)
    w = rng.random((40, 3))
    w /= w.sum(axis=0)
    v = rng.random((40, 3)) ** 4
    h = stats.mixture_half_width(w, v, 30, 0.95)
    for r in range(3):
        def tail(x: float, r: int = r) -> float:
            return float(np.sum(w[:, r] * 2.0 * sps.t.sf(x / np.sqrt(v[:, r]), 30))) - 0.05
        assert h[r] == pytest.approx(optimize.brentq(tail, 1e-9, 100.0), rel=1e-8)
    # one component: the Student-t interval
    assert stats.mixture_half_width(np.ones(1), np.array([4.0]), 12, 0.9)[0] == pytest.approx(
        2.0 * sps.t.ppf(0.95, 12), rel=1e-10
    )
    assert stats.mixture_half_width(np.ones(2) / 2, np.zeros(2), 12, 0.9)[0] == 0.0
    with pytest.raises(CalibrationError, match="confidence"):
        stats.mixture_half_width(np.ones(1), np.ones(1), 5, 1.5)


def test_equivalent_dof_round_trip() -> None:
    for nu in (2.0, 7.5, 40.0):
        assert stats.equivalent_dof(float(sps.t.ppf(0.975, nu)), 0.95) == pytest.approx(nu, rel=1e-6)
    assert stats.equivalent_dof(1.5, 0.95) == 1000.0


def test_white_noise_gives_the_classical_interval() -> None:
    """Long white-noise runs: the model finds them white and the interval is the textbook one."""
    rng = np.random.default_rng(8)
    blocks = [rng.standard_normal(600) * 0.2 + 1.0, rng.standard_normal(500) * 0.2 + 1.0]
    st = stats.straight_run_stats(blocks, [[0], [1]], dt_s=0.05)
    assert st.correlation_time_s[0] < 0.1  # whatever correlation is allowed lasts under 2 samples
    h_classic = 1.96 * 0.2 * math.sqrt(0.25 / 600 + 0.25 / 500)
    # within 25 %: a slow component too small to see within the runs is not excluded either
    assert h_classic < float(st.total.half_width[0]) < 1.25 * h_classic
    assert st.n_effective[0, 0] > 250
    assert not st.reference_used[0]


def test_correlated_noise_widens_the_interval() -> None:
    """White + Gauss–Markov (τ = 1 s) in two 8 s runs: the correlated part is found and n_eff is a few, not 160."""
    rng = np.random.default_rng(9)
    dt = 0.05
    blocks = [ar1(rng, 160, 0.15, 1.0, dt) + 0.1 * rng.standard_normal(160) for _ in range(2)]
    st = stats.straight_run_stats(blocks, [[0], [1]], dt_s=dt)
    assert 0.1 < st.white_share[0] < 0.8
    assert 0.3 < st.correlation_time_s[0] < 5.0
    assert np.all(st.n_effective[:, 0] < 20)
    # the truth for this noise: run mean variance 0.15² f_AR1 + 0.1²/n
    true_var = 0.15**2 * stats.ar1_mean_variance_factor(160, math.exp(-dt)) + 0.01 / 160
    assert float(st.blocks.std_error[0, 0]) > 0.8 * math.sqrt(true_var)


def test_reference_constrains_and_conflicts_are_detected() -> None:
    """A noise reference with the same Gauss–Markov part narrows the interval; a white one conflicts and is dropped."""
    rng = np.random.default_rng(10)
    dt = 0.05
    blocks = [ar1(rng, 120, 0.15, 1.0, dt) + 0.1 * rng.standard_normal(120) for _ in range(2)]
    same = [ar1(rng, 2400, 0.002, 1.0, dt) + 0.001 * rng.standard_normal(2400)]
    alone = stats.straight_run_stats(blocks, [[0], [1]], dt_s=dt)
    with_ref = stats.straight_run_stats(blocks, [[0], [1]], dt_s=dt, reference=same)
    assert with_ref.reference_used[0] and with_ref.reference_log_bf[0] > 0.0
    assert float(with_ref.total.half_width[0]) < 0.8 * float(alone.total.half_width[0])
    white = [rng.standard_normal(2400) * 0.003]
    conflict = stats.straight_run_stats(blocks, [[0], [1]], dt_s=dt, reference=white)
    assert not conflict.reference_used[0] and conflict.reference_log_bf[0] < -math.log(stats.REFERENCE_CONFLICT_BF)
    assert float(conflict.total.half_width[0]) == pytest.approx(float(alone.total.half_width[0]), rel=1e-9)


def test_groups_birge_and_errors() -> None:
    rng = np.random.default_rng(11)
    blocks = [rng.standard_normal(200) * 0.1 + c for c in (0.0, 0.0, 1.0)]
    st = stats.straight_run_stats(blocks, [[0, 1, 2]], dt_s=0.05)
    # the third run is 1.0 off with σ_mean ≈ 0.007: the Birge ratio sees it and the group interval covers the scatter
    assert st.birge_ratio[0, 0] > 20.0 and st.chi2_p_value[0, 0] < 1e-6
    assert float(st.groups.half_width[0, 0]) > 0.3
    assert st.difference is None
    with pytest.raises(CalibrationError, match="one or two groups"):
        stats.straight_run_stats(blocks, [[0], [1]], dt_s=0.05)
    with pytest.raises(CalibrationError, match="confidence"):
        stats.straight_run_stats(blocks, [[0, 1, 2]], dt_s=0.05, confidence=0.0)
