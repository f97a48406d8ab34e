"""Steering ratio from constant-SWA circles against the simulator's nonlinear gear, −520 … +520° in fine steps.

For every steering-wheel angle the simulator drives a circle at walking speed, forward and in
reverse, held long enough for ``--arc`` degrees of the rear-axle circle (the hold follows from the
expected radius R = L / tan δ). Antenna A's track and the dual-antenna heading get RTK-level noise
(1 cm per axis common to both antennas, Gauss–Markov τ = 30 s; 2 mm white per antenna), the CAN
steering-wheel angle 0.05° white noise in 0.1° steps. The table compares the fitted ratio SWA/δ with the ratio the
simulator actually applied (mean SWA / mean road-wheel angle over the circle) and shows the
kinematic limit: tyre slip makes δ_kin = atan(L/R) smaller than δ by about K·a_y (K the
understeer gradient), a relative error K·v²/L independent of the angle.

Run: ``/work/venv/bin/python benchmarks/study_steering_ratio.py [--step 30] [--arc 100] [--speed-kmh 5]``
(≈ 2000 s of simulated driving at 30° steps; the simulator runs ≈ 60× real time on one core).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy.signal import lfilter

from calibration.segments import Direction, find_constant_swa_segments
from calibration.steering import antenna_to_rear_axle, steering_ratio_from_circles
from sim_devices.vehicle import Drive, SteeringGear, VehicleParams, make_scenario, simulate

A_XY = (0.60, 0.0)
B_XY = (-0.98, 0.0)


def circles_drive(angles_deg: list[float], params: VehicleParams, *, speed_kmh: float, arc_deg: float) -> Drive:
    """Per angle X: circles at −X, 0, +X forward then +X, 0, −X in reverse, each held for ``arc_deg`` of arc."""
    gear = SteeringGear(params)
    v = speed_kmh / 3.6
    parts = []
    for x in angles_deg:
        radius = params.wheelbase_m / math.tan(gear.road_wheel_angle(math.radians(x)))
        hold = math.radians(arc_deg) * radius / v
        parts.append(make_scenario("swa_circles", speed_kmh=speed_kmh, swa_max_deg=x, swa_step_deg=x,
                                   direction="both", swa_rate_dps=360.0, settle_s=0.5, hold_s=hold))
    return Drive(parts, gap_s=0.5)


def _gm(rng: np.random.Generator, n: int, sigma: float, tau: float, dt: float) -> np.ndarray:
    phi = math.exp(-dt / tau)
    e = rng.standard_normal((n, 2)) * sigma * math.sqrt(1.0 - phi * phi)
    e[0] = rng.standard_normal(2) * sigma
    return np.asarray(lfilter([1.0], [1.0, -phi], e, axis=0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step", type=float, default=30.0, help="SWA step (deg); 520 is always included")
    ap.add_argument("--arc", type=float, default=100.0, help="arc driven per circle (deg)")
    ap.add_argument("--speed-kmh", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    params = VehicleParams()
    angles = [float(x) for x in np.arange(a.step, 520.0 - 1e-9, a.step)] + [520.0]
    t0 = time.perf_counter()
    truth = simulate(circles_drive(angles, params, speed_kmh=a.speed_kmh, arc_deg=a.arc), params, rate_hz=20.0)
    sim_s = time.perf_counter() - t0
    rng = np.random.default_rng(a.seed)
    n = len(truth.t)
    common = _gm(rng, n, 0.01, 30.0, truth.dt)
    ea, na, _ = truth.point_enu(*A_XY)
    eb, nb, _ = truth.point_enu(*B_XY)
    ea, na = ea + common[:, 0] + rng.normal(0, 0.002, n), na + common[:, 1] + rng.normal(0, 0.002, n)
    eb, nb = eb + common[:, 0] + rng.normal(0, 0.002, n), nb + common[:, 1] + rng.normal(0, 0.002, n)
    heading = np.mod(np.arctan2(ea - eb, na - nb), 2 * np.pi)
    swa = np.radians(np.round(np.degrees(truth.swa + rng.normal(0.0, math.radians(0.05), n)), 1))  # 0.1° SAS
    segs = find_constant_swa_segments(truth.t, swa, truth.vx, yaw_rate_rps=truth.yaw_rate, min_duration_s=3.0,
                                      min_turn_rad=math.radians(45.0))
    e, nn = antenna_to_rear_axle(ea, na, heading, A_XY, (-params.cg_to_rear_axle_m, 0.0))
    table = steering_ratio_from_circles(segs, truth.t, e, nn, wheelbase_m=params.wheelbase_m,
                                        min_arc_rad=math.radians(0.9 * a.arc))
    k = params.understeer_gradient_rad_per_mps2
    v = a.speed_kmh / 3.6
    print(f"{truth.t[-1]:.0f} s simulated in {sim_s:.1f} s; {len(table.rows)} circles at {a.speed_kmh:g} km/h, "
          f"≈ {a.arc:g}° of arc each; slip limit K·v²/L = {100 * k * v * v / params.wheelbase_m:.2f} %")
    print(f"{'dir':<8} {'SWA °':>7} {'R m':>7} {'arc °':>6} {'ratio':>8} {'sim':>8} {'err %':>7}")
    worst = 0.0
    for r in sorted(table.rows, key=lambda r: (r.direction is Direction.REVERSE, r.swa_rad)):
        m = (truth.t >= r.t_start_s) & (truth.t <= r.t_start_s + r.duration_s)
        true_ratio = float(np.mean(truth.swa[m]) / np.mean(truth.road_wheel_angle[m]))
        err = 100.0 * (r.ratio / true_ratio - 1.0)
        worst = max(worst, abs(err))
        print(f"{r.direction.value:<8} {r.swa_deg:7.1f} {r.radius_m:7.2f} {math.degrees(r.arc_rad):6.0f} "
              f"{r.ratio:8.3f} {true_ratio:8.3f} {err:+7.2f}")
    print(f"worst |error| {worst:.2f} %")
    for w in table.warnings:
        print(f"warning: {w}")


if __name__ == "__main__":
    main()
