"""Robust location of straight-run samples with an honest uncertainty for time-correlated noise.

The per-sample error of a GNSS heading − course (or of an optical slip angle) is not white. The
baseline heading carries the antennas' relative position error, which in an RTK solution is a slowly
wandering part (multipath, carrier-phase tracking; a first-order Gauss–Markov process with a
correlation time τ of a second or more) plus white noise; the course carries nearly white Doppler
velocity noise. Their sum, *white noise + Gauss–Markov*, is exactly an ARMA(1,1) process. Its lag-1
correlation is pulled down by the white part, so an AR(1) model fitted at lag 1 sees far more
independent samples than there are (the long-run variance of the mean is underestimated).

What the routines here do, all vectorised over replicates so that the same code serves one session
and a Monte-Carlo study:

1. Each block (one straight run) is located with a Huber M-estimate (robust to the odd glitch,
   ~95 % efficient for Gaussian noise); its residuals are winsorised at the Huber clipping point.
2. The noise model, per sample: variance σ², a share ω of it white and 1 − ω Gauss–Markov with
   correlation time τ (lag-k correlation φᵏ, φ = exp(−Δt/τ)). σ² is common to all blocks, each
   block has its own unknown mean. For every (ω, τ) on a grid (ω in 0 … 1, τ log-spaced from a
   quarter sample period up to ``max_correlation_s``) the *restricted* (REML) likelihood of the
   pooled blocks is evaluated exactly with a Kalman filter (the block means integrated out, which
   removes the bias that subtracting a short block's own mean puts into any correlation estimate),
   with σ² profiled out.
3. Given (ω, τ, σ²) the variance of a block's mean is exact for its length n:
   σ² (ω/n + (1 − ω) f_AR1(n, φ)), divided by the squared fraction of unclipped samples (Huber).
4. The parameters are not known well from a few runs of a few correlation times each. Instead of
   plugging in one estimate, the interval integrates over them: with flat priors in ω and log τ
   and 1/σ² in σ², the error of any linear combination of block means (a run, a direction group,
   the direction-balanced mean, the difference of directions) is a mixture over the grid of
   Student-t laws (N − J degrees of freedom, N samples in J blocks), weighted by the restricted
   likelihood. The half width is that mixture's quantile; the stated standard error is the root of
   its mean variance. With many correlation times of data the mixture collapses to one t and the
   interval to the familiar one; with few, it widens by as much as the data leave open.
5. Blocks driven in one direction are combined with inverse-variance weights and the variance is
   inflated by the Birge ratio² when they scatter more than the model says (a random-effects
   guard against what the model misses, e.g. a correlation longer than the runs).

Why step 4 matters, and what tightens it. Within a run of T seconds the noise spectrum is seen only
above ~1/T; the variance of the run's mean is the spectrum at zero. A Gauss–Markov process with
τ = 1 s and one with τ = 10 s (and the same short-term wander) look alike in 8 s runs, but the
second gives a run mean ten times as variable; the restricted likelihood barely tells them apart,
so a plug-in fit (REML, then a Student-t) covers only 65–90 % and the lag-1 AR(1) model 20–85 %
(tests/calibration/test_coverage.py). An optional *noise reference* helps: a second series, on
the same epochs, whose noise has the shape of the slow part of the blocks' noise and covers more
time. For the baseline heading this is the measured antenna separation over every RTK-fixed epoch
of the session: its error is the relative position error along the baseline, the heading's the one
across it, and horizontally these share their spectrum, while the Doppler course noise only adds
white noise. The fit then shares τ with the reference and requires the blocks' white share to be
at least the reference's; a Bayes-factor check drops the reference where the blocks contradict it.

Limits. Correlation longer than ``max_correlation_s`` is outside the model: such an error is a
constant per run, indistinguishable from the offset itself within a run; only more runs, spread in
time, reveal it (through the Birge ratio). Blocks are treated as independent of each other.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import special, stats

from vsccore.angles import FloatArray
from vsccore.errors import CalibrationError

HUBER_K = 1.345
"""Huber tuning constant: 95 % efficiency at the Gaussian."""

DEFAULT_MAX_CORRELATION_S = 30.0
"""Longest correlation time of the within-run noise the interval allows for (s)."""

REFERENCE_CONFLICT_BF = 20.0
"""Bayes factor against the reference's noise shape beyond which the reference is not used."""

