"""Front road-wheel angle reconstructed from GNSS speed and lateral acceleration, and its error model.

Kinematic single-track model in steady state: the car turns on a radius R = v_x² / a_y and the
Ackermann angle is l / R, so δ_kin = a_y·l / v_x². Two corrections:

- body roll: a body-fixed accelerometer also senses gravity through the roll angle; with the
  static roll gain k_φ (rad of roll per m/s² of lateral acceleration) the reading is
  ≈ a_y (1 + g·k_φ), so a_y = a_y,measured / (1 + g·k_φ);
- understeer: the tyres slip, α_f − α_r = K·a_y, with the understeer gradient
  K = m_f / C_f − m_r / C_r (rad per m/s²), m_f = m·b/l and m_r = m·a/l the axle masses and C the
  axle cornering stiffnesses (two tyres per axle), so δ = a_y·l / v_x² + K·a_y.

The uncorrected estimate δ_kin = a_y,measured·l / v_x² relates to the true angle by the relative
error γ = 1 − δ_kin/δ = 1 − l (1 + g·k_φ) / (l + K·v_x²): roll makes it read high at low speed,
understeer low at high speed, and it changes sign at v_x = √(l·g·k_φ / K).

That steady-state formula misses two things on a lane change (0.38° / 7.9 % at the peaks on the
simulator's noise-free 50 km/h DLC): a_y is not v·r while the sideslip changes (a_y = v(β̇ + r)),
and the tyres are not linear — an axle needs more slip than F/C near its peak force, more so
under lateral load transfer. With the yaw inertia (and optionally the tyre characteristic) in the
:class:`SteeringModel`, :func:`reconstruct_steering` inverts the single-track dynamics instead,
still from a_y and v alone:

- the rear axle's slip α_r = −β + b·r/v and force F_yr(α_r) drive the yaw and sideslip states:
  I_z ṙ = a·m·a_y − l·F_yr,  β̇ = a_y / v − r  (a stable, well damped system — the zero dynamics
  of a_y over δ — started in steady state at the start of each valid run);
- the front axle carries the rest, F_yf = m·a_y − F_yr, at the slip α_f that the inverted
  characteristic gives;
- δ = α_f + atan(tan β + a·r / v_x): the front axle's velocity direction at the actual speed.

Axle characteristic: two tyres, each with Pacejka's magic formula at its own vertical load
(:class:`LateralTyreModel`), quasi-static lateral load transfer per axle
ΔF_z = (m·(axle share)·h_roll-axis·a_y + K_φ,axle·φ) / track with φ = k_φ·a_y. Without a tyre
model the axles are linear (F = C·α); in steady state with linear axles the result is the formula
above. The formula and the figures are in docs/steering.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rig.analysis.arrays import BoolArray, as_1d, check_time, split_at_gaps
from vsccore.angles import FloatArray
from vsccore.errors import AnalysisError

__all__ = [
    "AyDelay",
    "ErrorModel",
    "LateralTyreModel",
    "SteeringModel",
    "SteeringReconstruction",
    "error_model",
    "error_table",
    "estimate_ay_delay",
    "reconstruct_steering",
]

G = 9.80665


@dataclass(frozen=True, slots=True)
class LateralTyreModel:
    """Lateral characteristic of the tyres and the lateral load transfer between the two wheels of an axle.

    Per tyre at vertical load F_z (static load F_z0) and slip angle α (rad), Pacejka's magic formula
    with load-dependent friction and cornering stiffness:
    μ = μ₀(1 − ε(F_z − F_z0)/F_z0), C_α(F_z) = C_α0·sin(2·atan(F_z/(k·F_z0)))/sin(2·atan(1/k)),
    F_y = μF_z·sin(C·atan(Bα − E(Bα − atan(Bα)))), B = C_α/(C·μF_z). The cornering stiffness C_α0
    per tyre is the :class:`SteeringModel`'s. ε and k default to typical passenger-car values
    (Pacejka p_Dy2 ≈ −0.1; stiffness peaking at twice the static load).
    """

    track_front_m: float
    track_rear_m: float
    roll_axis_height_m: float
    roll_stiffness_front_nm_per_rad: float
    roll_stiffness_rear_nm_per_rad: float
    peak_mu: float = 1.0
    shape_c: float = 1.3
    curvature_e: float = -0.5
    mu_load_sensitivity: float = 0.10
    stiffness_peak_load_ratio: float = 2.0

    def __post_init__(self) -> None:
        for name in ("track_front_m", "track_rear_m", "peak_mu", "shape_c", "stiffness_peak_load_ratio"):
            if not getattr(self, name) > 0.0:
                raise AnalysisError(f"tyre model: {name} must be positive, got {getattr(self, name)}")
        for name in ("roll_axis_height_m", "roll_stiffness_front_nm_per_rad", "roll_stiffness_rear_nm_per_rad",
                     "mu_load_sensitivity"):
            if not getattr(self, name) >= 0.0:
                raise AnalysisError(f"tyre model: {name} must not be negative, got {getattr(self, name)}")
        if not self.curvature_e < 1.0:
            raise AnalysisError(f"tyre model: curvature_e must be below 1, got {self.curvature_e}")


@dataclass(frozen=True, slots=True)
class SteeringModel:
    """The vehicle quantities the reconstruction needs (SI)."""

    wheelbase_m: float
    mass_kg: float
    front_axle_load_share: float
    """b / l: the share of the weight on the front axle (0.6 for a front-heavy car)."""
    cornering_stiffness_front_n_per_rad: float
    """Per tyre."""
    cornering_stiffness_rear_n_per_rad: float
    """Per tyre."""
    roll_gain_rad_per_mps2: float = 0.0
    """Static roll angle per unit lateral acceleration, k_φ."""
    yaw_inertia_kgm2: float | None = None
    """With it, :func:`reconstruct_steering` inverts the yaw and sideslip dynamics (module docstring);
    without it, it uses the steady-state formula."""
    tyres: LateralTyreModel | None = None
    """Non-linear axle characteristic with load transfer (dynamic reconstruction only); None: linear axles."""

    def __post_init__(self) -> None:
        names = ("wheelbase_m", "mass_kg", "cornering_stiffness_front_n_per_rad", "cornering_stiffness_rear_n_per_rad")
        for name in names:
            if not getattr(self, name) > 0.0:
                raise AnalysisError(f"steering model: {name} must be positive, got {getattr(self, name)}")
        if self.yaw_inertia_kgm2 is not None and not self.yaw_inertia_kgm2 > 0.0:
            raise AnalysisError(f"steering model: yaw_inertia_kgm2 must be positive, got {self.yaw_inertia_kgm2}")
        if not 0.0 < self.front_axle_load_share < 1.0:
            raise AnalysisError(
                f"steering model: front_axle_load_share must be in (0, 1), got {self.front_axle_load_share}"
            )

    @classmethod
    def from_degrees_per_g(
        cls,
        *,
        wheelbase_m: float,
        mass_kg: float,
        front_axle_load_share: float,
        cornering_stiffness_n_per_rad_per_tyre: float,
        roll_gain_deg_per_g: float,
        cornering_stiffness_rear_n_per_rad_per_tyre: float | None = None,
    ) -> SteeringModel:
        """From the units of the ``rig steering error-model`` options (roll gain in deg per g)."""
        cr = cornering_stiffness_rear_n_per_rad_per_tyre
        return cls(
            wheelbase_m=wheelbase_m,
            mass_kg=mass_kg,
            front_axle_load_share=front_axle_load_share,
            cornering_stiffness_front_n_per_rad=cornering_stiffness_n_per_rad_per_tyre,
            cornering_stiffness_rear_n_per_rad=cornering_stiffness_n_per_rad_per_tyre if cr is None else cr,
            roll_gain_rad_per_mps2=math.radians(roll_gain_deg_per_g) / G,
        )

    @property
    def understeer_gradient_rad_per_mps2(self) -> float:
        """K = m_f / C_f − m_r / C_r with two tyres per axle."""
        m_f = self.mass_kg * self.front_axle_load_share
        m_r = self.mass_kg - m_f
        c_f = 2.0 * self.cornering_stiffness_front_n_per_rad
        c_r = 2.0 * self.cornering_stiffness_rear_n_per_rad
        return m_f / c_f - m_r / c_r

    @property
    def roll_factor(self) -> float:
        """1 + g·k_φ."""
        return 1.0 + G * self.roll_gain_rad_per_mps2


@dataclass(frozen=True, slots=True)
class ErrorModel:
    """γ(v) of the uncorrected kinematic estimate (module docstring)."""

    speeds_mps: FloatArray
    gamma: FloatArray
    """Relative error 1 − δ_kin/δ at each speed."""
    sign_change_speed_mps: float | None
    """Where γ = 0 (None when K and k_φ do not allow it)."""
    understeer_gradient_rad_per_mps2: float
    roll_factor: float

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (speeds in km/h, γ in per cent)."""
        v0 = self.sign_change_speed_mps
        return {
            "sign_change_speed_kmh": None if v0 is None else 3.6 * v0,
            "understeer_gradient_deg_per_g": math.degrees(self.understeer_gradient_rad_per_mps2) * G,
            "roll_factor": self.roll_factor,
            "errors": [
                {"speed_kmh": 3.6 * float(v), "gamma_percent": 100.0 * float(g)}
                for v, g in zip(self.speeds_mps, self.gamma, strict=True)
            ],
        }


