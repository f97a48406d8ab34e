"""Rollover index: lateral load-transfer ratio (LTR) and its autoregressive prediction 1–3 s ahead.

LTR = (F_z,right − F_z,left) / ΣF_z, positive when the right wheels carry more (a left turn);
|LTR| = 1 means one side has lifted. From the roll-plane moment balance about the track centre
line on the ground, with the body rolling by φ about a roll axis at height h_r:

    (F_R − F_L)·t/2 = m·a_y·h + m·g·(h − h_r)·sin φ
    LTR = (2 / t)·(h·a_y / g + (h − h_r)·sin φ)

with h the CG height, t the track width (mean of front and rear), a_y the lateral acceleration
of the CG in the horizontal plane (a body-fixed accelerometer reads a_y·cos φ + g·sin φ;
:func:`horizontal_ay` undoes that) and φ positive right side down (ISO 8855). The unsprung
masses are neglected. In fast transients the body's roll inertia carries part of the moment:
with the roll acceleration φ̈ and the body's roll inertia I_x about the roll axis, the springs
and dampers (hence the wheels) see I_x·φ̈ less, LTR −= 2·I_x·φ̈ / (m·g·t) (optional).

Prediction: the LTR record is resampled to ``rate_hz``; on a sliding window of the last
``window_s`` (growing from ``min_window_s`` at the start) an autoregressive model of the LTR's
*increments* (an ARIMA(p, 1, 0): a held LTR stays held instead of decaying to the window's
mean), its order chosen by AIC (as statsmodels ``ar_select_order`` does it; a NumPy
re-implementation by default for speed, checked against it), is refitted every
``refit_every_s`` and iterated forward 1, 2 and 3 s; a fit with a root near the unit circle is
rejected in favour of holding the current value. A warning fires at every epoch where a
prediction (or the LTR itself) reaches ``threshold`` (0.9) in magnitude. Predictions are
clipped to [−1, 1], the physical range.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from statsmodels.tsa.ar_model import ar_select_order

from rig.analysis._arrays import as_1d, check_time, runs
from vsccore.angles import FloatArray
from vsccore.errors import AnalysisError

__all__ = [
    "LtrPrediction",
    "PredictionError",
    "horizontal_ay",
    "ltr_from_lateral",
    "predict_ltr",
    "prediction_errors",
]

G = 9.80665
_MAX_ROOT = 0.98
"""Largest modulus of the increments' AR roots accepted (closer to 1 is a near-integrated, runaway forecast)."""


def horizontal_ay(ay_body_mps2: npt.ArrayLike, roll_rad: npt.ArrayLike) -> FloatArray:
    """Lateral acceleration in the horizontal plane from a body-fixed accelerometer: (a_m − g sin φ) / cos φ."""
    a = np.asarray(ay_body_mps2, dtype=float)
    phi = np.asarray(roll_rad, dtype=float)
    return np.asarray((a - G * np.sin(phi)) / np.cos(phi), dtype=float)


def ltr_from_lateral(
    ay_mps2: npt.ArrayLike,
    roll_rad: npt.ArrayLike,
    *,
    cg_height_m: float,
    roll_axis_height_m: float,
    track_m: float,
    roll_accel_rps2: npt.ArrayLike | None = None,
    roll_inertia_kgm2: float = 0.0,
    mass_kg: float | None = None,
) -> FloatArray:
    """LTR from the horizontal lateral acceleration and the roll angle (module docstring).

    With ``roll_accel_rps2`` (e.g. the derivative of a roll rate), ``roll_inertia_kgm2`` and
    ``mass_kg`` the roll-inertia term is included.
    """
    if not (track_m > 0.0 and cg_height_m > 0.0):
        raise AnalysisError(f"ltr: track ({track_m} m) and CG height ({cg_height_m} m) must be positive")
    a = np.asarray(ay_mps2, dtype=float)
    phi = np.asarray(roll_rad, dtype=float)
    ltr = 2.0 / track_m * (cg_height_m * a / G + (cg_height_m - roll_axis_height_m) * np.sin(phi))
    if roll_accel_rps2 is not None and roll_inertia_kgm2 > 0.0:
        if mass_kg is None or not mass_kg > 0.0:
            raise AnalysisError("ltr: the roll-inertia term needs a positive mass_kg")
        ltr = ltr - 2.0 * roll_inertia_kgm2 * np.asarray(roll_accel_rps2, dtype=float) / (mass_kg * G * track_m)
    return np.asarray(ltr, dtype=float)


