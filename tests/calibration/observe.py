"""Dual-antenna GNSS and yaw-rate observations of a simulated drive, with RTK-level noise (test helper).

The model of a "1+2" set-up: both rovers use the same base, satellites and atmosphere, so most of
an RTK position error (≈ 1 cm) is common to both antennas and cancels in the baseline B → A; what
is left per antenna and axis is carrier-phase noise and multipath of a few millimetres. Dual-antenna
receivers quote 0.1–0.2° heading for 1–2 m baselines, i.e. ≈ 2 mm per antenna and axis. Each
part is a first-order Gauss–Markov (AR(1)) process; τ = 0 makes it white. Doppler velocity noise
is white.

Angles here are computed with numpy directly (atan2 of ENU vectors), not with vsccore.angles, so
that the tests check the project's conventions against plain geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from sim_devices.vehicle.truth import GroundTruth

A_XY = (0.60, 0.0)
"""Antenna A from the CG (m), as in the default vehicle profile."""
B_XY = (-0.98, 0.0)
BASELINE_M = 1.58


def gauss_markov(rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt: float, width: int) -> np.ndarray:
    """Stationary AR(1) noise, shape (n, width), standard deviation ``sigma``, correlation time ``tau_s`` (0: white)."""
    if sigma == 0.0:
        return np.zeros((n, width))
    phi = math.exp(-dt / tau_s) if tau_s > 0.0 else 0.0
    e = rng.standard_normal((n, width)) * sigma * math.sqrt(1.0 - phi * phi)
    e[0] = rng.standard_normal(width) * sigma
    if phi == 0.0:
        return e
    return np.asarray(lfilter([1.0], [1.0, -phi], e, axis=0), dtype=float)


@dataclass(frozen=True)
class RtkNoise:
    """Error model of the two rovers and the yaw-rate sensor (1σ)."""

    common_sigma_m: float = 0.01
    """Per axis, common to both antennas (m)."""
    common_tau_s: float = 30.0
    relative_sigma_m: float = 0.002
    """Per antenna and axis, independent between the antennas (m)."""
    relative_tau_s: float = 0.0
    velocity_sigma_mps: float = 0.015
    """Per horizontal axis, white."""
    rate_hz: float = 20.0
    yaw_rate_sigma_rps: float = math.radians(0.05)
    yaw_rate_bias_rps: float = math.radians(0.2)


@dataclass(frozen=True)
class DualAntennaObs:
    """What the receivers and the yaw-rate sensor report at the GNSS epochs."""

    idx: np.ndarray
    """Indices of the epochs in the truth arrays."""
    t: np.ndarray
    a_enu: tuple[np.ndarray, np.ndarray, np.ndarray]
    b_enu: tuple[np.ndarray, np.ndarray, np.ndarray]
    vel_a_en: tuple[np.ndarray, np.ndarray]
    heading: np.ndarray
    """Azimuth of the measured baseline B → A, clockwise from north, [0, 2π)."""
    baseline_length: np.ndarray
    course: np.ndarray
    """Azimuth of A's measured velocity, [0, 2π)."""
    speed: np.ndarray
    yaw_rate: np.ndarray
    rtk_fixed: np.ndarray


def observe(
    truth: GroundTruth,
    *,
    noise: RtkNoise | None = None,
    mount_offset_rad: float = 0.0,
    seed: int = 0,
    a_xy: tuple[float, float] = A_XY,
    b_xy: tuple[float, float] = B_XY,
) -> DualAntennaObs:
    """Sample ``truth`` at the GNSS rate with noise; baseline turned clockwise by ``mount_offset_rad`` about A."""
    nz = noise or RtkNoise()
    rng = np.random.default_rng(seed)
    step = max(1, int(round(1.0 / (truth.dt * nz.rate_hz))))
    idx = np.arange(0, len(truth), step)
    n = idx.size
    dt = step * truth.dt
    ea, na, ua = (x[idx] for x in truth.point_enu(*a_xy, 1.0))
    eb, nb, ub = (x[idx] for x in truth.point_enu(*b_xy, 1.0))
    # B rotated about A by −offset (counter-clockwise in ENU) turns the azimuth B → A clockwise by +offset.
    c, s = math.cos(-mount_offset_rad), math.sin(-mount_offset_rad)
    de, dn = eb - ea, nb - na
    eb, nb = ea + c * de - s * dn, na + s * de + c * dn
    common = gauss_markov(rng, n, nz.common_sigma_m, nz.common_tau_s, dt, 3)
    pa = common + gauss_markov(rng, n, nz.relative_sigma_m, nz.relative_tau_s, dt, 3)
    pb = common + gauss_markov(rng, n, nz.relative_sigma_m, nz.relative_tau_s, dt, 3)
    a_enu = (ea + pa[:, 0], na + pa[:, 1], ua + pa[:, 2])
    b_enu = (eb + pb[:, 0], nb + pb[:, 1], ub + pb[:, 2])
    ve, vn = (x[idx] for x in truth.point_velocity_enu(*a_xy))
    ve = ve + rng.standard_normal(n) * nz.velocity_sigma_mps
    vn = vn + rng.standard_normal(n) * nz.velocity_sigma_mps
    dbe, dbn, dbu = a_enu[0] - b_enu[0], a_enu[1] - b_enu[1], a_enu[2] - b_enu[2]
    yaw_rate = truth.yaw_rate[idx] + nz.yaw_rate_bias_rps + rng.standard_normal(n) * nz.yaw_rate_sigma_rps
    return DualAntennaObs(
        idx=idx,
        t=truth.t[idx],
        a_enu=a_enu,
        b_enu=b_enu,
        vel_a_en=(ve, vn),
        heading=np.mod(np.arctan2(dbe, dbn), 2.0 * np.pi),
        baseline_length=np.sqrt(dbe * dbe + dbn * dbn + dbu * dbu),
        course=np.mod(np.arctan2(ve, vn), 2.0 * np.pi),
        speed=np.hypot(ve, vn),
        yaw_rate=yaw_rate,
        rtk_fixed=np.ones(n, dtype=bool),
    )