def error_model(model: SteeringModel, speeds_mps: npt.ArrayLike) -> ErrorModel:
    """γ = 1 − l (1 + g·k_φ) / (l + K·v²) at the given speeds, and the speed where it changes sign."""
    v = np.atleast_1d(np.asarray(speeds_mps, dtype=float))
    ell = model.wheelbase_m
    k = model.understeer_gradient_rad_per_mps2
    rf = model.roll_factor
    gamma = 1.0 - ell * rf / (ell + k * v * v)
    v0: float | None = None
    ratio = ell * (rf - 1.0) / k if k != 0.0 else -1.0
    if ratio > 0.0:
        v0 = math.sqrt(ratio)
    return ErrorModel(np.asarray(v, dtype=float), np.asarray(gamma, dtype=float), v0, k, rf)


@dataclass(frozen=True, slots=True)
class SteeringReconstruction:
    """δ(t) from speed and lateral acceleration, compared with δ from the steering-wheel angle."""

    t: FloatArray
    delta: FloatArray
    """Reconstructed front road-wheel angle (rad), roll- and understeer-corrected; NaN below the minimum speed."""
    delta_kinematic: FloatArray
    """Uncorrected a_y,measured·l / v_x² (rad)."""
    delta_from_swa: FloatArray | None
    """SWA / steering ratio (rad), when a steering-wheel angle was given."""
    mean_abs_error_rad: float
    max_abs_error_rad: float
    max_relative_error_at_peaks: float
    """Largest |δ − δ_swa| / |δ_swa| at the peaks of |δ_swa| (local maxima above half the largest)."""
    peaks_t: tuple[float, ...]
    method: str = "steady state"
    """"steady state" or "single-track dynamics, …" (see :func:`reconstruct_steering`)."""
    delta_steady_state: FloatArray | None = None
    """The steady-state formula's δ (rad), for comparison."""
    beyond_tyre_peak: int = 0
    """Samples whose front-axle force exceeded the tyre model's peak (δ there is a lower bound)."""
    ay_delay_s: float = 0.0
    """The a_y time-stamp delay that was removed."""

    def to_dict(self) -> dict[str, object]:
        """JSON-able summary (degrees, per cent)."""

        def deg(x: float) -> float | None:
            return None if math.isnan(x) else math.degrees(x)

        return {
            "mean_abs_error_deg": deg(self.mean_abs_error_rad),
            "max_abs_error_deg": deg(self.max_abs_error_rad),
            "max_relative_error_at_peaks_percent": None
            if math.isnan(self.max_relative_error_at_peaks)
            else 100.0 * self.max_relative_error_at_peaks,
            "peaks_t_s": list(self.peaks_t),
            "method": self.method,
            "beyond_tyre_peak_samples": self.beyond_tyre_peak,
            "ay_delay_s": self.ay_delay_s,
        }


