"""Driver models: reference paths, a path follower, a heading controller and speed profiles.

The path follower is a pure-pursuit driver with a speed-proportional preview distance, in the
frame of the CG velocity (so the steady sideslip does not bias it), with the linear understeer
compensation δ = atan(Lκ) + K v² κ and a slow integral on the lateral error that removes the
steady offset left when the tyres leave their linear range. All controllers are called every
:data:`~sim_devices.vehicle.model.DRIVER_PERIOD_S` on plain floats.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np
import numpy.typing as npt

from sim_devices.vehicle.model import DRIVER_PERIOD_S, SpeedProfile, VehicleState
from sim_devices.vehicle.params import VehicleParams
from sim_devices.vehicle.steering import SteeringGear
from vsccore.angles import wrap_pi
from vsccore.errors import SimulationError

__all__ = [
    "CirclePath",
    "DriverNoise",
    "HeadingController",
    "Path",
    "PathFollower",
    "PolylinePath",
    "constant_speed",
    "piecewise_speed",
]

FloatArray = npt.NDArray[np.float64]

_INTEGRAL_FULL_SPEED = 10.0
"""Speed (m/s) from which the path follower's integral acts fully (it fades in with v²)."""


# ---------------------------------------------------------------------------------------------
# Paths
# ---------------------------------------------------------------------------------------------


class Path(ABC):
    """A reference path in the local ENU plane, parametrised by arc length s (m)."""

    @abstractmethod
    def project(self, x: float, y: float, s_hint: float) -> tuple[float, float]:
        """(s, lateral offset) of the point (x, y); the offset is positive left of the path."""

    @abstractmethod
    def point(self, s: float) -> tuple[float, float]:
        """Position (east, north) at arc length ``s`` (extrapolated straight beyond the ends)."""


class PolylinePath(Path):
    """A path through dense points, resampled uniformly in arc length."""

    def __init__(self, x: FloatArray, y: FloatArray, ds: float = 0.25) -> None:
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.shape != y.shape or x.ndim != 1 or x.size < 2:
            raise SimulationError("a path needs at least two points given as equal-length 1-D arrays")
        seg = np.hypot(np.diff(x), np.diff(y))
        keep = np.concatenate([[True], seg > 1e-9])
        x, y = x[keep], y[keep]
        s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
        if s[-1] <= 0.0:
            raise SimulationError("a path must have non-zero length")
        n = max(1, math.ceil(s[-1] / ds))
        self.ds = float(s[-1] / n)
        su = np.linspace(0.0, s[-1], n + 1)
        self.length = float(s[-1])
        self._x: list[float] = np.interp(su, s, x).tolist()
        self._y: list[float] = np.interp(su, s, y).tolist()
        self._n = n + 1

    @classmethod
    def line(cls, x0: float, y0: float, yaw: float, length: float) -> PolylinePath:
        """A straight line from (x0, y0) along the yaw angle ``yaw`` (rad, from east)."""
        return cls(
            np.array([x0, x0 + length * math.cos(yaw)]), np.array([y0, y0 + length * math.sin(yaw)]), ds=length
        )

    def point(self, s: float) -> tuple[float, float]:
        u = s / self.ds
        i = int(math.floor(u))
        i = 0 if i < 0 else (self._n - 2 if i > self._n - 2 else i)
        f = u - i
        xs, ys = self._x, self._y
        return xs[i] + f * (xs[i + 1] - xs[i]), ys[i] + f * (ys[i + 1] - ys[i])

    def project(self, x: float, y: float, s_hint: float) -> tuple[float, float]:
        xs, ys, n = self._x, self._y, self._n
        i = int(s_hint / self.ds)
        i = 0 if i < 0 else (n - 1 if i > n - 1 else i)

        # Walk to the nearest vertex from the hint (the vehicle moves about one segment per call).
        dx0, dy0 = xs[i] - x, ys[i] - y
        best = dx0 * dx0 + dy0 * dy0
        while i + 1 < n:
            dx0, dy0 = xs[i + 1] - x, ys[i + 1] - y
            d = dx0 * dx0 + dy0 * dy0
            if d >= best:
                break
            i += 1
            best = d
        while i > 0:
            dx0, dy0 = xs[i - 1] - x, ys[i - 1] - y
            d = dx0 * dx0 + dy0 * dy0
            if d >= best:
                break
            i -= 1
            best = d
        best_s, best_e, best_d = 0.0, 0.0, math.inf
        for j in (i - 1, i):
            if j < 0 or j > n - 2:
                continue
            dx, dy = xs[j + 1] - xs[j], ys[j + 1] - ys[j]
            seg2 = dx * dx + dy * dy
            t = ((x - xs[j]) * dx + (y - ys[j]) * dy) / seg2
            # Clamp inside the path, extrapolate past its ends.
            if j > 0:
                t = max(t, 0.0)
            if j < n - 2:
                t = min(t, 1.0)
            px, py = xs[j] + t * dx, ys[j] + t * dy
            dist = math.hypot(x - px, y - py)
            if dist < best_d:
                seg = math.sqrt(seg2)
                best_d = dist
                best_s = (j + t) * self.ds
                best_e = (dx * (y - ys[j]) - dy * (x - xs[j])) / seg
        return best_s, best_e


