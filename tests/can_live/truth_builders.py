"""Physically consistent ground truths with known answers for the CAN tests.

A steady circle (constant speed ``v`` on radius ``R``, turning left) of a single-track car whose
tyres saturate (F = μF_z·tanh(Cα / μF_z)): r = v/R, a = v²/R pointing to the circle's centre,
and the sideslip that the axle force balance demands. In the linear range β follows the linear
single-track model; near the limit the rear slip angle grows faster than linearly, so a linear
estimator underestimates |β| there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim_devices.vehicle.truth import GroundTruth

G = 9.80665


@dataclass(frozen=True)
class Car:
    mass_kg: float = 1550.0
    lf: float = 1.20
    lr: float = 1.60
    track: float = 1.56
    cg_height: float = 0.55
    cf_axle: float = 126_000.0  # the ECU assumes 120 000: a realistic 5 % calibration error
    cr_axle: float = 133_000.0  # the ECU assumes 140 000
    mu: float = 1.0
    steering_ratio: float = 16.0
    roll_gradient: float = 0.0079  # rad per m/s²; the ECU assumes 0.0070

    @property
    def wheelbase(self) -> float:
        return self.lf + self.lr


def steady_circle_state(v: float, radius: float, car: Car = Car()) -> dict[str, float]:
    """Steady-state β, δ, r, a of the saturating single-track car on a left-hand circle."""
    wheelbase = car.wheelbase
    a = v * v / radius
    r = v / radius
    fzf = car.mass_kg * G * car.lr / wheelbase
    fzr = car.mass_kg * G * car.lf / wheelbase
    fyf = car.mass_kg * a * car.lr / wheelbase
    fyr = car.mass_kg * a * car.lf / wheelbase
    if fyf >= car.mu * fzf or fyr >= car.mu * fzr:
        raise ValueError(f"a = {a:.2f} m/s² is beyond the friction limit")
    alpha_f = car.mu * fzf / car.cf_axle * math.atanh(fyf / (car.mu * fzf))
    alpha_r = car.mu * fzr / car.cr_axle * math.atanh(fyr / (car.mu * fzr))
    beta = car.lr * r / v - alpha_r
    delta = alpha_f + beta + car.lf * r / v
    beta_linear = car.lr * r / v - fyr / car.cr_axle
    return {"a": a, "r": r, "beta": beta, "delta": delta, "beta_linear": beta_linear}


def steady_circle(v: float, radius: float, duration_s: float, *, dt: float = 0.001, car: Car = Car()) -> GroundTruth:
    """Ground truth of ``duration_s`` on the steady circle (see module docstring)."""
    s = steady_circle_state(v, radius, car)
    t = np.arange(0.0, duration_s + dt / 2, dt)
    n = t.size
    beta, r, a, delta = s["beta"], s["r"], s["a"], s["delta"]
    yaw = r * t
    course = yaw + beta
    east = radius * np.sin(course)
    north = -radius * np.cos(course)
    full = np.full
    ay = a * math.cos(beta)
    ax = -a * math.sin(beta)
    roll = car.roll_gradient * ay
    vx, vy = v * math.cos(beta), v * math.sin(beta)
    wheels = (
        (car.lf, car.track / 2, delta),
        (car.lf, -car.track / 2, delta),
        (-car.lr, car.track / 2, 0.0),
        (-car.lr, -car.track / 2, 0.0),
    )
    wheel_speed = np.empty((n, 4))
    for i, (x, y, d) in enumerate(wheels):
        u, w = vx - r * y, vy + r * x
        wheel_speed[:, i] = u * math.cos(d) + w * math.sin(d)
    ltr = 2.0 * car.cg_height * ay / (G * car.track)
    fz = car.mass_kg * G
    load = np.empty((n, 4))
    load[:, 0] = load[:, 2] = fz / 4 * (1 - ltr)
    load[:, 1] = load[:, 3] = fz / 4 * (1 + ltr)
    return GroundTruth(
        t=t,
        east=east,
        north=north,
        yaw=yaw,
        vx=full(n, vx),
        vy=full(n, vy),
        yaw_rate=full(n, r),
        ax=full(n, ax),
        ay=full(n, ay),
        ax_meas=full(n, ax),
        ay_meas=full(n, ay * math.cos(roll) + G * math.sin(roll)),
        roll=full(n, roll),
        roll_rate=np.zeros(n),
        road_wheel_angle=full(n, delta),
        swa=full(n, delta * car.steering_ratio),
        wheel_speed=wheel_speed,
        wheel_load=load,
        ltr=full(n, ltr),
        meta={"scenario": "steady_circle", "v": v, "radius": radius},
    )


def standstill(duration_s: float, *, dt: float = 0.001) -> GroundTruth:
    """The car standing still (every true motion zero)."""
    t = np.arange(0.0, duration_s + dt / 2, dt)
    z = np.zeros(t.size)
    return GroundTruth(
        t=t,
        east=z,
        north=z,
        yaw=z,
        vx=z,
        vy=z,
        yaw_rate=z,
        ax=z,
        ay=z,
        ax_meas=z,
        ay_meas=z,
        roll=z,
        roll_rate=z,
        road_wheel_angle=z,
        swa=z,
        wheel_speed=np.zeros((t.size, 4)),
        wheel_load=np.full((t.size, 4), 1550.0 * G / 4),
        ltr=z,
    )