def _peaks(x: FloatArray, min_fraction: float, min_sep: int) -> list[int]:
    a = np.abs(np.nan_to_num(x))
    if a.size < 3 or float(np.max(a)) == 0.0:
        return []
    thr = min_fraction * float(np.max(a))
    cand = np.flatnonzero((a[1:-1] >= a[:-2]) & (a[1:-1] > a[2:]) & (a[1:-1] >= thr)) + 1
    out: list[int] = []
    for i in cand[np.argsort(-a[cand])]:
        if all(abs(int(i) - j) >= min_sep for j in out):
            out.append(int(i))
    return sorted(out)


# --------------------------------------------------------------------------------------------
# dynamic inversion of the single-track model (module docstring)

_SUBSTEP_S = 0.005
"""Largest integration step of the yaw/sideslip states (the zero dynamics are ≈ 2 Hz, well damped)."""
_MAX_GAP_S = 0.5
"""A longer gap between valid samples restarts the integration in steady state."""


class _Axles:
    """Lateral force of each axle as a function of its slip angle and the lateral acceleration (load transfer)."""

    def __init__(self, model: SteeringModel) -> None:
        self.m = model
        ell = model.wheelbase_m
        self.b_over_l = model.front_axle_load_share
        self.a = ell * (1.0 - self.b_over_l)
        self.b = ell * self.b_over_l
        self.c_front = 2.0 * model.cornering_stiffness_front_n_per_rad
        self.c_rear = 2.0 * model.cornering_stiffness_rear_n_per_rad
        w = model.mass_kg * G
        self.fz0 = (0.5 * w * self.b_over_l, 0.5 * w * (1.0 - self.b_over_l))
        self.c0 = (model.cornering_stiffness_front_n_per_rad, model.cornering_stiffness_rear_n_per_rad)
        ty = model.tyres
        if ty is not None:
            # load transfer per m/s² of a_y: roll-axis (geometric) share plus the roll moment via φ = k_φ·a_y
            kphi = model.roll_gain_rad_per_mps2
            m = model.mass_kg
            self.transfer = (
                (m * self.b_over_l * ty.roll_axis_height_m + ty.roll_stiffness_front_nm_per_rad * kphi)
                / ty.track_front_m,
                (m * (1.0 - self.b_over_l) * ty.roll_axis_height_m + ty.roll_stiffness_rear_nm_per_rad * kphi)
                / ty.track_rear_m,
            )
            x0 = 1.0 / ty.stiffness_peak_load_ratio
            self.norm = 2.0 * x0 / (1.0 + x0 * x0)

    def _tyre(self, alpha: FloatArray, fz: FloatArray, axle: int) -> FloatArray:
        ty = self.m.tyres
        assert ty is not None
        fz0 = self.fz0[axle]
        fz = np.maximum(fz, 0.0)
        mu = np.maximum(ty.peak_mu * (1.0 - ty.mu_load_sensitivity * (fz - fz0) / fz0), 0.1 * ty.peak_mu)
        xk = 1.0 / (ty.stiffness_peak_load_ratio * fz0)
        x = fz * xk
        bb = self.c0[axle] * 2.0 * xk / ((1.0 + x * x) * self.norm * ty.shape_c * mu)
        ba = bb * alpha
        e = ty.curvature_e
        return np.asarray(mu * fz * np.sin(ty.shape_c * np.arctan(ba - e * (ba - np.arctan(ba)))), dtype=float)

    def force(self, alpha: FloatArray, ay: FloatArray, axle: int) -> FloatArray:
        """Axle lateral force (N) at slip ``alpha`` (rad) with the load transfer of ``ay`` (0 front, 1 rear)."""
        if self.m.tyres is None:
            return np.asarray((self.c_front, self.c_rear)[axle] * alpha, dtype=float)
        d = self.transfer[axle] * ay
        fz0 = self.fz0[axle]
        return self._tyre(alpha, fz0 - d, axle) + self._tyre(alpha, fz0 + d, axle)

    def force_scalar(self, alpha: float, ay: float, axle: int) -> float:
        """:meth:`force` on plain floats (the integration loop)."""
        if self.m.tyres is None:
            return (self.c_front, self.c_rear)[axle] * alpha
        ty = self.m.tyres
        fz0 = self.fz0[axle]
        d = self.transfer[axle] * ay
        xk = 1.0 / (ty.stiffness_peak_load_ratio * fz0)
        c, e = ty.shape_c, ty.curvature_e
        total = 0.0
        for fz in (fz0 - d, fz0 + d):
            fz = max(fz, 0.0)
            mu = max(ty.peak_mu * (1.0 - ty.mu_load_sensitivity * (fz - fz0) / fz0), 0.1 * ty.peak_mu)
            x = fz * xk
            ba = self.c0[axle] * 2.0 * xk / ((1.0 + x * x) * self.norm * c * mu) * alpha
            total += mu * fz * math.sin(c * math.atan(ba - e * (ba - math.atan(ba))))
        return total

    def slip(self, f: FloatArray, ay: FloatArray, axle: int) -> tuple[FloatArray, BoolArray]:
        """Slip angle at which the axle carries ``f`` (inverse of :meth:`force` on its rising branch).

        Returns the slip and a mask of samples whose force exceeds the axle's peak (slip held at the peak).
        """
        c = (self.c_front, self.c_rear)[axle]
        if self.m.tyres is None:
            return np.asarray(f / c, dtype=float), np.zeros(f.shape, dtype=bool)
        sign = np.sign(f)
        target = np.abs(f)
        # the peak: coarse grid, then the bracket [0, α_peak] is monotone
        grid = np.linspace(0.0, 0.5, 251)
        fg = self.force(grid[None, :], ay[:, None] + 0.0 * grid[None, :], axle)
        ipk = np.argmax(fg, axis=1)
        hi = grid[np.minimum(ipk + 1, grid.size - 1)]
        fpk = fg[np.arange(f.size), ipk]
        over = target >= fpk
        lo = np.zeros_like(target)
        for _ in range(48):
            mid = 0.5 * (lo + hi)
            below = self.force(mid, ay, axle) < target
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        alpha = np.where(over, grid[ipk], 0.5 * (lo + hi))
        return np.asarray(sign * alpha, dtype=float), over


