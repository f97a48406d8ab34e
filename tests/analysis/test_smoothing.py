"""The RTS smoother against a dense batch least-squares solution, and the wavelet denoiser on known signals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.analysis.smoothing import rts_smooth3, wavelet_denoise
from vsccore.errors import AnalysisError


def _batch_solution(f01, f02, f22, g, q, h2, z, r, x0, p0):
    """Posterior mean and variances of all states by weighted least squares over the whole record.

    An independent route to the same answer: the smoother's output is the marginal of the joint
    Gaussian posterior, i.e. the solution of the normal equations and the diagonal of their inverse.
    """
    n = z.size
    m = 3 * n
    rows, rhs, w = [], [], []
    for i in range(3):  # prior
        row = np.zeros(m)
        row[i] = 1.0
        rows.append(row)
        rhs.append(x0[i])
        w.append(1.0 / p0[i])
    for k in range(n - 1):  # dynamics: x[k+1] − F x[k] = g + noise
        F = np.array([[1.0, f01[k], f02[k]], [0.0, 1.0, 0.0], [0.0, 0.0, f22[k]]])
        for i in range(3):
            row = np.zeros(m)
            row[3 * (k + 1) + i] = 1.0
            row[3 * k : 3 * k + 3] -= F[i]
            rows.append(row)
            rhs.append(g[k] if i == 0 else 0.0)
            w.append(1.0 / q[k, i])
    for k in range(n):
        if np.isfinite(z[k]):
            row = np.zeros(m)
            row[3 * k] = 1.0
            row[3 * k + 2] = h2
            rows.append(row)
            rhs.append(z[k])
            w.append(1.0 / r[k])
    J = np.array(rows)
    W = np.array(w)
    info = J.T @ (J * W[:, None])
    cov = np.linalg.inv(info)
    mean = cov @ (J.T @ (W * np.array(rhs)))
    return mean.reshape(n, 3), np.diag(cov).reshape(n, 3)


@pytest.mark.parametrize(("h2", "seed"), [(1.0, 1), (0.0, 2), (0.5, 3)])
def test_rts_matches_batch_least_squares(h2: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 60
    f01 = rng.normal(0.0, 0.3, n - 1)
    f02 = rng.normal(0.0, 0.2, n - 1)
    f22 = rng.uniform(0.5, 1.0, n - 1)
    g = rng.normal(0.0, 0.1, n - 1)
    q = rng.uniform(1e-4, 1e-2, (n - 1, 3))
    z = rng.normal(0.0, 1.0, n).cumsum() * 0.1
    z[[5, 6, 7, 30, 59]] = np.nan  # gaps, including the last epoch
    r = rng.uniform(1e-3, 1e-1, n)
    x0 = (0.2, -0.1, 0.05)
    p0 = (4.0, 0.5, 0.3)
    res = rts_smooth3(f01, f02, f22, g, q, h2, z, r, x0, p0)
    mean, var = _batch_solution(f01, f02, f22, g, q, h2, z, r, x0, p0)
    np.testing.assert_allclose(res.x, mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.var, var, rtol=1e-7, atol=1e-12)
    assert np.isnan(res.nis[5]) and np.isfinite(res.nis[4])


def test_rts_rejects_bad_shapes() -> None:
    with pytest.raises(AnalysisError, match="q must have shape"):
        rts_smooth3([0.0], [0.0], [1.0], [0.0], np.ones((2, 3)), 1.0, [0.0, 1.0], [1.0, 1.0], (0, 0, 0), (1, 1, 1))
    with pytest.raises(AnalysisError, match="f01"):
        rts_smooth3([0.0, 1.0], [0.0], [1.0], [0.0], np.ones((1, 3)), 1.0, [0.0, 1.0], [1.0, 1.0], (0, 0, 0), (1, 1, 1))


def test_wavelet_denoise_white_noise() -> None:
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 60.0, 0.05)
    signal = np.radians(1.0) * np.sin(2 * np.pi * 0.2 * t) * np.exp(-(((t - 30) / 10) ** 2))
    sigma = np.radians(0.5)
    x = signal + rng.normal(0.0, sigma, t.size)
    x[400:420] = np.nan  # a gap splits the record
    res = wavelet_denoise(x)
    ok = np.isfinite(x)
    assert np.all(np.isnan(res.x[~ok])) and np.all(np.isfinite(res.x[ok]))
    assert res.noise_sigma == pytest.approx(sigma, rel=0.1)  # MAD of the finest details finds the noise level
    err = res.x[ok] - signal[ok]
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < sigma / 3.0  # the universal soft threshold removes most of white noise
    # the bootstrap σ is of the right order (it covers the bias as well as the variance)
    assert 0.3 < float(np.median(res.sigma[ok])) / rms < 3.0


def test_wavelet_short_segments_pass_through() -> None:
    x = np.array([0.1, 0.2, np.nan, 0.3])
    res = wavelet_denoise(x)
    np.testing.assert_array_equal(res.x[[0, 1, 3]], x[[0, 1, 3]])
    assert math.isnan(res.noise_sigma)
    with pytest.raises(AnalysisError, match="unknown wavelet"):
        wavelet_denoise(np.zeros(64), wavelet="nope")
