"""Steering ratio from constant-SWA circles against the simulator's nonlinear gear, with the SAS zero offset removed.

For every steering-wheel angle the simulator drives a circle at walking speed, forward and in
reverse, held long enough for ``--arc`` degrees of the rear-axle circle (the hold follows from the
expected radius R = L / tan δ); a straight run at 40 km/h comes first. The steering-wheel angle is
the one the simulated VSC ECU sends on CAN — SAS_Steering frames decoded with the DBC and the role
map, with the sensor's zero offset (``--sas-zero-deg``), 0.1° resolution and its transmit timing —
interpolated onto the GNSS epochs as ``rig calibrate-steering-ratio`` does. Antenna A's track and the
dual-antenna heading get RTK-level noise (1 cm per axis common to both antennas, Gauss–Markov
τ = 30 s; 2 mm white per antenna). The SAS zero is estimated from left/right circle pairs and the
straight run (calibration.steering), removed, and each row compared with the ratio the simulator
applied (mean true SWA / mean road-wheel angle over the circle). Tyre slip makes δ_kin = atan(L/R)
smaller than δ by about K·a_y (K the understeer gradient): ≈ +0.2 % forward, −0.2 % in reverse,
growing towards the lock.

Every seed is observed twice: with the shipped antennas (A 0.60 m, B −0.98 m: 1.58 m baseline) and
with a 2.40 m baseline (A 1.10 m, B −1.30 m).

Run: ``.venv/bin/python benchmarks/study_steering_ratio.py [--step 65] [--arc 100] [--seeds 1,2,3]
[--sas-zero-deg 1.5]`` (≈ 920 s of simulated driving per seed at 65° steps; ≈ 20 s per seed here). The
``raw %`` column is the row's error with the SAS zero left in (what the command printed before).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from calibration.segments import Direction, find_constant_swa_segments, find_straight_segments
from calibration.steering import (
    antenna_to_rear_axle,
    apply_sas_zero,
    combine_sas_zero,
    sas_zero_from_circle_pairs,
    sas_zero_from_straights,
    steering_ratio_from_circles,
)
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleMap
from sim_devices.vehicle import Drive, GroundTruth, SteeringGear, VehicleParams, make_scenario, simulate
from sim_devices.vsc_ecu import VscEcuConfig, frames, vsc_sim_dbc_path

ROLES = Path(__file__).resolve().parents[1] / "rig" / "examples" / "roles" / "vsc_sim.toml"
LAYOUTS = {"1.58 m": ((0.60, 0.0), (-0.98, 0.0)), "2.40 m": ((1.10, 0.0), (-1.30, 0.0))}


def circles_drive(angles_deg: list[float], params: VehicleParams, *, speed_kmh: float, arc_deg: float) -> Drive:
    """A 6 s straight at 40 km/h; per angle X circles at −X, 0, +X forward then +X, 0, −X in reverse."""
    gear = SteeringGear(params)
    v = speed_kmh / 3.6
    parts = [make_scenario("straight", speed_kmh=40.0, duration_s=6.0)]
    for x in angles_deg:
        radius = params.wheelbase_m / math.tan(gear.road_wheel_angle(math.radians(x)))
        hold = max(math.radians(arc_deg) * radius / v, 5.0)
        parts.append(make_scenario("swa_circles", speed_kmh=speed_kmh, swa_max_deg=x, swa_step_deg=x,
                                   direction="both", swa_rate_dps=360.0, settle_s=1.0, hold_s=hold))
    return Drive(parts, gap_s=1.0)


def _gm(rng: np.random.Generator, n: int, sigma: float, tau: float, dt: float) -> np.ndarray:
    phi = math.exp(-dt / tau)
    e = rng.standard_normal((n, 2)) * sigma * math.sqrt(1.0 - phi * phi)
    e[0] = rng.standard_normal(2) * sigma
    return np.asarray(lfilter([1.0], [1.0, -phi], e, axis=0))


def recorded_swa(truth: GroundTruth, seed: int, sas_zero_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, SWA rad ISO) as the simulated ECU sends it on CAN, decoded with the DBC and the role map."""
    db = load_dbc(vsc_sim_dbc_path())
    spec = RoleMap.from_toml(ROLES, db).role("swa")
    frame_id = db.get_message_by_name(spec.message).frame_id
    cfg = VscEcuConfig(seed=seed, swa_offset_rad=math.radians(sas_zero_deg))
    t, v = [], []
    for ts, msg in frames(truth, cfg, db=db):
        if msg.arbitration_id == frame_id:
            phys = db.decode_message(frame_id, bytes(msg.data), decode_choices=False)
            t.append(ts)
            v.append(spec.to_si(float(phys[spec.signal])))
    return np.asarray(t), np.asarray(v)