def _dynamic_delta(t: FloatArray, v: FloatArray, ay: FloatArray, ok: BoolArray, model: SteeringModel
                   ) -> tuple[FloatArray, int, FloatArray]:
    """δ by inverting the single-track dynamics on each run of valid samples.

    Returns δ, the number of samples beyond the tyre peak, and the model's yaw rate r (NaN where not valid).
    """
    assert model.yaw_inertia_kgm2 is not None
    ax = _Axles(model)
    a, b, ell, m, iz = ax.a, ax.b, model.wheelbase_m, model.mass_kg, model.yaw_inertia_kgm2
    delta = np.full(t.size, np.nan)
    yaw_rate = np.full(t.size, np.nan)
    saturated = 0
    for i0, i1 in split_at_gaps(t, ok, _MAX_GAP_S):
        if i1 - i0 < 2:
            continue
        tt, vv, aa = t[i0:i1], np.abs(v[i0:i1]), ay[i0:i1]
        # steady state at the start: r = a_y/v, rear force m·a·a_y/l
        r = float(aa[0] / vv[0])
        ar0, _ = ax.slip(np.array([m * a * aa[0] / ell]), aa[:1], 1)
        beta = b * r / float(vv[0]) - float(ar0[0])
        beta_s = np.empty(tt.size)
        r_s = np.empty(tt.size)
        beta_s[0], r_s[0] = beta, r

        def deriv(bt: float, rr: float, vel: float, acc: float) -> tuple[float, float]:
            f_r = ax.force_scalar(-bt + b * rr / vel, acc, 1)
            return acc / vel - rr, (a * m * acc - ell * f_r) / iz

        for k in range(tt.size - 1):
            span = float(tt[k + 1] - tt[k])
            n_sub = max(1, math.ceil(span / _SUBSTEP_S))
            h = span / n_sub
            v0, v1, a0, a1 = float(vv[k]), float(vv[k + 1]), float(aa[k]), float(aa[k + 1])
            for j in range(n_sub):
                f0, f1 = j / n_sub, (j + 1) / n_sub
                va, aa0 = v0 + f0 * (v1 - v0), a0 + f0 * (a1 - a0)
                vb, aa1 = v0 + f1 * (v1 - v0), a0 + f1 * (a1 - a0)
                d1 = deriv(beta, r, va, aa0)  # Heun (trapezoidal predictor-corrector)
                d2 = deriv(beta + h * d1[0], r + h * d1[1], vb, aa1)
                beta += 0.5 * h * (d1[0] + d2[0])
                r += 0.5 * h * (d1[1] + d2[1])
            beta_s[k + 1], r_s[k + 1] = beta, r
        f_rear = ax.force(-beta_s + b * r_s / vv, aa, 1)
        alpha_f, over = ax.slip(m * aa - f_rear, aa, 0)
        saturated += int(np.count_nonzero(over))
        vx = vv * np.cos(beta_s)
        delta[i0:i1] = alpha_f + np.arctan(np.tan(beta_s) + a * r_s / vx)
        yaw_rate[i0:i1] = r_s
    return delta, saturated, yaw_rate