_MAD_TO_SIGMA = 1.482602218505602
_WHITE_SHARES = np.linspace(0.0, 1.0, 21)
_TAU_POINTS_PER_EFOLD = 3.0
_TINY = 1e-300

def method_text(
    confidence: float,
    dt_s: float,
    max_correlation_s: float = DEFAULT_MAX_CORRELATION_S,
    *,
    reference: str = "",
    reference_s: float = 0.0,
) -> str:
    """The uncertainty method in words, for reports.

    ``reference`` names the noise reference series when one constrained the fit (e.g. "the antenna
    baseline length"), ``reference_s`` says how much of it (s).
    """
    tau_range = f"{_fmt_s(0.25 * dt_s)} … {_fmt_s(max_correlation_s)}"
    text = (
        "Each straight run gives a Huber (robust) mean. Its samples are correlated: the within-run noise is "
        "modelled as white noise plus a first-order Gauss–Markov (AR(1)) process, i.e. ARMA(1,1), with the white "
        f"share and correlation time ({tau_range}) pooled over all runs by their restricted likelihood (Kalman "
        "filter, run means integrated out); a run's mean then has the exact variance of that process over its "
        "length. "
    )
    if reference:
        text += (
            f"The correlation time is shared with {reference} over {reference_s:.0f} s of RTK-fixed data (the "
            "relative position error along the baseline has the spectrum of the one across it; course noise is "
            "white), and the white share is at least the reference's. "
        )
    text += (
        f"The {100.0 * confidence:g} % interval integrates over the noise parameters the data leave open "
        "(likelihood-weighted mixture of Student-t laws) instead of trusting one fit. Runs in one direction are "
        "combined by inverse-variance weights, inflated by the Birge ratio when they scatter more than the model "
        "says; with runs in both directions the offset is the mean of the two direction means (cross-wind and "
        "road-crown effects cancel). Runs are treated as independent; correlation slower than "
        f"{_fmt_s(max_correlation_s)} would look like an offset."
    )
    return text


def _fmt_s(t: float) -> str:
    return f"{1000.0 * t:.3g} ms" if t < 1.0 else f"{t:.3g} s"


# --- robust location ---------------------------------------------------------------------------


