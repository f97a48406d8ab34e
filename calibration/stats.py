"""Robust location estimates with honest uncertainty for time-correlated samples.

GNSS heading, course and optical slip errors are correlated in time over about a second
(multipath, carrier-phase noise, tracking loops), so n samples of a 5 s run at 20 Hz carry the
information of a handful of independent ones, not of a hundred. The routines here:

- locate each block (one straight run) with a Huber M-estimate (robust to the odd glitch, ~95 %
  efficient for Gaussian noise),
- model the within-block residuals as AR(1), with the lag-1 coefficient pooled over all blocks and
  made median-unbiased by simulation (subtracting each short block's own mean biases it low), and turn
  it into the exact variance of the mean of an AR(1) block, an effective sample size and degrees
  of freedom,
- combine blocks by inverse-variance weighting, inflating the uncertainty by the Birge ratio when
  the blocks scatter more than their own uncertainties say (a random-effects guard), and
- form Student-t intervals with Welch–Satterthwaite degrees of freedom.

Correlation longer than a block cannot be seen inside it; the Birge ratio over several blocks is
what guards against it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal, stats

from vsccore.angles import FloatArray
from vsccore.errors import CalibrationError

HUBER_K = 1.345
"""Huber tuning constant: 95 % efficiency at the Gaussian."""

_MAD_TO_SIGMA = 1.482602218505602
_PHI_MAX = 1.0 - 1e-9
_SIM_REPS = 300
_SIM_MIN_REPS = 40
_SIM_BUDGET = 400_000
"""Simulated samples per bisection step when correcting φ (keeps 1 kHz data affordable)."""


@dataclass(frozen=True, slots=True)
class LocationEstimate:
    """A location (e.g. mean offset) with its standard error and degrees of freedom."""

    value: float
    std_error: float
    dof: float
    """Degrees of freedom for the Student-t interval (may be fractional; ≥ 1)."""
    n_samples: int
    n_effective: float
    """Number of independent samples carrying the same information as the correlated ones."""

    def interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """Two-sided Student-t confidence interval (value − h, value + h)."""
        h = half_width(self.std_error, self.dof, confidence)
        return self.value - h, self.value + h


@dataclass(frozen=True, slots=True)
class CombinedEstimate:
    """Inverse-variance combination of several block estimates."""

    value: float
    std_error: float
    dof: float
    n_blocks: int
    birge_ratio: float
    """sqrt(χ² / (k − 1)) of the blocks about the combined value; > 1 means more scatter than expected."""
    chi2_p_value: float
    """Probability of at least this much scatter if the blocks agreed (1.0 for a single block)."""

    def interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """Two-sided Student-t confidence interval (value − h, value + h)."""
        h = half_width(self.std_error, self.dof, confidence)
        return self.value - h, self.value + h


def half_width(std_error: float, dof: float, confidence: float) -> float:
    """Half width of a two-sided Student-t interval."""
    if not 0.0 < confidence < 1.0:
        raise CalibrationError(f"confidence must be in (0, 1), got {confidence}")
    if std_error == 0.0:
        return 0.0
    return float(stats.t.ppf(0.5 + confidence / 2.0, max(dof, 1.0)) * std_error)


def huber_location(x: FloatArray, *, k: float = HUBER_K, max_iter: int = 100) -> tuple[float, float]:
    """Huber M-estimate of location with the MAD as a fixed scale; returns (location, scale).

    Iteratively re-weighted mean: residuals beyond k·scale get weight k·scale/|r|. With zero MAD
    (more than half the samples identical) the median is returned with zero scale.
    """
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        raise CalibrationError("huber_location: no samples")
    med = float(np.median(x))
    scale = _MAD_TO_SIGMA * float(np.median(np.abs(x - med)))
    if scale == 0.0:
        return med, 0.0
    mu = med
    c = k * scale
    for _ in range(max_iter):
        r = np.abs(x - mu)
        w = np.where(r <= c, 1.0, c / np.maximum(r, c))
        mu_new = float(np.sum(w * x) / np.sum(w))
        if abs(mu_new - mu) <= 1e-12 * (abs(mu) + scale):
            mu = mu_new
            break
        mu = mu_new
    return mu, scale


def ar1_mean_variance_factor(n: int, phi: float) -> float:
    """Var(mean of n AR(1) samples) / Var(one sample) = (n + 2 Σ_{k=1}^{n−1} (n − k) φ^k) / n²."""
    if n <= 0:
        raise CalibrationError("ar1_mean_variance_factor: n must be positive")
    if phi <= 0.0 or n == 1:
        return 1.0 / n
    k = np.arange(1, n, dtype=float)
    return float((n + 2.0 * np.sum((n - k) * np.power(phi, k))) / (n * n))


def _influence(x: FloatArray, loc: float, scale: float, k: float) -> tuple[FloatArray, float]:
    """Huber ψ of the residuals (winsorised residuals) and the fraction of samples not clipped."""
    e = np.asarray(x, dtype=float) - loc
    if scale == 0.0:
        return e, 1.0
    c = k * scale
    psi = np.clip(e, -c, c)
    frac = float(np.mean(np.abs(e) < c))
    return psi, max(frac, 1.0 / e.size)


def ar1_mean_variance_factors(n: int, phi: FloatArray) -> FloatArray:
    """Vectorised :func:`ar1_mean_variance_factor` for many φ (closed form of the sum)."""
    p = np.clip(np.asarray(phi, dtype=float), 0.0, _PHI_MAX)
    if n <= 1:
        return np.ones_like(p)
    q = 1.0 - p
    s = p * (n * q - 1.0 + np.power(p, n)) / np.where(q > 0.0, q * q, 1.0)
    return np.asarray((n + 2.0 * s) / (n * n), dtype=float)


def _simulate_ar1(z: FloatArray, phi: float) -> FloatArray:
    """Unit-variance stationary AR(1) rows from standard-normal rows ``z`` (reps, n)."""
    g = math.sqrt(max(1.0 - phi * phi, 0.0))
    x0 = z[:, :1]
    if z.shape[1] == 1:
        return z.copy()
    rest = signal.lfilter([g], [1.0, -phi], z[:, 1:], axis=1, zi=phi * x0)[0]
    return np.concatenate([x0, rest], axis=1)


def _pooled_lag1(blocks: Sequence[FloatArray]) -> FloatArray:
    """Pooled lag-1 coefficient Σc₁/Σc₀ of blocks (each (reps, n)) demeaned block by block, per replicate."""
    reps = blocks[0].shape[0]
    c0 = np.zeros(reps)
    c1 = np.zeros(reps)
    for x in blocks:
        e = x - np.mean(x, axis=1, keepdims=True)
        c0 += np.sum(e * e, axis=1)
        c1 += np.sum(e[:, :-1] * e[:, 1:], axis=1)
    return np.asarray(np.where(c0 > 0.0, c1 / np.where(c0 > 0.0, c0, 1.0), 0.0), dtype=float)


_UPPER_PCT = 15.865525393145708
"""Percentile of φ̂ that defines the 1σ (84 %) upper bound of φ."""
_PHI_GRID = np.concatenate(([0.0], 1.0 - np.geomspace(0.95, 1e-3, 35)))
"""φ grid of the bias table: dense towards 1, where short blocks hide most of the correlation."""


class Ar1BiasTable:
    """Median of the pooled, block-demeaned lag-1 coefficient φ̂ as a function of the true φ.

    Built by simulation for given block lengths with common random numbers (deterministic for a
    seed), so the map is smooth; it is made monotone and inverted by interpolation. Subtracting
    each short block's own mean biases φ̂ low: by about (1 + 3φ)/n for long blocks and far more
    when a block lasts only a few correlation times (a 5 s run at τ ≈ 1 s).
    """

    def __init__(self, lengths: Sequence[int], *, seed: int = 0x5EED) -> None:
        lens = [int(n) for n in lengths if int(n) >= 2]
        if not lens:
            raise CalibrationError("Ar1BiasTable: need at least one block of 2 or more samples")
        total = sum(lens)
        reps = int(min(_SIM_REPS, max(_SIM_MIN_REPS, _SIM_BUDGET // total)))
        rng = np.random.default_rng(seed)
        z = [rng.standard_normal((reps, n)) for n in lens]
        pct = np.array(
            [
                np.percentile(_pooled_lag1([_simulate_ar1(b, float(p)) for b in z]), [50.0, _UPPER_PCT])
                for p in _PHI_GRID
            ]
        )
        self.lengths = tuple(lens)
        self.grid = _PHI_GRID.copy()
        self.median_hat = np.maximum.accumulate(pct[:, 0])
        self.low_hat = np.maximum.accumulate(pct[:, 1])
        """The 16th percentile of φ̂ at each grid φ (for the one-sided upper bound of φ)."""

    def correct(self, phi_hat: FloatArray | float) -> FloatArray:
        """The φ whose median φ̂ equals ``phi_hat`` (clipped to [0, 0.999])."""
        return _invert(self.median_hat, self.grid, phi_hat)

    def upper(self, phi_hat: FloatArray | float) -> FloatArray:
        """One-sided 84 % upper confidence bound of φ: the φ whose 16th percentile of φ̂ equals ``phi_hat``."""
        return _invert(self.low_hat, self.grid, phi_hat)


def _invert(curve: FloatArray, grid: FloatArray, y: FloatArray | float) -> FloatArray:
    # strictly increasing abscissae for np.interp (flat stretches: keep the first grid point)
    keep = np.concatenate(([True], np.diff(curve) > 0.0))
    return np.asarray(np.interp(np.asarray(y, dtype=float), curve[keep], grid[keep]), dtype=float)


def pooled_lag1(blocks: Sequence[FloatArray]) -> float:
    """Raw pooled lag-1 coefficient Σc₁/Σc₀ of blocks, each demeaned (biased low; see :class:`Ar1BiasTable`)."""
    arrays = [np.asarray(e, dtype=float) for e in blocks]
    arrays = [e for e in arrays if e.size >= 2]
    if not arrays:
        return 0.0
    return float(_pooled_lag1([e[None, :] for e in arrays])[0])


def pooled_ar1(blocks: Sequence[FloatArray], *, seed: int = 0x5EED, table: Ar1BiasTable | None = None) -> float:
    """Lag-1 autocorrelation φ of residual blocks, pooled and median-unbiased.

    φ̂ = Σ c₁ / Σ c₀ over the blocks, each taken about its own mean; then, following Andrews (1993),
    the φ for which the *median* of φ̂ over simulated AR(1) blocks of the same lengths equals the
    observed φ̂ (:class:`Ar1BiasTable`). The result lies in [0, 0.999]: negative correlation would
    only narrow the interval.
    """
    arrays = [np.asarray(e, dtype=float) for e in blocks]
    arrays = [e for e in arrays if e.size >= 2]
    if not arrays:
        return 0.0
    phi_hat = float(_pooled_lag1([e[None, :] for e in arrays])[0])
    if phi_hat <= 0.0:
        return 0.0
    tab = table if table is not None else Ar1BiasTable([e.size for e in arrays], seed=seed)
    return float(tab.correct(phi_hat))


@dataclass(frozen=True, slots=True)
class StudentizedQuantiles:
    """Two-sided quantiles of |estimate − truth| / stated standard error, found by simulation.

    Used in place of Student-t quantiles: with only a few correlation times per run, the error of
    the estimated φ (and so of the standard error) widens the distribution beyond any t.
    """

    total: float
    """For the overall estimate (direction-balanced mean of two groups, or the one group)."""
    groups: tuple[float, ...]
    """For each direction group's inverse-variance mean."""
    blocks: tuple[float, ...]
    """For each single run."""
    difference: float
    """For the difference of the two group means (NaN with one group)."""
    reps: int


