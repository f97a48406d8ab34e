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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rig.analysis._arrays import as_1d, check_time
from vsccore.angles import FloatArray
from vsccore.errors import AnalysisError

__all__ = [
    "ErrorModel",
    "SteeringModel",
    "SteeringReconstruction",
    "error_model",
    "error_table",
    "reconstruct_steering",
]

G = 9.80665


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

    def __post_init__(self) -> None:
        names = ("wheelbase_m", "mass_kg", "cornering_stiffness_front_n_per_rad", "cornering_stiffness_rear_n_per_rad")
        for name in names:
            if not getattr(self, name) > 0.0:
                raise AnalysisError(f"steering model: {name} must be positive, got {getattr(self, name)}")
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
) -> SteeringReconstruction:
    """Reconstruct δ(t) and, with ``swa_rad`` and ``steering_ratio`` (a number or a function of the SWA), score it.

    ``speed_mps`` is the longitudinal speed (GNSS speed over ground, ≈ v_x for small sideslip);
    ``ay_measured_mps2`` a body-fixed lateral accelerometer (the roll correction assumes one).

    Raises:
        AnalysisError: malformed arrays, or an SWA without a steering ratio.
    """
    t = check_time("t_s", t_s)
    n = t.size
    v = as_1d("speed_mps", speed_mps, n)
    ay_m = as_1d("ay_measured_mps2", ay_measured_mps2, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.isfinite(v) & (np.abs(v) >= min_speed_mps) & np.isfinite(ay_m)
        v2 = np.where(ok, v * v, np.nan)
        ay = ay_m / model.roll_factor
        kin = np.where(ok, ay_m * model.wheelbase_m / v2, np.nan)
        delta = np.where(ok, ay * model.wheelbase_m / v2 + model.understeer_gradient_rad_per_mps2 * ay, np.nan)
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
    )


def error_table(model: SteeringModel, speeds_kmh: Sequence[float]) -> ErrorModel:
    """:func:`error_model` at speeds in km/h (for the CLI)."""
    return error_model(model, np.asarray(speeds_kmh, dtype=float) / 3.6)
