"""Tyre lateral force: Pacejka magic formula with load-dependent stiffness and friction, friction ellipse.

For one tyre at vertical load F_z (static load F_z0) and slip angle α (rad; positive when the
contact patch slides to the left, so the force is negative):

- peak friction  μ(F_z) = μ₀ · (1 − ε·(F_z − F_z0)/F_z0)          (ε = ``tyre_mu_load_sensitivity``)
- cornering stiffness  C_α(F_z) = C_α0 · sin(2·atan(F_z/(k·F_z0))) / sin(2·atan(1/k))
  (Pacejka's classic form; it peaks at F_z = k·F_z0 and makes an axle lose stiffness under
  lateral load transfer)
- F_y0 = −D·sin(C·atan(Bα − E(Bα − atan(Bα)))) with D = μF_z and B = C_α/(C·D)
- combined with a longitudinal force F_x by the friction ellipse: F_y = F_y0·√(1 − (F_x/μF_z)²).

The integrator in :mod:`sim_devices.vehicle.model` evaluates the same formula inline on plain
floats for speed; this module is the readable reference (vectorised) used for tests and docs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_devices.vehicle.params import VehicleParams

__all__ = ["AxleTyre", "axle_tyres"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class AxleTyre:
    """Magic-formula coefficients of the tyres on one axle."""

    c_alpha0: float
    """Cornering stiffness per tyre at the static load (N/rad)."""
    fz0: float
    """Static load per tyre (N)."""
    mu0: float
    shape_c: float
    curvature_e: float
    mu_load_sensitivity: float
    stiffness_peak_ratio: float

    @property
    def stiffness_norm(self) -> float:
        """sin(2·atan(1/k)) = 2x/(1+x²) at x = 1/k: normalises C_α to ``c_alpha0`` at the static load."""
        x0 = 1.0 / self.stiffness_peak_ratio
        return 2.0 * x0 / (1.0 + x0 * x0)

    def mu(self, fz: FloatArray | float) -> FloatArray:
        """Peak friction coefficient at load ``fz`` (floored at 10 % of μ₀)."""
        fz = np.asarray(fz, dtype=float)
        mu = self.mu0 * (1.0 - self.mu_load_sensitivity * (fz - self.fz0) / self.fz0)
        return np.maximum(mu, 0.1 * self.mu0)

    def cornering_stiffness(self, fz: FloatArray | float) -> FloatArray:
        """C_α (N/rad) at load ``fz``."""
        x = np.asarray(fz, dtype=float) / (self.stiffness_peak_ratio * self.fz0)
        return self.c_alpha0 * (2.0 * x / (1.0 + x * x)) / self.stiffness_norm

    def lateral_force(
        self, alpha: FloatArray | float, fz: FloatArray | float, fx: FloatArray | float = 0.0
    ) -> FloatArray:
        """Lateral force (N) at slip angle ``alpha`` (rad), load ``fz`` (N) and longitudinal force ``fx`` (N)."""
        alpha = np.asarray(alpha, dtype=float)
        fz = np.maximum(np.asarray(fz, dtype=float), 0.0)
        mu = self.mu(fz)
        d = mu * fz
        # B = C_α/(C·D): the F_z in C_α and in D cancel, so B stays finite at zero load.
        x_per_fz = 1.0 / (self.stiffness_peak_ratio * self.fz0)
        x = fz * x_per_fz
        b = self.c_alpha0 * 2.0 * x_per_fz / ((1.0 + x * x) * self.stiffness_norm * self.shape_c * mu)
        ba = b * alpha
        fy0 = -d * np.sin(self.shape_c * np.arctan(ba - self.curvature_e * (ba - np.arctan(ba))))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(d > 0.0, np.asarray(fx, dtype=float) / d, 0.0)
        return np.asarray(fy0 * np.sqrt(np.clip(1.0 - ratio * ratio, 0.0, 1.0)), dtype=float)

    def peak_slip_angle(self) -> float:
        """Slip angle (rad) of the force peak at the static load (where C·atan(x_E) = π/2)."""
        if self.shape_c <= 1.0:
            return math.inf
        target = math.tan(math.pi / (2.0 * self.shape_c))
        b = float(self.cornering_stiffness(self.fz0)) / (self.shape_c * self.mu0 * self.fz0)
        lo, hi = 0.0, 1e3
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if mid - self.curvature_e * (mid - math.atan(mid)) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi) / b


def axle_tyres(params: VehicleParams) -> tuple[AxleTyre, AxleTyre]:
    """(front, rear) tyre models of a vehicle; the static loads come from the CG position."""
    fz_front, fz_rear = params.static_axle_loads_n
    common = {
        "mu0": params.tyre_peak_mu,
        "shape_c": params.tyre_shape_c,
        "curvature_e": params.tyre_curvature_e,
        "mu_load_sensitivity": params.tyre_mu_load_sensitivity,
        "stiffness_peak_ratio": params.tyre_stiffness_peak_load_ratio,
    }
    return (
        AxleTyre(c_alpha0=params.cornering_stiffness_front_n_per_rad, fz0=0.5 * fz_front, **common),
        AxleTyre(c_alpha0=params.cornering_stiffness_rear_n_per_rad, fz0=0.5 * fz_rear, **common),
    )