def huber_locations(x: FloatArray, *, k: float = HUBER_K, max_iter: int = 100) -> tuple[FloatArray, FloatArray]:
    """Row-wise Huber M-estimate of location with the MAD as a fixed scale: (location (R,), scale (R,)).

    ``x`` has shape (R, n). Iteratively re-weighted mean: residuals beyond k·scale get weight
    k·scale/|r|. A row with zero MAD (more than half its samples identical) gets its median and
    zero scale.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    if x.shape[1] == 0:
        raise CalibrationError("huber_location: no samples")
    med = np.median(x, axis=1)
    scale = _MAD_TO_SIGMA * np.median(np.abs(x - med[:, None]), axis=1)
    mu = med.copy()
    c = (k * scale)[:, None]
    live = scale > 0.0
    for _ in range(max_iter):
        if not np.any(live):
            break
        r = np.abs(x[live] - mu[live, None])
        cl = c[live]
        w = np.where(r <= cl, 1.0, cl / np.maximum(r, cl))
        new = np.sum(w * x[live], axis=1) / np.sum(w, axis=1)
        done = np.abs(new - mu[live]) <= 1e-12 * (np.abs(mu[live]) + scale[live])
        mu[live] = new
        idx = np.flatnonzero(live)
        live[idx[done]] = False
    return mu, scale


def huber_location(x: FloatArray, *, k: float = HUBER_K, max_iter: int = 100) -> tuple[float, float]:
    """Huber M-estimate of location of a 1-D sample; returns (location, scale) (see :func:`huber_locations`)."""
    a = np.asarray(x, dtype=float).ravel()
    if a.size == 0:
        raise CalibrationError("huber_location: no samples")
    mu, scale = huber_locations(a[None, :], k=k, max_iter=max_iter)
    return float(mu[0]), float(scale[0])


def winsorise(x: FloatArray, *, k: float = HUBER_K) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Huber location of each row and the residuals clipped at k·scale.

    Returns (location (R,), clipped residuals (R, n), fraction of samples not clipped (R,), ≥ 1/n).
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    loc, scale = huber_locations(x, k=k)
    e = x - loc[:, None]
    c = (k * scale)[:, None]
    clip = scale[:, None] > 0.0
    psi = np.where(clip, np.clip(e, -c, c), e)
    frac = np.where(scale > 0.0, np.mean(np.abs(e) < c, axis=1), 1.0)
    return loc, psi, np.maximum(frac, 1.0 / x.shape[1])


# --- white + Gauss–Markov noise model ----------------------------------------------------------


def ar1_mean_variance_factors(n: int, phi: FloatArray) -> FloatArray:
    """Var(mean of n samples) / Var(one sample) of a stationary AR(1) with lag-1 correlation φ (vectorised).

    (n + 2 Σ_{k=1}^{n−1} (n − k) φ^k) / n², in closed form.
    """
    p = np.clip(np.asarray(phi, dtype=float), 0.0, 1.0 - 1e-12)
    if n <= 0:
        raise CalibrationError("ar1_mean_variance_factors: n must be positive")
    if n == 1:
        return np.ones_like(p)
    q = 1.0 - p
    s = p * (n * q - 1.0 + np.power(p, n)) / (q * q)
    return np.asarray((n + 2.0 * s) / (n * n), dtype=float)


def ar1_mean_variance_factor(n: int, phi: float) -> float:
    """Scalar :func:`ar1_mean_variance_factors`."""
    return float(ar1_mean_variance_factors(n, np.array([phi]))[0])


@dataclass(frozen=True, slots=True)
class NoiseGrid:
    """The (white share ω, correlation time τ) nodes over which the noise model is integrated."""

    white_share: FloatArray
    """ω of each node, shape (M,)."""
    tau_s: FloatArray
    """τ of each node (s), shape (M,)."""
    phi: FloatArray
    """exp(−Δt/τ) of each node, shape (M,)."""
    dt_s: float
    max_correlation_s: float

    @classmethod
    def make(cls, dt_s: float, max_correlation_s: float = DEFAULT_MAX_CORRELATION_S) -> NoiseGrid:
        """Nodes: ω in 0, 0.05, …, 1 × τ log-spaced (3 per e-fold) from Δt/4 to ``max_correlation_s``."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise CalibrationError(f"noise grid: sample period must be > 0, got {dt_s}")
        tau_min = 0.25 * dt_s
        if not max_correlation_s > tau_min:
            raise CalibrationError(
                f"noise grid: max correlation time {max_correlation_s} s must exceed a quarter sample period "
                f"({tau_min} s)"
            )
        n_tau = max(2, int(math.ceil(_TAU_POINTS_PER_EFOLD * math.log(max_correlation_s / tau_min))) + 1)
        taus = np.geomspace(tau_min, max_correlation_s, n_tau)
        w, t = np.meshgrid(_WHITE_SHARES, taus, indexing="ij")
        return cls(
            white_share=w.ravel(),
            tau_s=t.ravel(),
            phi=np.exp(-dt_s / t.ravel()),
            dt_s=float(dt_s),
            max_correlation_s=float(max_correlation_s),
        )

    def mean_factor(self, n: int) -> FloatArray:
        """Var(mean of n samples) / σ² at each node: ω/n + (1 − ω) f_AR1(n, φ), shape (M,)."""
        return np.asarray(
            self.white_share / n + (1.0 - self.white_share) * ar1_mean_variance_factors(n, self.phi), dtype=float
        )