def _sim_blocks_var(x: FloatArray, table: Ar1BiasTable, phi_hat: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean and stated variance of the mean of simulated blocks (reps, n), as :func:`correlated_location` does."""
    n = x.shape[1]
    m = np.mean(x, axis=1)
    phi_c = table.correct(phi_hat)
    f = np.minimum(ar1_mean_variance_factors(n, phi_c), 1.0 - 1.0 / max(n, 2))
    s2 = np.mean((x - m[:, None]) ** 2, axis=1)
    var = f * s2 / (1.0 - f)
    return m, np.maximum(var, 1e-300)


def _sim_combine(means: Sequence[FloatArray], variances: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray]:
    """Vectorised :func:`combine` (inverse-variance mean, Birge-inflated) over replicates."""
    if len(means) == 1:
        return means[0], variances[0]
    w = np.stack([1.0 / v for v in variances])
    mm = np.stack(means)
    sw = np.sum(w, axis=0)
    mean = np.sum(w * mm, axis=0) / sw
    se2 = 1.0 / sw
    birge2 = np.sum(w * (mm - mean) ** 2, axis=0) / (len(means) - 1)
    return mean, se2 * np.maximum(birge2, 1.0)


def studentized_quantiles(
    lengths: Sequence[int],
    groups: Sequence[Sequence[int]],
    phi: float,
    confidence: float,
    *,
    table: Ar1BiasTable,
    seed: int = 0xB007,
    max_reps: int = 2000,
) -> StudentizedQuantiles:
    """Parametric bootstrap-t of the whole straight-run estimator under AR(1) noise with lag-1 ``phi``.

    Simulates blocks of the given lengths, re-estimates φ from them exactly as the data were
    treated (pooled, median-unbiased through ``table``), forms each block's mean and stated
    standard error, combines blocks within each group (inverse variance, Birge ratio) and the two
    groups by their plain mean, and returns the ``confidence`` quantile of |z| = |error| / stated
    standard error for each of these. Robust (Huber) location is replaced by the mean here; for
    Gaussian noise the two agree to a few per cent.
    """
    if not 0.0 < confidence < 1.0:
        raise CalibrationError(f"confidence must be in (0, 1), got {confidence}")
    lens = [int(n) for n in lengths]
    if not lens or min(lens) < 2:
        raise CalibrationError("studentized_quantiles: every block needs at least 2 samples")
    total_n = sum(lens)
    reps = int(min(max_reps, max(400, 1_000_000 // total_n)))
    rng = np.random.default_rng(seed)
    phi = float(min(max(phi, 0.0), 0.999))
    sims = [_simulate_ar1(rng.standard_normal((reps, n)), phi) for n in lens]
    phi_hat = np.maximum(_pooled_lag1(sims), 0.0)
    bm: list[FloatArray] = []
    bv: list[FloatArray] = []
    for x in sims:
        m, v = _sim_blocks_var(x, table, phi_hat)
        bm.append(m)
        bv.append(v)

    def q(z: FloatArray) -> float:
        return float(np.quantile(np.abs(z), confidence))

    blocks_q = tuple(q(m / np.sqrt(v)) for m, v in zip(bm, bv, strict=True))
    gm: list[FloatArray] = []
    gv: list[FloatArray] = []
    for members in groups:
        m, v = _sim_combine([bm[i] for i in members], [bv[i] for i in members])
        gm.append(m)
        gv.append(v)
    groups_q = tuple(q(m / np.sqrt(v)) for m, v in zip(gm, gv, strict=True))
    if len(gm) == 2:
        tot = q(0.5 * (gm[0] + gm[1]) / np.sqrt(0.25 * (gv[0] + gv[1])))
        diff = q((gm[0] - gm[1]) / np.sqrt(gv[0] + gv[1]))
    elif len(gm) == 1:
        tot, diff = groups_q[0], math.nan
    else:
        raise CalibrationError(f"studentized_quantiles: need one or two groups, got {len(gm)}")
    return StudentizedQuantiles(total=tot, groups=groups_q, blocks=blocks_q, difference=diff, reps=reps)


def correlated_location(x: FloatArray, phi: float, *, k: float = HUBER_K) -> LocationEstimate:
    """Huber location of one block of AR(1)-correlated samples with its standard error.

    Uses the Huber asymptotic variance (mean ψ² / (fraction unclipped)²) with the stationary
    variance recovered from residuals about the block's own mean: E[s²] = γ₀ (1 − f), where
    f = Var(mean)/γ₀ for an AR(1) block of this length.
    """
    x = np.asarray(x, dtype=float)
    n = int(x.size)
    if n == 0:
        raise CalibrationError("correlated_location: empty block")
    loc, scale = huber_location(x, k=k)
    psi, frac = _influence(x, loc, scale, k)
    f = ar1_mean_variance_factor(n, phi)
    f = min(f, 1.0 - 1.0 / max(n, 2))  # a block always carries at least a little information
    s2 = float(np.mean((psi - np.mean(psi)) ** 2)) if n > 1 else 0.0
    gamma0 = s2 / (1.0 - f) / (frac * frac)
    var = f * gamma0
    n_eff = 1.0 / f
    return LocationEstimate(
        value=loc,
        std_error=float(np.sqrt(var)),
        dof=max(n_eff - 1.0, 1.0),
        n_samples=n,
        n_effective=n_eff,
    )


def block_residuals(x: FloatArray, *, k: float = HUBER_K) -> FloatArray:
    """Winsorised residuals of a block about its Huber location, centred (for :func:`pooled_ar1`)."""
    x = np.asarray(x, dtype=float)
    loc, scale = huber_location(x, k=k)
    psi, _ = _influence(x, loc, scale, k)
    return psi - np.mean(psi)


def combine(estimates: Sequence[LocationEstimate | CombinedEstimate]) -> CombinedEstimate:
    """Inverse-variance weighted mean of block estimates, Birge-inflated when they disagree.

    Degrees of freedom by Welch–Satterthwaite; when the Birge ratio exceeds 1 the uncertainty is
    scaled by it and the degrees of freedom are limited to k − 1 (the scatter then sets the width).
    """
    if not estimates:
        raise CalibrationError("combine: no estimates")
    values = np.array([e.value for e in estimates], dtype=float)
    var = np.array([e.std_error**2 for e in estimates], dtype=float)
    dofs = np.array([e.dof for e in estimates], dtype=float)
    k = len(estimates)
    if k == 1:
        e = estimates[0]
        return CombinedEstimate(e.value, e.std_error, e.dof, 1, 1.0, 1.0)
    # Noise-free blocks (zero variance) would get infinite weight; floor relative to the values.
    floor = (1e-15 * max(1.0, float(np.max(np.abs(values))))) ** 2
    var_w = np.maximum(var, floor)
    w = 1.0 / var_w
    mean = float(np.sum(w * values) / np.sum(w))
    se2 = float(1.0 / np.sum(w))
    c = w / np.sum(w)
    terms = (c * c * var_w) ** 2 / dofs
    dof = float(se2 * se2 / np.sum(terms)) if np.sum(terms) > 0 else float(np.sum(dofs))
    chi2 = float(np.sum(w * (values - mean) ** 2))
    birge = float(np.sqrt(chi2 / (k - 1)))
    p = float(stats.chi2.sf(chi2, k - 1))
    if birge > 1.0 and np.all(var > 0.0):
        se2 *= birge * birge
        dof = min(dof, float(k - 1))
    elif birge > 1.0:
        se2 = float(np.var(values, ddof=1) / k)
        dof = float(k - 1)
    return CombinedEstimate(mean, float(np.sqrt(se2)), max(dof, 1.0), k, birge, p)


def average_of_two(a: CombinedEstimate, b: CombinedEstimate) -> CombinedEstimate:
    """Equal-weight mean (a + b)/2 with Satterthwaite degrees of freedom (direction-balanced estimate)."""
    va, vb = a.std_error**2, b.std_error**2
    se2 = 0.25 * (va + vb)
    den = va * va / a.dof + vb * vb / b.dof
    dof = (va + vb) ** 2 / den if den > 0.0 else a.dof + b.dof
    return CombinedEstimate(
        value=0.5 * (a.value + b.value),
        std_error=float(np.sqrt(se2)),
        dof=max(float(dof), 1.0),
        n_blocks=a.n_blocks + b.n_blocks,
        birge_ratio=max(a.birge_ratio, b.birge_ratio),
        chi2_p_value=min(a.chi2_p_value, b.chi2_p_value),
    )
