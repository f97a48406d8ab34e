"""Validation metrics of a sideslip estimate β̂(t) against a reference β(t).

All inputs are arrays on one common time base (s); angles in rad, accelerations in m/s². Only
epochs where both signals are finite and the reference is valid count. The results are frozen
dataclasses whose ``to_dict()`` gives a JSON-able view with degrees at the edge.

- error e = β̂ − β: RMSE, bias (mean), maximum |e|, 95th percentile of |e|;
- lag: peak of the normalised cross-correlation of the demeaned signals within ±``max_lag_s``,
  refined to a fraction of a sample by a parabola through the peak and its neighbours; positive
  when the estimate lags (is late on) the reference;
- the error in bins of |a_y| (default 0–2, 2–4, 4–6, 6–8, > 8 m/s²), since estimators usually
  degrade towards the tyre limit;
- pass/fail against :class:`Tolerances`, with the failed criteria named.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import signal

from rig.analysis.arrays import as_1d, as_bool, check_time
from vsccore.angles import FloatArray, wrap_pi
from vsccore.errors import AnalysisError

__all__ = [
    "DEFAULT_AY_BINS",
    "AyBin",
    "Tolerances",
    "ValidationMetrics",
    "compare",
    "error_series",
    "estimate_lag",
]

DEFAULT_AY_BINS: tuple[float, ...] = (0.0, 2.0, 4.0, 6.0, 8.0, math.inf)
"""Edges of the |a_y| bins (m/s²)."""


@dataclass(frozen=True, slots=True)
class Tolerances:
    """Pass/fail limits (rad, s). ``None`` leaves a criterion out."""

    rmse_rad: float | None = math.radians(0.5)
    max_abs_rad: float | None = math.radians(1.5)
    bias_rad: float | None = math.radians(0.3)
    p95_rad: float | None = None
    max_lag_s: float | None = None
    min_valid_fraction: float | None = 0.5

    @classmethod
    def from_degrees(
        cls,
        rmse_deg: float | None = 0.5,
        max_abs_deg: float | None = 1.5,
        bias_deg: float | None = 0.3,
        p95_deg: float | None = None,
        max_lag_s: float | None = None,
        min_valid_fraction: float | None = 0.5,
    ) -> Tolerances:
        """Tolerances given in degrees (as in the session configuration's ``[validation]``)."""

        def rad(x: float | None) -> float | None:
            return None if x is None else math.radians(x)

        return cls(rad(rmse_deg), rad(max_abs_deg), rad(bias_deg), rad(p95_deg), max_lag_s, min_valid_fraction)


@dataclass(frozen=True, slots=True)
class AyBin:
    """Error statistics of the epochs whose |a_y| lies in [lo, hi)."""

    lo_mps2: float
    hi_mps2: float
    n: int
    rmse_rad: float
    bias_rad: float
    max_abs_rad: float

    def to_dict(self) -> dict[str, float | int | None]:
        """JSON-able view (degrees)."""
        return {
            "ay_lo_mps2": self.lo_mps2,
            "ay_hi_mps2": None if math.isinf(self.hi_mps2) else self.hi_mps2,
            "n": self.n,
            "rmse_deg": _deg(self.rmse_rad),
            "bias_deg": _deg(self.bias_rad),
            "max_abs_deg": _deg(self.max_abs_rad),
        }


@dataclass(frozen=True, slots=True)
class ValidationMetrics:
    """Error of an estimate against a reference, and the verdict."""

    n_samples: int
    n_compared: int
    valid_fraction: float
    """Fraction of the time (by samples) where the reference was valid."""
    rmse_rad: float
    bias_rad: float
    max_abs_rad: float
    p95_abs_rad: float
    lag_s: float
    lag_correlation: float
    reference_sigma_rms_rad: float
    """RMS of the reference's stated σ over the compared epochs (NaN when not given)."""
    bins: tuple[AyBin, ...]
    passed: bool
    failures: tuple[str, ...]
    warnings: tuple[str, ...]

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (degrees, seconds)."""
        return {
            "n_samples": self.n_samples,
            "n_compared": self.n_compared,
            "valid_fraction": self.valid_fraction,
            "rmse_deg": _deg(self.rmse_rad),
            "bias_deg": _deg(self.bias_rad),
            "max_abs_deg": _deg(self.max_abs_rad),
            "p95_abs_deg": _deg(self.p95_abs_rad),
            "lag_s": None if math.isnan(self.lag_s) else self.lag_s,
            "lag_correlation": None if math.isnan(self.lag_correlation) else self.lag_correlation,
            "reference_sigma_rms_deg": _deg(self.reference_sigma_rms_rad),
            "ay_bins": [b.to_dict() for b in self.bins],
            "passed": self.passed,
            "failures": list(self.failures),
            "warnings": list(self.warnings),
        }


def _deg(x: float) -> float | None:
    return None if math.isnan(x) else math.degrees(x)


def estimate_lag(
    t: npt.ArrayLike,
    estimate: npt.ArrayLike,
    reference: npt.ArrayLike,
    *,
    max_lag_s: float = 1.0,
    valid: npt.ArrayLike | None = None,
) -> tuple[float, float]:
    """Delay (s) of ``estimate`` behind ``reference`` and the normalised correlation at the peak.

    The signals must be on one uniform time base. Invalid or non-finite samples are set to zero
    after demeaning (they add nothing to the correlation); the correlation at each lag is
    normalised by the energies of the overlapping valid samples. Returns (NaN, NaN) when there is
    nothing to correlate (constant signals, no overlap).
    """
    tt = check_time("t", t, min_samples=3)
    n = tt.size
    x = as_1d("estimate", estimate, n)
    y = as_1d("reference", reference, n)
    m = as_bool("valid", valid, n) & np.isfinite(x) & np.isfinite(y)
    if np.count_nonzero(m) < 3:
        return math.nan, math.nan
    dt = float(np.median(np.diff(tt)))
    if np.max(np.abs(np.diff(tt) - dt)) > 0.01 * dt:
        raise AnalysisError("estimate_lag: the time base must be uniform (resample first)")
    xm = np.where(m, x - np.mean(x[m]), 0.0)
    ym = np.where(m, y - np.mean(y[m]), 0.0)
    mf = m.astype(float)
    c = signal.correlate(xm, ym, mode="full", method="fft")
    ex = signal.correlate(xm * xm, mf, mode="full", method="fft")  # Σ x² over pairs where y is valid
    ey = signal.correlate(mf, ym * ym, mode="full", method="fft")
    lags = signal.correlation_lags(n, n, mode="full")
    k_max = max(1, int(round(max_lag_s / dt)))
    sel = np.abs(lags) <= k_max
    c, ex, ey, lags = c[sel], ex[sel], ey[sel], lags[sel]
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = c / np.sqrt(np.maximum(ex, 0.0) * np.maximum(ey, 0.0))
    rho = np.where(np.isfinite(rho), rho, -np.inf)
    i = int(np.argmax(rho))
    if not np.isfinite(rho[i]):
        return math.nan, math.nan
    frac = 0.0
    if 0 < i < rho.size - 1 and np.isfinite(rho[i - 1]) and np.isfinite(rho[i + 1]):
        den = rho[i - 1] - 2.0 * rho[i] + rho[i + 1]
        if den < 0.0:
            frac = float(0.5 * (rho[i - 1] - rho[i + 1]) / den)
    return float((lags[i] + frac) * dt), float(rho[i])


def compare(
    t: npt.ArrayLike,
    estimate: npt.ArrayLike,
    reference: npt.ArrayLike,
    *,
    reference_valid: npt.ArrayLike | None = None,
    reference_sigma: npt.ArrayLike | None = None,
    ay: npt.ArrayLike | None = None,
    tolerances: Tolerances | None = None,
    ay_bins: Sequence[float] = DEFAULT_AY_BINS,
    max_lag_s: float = 1.0,
    scored: npt.ArrayLike | None = None,
) -> ValidationMetrics:
    """Score ``estimate`` against ``reference`` (both rad, on ``t``).

    ``reference_valid`` restricts the comparison (e.g. ``ReferenceSideslip.valid`` or a
    manoeuvre's mask); ``ay`` (m/s²) enables the per-bin statistics. ``scored``: the samples being
    judged (default all); the reference's valid fraction is counted over them only, so samples of
    manoeuvres that do not need the reference (low-speed manoeuvring) do not count as invalid.

    Raises:
        AnalysisError: bad arrays or no common valid sample.
    """
    tt = check_time("t", t)
    n = tt.size
    est = as_1d("estimate", estimate, n)
    ref = as_1d("reference", reference, n)
    ref_ok = as_bool("reference_valid", reference_valid, n) & np.isfinite(ref)
    m = ref_ok & np.isfinite(est)
    if not np.any(m):
        raise AnalysisError("compare: the estimate and the reference have no common valid sample")
    tol = tolerances or Tolerances()
    e = np.asarray(wrap_pi(est[m] - ref[m]), dtype=float)
    ae = np.abs(e)
    rmse = float(np.sqrt(np.mean(e * e)))
    bias = float(np.mean(e))
    max_abs = float(np.max(ae))
    p95 = float(np.percentile(ae, 95.0))
    judged = np.ones(n, dtype=bool) if scored is None else as_bool("scored", scored, n)
    valid_fraction = float(np.count_nonzero(ref_ok & judged)) / float(max(1, int(np.count_nonzero(judged))))
    if n >= 3:
        try:
            lag, corr = estimate_lag(tt, est, ref, max_lag_s=max_lag_s, valid=m)
        except AnalysisError:
            lag, corr = math.nan, math.nan
    else:
        lag, corr = math.nan, math.nan
    sig_rms = math.nan
    warnings: list[str] = []
    if reference_sigma is not None:
        sg = as_1d("reference_sigma", reference_sigma, n)[m]
        sg = sg[np.isfinite(sg)]
        if sg.size:
            sig_rms = float(np.sqrt(np.mean(sg * sg)))
            if tol.rmse_rad is not None and 2.0 * sig_rms > tol.rmse_rad / 2.0:
                warnings.append(
                    f"reference uncertainty (2σ RMS {math.degrees(2 * sig_rms):.3f}°) exceeds half the RMSE "
                    f"tolerance ({math.degrees(tol.rmse_rad):.3f}°): the verdict is weak"
                )
    bins: list[AyBin] = []
    if ay is not None:
        a = np.abs(as_1d("ay", ay, n)[m])
        edges = [float(x) for x in ay_bins]
        if any(b <= a_ for a_, b in zip(edges, edges[1:], strict=False)):
            raise AnalysisError(f"ay_bins must increase, got {edges}")
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            sel = (a >= lo) & (a < hi)
            k = int(np.count_nonzero(sel))
            if k:
                eb = e[sel]
                rms_b = float(np.sqrt(np.mean(eb * eb)))
                bins.append(AyBin(lo, hi, k, rms_b, float(np.mean(eb)), float(np.max(np.abs(eb)))))
            else:
                bins.append(AyBin(lo, hi, 0, math.nan, math.nan, math.nan))
    failures: list[str] = []

    def check(name: str, value: float, limit: float | None, unit_deg: bool = True) -> None:
        if limit is None:
            return
        if not (value <= limit):
            if unit_deg:
                failures.append(f"{name} {math.degrees(value):.3f}° > {math.degrees(limit):.3f}°")
            else:
                failures.append(f"{name} {value:.3f} s > {limit:.3f} s")

    check("RMSE", rmse, tol.rmse_rad)
    check("max |error|", max_abs, tol.max_abs_rad)
    check("|bias|", abs(bias), tol.bias_rad)
    check("95th percentile |error|", p95, tol.p95_rad)
    if tol.max_lag_s is not None:
        if math.isnan(lag):
            failures.append("lag could not be estimated")
        else:
            check("|lag|", abs(lag), tol.max_lag_s, unit_deg=False)
    if tol.min_valid_fraction is not None and valid_fraction < tol.min_valid_fraction:
        failures.append(
            f"reference valid {100 * valid_fraction:.1f} % of the time < {100 * tol.min_valid_fraction:.1f} %"
        )
    return ValidationMetrics(
        n_samples=n,
        n_compared=int(e.size),
        valid_fraction=valid_fraction,
        rmse_rad=rmse,
        bias_rad=bias,
        max_abs_rad=max_abs,
        p95_abs_rad=p95,
        lag_s=lag,
        lag_correlation=corr,
        reference_sigma_rms_rad=sig_rms,
        bins=tuple(bins),
        passed=not failures,
        failures=tuple(failures),
        warnings=tuple(warnings),
    )


def error_series(estimate: npt.ArrayLike, reference: npt.ArrayLike) -> FloatArray:
    """β̂ − β wrapped to (−π, π] (rad), NaN where either is."""
    return np.asarray(wrap_pi(np.asarray(estimate, dtype=float) - np.asarray(reference, dtype=float)), dtype=float)