class CirclePath(Path):
    """A circle of radius ``radius`` around (cx, cy), driven counter-clockwise (turn=+1) or clockwise (−1)."""

    def __init__(self, cx: float, cy: float, radius: float, turn: int, theta0: float) -> None:
        if radius <= 0.0:
            raise SimulationError(f"circle radius must be > 0, got {radius}")
        self.cx, self.cy, self.radius, self.turn, self.theta0 = cx, cy, radius, 1 if turn >= 0 else -1, theta0
        self.length = math.inf

    def point(self, s: float) -> tuple[float, float]:
        th = self.theta0 + self.turn * s / self.radius
        return self.cx + self.radius * math.cos(th), self.cy + self.radius * math.sin(th)

    def project(self, x: float, y: float, s_hint: float) -> tuple[float, float]:
        th_hint = self.theta0 + self.turn * s_hint / self.radius
        th = math.atan2(y - self.cy, x - self.cx)
        th = th_hint + wrap_pi(th - th_hint)
        s = (th - self.theta0) * self.turn * self.radius
        dist = math.hypot(x - self.cx, y - self.cy)
        return s, self.turn * (self.radius - dist)


# ---------------------------------------------------------------------------------------------
# Drivers
# ---------------------------------------------------------------------------------------------


class DriverNoise:
    """Band-limited random steering of a human driver: an Ornstein–Uhlenbeck process (rad)."""

    def __init__(self, std_rad: float, seed: int | None, correlation_s: float = 0.5) -> None:
        self.std = float(std_rad)
        self._rng = np.random.default_rng(seed)
        self._a = math.exp(-DRIVER_PERIOD_S / correlation_s)
        self._b = self.std * math.sqrt(1.0 - self._a * self._a)
        self.value = 0.0

    def step(self) -> float:
        if self.std > 0.0:
            self.value = self._a * self.value + self._b * float(self._rng.standard_normal())
        return self.value


class _VehicleLaw:
    """Steady-state steering law of the linear single-track model (for feed-forward)."""

    def __init__(self, params: VehicleParams, gear: SteeringGear) -> None:
        self.L = params.wheelbase_m
        self.b = params.cg_to_rear_axle_m
        self.K = params.understeer_gradient_rad_per_mps2
        self.gear = gear

    def swa_for_curvature(self, kappa: float, speed: float) -> float:
        """SWA (rad) for a CG-path curvature ``kappa`` (1/m) at ``speed`` (m/s).

        δ = δ_kin + K v² κ, with the kinematic (no-slip) angle δ_kin = atan(L κ / √(1 − (bκ)²)):
        the rear axle, b behind the CG, runs on the radius √(R² − b²) about the same centre.
        """
        bk = self.b * kappa
        root = math.sqrt(max(1.0 - bk * bk, 0.01))
        delta = math.atan(self.L * kappa / root) + self.K * speed * speed * kappa
        return self.gear.swa_scalar(delta)


