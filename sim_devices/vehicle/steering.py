"""Steering gear with a variable ratio: steering-wheel angle ↔ front road-wheel angle.

The ratio i(θ) = dθ/dδ is given as a table over the steering-wheel angle θ. The road-wheel angle is
δ(θ) = ∫₀^θ dθ'/i(θ'), which is strictly monotonic for any positive ratio, so the inverse exists
and a ratio that falls towards the lock (≈ 16 at the centre, ≈ 13.5 at ±520°) makes the
steering more direct at large angles without ever reversing. The integral is tabulated once
on a fine grid; lookups interpolate that table (error well below 1e-6 deg).
"""

from __future__ import annotations

import bisect
import math
from typing import overload

import numpy as np
import numpy.typing as npt

from sim_devices.vehicle.params import VehicleParams

__all__ = ["SteeringGear"]

FloatArray = npt.NDArray[np.float64]

_GRID_STEP_DEG = 0.25
_FINE_PER_STEP = 25


class SteeringGear:
    """Variable-ratio steering of one vehicle (angles in rad, positive to the left)."""

    def __init__(self, params: VehicleParams) -> None:
        bp = np.asarray(params.steering_ratio_swa_deg, dtype=float)
        ratio = np.asarray(params.steering_ratio, dtype=float)
        if bp.size and bp[0] >= 0.0:
            # Only one side given: mirror it (the gear is symmetric).
            positive = bp > 0.0
            bp = np.concatenate([-bp[positive][::-1], bp])
            ratio = np.concatenate([ratio[positive][::-1], ratio])
        self._bp_deg = bp
        self._ratio = ratio
        self.lock_swa = math.radians(params.swa_lock_deg)
        """Steering-wheel angle at full lock (rad, either side)."""
        span = max(params.swa_lock_deg, float(np.max(np.abs(bp)))) + 10.0
        n_steps = math.ceil(span / _GRID_STEP_DEG)
        span = n_steps * _GRID_STEP_DEG
        fine = np.linspace(0.0, span, n_steps * _FINE_PER_STEP + 1)
        pos = _cumulative_integral(fine, 1.0 / self.ratio_deg(fine))[::_FINE_PER_STEP]
        neg = _cumulative_integral(-fine, 1.0 / self.ratio_deg(-fine))[::_FINE_PER_STEP]
        grid_deg = np.concatenate([-fine[::_FINE_PER_STEP][:0:-1], fine[::_FINE_PER_STEP]])
        delta_deg = np.concatenate([neg[:0:-1], pos])
        self._grid = np.radians(grid_deg)
        self._delta = np.radians(delta_deg)
        # Plain-float copies for the integrator's per-step scalar lookup.
        self.grid_start = float(self._grid[0])
        self.grid_inv_step = 1.0 / math.radians(_GRID_STEP_DEG)
        self.grid_values: list[float] = self._delta.tolist()
        self._end_ratio_lo = float(ratio[0])
        self._end_ratio_hi = float(ratio[-1])
        self.lock_road_wheel = float(self.road_wheel_angle(self.lock_swa))
        """Road-wheel angle at full left lock (rad)."""

    def ratio_deg(self, swa_deg: float | FloatArray) -> FloatArray:
        """Steering ratio at the steering-wheel angle(s) ``swa_deg`` (deg), from the table."""
        return np.asarray(np.interp(swa_deg, self._bp_deg, self._ratio), dtype=float)

    @overload
    def road_wheel_angle(self, swa: float) -> float: ...
    @overload
    def road_wheel_angle(self, swa: FloatArray) -> FloatArray: ...
    def road_wheel_angle(self, swa: float | FloatArray) -> float | FloatArray:
        """Front road-wheel angle δ (rad) for steering-wheel angle(s) ``swa`` (rad)."""
        x = np.asarray(swa, dtype=float)
        out = np.interp(x, self._grid, self._delta)
        # Beyond the tabulated span the end ratio holds.
        out = np.where(x > self._grid[-1], self._delta[-1] + (x - self._grid[-1]) / self._end_ratio_hi, out)
        out = np.where(x < self._grid[0], self._delta[0] + (x - self._grid[0]) / self._end_ratio_lo, out)
        return float(out) if out.ndim == 0 else out

    @overload
    def swa_from_road_wheel(self, delta: float) -> float: ...
    @overload
    def swa_from_road_wheel(self, delta: FloatArray) -> FloatArray: ...
    def swa_from_road_wheel(self, delta: float | FloatArray) -> float | FloatArray:
        """Steering-wheel angle (rad) that gives the road-wheel angle(s) ``delta`` (rad)."""
        d = np.asarray(delta, dtype=float)
        out = np.interp(d, self._delta, self._grid)
        out = np.where(d > self._delta[-1], self._grid[-1] + (d - self._delta[-1]) * self._end_ratio_hi, out)
        out = np.where(d < self._delta[0], self._grid[0] + (d - self._delta[0]) * self._end_ratio_lo, out)
        return float(out) if out.ndim == 0 else out

    def road_wheel_scalar(self, swa: float) -> float:
        """Fast plain-float version of :meth:`road_wheel_angle` for |swa| within the table."""
        x = (swa - self.grid_start) * self.grid_inv_step
        i = int(x)
        vals = self.grid_values
        if i < 0:
            i = 0
        elif i > len(vals) - 2:
            i = len(vals) - 2
        f = x - i
        return vals[i] + f * (vals[i + 1] - vals[i])

    def swa_scalar(self, delta: float) -> float:
        """Fast plain-float version of :meth:`swa_from_road_wheel` (clamped to the tabulated span)."""
        vals = self.grid_values
        i = bisect.bisect_right(vals, delta) - 1
        if i < 0:
            i = 0
        elif i > len(vals) - 2:
            i = len(vals) - 2
        lo, hi = vals[i], vals[i + 1]
        return self.grid_start + (i + (delta - lo) / (hi - lo)) / self.grid_inv_step


def _cumulative_integral(x: FloatArray, y: FloatArray) -> FloatArray:
    """Cumulative trapezoid integral of y over x, starting at 0."""
    out = np.zeros_like(x)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(x))
    return out
