"""Synthetic drives built from kinematics for the calibration tests (no project code used to build them).

Angles here are computed with numpy directly (atan2 of ENU vectors), independent of vsccore.angles,
so the tests check the calibration against geometry rather than against itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

G = 9.80665


def ar1(rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt: float) -> np.ndarray:
    """Stationary AR(1) (first-order Gauss–Markov) noise with std ``sigma`` and correlation time ``tau_s``."""
    phi = math.exp(-dt / tau_s)
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    x = np.empty(n)
    x[0] = rng.standard_normal() * sigma
    for k in range(1, n):
        x[k] = phi * x[k - 1] + e[k]
    return x


@dataclass
class StraightDrive:
    """Two antennas on a car driving straights joined by turns, as a dual-antenna receiver reports them."""

    t: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray
    course: np.ndarray  # azimuth of antenna A's measured velocity (rad)
    heading: np.ndarray  # azimuth of the measured baseline B -> A (rad)
    baseline_length: np.ndarray
    rtk_fixed: np.ndarray
    true_yaw: np.ndarray  # counter-clockwise from east (rad)
    true_vx: np.ndarray
    true_vy: np.ndarray
    straight_mask: np.ndarray  # samples where the car truly drives straight


def straight_drive(
    *,
    offset_rad: float,
    rng: np.random.Generator,
    speed_mps: float = 40.0 / 3.6,
    courses_deg: tuple[float, ...] = (80.0, 260.0),
    straight_s: float = 5.0,
    turn_rate_dps: float = 20.0,
    rate_hz: float = 20.0,
    pos_sigma_m: float = 0.01,
    vel_sigma_mps: float = 0.03,
    tau_s: float = 1.0,
    baseline_m: float = 1.58,
    yaw_rate_sigma_rps: float = math.radians(0.05),
    lead_in_s: float = 2.0,
    beta_on_straights: tuple[float, ...] | None = None,
) -> StraightDrive:
    """Straights at the given course azimuths joined by constant-rate turns (with 0.5 s rate ramps).

    The baseline points ``offset_rad`` clockwise of the vehicle x axis. Each antenna position gets
    independent AR(1) noise (east and north) with std ``pos_sigma_m``; antenna A's velocity gets
    AR(1) noise with std ``vel_sigma_mps``. ``beta_on_straights`` adds a true sideslip per straight
    (e.g. a cross wind).
    """
    dt = 1.0 / rate_hz
    # Build the yaw-rate profile: lead-in turn, straight, turn, straight, ..., lead-out turn.
    yaw0 = math.pi / 2.0 - math.radians(courses_deg[0])
    r_turn = math.radians(turn_rate_dps)
    pieces: list[np.ndarray] = []
    straight_flags: list[np.ndarray] = []
    betas: list[np.ndarray] = []
    ramp_n = int(round(0.5 * rate_hz))
    ramp = np.linspace(0.0, 1.0, ramp_n, endpoint=False)

    def turn(angle: float) -> None:
        # Ramp up, hold, ramp down so the yaw angle changes by exactly `angle`.
        sgn = math.copysign(1.0, angle) if angle != 0 else 1.0
        ramp_angle = 2.0 * float(np.sum(ramp)) * r_turn * dt
        hold_n = max(int(round((abs(angle) - ramp_angle) / (r_turn * dt))), 0)
        prof = np.concatenate([ramp, np.ones(hold_n), ramp[::-1]]) * r_turn
        scale = abs(angle) / (float(np.sum(prof)) * dt) if np.sum(prof) > 0 else 0.0
        pieces.append(sgn * prof * scale)
        straight_flags.append(np.zeros(prof.size, dtype=bool))
        betas.append(np.zeros(prof.size))

    n_lead = int(round(lead_in_s * rate_hz))
    pieces.append(np.full(n_lead, r_turn))
    straight_flags.append(np.zeros(n_lead, dtype=bool))
    betas.append(np.zeros(n_lead))
    yaw0 -= r_turn * n_lead * dt
    n_straight = int(round(straight_s * rate_hz))
    for i, c in enumerate(courses_deg):
        if i > 0:
            d_yaw = -(math.radians(c) - math.radians(courses_deg[i - 1]))
            d_yaw = (d_yaw + math.pi) % (2 * math.pi) - math.pi
            if abs(abs(d_yaw) - math.pi) < 1e-9:
                d_yaw = math.pi  # U-turn to the left
            turn(d_yaw)
        pieces.append(np.zeros(n_straight))
        straight_flags.append(np.ones(n_straight, dtype=bool))
        b = 0.0 if beta_on_straights is None else beta_on_straights[i]
        betas.append(np.full(n_straight, b))
    pieces.append(np.full(n_lead, -r_turn))
    straight_flags.append(np.zeros(n_lead, dtype=bool))
    betas.append(np.zeros(n_lead))

    r = np.concatenate(pieces)
    straight = np.concatenate(straight_flags)
    beta = np.concatenate(betas)
    n = r.size
    t = 1000.0 + np.arange(n) * dt
    # Yaw angle: integrate the rate so that each straight starts exactly at its course.
    yaw = yaw0 + np.concatenate([[0.0], np.cumsum(r[:-1]) * dt])
    # On straights with a sideslip β the course is yaw + β; hold the heading so the course is as asked.
    yaw = yaw - beta
    vx = speed_mps * np.cos(beta)
    vy = speed_mps * np.sin(beta)
    c, s = np.cos(yaw), np.sin(yaw)
    ve = c * vx - s * vy
    vn = s * vx + c * vy
    east = np.concatenate([[0.0], np.cumsum(ve[:-1]) * dt])
    north = np.concatenate([[0.0], np.cumsum(vn[:-1]) * dt])
    # Antenna A 0.3 m ahead of the CG; B behind it along a baseline rotated clockwise by offset_rad.
    a_x = 0.3
    bl_yaw = yaw - offset_rad
    ea = east + c * a_x
    na = north + s * a_x
    eb = ea - baseline_m * np.cos(bl_yaw)
    nb = na - baseline_m * np.sin(bl_yaw)
    ea_m = ea + ar1(rng, n, pos_sigma_m, tau_s, dt)
    na_m = na + ar1(rng, n, pos_sigma_m, tau_s, dt)
    eb_m = eb + ar1(rng, n, pos_sigma_m, tau_s, dt)
    nb_m = nb + ar1(rng, n, pos_sigma_m, tau_s, dt)
    de, dn = ea_m - eb_m, na_m - nb_m
    heading = np.mod(np.arctan2(de, dn), 2 * np.pi)
    length = np.hypot(de, dn)
    # Velocity of antenna A: CG velocity + r × lever arm.
    vea = ve - r * s * a_x
    vna = vn + r * c * a_x
    vea_m = vea + ar1(rng, n, vel_sigma_mps, tau_s, dt)
    vna_m = vna + ar1(rng, n, vel_sigma_mps, tau_s, dt)
    course = np.mod(np.arctan2(vea_m, vna_m), 2 * np.pi)
    speed = np.hypot(vea_m, vna_m)
    yaw_rate = r + rng.standard_normal(n) * yaw_rate_sigma_rps
    return StraightDrive(
        t=t,
        speed=speed,
        yaw_rate=yaw_rate,
        course=course,
        heading=heading,
        baseline_length=length,
        rtk_fixed=np.ones(n, dtype=bool),
        true_yaw=yaw,
        true_vx=vx,
        true_vy=vy,
        straight_mask=straight,
    )