@dataclass(frozen=True, slots=True)
class NoiseFit:
    """Restricted likelihood of the white + Gauss–Markov model over a :class:`NoiseGrid`, per replicate."""

    grid: NoiseGrid
    weight: FloatArray
    """Normalised likelihood weight of each node, shape (M, R); each column sums to 1."""
    sigma2: FloatArray
    """REML per-sample variance σ̂²(ω, τ) = Q/(N − J) at each node, shape (M, R)."""
    dof: int
    """N − J: samples minus blocks (degrees of freedom of σ̂² at a node)."""
    mean_factors: tuple[FloatArray, ...]
    """Per block, Var(block mean)/σ² at each node, shape (M,)."""
    reference_used: npt.NDArray[np.bool_]
    """Per replicate: the reference series constrained the fit (False: none given, or it conflicted)."""
    reference_log_bf: FloatArray
    """Per replicate: log Bayes factor of 'shares the reference's noise shape' against 'does not' (0 without)."""

    def posterior_mean(self, values: FloatArray) -> FloatArray:
        """Likelihood-weighted mean over the nodes of ``values`` (M,) or (M, R); shape (R,)."""
        v = np.asarray(values, dtype=float)
        if v.ndim == 1:
            v = v[:, None]
        return np.asarray(np.sum(self.weight * v, axis=0), dtype=float)

    def posterior_quantile(self, values: FloatArray, q: float, where: npt.ArrayLike | None = None) -> FloatArray:
        """Weighted ``q`` quantile of per-node ``values`` (M,) over the nodes (those ``where`` is True); shape (R,)."""
        v = np.asarray(values, dtype=float)
        w = self.weight if where is None else self.weight * np.asarray(where, dtype=float)[:, None]
        w = w / np.maximum(np.sum(w, axis=0, keepdims=True), _TINY)
        order = np.argsort(v, kind="stable")
        cum = np.cumsum(w[order], axis=0)
        idx = np.argmax(cum >= q - 1e-12, axis=0)
        return np.asarray(v[order][idx], dtype=float)


