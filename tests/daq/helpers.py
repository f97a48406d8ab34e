"""Test helpers for the DAQ layer: kinematically consistent synthetic ground truth and a manual clock."""

from __future__ import annotations

import threading

import numpy as np
from scipy.integrate import cumulative_trapezoid

from sim_devices.vehicle.truth import GroundTruth

T0_NS = 1_700_000_000 * 10**9


def truth_from_body_velocity(
    t: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    yaw_rate: np.ndarray,
    road_wheel_angle: np.ndarray | None = None,
) -> GroundTruth:
    """A planar rigid-body motion from its body-axis velocity and yaw rate (yaw and position integrated).

    Accelerations follow from a = dv/dt + ω × v, so every field is consistent with the motion.
    """
    n = t.size
    yaw = cumulative_trapezoid(yaw_rate, t, initial=0.0)
    ve = np.cos(yaw) * vx - np.sin(yaw) * vy
    vn = np.sin(yaw) * vx + np.cos(yaw) * vy
    east = cumulative_trapezoid(ve, t, initial=0.0)
    north = cumulative_trapezoid(vn, t, initial=0.0)
    ax = np.gradient(vx, t) - yaw_rate * vy
    ay = np.gradient(vy, t) + yaw_rate * vx
    rwa = np.zeros(n) if road_wheel_angle is None else road_wheel_angle
    speed = np.hypot(vx, vy)
    return GroundTruth(
        t=t,
        east=east,
        north=north,
        yaw=yaw,
        vx=vx,
        vy=vy,
        yaw_rate=yaw_rate,
        ax=ax,
        ay=ay,
        ax_meas=ax,
        ay_meas=ay,
        roll=np.zeros(n),
        roll_rate=np.zeros(n),
        road_wheel_angle=rwa,
        swa=15.0 * rwa,
        wheel_speed=np.repeat(speed[:, None], 4, axis=1),
        wheel_load=np.full((n, 4), 4000.0),
        ltr=np.zeros(n),
        meta={"scenario": "synthetic"},
    )


def steady_circle(
    speed: float = 20.0, radius: float = 100.0, beta: float = -0.03, duration: float = 10.0, rate: float = 1000.0
) -> GroundTruth:
    """Steady left-hand circle: yaw rate = v / R, CG sideslip beta, constant speed."""
    t = np.arange(0.0, duration, 1.0 / rate)
    n = t.size
    r = speed / radius
    return truth_from_body_velocity(
        t, np.full(n, speed * np.cos(beta)), np.full(n, speed * np.sin(beta)), np.full(n, r), np.full(n, 0.04)
    )


def slalom(duration: float = 10.0, rate: float = 1000.0) -> GroundTruth:
    """Sine steer at 0.5 Hz: vy and yaw rate oscillate (with a phase lag), vx constant."""
    t = np.arange(0.0, duration, 1.0 / rate)
    w = 2 * np.pi * 0.5
    vx = np.full(t.size, 22.0)
    vy = 0.6 * np.sin(w * t - 0.4)
    r = 0.25 * np.sin(w * t)
    return truth_from_body_velocity(t, vx, vy, r, 0.05 * np.sin(w * t + 0.1))


def ramp(v0: float = 5.0, accel: float = 2.0, duration: float = 10.0, rate: float = 1000.0) -> GroundTruth:
    """Straight-line constant acceleration from v0."""
    t = np.arange(0.0, duration, 1.0 / rate)
    n = t.size
    return truth_from_body_velocity(t, v0 + accel * t, np.zeros(n), np.zeros(n))


class ManualClock:
    """A clock that only moves when told to, or when something sleeps on it (it jumps to the wake time)."""

    def __init__(self, start_ns: int = T0_NS) -> None:
        self._t = start_ns
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        with self._lock:
            self._t += round(seconds * 1e9)

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        if stop is not None and stop.is_set():
            return False
        with self._lock:
            self._t = max(self._t, t_ns)
        return True


def optical_channels(
    prefix: str, first_ai: int, roles: tuple[str, ...] = ("vx", "vy", "slip_angle", "speed", "valid")
) -> list:
    """DAQ channel configs ``{prefix}_{role}`` on consecutive simulated inputs."""
    from drivers.daq import DaqChannelConfig

    return [
        DaqChannelConfig(f"{prefix}_{r}", f"sim/ai{first_ai + i}", -10.0, 10.0, role=f"optical.{prefix}.{r}")
        for i, r in enumerate(roles)
    ]


def optical_wiring(sensor, channels) -> dict:
    """Wire the simulated sensor's outputs to those of ``channels`` its spec names (others stay unwired)."""
    from sim_devices.daq import wire_optical

    return wire_optical(sensor, channels, require_all=False)