def _shifted(t: FloatArray, x: FloatArray, delay_s: float) -> FloatArray:
    """``x`` stamped ``delay_s`` late, put back on time: x(t + delay) (NaN kept, no extrapolation)."""
    if delay_s == 0.0:
        return x
    ok = np.isfinite(x)
    if np.count_nonzero(ok) < 2:
        return x
    out = np.interp(t + delay_s, t[ok], x[ok], left=np.nan, right=np.nan)
    # a sample next to a gap stays a gap
    out[np.interp(t + delay_s, t, ok.astype(float), left=0.0, right=0.0) < 1.0 - 1e-9] = np.nan
    return np.asarray(out, dtype=float)


@dataclass(frozen=True, slots=True)
class AyDelay:
    """How much later the lateral acceleration is stamped than the GNSS heading (see :func:`estimate_ay_delay`)."""

    delay_s: float
    se_s: float
    """Standard error (s); NaN when it could not be estimated."""
    n: int
    """Epochs used."""


def estimate_ay_delay(
    t_s: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    ay_measured_mps2: npt.ArrayLike,
    heading_yaw_rad: npt.ArrayLike,
    model: SteeringModel,
    *,
    min_speed_mps: float = 5.0,
    max_delay_s: float = 0.2,
) -> AyDelay:
    """Delay of the a_y time stamps behind the GNSS epochs, from the dual-antenna heading (not from the SWA).

    The dynamic inversion gives the yaw rate r(t) that the measured a_y implies; its integral θ lags the
    GNSS yaw ψ (heading, counter-clockwise, any constant offset) by r·d when a_y is stamped d late. A least
    squares fit of ψ − θ = d·r + c + e·t (c, e per run: the integral's start and the drift an a_y bias
    causes) gives d. Sensing filters and CAN latency make d tens of milliseconds; at 50 km/h 20 ms shift
    the reconstruction by up to 0.2° in a lane change. Needs ``model.yaw_inertia_kgm2``.

    Raises:
        AnalysisError: malformed arrays or a model without yaw inertia.
    """
    if model.yaw_inertia_kgm2 is None:
        raise AnalysisError("estimate_ay_delay: the steering model needs yaw_inertia_kgm2 (dynamic inversion)")
    t = check_time("t_s", t_s)
    n = t.size
    v = as_1d("speed_mps", speed_mps, n)
    ay_m = as_1d("ay_measured_mps2", ay_measured_mps2, n)
    psi = as_1d("heading_yaw_rad", heading_yaw_rad, n)
    d_total = 0.0
    result = AyDelay(0.0, math.nan, 0)
    for _ in range(3):  # the model's r depends a little on the shift: iterate
        ay = _shifted(t, ay_m, d_total) / model.roll_factor
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(v) & (np.abs(v) >= min_speed_mps) & np.isfinite(ay) & np.isfinite(psi)
        _, _, r = _dynamic_delta(t, v, np.where(ok, ay, np.nan), ok, model)
        cols: list[FloatArray] = []
        rows_r: list[FloatArray] = []
        ys: list[FloatArray] = []
        blocks = [(i0, i1) for i0, i1 in split_at_gaps(t, ok & np.isfinite(r), _MAX_GAP_S) if i1 - i0 >= 20]
        if not blocks:
            return result
        total = sum(i1 - i0 for i0, i1 in blocks)
        pos = 0
        for i0, i1 in blocks:
            tt, rr = t[i0:i1], r[i0:i1]
            theta = np.concatenate(([0.0], np.cumsum(0.5 * (rr[1:] + rr[:-1]) * np.diff(tt))))
            ys.append(np.unwrap(psi[i0:i1]) - theta)
            rows_r.append(rr)
            k = i1 - i0
            for col in (np.ones(k), tt - tt[0]):
                c = np.zeros(total)
                c[pos: pos + k] = col
                cols.append(c)
            pos += k
        a_mat = np.column_stack([np.concatenate(rows_r), *cols])
        y = np.concatenate(ys)
        coef, *_ = np.linalg.lstsq(a_mat, y, rcond=None)
        res = y - a_mat @ coef
        dof = max(total - a_mat.shape[1], 1)
        try:
            cov = np.linalg.inv(a_mat.T @ a_mat) * float(res @ res) / dof
        except np.linalg.LinAlgError:
            return result
        step = float(coef[0])
        se = math.sqrt(max(float(cov[0, 0]), 0.0))
        if not math.isfinite(step) or abs(d_total + step) > max_delay_s:
            return AyDelay(0.0, math.nan, total)
        d_total += step
        result = AyDelay(d_total, se, total)
        if abs(step) < 1e-4:
            break
    return result