def run(truth: GroundTruth, params: VehicleParams, seed: int, layout: str, sas: tuple[np.ndarray, np.ndarray],
        arc_deg: float, verbose: bool) -> tuple[float, float, float, int, int]:
    """One observation of the drive; returns (estimated zero deg, u95 deg, worst |row error| %, rows, flagged)."""
    a_xy, b_xy = LAYOUTS[layout]
    rng = np.random.default_rng(1000 * seed + len(layout))
    k = np.arange(0, len(truth.t), max(1, round(0.05 / truth.dt)))  # 20 Hz GNSS epochs
    t = truth.t[k]
    n = t.size
    common = _gm(rng, n, 0.01, 30.0, 0.05)
    ea, na, _ = truth.point_enu(*a_xy)
    eb, nb, _ = truth.point_enu(*b_xy)
    ea, na = ea[k] + common[:, 0] + rng.normal(0, 0.002, n), na[k] + common[:, 1] + rng.normal(0, 0.002, n)
    eb, nb = eb[k] + common[:, 0] + rng.normal(0, 0.002, n), nb[k] + common[:, 1] + rng.normal(0, 0.002, n)
    heading = np.mod(np.arctan2(ea - eb, na - nb), 2 * np.pi)
    swa = np.interp(t, *sas)  # the CAN signal on the GNSS epochs
    yaw_rate = truth.yaw_rate[k] + rng.normal(0.0, math.radians(0.05), n)
    v_signed = truth.vx[k]
    segs = find_constant_swa_segments(t, swa, v_signed, yaw_rate_rps=yaw_rate, min_duration_s=3.0,
                                      min_turn_rad=math.radians(45.0))
    e, nn = antenna_to_rear_axle(ea, na, heading, a_xy, (-params.cg_to_rear_axle_m, 0.0))
    table = steering_ratio_from_circles(segs, t, e, nn, wheelbase_m=params.wheelbase_m,
                                        min_arc_rad=math.radians(0.9 * arc_deg))
    course = np.arctan2(*np.gradient(np.vstack([ea, na]), t, axis=1))
    straights = find_straight_segments(t, np.abs(truth.speed[k]), yaw_rate, course, np.ones(n, dtype=bool),
                                       min_duration_s=3.0)
    idx = np.arange(n)
    masks = [(idx >= s.start_index) & (idx < s.stop_index) for s in straights]
    zero = combine_sas_zero([sas_zero_from_circle_pairs(table.rows),
                             sas_zero_from_straights(t, swa, yaw_rate, v_signed, masks)],
                            resolution_rad=math.radians(0.1))
    table = apply_sas_zero(table, zero)
    worst = 0.0
    lines = [(f"{'dir':<8} {'SWA °':>7} {'R m':>7} {'arc °':>6} {'ratio':>8} {'±95 %':>6} {'sim':>8} {'err %':>7} "
              f"{'raw %':>7}")]
    for r in sorted(table.rows, key=lambda r: (r.direction is Direction.REVERSE, r.swa_rad)):
        m = (truth.t >= r.t_start_s) & (truth.t <= r.t_start_s + r.duration_s)
        true_ratio = float(np.mean(truth.swa[m]) / np.mean(truth.road_wheel_angle[m]))
        err = 100.0 * (r.ratio / true_ratio - 1.0)
        raw = 100.0 * ((r.swa_rad + r.swa_zero_removed_rad) / r.delta_rad / true_ratio - 1.0)
        worst = max(worst, abs(err))
        lines.append(f"{r.direction.value:<8} {r.swa_deg:7.1f} {r.radius_m:7.2f} {math.degrees(r.arc_rad):6.0f} "
                     f"{r.ratio:8.3f} {100 * r.ratio_u95:5.2f}% {true_ratio:8.3f} {err:+7.2f} {raw:+7.2f}")
    if verbose:
        print("\n".join(lines))
        for f in table.flagged:
            print(f"flagged: {f.direction.value} {f.swa_deg:+.0f}° ± {100 * f.ratio_u95:.2f} %")
    return zero.offset_deg, zero.u95_deg, worst, len(table.rows), len(table.flagged)


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--step", type=float, default=65.0, help="SWA step (deg); 520 is always included")
    ap.add_argument("--arc", type=float, default=100.0, help="arc driven per circle (deg)")
    ap.add_argument("--speed-kmh", type=float, default=5.0)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--sas-zero-deg", type=float, default=1.5, help="the simulated SAS zero offset (deg)")
    ap.add_argument("--quiet", action="store_true", help="summary lines only")
    a = ap.parse_args()
    params = VehicleParams()
    angles = [float(x) for x in np.arange(a.step, 520.0 - 1e-9, a.step)] + [520.0]
    k_slip = params.understeer_gradient_rad_per_mps2 * (a.speed_kmh / 3.6) ** 2 / params.wheelbase_m
    print(f"SAS zero {a.sas_zero_deg:+.2f}°, circles ±{angles[0]:g} … ±520° at {a.speed_kmh:g} km/h, ≈ {a.arc:g}° "
          f"of arc each; slip limit K·v²/L = {100 * k_slip:.2f} %")
    summary = []
    for seed in (int(s) for s in a.seeds.split(",")):
        t0 = time.perf_counter()
        truth = simulate(circles_drive(angles, params, speed_kmh=a.speed_kmh, arc_deg=a.arc), params,
                         rate_hz=100.0, seed=seed)
        sas = recorded_swa(truth, seed, a.sas_zero_deg)
        sim_s = time.perf_counter() - t0
        for layout in LAYOUTS:
            if not a.quiet:
                print(f"\nseed {seed}, baseline {layout}: {truth.t[-1]:.0f} s simulated (+ ECU) in {sim_s:.1f} s")
            res = run(truth, params, seed, layout, sas, a.arc, not a.quiet)
            summary.append((seed, layout, *res))
    print(f"\n{'seed':>4} {'baseline':>8} {'zero °':>8} {'±95 % °':>8} {'|err| °':>8} {'worst row %':>11} "
          f"{'rows':>5} {'flagged':>7}")
    for seed, layout, z, u, worst, nrows, nflag in summary:
        print(f"{seed:4d} {layout:>8} {z:+8.3f} {u:8.3f} {abs(z - a.sas_zero_deg):8.3f} {worst:11.2f} {nrows:5d} "
              f"{nflag:7d}")
    print(f"worst row over all: {max(s[4] for s in summary):.2f} %")


if __name__ == "__main__":
    main()