class PathFollower:
    """Pure-pursuit path follower with preview and understeer compensation (forward driving)."""

    def __init__(
        self,
        path: Path,
        params: VehicleParams,
        gear: SteeringGear,
        *,
        preview_time_s: float = 0.35,
        min_preview_m: float = 3.0,
        integral_gain: float = 0.004,
        end_s: float | None = None,
        noise: DriverNoise | None = None,
    ) -> None:
        self.path = path
        self._law = _VehicleLaw(params, gear)
        self.preview_time_s = preview_time_s
        self.min_preview_m = min_preview_m
        self.integral_gain = integral_gain
        self.end_s = end_s
        self.noise = noise
        self.done = False
        self._s = 0.0
        self._int = 0.0
        self.max_abs_error = 0.0
        """Largest lateral error of the CG seen so far (m)."""

    def update(self, state: VehicleState) -> float:
        s, e = self.path.project(state.east, state.north, self._s)
        self._s = s
        if self.end_s is not None and s >= self.end_s:
            self.done = True
            return state.swa
        self.max_abs_error = max(self.max_abs_error, abs(e))
        v = math.hypot(state.vx, state.vy)
        course = state.yaw + (math.atan2(state.vy, state.vx) if state.vx > 0.5 else 0.0)
        ld = max(self.min_preview_m, self.preview_time_s * v)
        px, py = self.path.point(s + ld)
        dx, dy = px - state.east, py - state.north
        c, sn = math.cos(course), math.sin(course)
        xl = c * dx + sn * dy
        yl = -sn * dx + c * dy
        kappa = 2.0 * yl / (xl * xl + yl * yl)
        # The offset the integral removes comes from the non-linear understeer, which grows with a_y ∝ v²;
        # at walking speed the feed-forward is exact and an integral only winds up on the entry transient.
        w_int = min(1.0, (v / _INTEGRAL_FULL_SPEED) ** 2)
        self._int = min(max(self._int + w_int * e * DRIVER_PERIOD_S, -5.0), 5.0)
        kappa -= self.integral_gain * self._int
        swa = self._law.swa_for_curvature(kappa, v)
        if self.noise is not None:
            swa += self.noise.step()
        return swa


class HeadingController:
    """Turns the car onto a yaw angle (or just straightens it) at a limited lateral acceleration.

    Used between the scenarios of a drive. Finishes after ``min_time_s`` once the heading is
    within 0.3° of the target and the yaw rate is below 0.3°/s (and |v_x| > 1 m/s). Below 1 m/s
    or when reversing, it steers straight ahead.
    """

    def __init__(
        self,
        params: VehicleParams,
        gear: SteeringGear,
        target_yaw: float | None,
        *,
        min_time_s: float,
        ay_max: float = 3.0,
        heading_gain: float = 0.8,
        noise: DriverNoise | None = None,
    ) -> None:
        self._law = _VehicleLaw(params, gear)
        self.gear = gear
        self.target_yaw = target_yaw
        self.min_time_s = min_time_s
        self.ay_max = ay_max
        self.heading_gain = heading_gain
        self.noise = noise
        self.done = False
        self._t0: float | None = None
        self._tol = math.radians(0.3)

    def update(self, state: VehicleState) -> float:
        if self._t0 is None:
            self._t0 = state.t
        v = state.vx
        if v < 1.0:
            return 0.0
        err = 0.0 if self.target_yaw is None else wrap_pi(self.target_yaw - state.yaw)
        r_max = min(self.ay_max / v, 0.6)
        r_d = min(max(self.heading_gain * err, -r_max), r_max)
        swa = self._law.swa_for_curvature(r_d / v, v)
        # Yaw-rate feedback damps the response; the gain scales with the inverse steady-state gain.
        swa += self.gear.swa_scalar(0.4 * (self._law.L + self._law.K * v * v) / v * (r_d - state.yaw_rate))
        if self.noise is not None:
            swa += self.noise.step()
        if (
            state.t - self._t0 >= self.min_time_s
            and abs(err) < self._tol
            and abs(state.yaw_rate) < self._tol
            and abs(state.swa) < math.radians(20.0)
        ):
            self.done = True
        return swa


# ---------------------------------------------------------------------------------------------
# Speed profiles
# ---------------------------------------------------------------------------------------------


def constant_speed(speed: float) -> SpeedProfile:
    """Hold ``speed`` (m/s, negative for reverse)."""

    def profile(tau: FloatArray) -> tuple[FloatArray, FloatArray]:
        return np.full_like(tau, speed), np.zeros_like(tau)

    return profile


def piecewise_speed(times: list[float] | FloatArray, speeds: list[float] | FloatArray) -> SpeedProfile:
    """Piecewise-linear speed (m/s) through (time, speed) knots, held after the last knot."""
    t = np.asarray(times, dtype=float)
    v = np.asarray(speeds, dtype=float)
    if t.shape != v.shape or t.size < 1 or np.any(np.diff(t) < 0.0):
        raise SimulationError("speed knots must be equal-length with non-decreasing times")
    dt = np.diff(t)
    slopes = np.where(dt > 0.0, np.diff(v) / np.where(dt > 0.0, dt, 1.0), 0.0)

    def profile(tau: FloatArray) -> tuple[FloatArray, FloatArray]:
        vref = np.interp(tau, t, v)
        if slopes.size == 0:
            return vref, np.zeros_like(tau)
        idx = np.clip(np.searchsorted(t, tau, side="right") - 1, 0, slopes.size - 1)
        acc = np.where((tau >= t[0]) & (tau < t[-1]), slopes[idx], 0.0)
        return vref, acc

    return profile

