"""Analysis and calibration time for a simulated session at the rig's rates (default 10 minutes).

The session: the vehicle simulator drives every manoeuvre kind (straights, double lane changes,
step steers, J-turns, fishhooks, circles, sine with dwell, low-speed circles) repeatedly; the
GNSS "1+2" epochs come at 20 Hz with RTK-level noise, the yaw rate, lateral acceleration and
the VSC estimate at 100 Hz (CAN), the optical sensor at 1 kHz (DAQ). Setting the session up
(simulation, noise) is not timed; every analysis step is, on one core, and the total is also
scaled to one hour (the issue's budget: read + validate an hour in under 30 s; reading is the
dataset's and not included here).

Run: ``/work/venv/bin/python benchmarks/bench_analysis.py [--minutes 10] [--seed 1]``
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np
from scipy.signal import lfilter

from calibration.mount import calibrate_mount_offset
from rig.analysis.reference import (
    AntennaGeometry,
    GnssEpochs,
    GnssSpec,
    ImuSeries,
    cross_check,
    optical_sideslip,
    reference_sideslip,
    resample_mean,
)
from rig.analysis.rollover import horizontal_ay, ltr_from_lateral, predict_ltr
from rig.analysis.scoring import validate_estimate
from rig.analysis.steering import SteeringModel, reconstruct_steering
from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, make_scenario, simulate

T = TypeVar("T")
A_XY, B_XY, BASELINE = (0.60, 0.0), (-0.98, 0.0), 1.58
OPTICAL_XY = (1.8, 0.3)
SCENARIOS: list[tuple[str, dict[str, float | str]]] = [
    ("straight", {"speed_kmh": 60.0, "duration_s": 8.0, "heading_deg": 0.0}),
    ("straight", {"speed_kmh": 60.0, "duration_s": 8.0, "heading_deg": 180.0}),
    ("double_lane_change", {"speed_kmh": 60.0}),
    ("step_steer", {"speed_kmh": 80.0}),
    ("j_turn", {}),
    ("fishhook", {}),
    ("steady_state_circle", {"radius_m": 40.0, "speed_start_kmh": 30.0, "speed_end_kmh": 50.0, "ay_rate_mps3": 0.5}),
    ("sine_with_dwell", {}),
    ("swa_circles", {"swa_step_deg": 260.0, "hold_s": 6.0, "settle_s": 2.0, "direction": "forward"}),
]


def _drive(minutes: float) -> GroundTruth:
    one = [make_scenario(name, **kw) for name, kw in SCENARIOS]
    probe = simulate(Drive(one, gap_s=4.0), rate_hz=100.0)
    reps = max(1, round(minutes * 60.0 / probe.t[-1]))
    return simulate(Drive(one * reps, gap_s=4.0), rate_hz=100.0) if reps > 1 else probe


def _ar1(rng: np.random.Generator, n: int, sigma: float, phi: float) -> np.ndarray:
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    e[0] = rng.standard_normal() * sigma
    return np.asarray(lfilter([1.0], [1.0, -phi], e), dtype=float)


def _timed(results: list[tuple[str, float]], name: str, fn: Callable[[], T]) -> T:
    t0 = time.perf_counter()
    out = fn()
    results.append((name, time.perf_counter() - t0))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    p = VehicleParams()
    t0 = time.perf_counter()
    truth = _drive(args.minutes)
    print(f"simulated {truth.t[-1] / 60:.1f} min in {time.perf_counter() - t0:.1f} s (not timed below)")
    rng = np.random.default_rng(args.seed)

    # GNSS epochs at 20 Hz: 1 cm common + 2 mm per antenna, Doppler velocity 1.5 cm/s
    gi = np.arange(0, len(truth), 5)
    n = gi.size
    offset = math.radians(0.7)
    ea, na, ua = (x[gi] for x in truth.point_enu(*A_XY, 1.0))
    eb, nb, ub = (x[gi] for x in truth.point_enu(*B_XY, 1.0))
    c, s = math.cos(-offset), math.sin(-offset)
    eb, nb = ea + c * (eb - ea) - s * (nb - na), na + s * (eb - ea) + c * (nb - na)
    common = [_ar1(rng, n, 0.01, math.exp(-0.05 / 30.0)) for _ in range(3)]
    a_enu = tuple(x + cm + rng.standard_normal(n) * 0.002 for x, cm in zip((ea, na, ua), common, strict=True))
    b_enu = tuple(x + cm + rng.standard_normal(n) * 0.002 for x, cm in zip((eb, nb, ub), common, strict=True))
    ve, vn = (x[gi] + rng.standard_normal(n) * 0.015 for x in truth.point_velocity_enu(*A_XY))
    # CAN at 100 Hz: yaw rate, a_y, SWA, speed and the VSC estimate (late by 0.1 s, 0.2° high)
    r_can = truth.yaw_rate + math.radians(0.25) + rng.standard_normal(len(truth)) * math.radians(0.08)
    ay_can = truth.ay_meas + 0.05 + rng.standard_normal(len(truth)) * 0.03
    est_can = np.interp(truth.t - 0.1, truth.t, truth.beta_cg) + math.radians(0.2)
    # optical sensor at 1 kHz
    t_opt = np.arange(0.0, truth.t[-1], 0.001)
    vx_o, vy_o = truth.point_velocity(*OPTICAL_XY)
    vx_opt = np.interp(t_opt, truth.t, vx_o) + rng.standard_normal(t_opt.size) * 0.05
    vy_opt = np.interp(t_opt, truth.t, vy_o) + rng.standard_normal(t_opt.size) * 0.05
    r_opt = np.interp(t_opt, truth.t, r_can)

    res: list[tuple[str, float]] = []
    gnss = _timed(res, "GNSS epochs from ENU", lambda: GnssEpochs.from_enu(truth.t[gi], a_enu, b_enu, (ve, vn)))
    imu = ImuSeries(truth.t, r_can, ay_can)
    heading = gnss.baseline_azimuth
    course = np.mod(np.arctan2(ve, vn), 2 * np.pi)
    speed = np.hypot(ve, vn)
    cal = _timed(
        res,
        "mounting offset (straight runs)",
        lambda: calibrate_mount_offset(
            gnss.t, heading, course, speed, r_can[gi], gnss.baseline_length, np.ones(n, bool), BASELINE
        ),
    )
    geom = AntennaGeometry(A_XY, BASELINE, mount_offset_rad=cal.offset_rad)
    spec = GnssSpec(position_sigma_m=0.0102, relative_sigma_m=0.002, relative_tau_s=0.05, velocity_sigma_mps=0.015)
    for method in ("raw", "wavelet", "rts"):
        _timed(res, f"reference sideslip ({method})", lambda m=method: reference_sideslip(  # type: ignore[misc]
            gnss, imu, geom, method=m, gnss_spec=spec))
    ref = reference_sideslip(gnss, imu, geom, gnss_spec=spec)

    def optical() -> object:
        o = optical_sideslip(t_opt, vx_opt, vy_opt, r_opt, OPTICAL_XY)
        b = resample_mean(o.t, o.beta, ref.t)
        return cross_check(ref.t, ref.beta, ref.sigma, b, np.full(ref.t.size, math.radians(0.1)))

    _timed(res, "optical 1 kHz → CG, resample, cross-check", optical)
    val = _timed(
        res,
        "segmentation + scoring",
        lambda: validate_estimate(
            ref, np.interp(ref.t, truth.t, est_can), speed_mps=speed, swa_rad=truth.swa[gi],
            yaw_rate_rps=r_can[gi], ay_mps2=ay_can[gi], truth_rad=truth.beta_cg[gi],
        ),
    )
    model = SteeringModel(p.wheelbase_m, p.mass_kg, p.cg_to_rear_axle_m / p.wheelbase_m,
                          p.cornering_stiffness_front_n_per_rad, p.cornering_stiffness_rear_n_per_rad)
    _timed(res, "steering reconstruction (100 Hz)",
           lambda: reconstruct_steering(truth.t, np.interp(truth.t, gnss.t, speed), ay_can, model,
                                        swa_rad=truth.swa, steering_ratio=16.0))
    ltr = ltr_from_lateral(horizontal_ay(truth.ay_meas, truth.roll), truth.roll, cg_height_m=p.cg_height_m,
                           roll_axis_height_m=p.roll_axis_height_m, track_m=0.5 * (p.track_front_m + p.track_rear_m))
    _timed(res, "LTR + AR prediction (20 Hz, refit 0.25 s)", lambda: predict_ltr(truth.t, ltr))

    minutes = truth.t[-1] / 60.0
    width = max(len(k) for k, _ in res)
    print(f"\nsession: {minutes:.1f} min; GNSS {n} epochs, CAN {len(truth)} samples, optical {t_opt.size} samples")
    for name, dt in res:
        print(f"  {name:<{width}}  {dt:7.3f} s")
    total = sum(dt for _, dt in res)
    print(f"  {'total':<{width}}  {total:7.3f} s  → {total * 60.0 / minutes:.1f} s per hour of driving")
    print(f"\nmounting offset {math.degrees(cal.offset_rad):.4f}° (true 0.7000°) from "
          f"{len(cal.estimate.segments)} runs; GNSS reference vs truth: "
          f"RMS {math.degrees(val.truth[0].metrics.rmse_rad):.4f}°, coverage {val.truth[0].coverage:.3f}; "
          f"{len(val.manoeuvres)} manoeuvres")


if __name__ == "__main__":
    main()