def _kalman_reml_terms(
    y: FloatArray, omega: FloatArray, phi: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Innovation sums of one block under y = (Gauss–Markov φ, variance 1 − ω) + (white, variance ω).

    ``y`` (R, n) is filtered at every node (M,) at once, and so is the all-ones vector. Returns
    (log det V (M,), 1ᵀV⁻¹1 (M,), 1ᵀV⁻¹y (M, R), yᵀV⁻¹y (M, R)) where V is the unit-σ² covariance.
    """
    r, n = y.shape
    m = omega.size
    # The gains, innovation variances and the ones-vector innovations do not depend on the data.
    inv_f = np.empty((n, m))
    gain = np.empty((n, m))
    e_1 = np.empty((n, m))
    p = 1.0 - omega  # stationary start of the Gauss–Markov state
    q = (1.0 - omega) * (1.0 - phi * phi)
    pred_1 = np.zeros(m)
    logdet = np.zeros(m)
    for t in range(n):
        f = np.maximum(p + omega, _TINY)
        inv_f[t] = 1.0 / f
        gain[t] = p * inv_f[t]
        e_1[t] = 1.0 - pred_1
        logdet += np.log(f)
        pred_1 = phi * (pred_1 + gain[t] * e_1[t])
        p = phi * phi * p * omega * inv_f[t] + q
    w_1 = e_1 * inv_f
    a = np.sum(e_1 * w_1, axis=0)
    yt = np.ascontiguousarray(y.T)
    pred = np.zeros((m, r))
    e = np.empty((m, r))
    tmp = np.empty((m, r))
    b = np.zeros((m, r))
    c = np.zeros((m, r))
    phi_c = phi[:, None]
    for t in range(n):
        np.subtract(yt[t][None, :], pred, out=e)
        np.multiply(e, w_1[t][:, None], out=tmp)
        b += tmp
        np.multiply(e, e, out=tmp)
        tmp *= inv_f[t][:, None]
        c += tmp
        np.multiply(e, gain[t][:, None], out=tmp)
        pred += tmp
        pred *= phi_c
    return logdet, a, b, c


def _block_terms(blocks: Sequence[FloatArray], grid: NoiseGrid) -> tuple[FloatArray, FloatArray, int, int]:
    """(−2 log L_R without the σ² term (M, R), Σ_j Q_j (M, R), N − J, R) of residual blocks at every node."""
    arrays = [np.atleast_2d(np.asarray(b, dtype=float)) for b in blocks]
    if not arrays:
        raise CalibrationError("fit_noise: no blocks")
    reps = arrays[0].shape[0]
    if any(b.shape[0] != reps for b in arrays):
        raise CalibrationError("fit_noise: blocks have different numbers of replicates")
    if any(b.shape[1] < 2 for b in arrays):
        raise CalibrationError("fit_noise: every block needs at least 2 samples")
    m = grid.white_share.size
    m2ll = np.zeros((m, reps))
    q_sum = np.zeros((m, reps))
    for blk in arrays:
        y = blk - np.mean(blk, axis=1, keepdims=True)  # REML is invariant to a constant; keeps the sums well scaled
        logdet, a, b, c = _kalman_reml_terms(y, grid.white_share, grid.phi)
        a = np.maximum(a, _TINY)
        q_sum += np.maximum(c - b * b / a[:, None], 0.0)
        m2ll += (logdet + np.log(a))[:, None]
    dof = sum(b.shape[1] for b in arrays) - len(arrays)
    return m2ll, q_sum, dof, reps


def _log_likelihood(m2ll: FloatArray, q_sum: FloatArray, dof: int) -> FloatArray:
    """Restricted log-likelihood with σ² profiled out, shifted so that each column's maximum is 0."""
    scale = np.maximum(np.max(q_sum, axis=0, keepdims=True), _TINY)
    ll = -0.5 * (m2ll + dof * np.log(np.maximum(q_sum / scale, 1e-300)))
    return np.asarray(ll - np.max(ll, axis=0, keepdims=True), dtype=float)


def fit_noise(
    blocks: Sequence[FloatArray], grid: NoiseGrid, *, reference: Sequence[FloatArray] | None = None
) -> NoiseFit:
    """Restricted likelihood of the pooled blocks at every node of ``grid`` (σ² profiled out).

    ``blocks`` are residual blocks, each (R, n_j) (R replicates, the same for all blocks) or 1-D.
    Each block has its own unknown mean; −2 log L_R = Σ_j (log|V_j| + log 1ᵀV_j⁻¹1) + (N − J) log Σ_j Q_j
    with Q_j = y_jᵀ V_j⁻¹ y_j − (1ᵀV_j⁻¹y_j)² / 1ᵀV_j⁻¹1.

    ``reference``: blocks (same sample period and replicates) of a second series whose noise is the
    slow-capable part of the first one's, with the first's only adding white noise to it (the
    antenna baseline length against the baseline heading − course: the relative position error
    along the baseline has the same spectrum as the one across it, and Doppler course noise is
    white). Its likelihood then constrains the first: the same correlation time τ, and a white
    share ω at least the reference's, ω_ref uniform on [0, ω] a priori. Typically the reference
    covers far more time (every RTK-fixed epoch of a session), so it pins τ down.
    """
    m2ll, q_sum, dof, reps = _block_terms(blocks, grid)
    ll = _log_likelihood(m2ll, q_sum, dof)
    if reference is not None and len(reference) > 0:
        r_m2ll, r_q, r_dof, r_reps = _block_terms(reference, grid)
        if r_reps != reps:
            raise CalibrationError("fit_noise: reference blocks have a different number of replicates")
        n_w = np.unique(grid.white_share).size
        lr = np.exp(_log_likelihood(r_m2ll, r_q, r_dof)).reshape(n_w, -1, reps)  # (ω_ref, τ, R)
        # mean over ω_ref ≤ ω of the reference likelihood (ω ascending along the first grid axis)
        cond = (np.cumsum(lr, axis=0) / np.arange(1, n_w + 1, dtype=float)[:, None, None]).reshape(-1, reps)
        prior = cond / np.sum(cond, axis=0, keepdims=True)  # the reference's say on (ω, τ), as a prior
        lik = np.exp(ll)
        log_bf = np.log(np.maximum(np.sum(lik * prior, axis=0), 1e-300)) - np.log(np.mean(lik, axis=0))
        used = log_bf > -math.log(REFERENCE_CONFLICT_BF)
        ll = np.where(used[None, :], ll + np.log(np.maximum(prior, 1e-300)), ll)
    else:
        log_bf = np.zeros(reps)
        used = np.zeros(reps, dtype=bool)
    w = np.exp(ll - np.max(ll, axis=0, keepdims=True))
    w /= np.sum(w, axis=0, keepdims=True)
    factors = tuple(grid.mean_factor(np.atleast_2d(np.asarray(b)).shape[1]) for b in blocks)
    return NoiseFit(
        grid=grid, weight=w, sigma2=q_sum / dof, dof=dof, mean_factors=factors, reference_used=used,
        reference_log_bf=np.asarray(log_bf, dtype=float),
    )


def mixture_half_width(weight: FloatArray, variance: FloatArray, dof: float, confidence: float) -> FloatArray:
    """Half width h with Σ_nodes weight · P(|t_dof| > h / √variance) = 1 − confidence, per column.

    ``weight`` and ``variance`` are (M, R); returns (R,). Zero where every variance is zero.
    Safeguarded Newton iteration on h (the tail probability falls monotonically with h).
    """
    if not 0.0 < confidence < 1.0:
        raise CalibrationError(f"confidence must be in (0, 1), got {confidence}")
    alpha = 1.0 - confidence
    nu = max(float(dof), 1.0)
    w = np.asarray(weight, dtype=float)
    v = np.maximum(np.asarray(variance, dtype=float), 0.0)
    if w.ndim == 1:
        w, v = w[:, None], v[:, None]
    keep = np.any(w > 1e-12 * np.max(w, axis=0, keepdims=True), axis=1)  # nodes no replicate needs are dropped
    w, v = w[keep], v[keep]
    sd = np.sqrt(v)
    top = np.max(sd, axis=0)
    inv_sd = 1.0 / np.maximum(sd, _TINY)
    t_q = float(stats.t.ppf(1.0 - alpha / 2.0, nu))
    lo = np.zeros_like(top)
    hi = t_q * np.maximum(top, _TINY) * 1.0001  # every component's tail is below α here
    h = t_q * np.sqrt(np.sum(w * v, axis=0))
    h = np.clip(h, lo, hi)
    log_c = special.gammaln((nu + 1.0) / 2.0) - special.gammaln(nu / 2.0) - 0.5 * math.log(nu * math.pi)
    for _ in range(50):
        z = h[None, :] * inv_sd
        g = np.sum(w * 2.0 * special.stdtr(nu, -z), axis=0) - alpha  # decreasing in h
        dens = np.exp(log_c - 0.5 * (nu + 1.0) * np.log1p(z * z / nu))
        dg = -np.sum(w * 2.0 * dens * inv_sd, axis=0)
        lo = np.where(g > 0.0, h, lo)
        hi = np.where(g > 0.0, hi, h)
        step = np.where(dg < 0.0, h - g / np.where(dg < 0.0, dg, -1.0), np.nan)
        inside = np.isfinite(step) & (step > lo) & (step < hi)
        new = np.where(inside, step, 0.5 * (lo + hi))
        if np.all(np.abs(new - h) <= 1e-10 * np.maximum(h, _TINY)):
            h = new
            break
        h = new
    return np.where(top > 0.0, h, 0.0)


def equivalent_dof(coverage_factor: float, confidence: float, *, cap: float = 1000.0) -> float:
    """Degrees of freedom of the Student-t whose two-sided quantile equals ``coverage_factor`` (≤ ``cap``)."""
    tail = 0.5 + confidence / 2.0
    if not math.isfinite(coverage_factor) or coverage_factor <= float(stats.t.ppf(tail, cap)):
        return cap
    lo, hi = 1.0, cap
    if coverage_factor >= float(stats.t.ppf(tail, lo)):
        return 1.0
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if float(stats.t.ppf(tail, mid)) > coverage_factor:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


# --- straight runs: blocks, direction groups, balanced mean ------------------------------------


@dataclass(frozen=True, slots=True)
class Estimates:
    """Values with standard errors and interval half widths; each array has the replicates last."""

    value: FloatArray
    std_error: FloatArray
    """Root of the likelihood-weighted mean variance."""
    half_width: FloatArray
    """Half width of the two-sided interval at the requested confidence."""

    @property
    def coverage_factor(self) -> FloatArray:
        """half_width / std_error (1.96 would be a normal law)."""
        se = np.asarray(self.std_error)
        return np.asarray(np.where(se > 0.0, self.half_width / np.where(se > 0.0, se, 1.0), 0.0), dtype=float)


@dataclass(frozen=True, slots=True)
class StraightRunStats:
    """Everything :func:`straight_run_stats` finds, per replicate (arrays end in the replicate axis R)."""

    blocks: Estimates
    """Each run: shape (J, R)."""
    n_effective: FloatArray
    """Each run: variance of one sample / variance of its mean, shape (J, R)."""
    groups: Estimates
    """Each direction group (inverse-variance mean of its runs, Birge-inflated): shape (G, R)."""
    birge_ratio: FloatArray
    """sqrt(χ²/(k − 1)) of each group's runs about the group mean (1 for a single run), shape (G, R)."""
    chi2_p_value: FloatArray
    """Probability of at least that scatter if the runs agreed (1 for a single run), shape (G, R)."""
    total: Estimates
    """Direction-balanced mean of two groups, or the one group: shape (R,)."""
    difference: Estimates | None
    """Group 0 minus group 1 (None with one group): shape (R,)."""
    white_share: FloatArray
    """Likelihood-weighted mean white share ω of the per-sample noise variance, (R,)."""
    correlation_time_s: FloatArray
    """Likelihood-weighted median correlation time τ of the Gauss–Markov part (nodes with ω < 1; s), (R,)."""
    sigma: FloatArray
    """Per-sample standard deviation of the (winsorised) noise, (R,)."""
    reference_used: npt.NDArray[np.bool_]
    """The reference series constrained the noise model, (R,)."""
    reference_log_bf: FloatArray
    """Log Bayes factor for the reference's noise shape (see :func:`fit_noise`), (R,)."""
    confidence: float


def straight_run_stats(
    blocks: Sequence[FloatArray],
    groups: Sequence[Sequence[int]],
    *,
    dt_s: float,
    confidence: float = 0.95,
    max_correlation_s: float = DEFAULT_MAX_CORRELATION_S,
    k: float = HUBER_K,
    reference: Sequence[FloatArray] | None = None,
) -> StraightRunStats:
    """Robust run means, direction-group means and the direction-balanced mean with honest intervals.

    ``blocks``: the samples of each run, each 1-D (n_j,) or (R, n_j) for R replicates; ``groups``:
    one or two lists of block indices (runs driven in one direction); ``dt_s``: the sample period;
    ``reference``: optional blocks of a noise reference series (see :func:`fit_noise`), winsorised
    here like the runs. See the module docstring for the method.

    Raises:
        CalibrationError: no blocks, a block with fewer than 2 samples, bad groups or confidence.
    """
    if not 0.0 < confidence < 1.0:
        raise CalibrationError(f"confidence must be in (0, 1), got {confidence}")
    arrays = [np.atleast_2d(np.asarray(b, dtype=float)) for b in blocks]
    if not arrays:
        raise CalibrationError("straight_run_stats: no blocks")
    members = [list(g) for g in groups]
    flat = sorted(i for g in members for i in g)
    if not 1 <= len(members) <= 2 or flat != list(range(len(arrays))):
        raise CalibrationError(
            f"straight_run_stats: groups {members} must split the {len(arrays)} blocks into one or two groups"
        )
    loc: list[FloatArray] = []
    resid: list[FloatArray] = []
    frac: list[FloatArray] = []
    for b in arrays:
        lo, psi, fr = winsorise(b, k=k)
        loc.append(lo)
        resid.append(psi)
        frac.append(fr)
    ref = [winsorise(b, k=k)[1] for b in reference] if reference else None
    fit = fit_noise(resid, NoiseGrid.make(dt_s, max_correlation_s), reference=ref)
    w = fit.weight
    # per node and replicate: variance of each run's mean (Huber: ÷ fraction unclipped²)
    blk_var = [fit.sigma2 * f[:, None] / (fr * fr)[None, :] for f, fr in zip(fit.mean_factors, frac, strict=True)]
    values = np.stack(loc)
    blk_mean_var = np.stack([np.sum(w * v, axis=0) for v in blk_var])
    blk_h = np.stack([mixture_half_width(w, v, fit.dof, confidence) for v in blk_var])
    s2_bar = fit.posterior_mean(fit.sigma2)
    n_eff = np.stack([s2_bar / np.maximum(np.sum(w * fit.sigma2 * f[:, None], axis=0), _TINY)
                      for f in fit.mean_factors])

    g_val: list[FloatArray] = []
    g_var: list[FloatArray] = []  # (M, R) per group, Birge-inflated
    birge: list[FloatArray] = []
    p_val: list[FloatArray] = []
    for mem in members:
        vbar = np.maximum(blk_mean_var[mem], _TINY)  # (k, R)
        wts = 1.0 / vbar
        coef = wts / np.sum(wts, axis=0, keepdims=True)
        mean = np.sum(coef * values[mem], axis=0)
        var_nodes = sum(coef[i][None, :] ** 2 * blk_var[j] for i, j in enumerate(mem))
        kk = len(mem)
        if kk > 1:
            chi2 = np.sum(wts * (values[mem] - mean[None, :]) ** 2, axis=0)
            ratio = np.sqrt(chi2 / (kk - 1))
            pv = stats.chi2.sf(chi2, kk - 1)
            var_nodes = var_nodes * np.maximum(ratio * ratio, 1.0)[None, :]
        else:
            ratio = np.ones_like(mean)
            pv = np.ones_like(mean)
        g_val.append(mean)
        g_var.append(np.asarray(var_nodes, dtype=float))
        birge.append(np.asarray(ratio, dtype=float))
        p_val.append(np.asarray(pv, dtype=float))

    def est(value: FloatArray, var_nodes: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        return value, np.sqrt(np.sum(w * var_nodes, axis=0)), mixture_half_width(w, var_nodes, fit.dof, confidence)

    grp = [est(v, vn) for v, vn in zip(g_val, g_var, strict=True)]
    if len(members) == 2:
        total = est(0.5 * (g_val[0] + g_val[1]), 0.25 * (g_var[0] + g_var[1]))
        diff_t = est(g_val[0] - g_val[1], g_var[0] + g_var[1])
        difference: Estimates | None = Estimates(*diff_t)
    else:
        total = grp[0]
        difference = None
    return StraightRunStats(
        blocks=Estimates(values, np.sqrt(blk_mean_var), blk_h),
        n_effective=n_eff,
        groups=Estimates(np.stack([g[0] for g in grp]), np.stack([g[1] for g in grp]), np.stack([g[2] for g in grp])),
        birge_ratio=np.stack(birge),
        chi2_p_value=np.stack(p_val),
        total=Estimates(*total),
        difference=difference,
        white_share=fit.posterior_mean(fit.grid.white_share),
        correlation_time_s=fit.posterior_quantile(fit.grid.tau_s, 0.5, where=fit.grid.white_share < 1.0),
        sigma=np.sqrt(s2_bar),
        reference_used=fit.reference_used,
        reference_log_bf=fit.reference_log_bf,
        confidence=confidence,
    )