def reconstruct_steering(
    t_s: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    ay_measured_mps2: npt.ArrayLike,
    model: SteeringModel,
    *,
    swa_rad: npt.ArrayLike | None = None,
    steering_ratio: float | Callable[[FloatArray], FloatArray] | None = None,
    min_speed_mps: float = 5.0,
    peak_fraction: float = 0.5,
    ay_delay_s: float = 0.0,
) -> SteeringReconstruction:
    """Reconstruct δ(t) and, with ``swa_rad`` and ``steering_ratio`` (a number or a function of the SWA), score it.

    ``speed_mps`` is the speed over ground of the CG (GNSS; forward driving); ``ay_measured_mps2``
    a body-fixed lateral accelerometer (the roll correction assumes one). With
    ``model.yaw_inertia_kgm2`` the single-track dynamics are inverted (module docstring), else the
    steady-state formula is used; ``delta_steady_state`` holds the latter either way. ``ay_delay_s``: how
    much later a_y is stamped than the speed and SWA (:func:`estimate_ay_delay`); a_y is shifted back by it.

    Raises:
        AnalysisError: malformed arrays, or an SWA without a steering ratio.
    """
    t = check_time("t_s", t_s)
    n = t.size
    v = as_1d("speed_mps", speed_mps, n)
    ay_m = _shifted(t, as_1d("ay_measured_mps2", ay_measured_mps2, n), float(ay_delay_s))
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.isfinite(v) & (np.abs(v) >= min_speed_mps) & np.isfinite(ay_m)
        v2 = np.where(ok, v * v, np.nan)
        ay = ay_m / model.roll_factor
        kin = np.where(ok, ay_m * model.wheelbase_m / v2, np.nan)
        steady = np.where(ok, ay * model.wheelbase_m / v2 + model.understeer_gradient_rad_per_mps2 * ay, np.nan)
    beyond_peak = 0
    if model.yaw_inertia_kgm2 is None:
        method = "steady state"
        delta = steady
    else:
        method = "single-track dynamics, " + ("non-linear tyres" if model.tyres is not None else "linear tyres")
        delta, beyond_peak, _ = _dynamic_delta(t, v, np.where(ok, ay, np.nan), ok, model)
    d_swa: FloatArray | None = None
    mean_abs = max_abs = rel = math.nan
    peaks_t: tuple[float, ...] = ()
    if swa_rad is not None:
        if steering_ratio is None:
            raise AnalysisError("reconstruct_steering: a steering-wheel angle needs a steering_ratio to compare")
        swa = as_1d("swa_rad", swa_rad, n)
        ratio = np.asarray(steering_ratio(swa), dtype=float) if callable(steering_ratio) else float(steering_ratio)
        d_swa = np.asarray(swa / ratio, dtype=float)
        err = delta - d_swa
        m = np.isfinite(err)
        if np.any(m):
            mean_abs = float(np.mean(np.abs(err[m])))
            max_abs = float(np.max(np.abs(err[m])))
            dt = float(np.median(np.diff(t))) if n > 1 else 1.0
            pk = [i for i in _peaks(np.where(ok, d_swa, 0.0), peak_fraction, max(1, int(round(0.3 / dt)))) if m[i]]
            if pk:
                rel = max(abs(float(err[i])) / abs(float(d_swa[i])) for i in pk)
                peaks_t = tuple(float(t[i]) for i in pk)
    return SteeringReconstruction(
        t=t,
        delta=np.asarray(delta, dtype=float),
        delta_kinematic=np.asarray(kin, dtype=float),
        delta_from_swa=d_swa,
        mean_abs_error_rad=mean_abs,
        max_abs_error_rad=max_abs,
        max_relative_error_at_peaks=rel,
        peaks_t=peaks_t,
        method=method,
        delta_steady_state=np.asarray(steady, dtype=float),
        beyond_tyre_peak=beyond_peak,
        ay_delay_s=float(ay_delay_s),
    )


def error_table(model: SteeringModel, speeds_kmh: Sequence[float]) -> ErrorModel:
    """:func:`error_model` at speeds in km/h (for the CLI)."""
    return error_model(model, np.asarray(speeds_kmh, dtype=float) / 3.6)