@dataclass(frozen=True, slots=True)
class LtrPrediction:
    """Predictions issued at each epoch ``t`` for ``t + horizon``."""

    t: FloatArray
    """Issue times (s), uniform at the prediction rate."""
    ltr: FloatArray
    """The LTR at the issue times (resampled)."""
    horizons_s: tuple[float, ...]
    predicted: FloatArray
    """(n, len(horizons)): the LTR predicted for t + horizon; NaN for the first ``min_window_s``."""
    order: npt.NDArray[np.int64]
    """AR order in use at each epoch (0: none yet)."""
    warning: npt.NDArray[np.bool_]
    """True where |LTR| or any |prediction| reaches the threshold."""
    threshold: float

    @property
    def warning_intervals(self) -> list[tuple[float, float]]:
        """(start, end) times (s) of the warning."""
        return [(float(self.t[a]), float(self.t[b - 1])) for a, b in runs(self.warning)]

    def first_warning_s(self) -> float | None:
        """Time of the first warning, or None."""
        i = np.flatnonzero(self.warning)
        return float(self.t[i[0]]) if i.size else None


def _forecast(coef: FloatArray, history: FloatArray, steps: int) -> FloatArray:
    """Levels ``steps`` ahead: the last value plus the AR(p) increments Δx[k] = Σ a_i Δx[k−i] iterated forward."""
    p = coef.size
    level = float(history[-1])
    if p == 0:
        return np.full(steps, level)
    inc = list(np.diff(history)[-p:])
    out = np.empty(steps)
    for k in range(steps):
        d = float(np.dot(coef, inc[::-1]))
        level += d
        out[k] = level
        inc.append(d)
        inc.pop(0)
    return out


def _select_numpy(d: FloatArray, maxlag: int) -> tuple[FloatArray, int]:
    """AIC order selection and OLS fit of a zero-mean AR on ``d``, as statsmodels' ``ar_select_order`` does it.

    All orders 0 … maxlag are fitted on the same samples (the first ``maxlag`` held back);
    AIC = −2·llf + 2·(p + 1) with the Gaussian log-likelihood at σ² = SSR / nobs; the smallest wins.
    """
    y = d[maxlag:]
    nobs = y.size
    x_full = np.column_stack([d[maxlag - i : d.size - i] for i in range(1, maxlag + 1)])
    best_aic, best_p = math.inf, 0
    for p in range(maxlag + 1):
        coef: FloatArray
        if p == 0:
            coef = np.zeros(0)
            ssr = float(np.dot(y, y))
        else:
            sol = np.linalg.lstsq(x_full[:, :p], y, rcond=None)[0]
            coef = np.asarray(sol, dtype=np.float64)
            r = y - x_full[:, :p] @ coef
            ssr = float(np.dot(r, r))
        if ssr <= 0.0:
            return np.asarray(coef, dtype=float), p
        llf = -0.5 * nobs * (math.log(2.0 * math.pi) + math.log(ssr / nobs) + 1.0)
        aic = -2.0 * llf + 2.0 * (p + 1)
        if aic < best_aic - 1e-12:
            best_aic, best_p = aic, p
    if best_p == 0:
        return np.zeros(0), 0
    # refit the chosen order on all available samples, as statsmodels' final fit does
    y2 = d[best_p:]
    x2 = np.column_stack([d[best_p - i : d.size - i] for i in range(1, best_p + 1)])
    coef2, *_ = np.linalg.lstsq(x2, y2, rcond=None)
    return np.asarray(coef2, dtype=float), best_p


def _select_statsmodels(d: FloatArray, maxlag: int) -> tuple[FloatArray, int]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # statsmodels warns on near-singular fits of short windows
        sel = ar_select_order(d, maxlag=maxlag, ic="aic", trend="n")
        lags = sel.ar_lags or []
        if not lags:
            return np.zeros(0), 0
        res = sel.model.fit()
    order = int(max(lags))
    coef = np.zeros(order)
    for lag, value in zip(lags, np.asarray(res.params, dtype=float), strict=True):
        coef[int(lag) - 1] = float(value)
    return coef, order


def _fit(window: FloatArray, max_order: int, engine: str = "numpy") -> tuple[FloatArray, int]:
    """AR coefficients (lag 1 first) of the increments, order by AIC; none if flat or explosive.

    ``engine`` "statsmodels" uses ``ar_select_order``; "numpy" (default) the same computation
    in plain least squares, ≈ 50× faster (the tests check that both agree). A fit whose
    characteristic roots reach the unit circle would extrapolate a transient without bound: it is
    rejected and the LTR is held (persistence) until the next refit.
    """
    d = np.diff(window)
    if d.size < 4 or float(np.max(np.abs(d))) < 1e-9:
        return np.zeros(0), 0
    maxlag = int(min(max_order, max(1, d.size // 4)))
    coef, order = _select_statsmodels(d, maxlag) if engine == "statsmodels" else _select_numpy(d, maxlag)
    if order and np.any(np.abs(np.roots(np.concatenate(([1.0], -coef)))) >= _MAX_ROOT):
        return np.zeros(0), 0
    return coef, order


def predict_ltr(
    t_s: npt.ArrayLike,
    ltr: npt.ArrayLike,
    *,
    horizons_s: Sequence[float] = (1.0, 2.0, 3.0),
    rate_hz: float = 20.0,
    window_s: float = 3.0,
    min_window_s: float = 1.0,
    max_order: int = 8,
    refit_every_s: float = 0.25,
    threshold: float = 0.9,
    engine: str = "numpy",
) -> LtrPrediction:
    """Predict the LTR ``horizons_s`` ahead with a sliding-window AR model (module docstring).

    ``engine``: "numpy" (default, fast) or "statsmodels" (``ar_select_order``; the same result).

    Raises:
        AnalysisError: malformed arrays, a record shorter than the window, or bad settings.
    """
    t_in = check_time("t_s", t_s, min_samples=2)
    x_in = as_1d("ltr", ltr, t_in.size)
    if not (rate_hz > 0.0 and window_s > 0.0 and refit_every_s > 0.0 and max_order >= 1):
        raise AnalysisError("predict_ltr: rate_hz, window_s, refit_every_s must be positive and max_order ≥ 1")
    if engine not in ("numpy", "statsmodels"):
        raise AnalysisError(f"predict_ltr: engine must be 'numpy' or 'statsmodels', got {engine!r}")
    hs = tuple(float(h) for h in horizons_s)
    if not hs or min(hs) <= 0.0:
        raise AnalysisError(f"predict_ltr: horizons must be positive, got {hs}")
    dt = 1.0 / rate_hz
    t = np.arange(t_in[0], t_in[-1] + 0.5 * dt, dt)
    ok = np.isfinite(x_in)
    if np.count_nonzero(ok) < 2:
        raise AnalysisError("predict_ltr: fewer than two finite LTR samples")
    x = np.interp(t, t_in[ok], x_in[ok])
    w = int(round(window_s * rate_hz))
    if t.size < max(2, int(round(min_window_s * rate_hz))):
        raise AnalysisError(
            f"predict_ltr: record of {t[-1] - t[0]:.1f} s is shorter than the {min_window_s} s minimum window"
        )
    steps = [max(1, int(round(h * rate_hz))) for h in hs]
    n_ahead = max(steps)
    refit = max(1, int(round(refit_every_s * rate_hz)))
    pred = np.full((t.size, len(hs)), np.nan)
    order = np.zeros(t.size, dtype=np.int64)
    coef, p = np.zeros(0), 0
    k0 = min(w, max(2, int(round(min_window_s * rate_hz)))) - 1
    for k in range(k0, t.size):
        window = x[max(0, k - w + 1) : k + 1]  # grows to the full window at the start of the record
        if (k - k0) % refit == 0:
            coef, p = _fit(window, max_order, engine)
        path = _forecast(coef, window, n_ahead)
        pred[k] = np.clip(path[[s - 1 for s in steps]], -1.0, 1.0)
        order[k] = p
    with np.errstate(invalid="ignore"):
        warn = (np.abs(x) >= threshold) | np.any(np.abs(pred) >= threshold, axis=1)
    return LtrPrediction(t=t, ltr=x, horizons_s=hs, predicted=pred, order=order, warning=warn, threshold=threshold)


@dataclass(frozen=True, slots=True)
class PredictionError:
    """Mean absolute prediction error at one horizon, over the epochs evaluated."""

    horizon_s: float
    mean_abs_error: float
    percent_of_peak: float
    """mean_abs_error / max |LTR| over the evaluated span, in per cent."""
    n: int


def prediction_errors(
    pred: LtrPrediction,
    t_truth_s: npt.ArrayLike,
    ltr_truth: npt.ArrayLike,
    *,
    t_start_s: float | None = None,
    t_stop_s: float | None = None,
    issued_from_s: float | None = None,
) -> list[PredictionError]:
    """Score the predictions against a true LTR record over [t_start, t_stop] (target times).

    A prediction issued at t for t + h counts when t + h lies in the span, the prediction exists
    and (with ``issued_from_s``) t ≥ issued_from_s; the peak is the largest true |LTR| in the span.

    Raises:
        AnalysisError: nothing to score.
    """
    tt = check_time("t_truth_s", t_truth_s, min_samples=2)
    lt = as_1d("ltr_truth", ltr_truth, tt.size)
    a = tt[0] if t_start_s is None else t_start_s
    b = tt[-1] if t_stop_s is None else t_stop_s
    span = (tt >= a) & (tt <= b)
    if not np.any(span):
        raise AnalysisError(f"prediction_errors: no truth sample in [{a}, {b}] s")
    peak = float(np.max(np.abs(lt[span])))
    out: list[PredictionError] = []
    for j, h in enumerate(pred.horizons_s):
        target = pred.t + h
        m = (target >= a) & (target <= b) & np.isfinite(pred.predicted[:, j]) & (target <= tt[-1])
        if issued_from_s is not None:
            m &= pred.t >= issued_from_s
        if not np.any(m):
            raise AnalysisError(f"prediction_errors: no prediction {h} s ahead lands in [{a}, {b}] s")
        truth = np.interp(target[m], tt, lt)
        mae = float(np.mean(np.abs(pred.predicted[m, j] - truth)))
        out.append(PredictionError(h, mae, 100.0 * mae / peak if peak > 0 else math.nan, int(np.count_nonzero(m))))
    return out
