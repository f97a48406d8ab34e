"""Offline Monte-Carlo of the straight-run offset estimator: many noise realisations, no live simulation.

The truth is the vehicle simulator's: two straight runs at 40 km/h in opposite directions
(:func:`straight_truth`), sampled at the 20 Hz GNSS rate. The antenna errors are those of the
simulated receivers, :class:`sim_devices.gnss.error_model.GnssErrorModel` for RTK fixed
(NARROW_INT): per axis a Gauss–Markov part (``correlated_fraction``, ``correlation_time_s``) plus
white noise, a share ``common_fraction`` of the variance common to both rovers, and white Doppler
velocity noise. :func:`gnss_errors` draws them for many realisations at once, consuming each
receiver's random stream exactly as ``GnssErrorModel.sample`` does (a test checks the two agree to
rounding), so the harness is the simulator's noise, only vectorised.

The common-mode part is a deterministic function of GPS time (:class:`CommonModeError`); it is the
same for both rovers at the same epoch and so cancels exactly in the baseline A → B. It is evaluated
once per epoch (one ``common_seed`` for all realisations) and added anyway, to keep the positions what
the simulated receivers would report.

The observed series per realisation is heading − course (rad): azimuth of the measured baseline
B → A minus the azimuth of antenna A's measured velocity; its true value on a straight is the
injected mounting offset (the simulated car's sideslip there is < 0.001°).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from calibration.segments import Segment, find_straight_segments
from drivers.novatel.enums import PositionType
from sim_devices.gnss.error_model import CommonModeError, GnssErrorParams, SolutionNoise
from sim_devices.vehicle import Drive, GroundTruth, make_scenario, simulate
from tests.calibration.observe import A_XY, B_XY

RATE_HZ = 20.0
GPS_T0_NS = 2400 * 7 * 86400 * 10**9 + 345_600 * 10**9
"""GPS time of the first truth sample (week 2400, as the example session configuration)."""


@dataclass(frozen=True, slots=True)
class NoiseCase:
    """One GNSS error model of the harness (RTK fixed; figures per rover)."""

    correlation_time_s: float
    correlated_fraction: float
    position_drms_m: float = 0.015
    """Horizontal 2-D RMS of each rover's position (the simulator's default RTK fixed figure)."""
    common_fraction: float = 0.95
    velocity_sigma_mps: float = 0.02

    @property
    def name(self) -> str:
        """Short label, e.g. ``τ=1s cf=0.7``."""
        return f"τ={self.correlation_time_s:g}s cf={self.correlated_fraction:g}"

    def params(self, common_seed: int = 1) -> GnssErrorParams:
        """The simulator's error parameters for this case (NARROW_INT noise replaced)."""
        noise = dict(GnssErrorParams().noise)
        fixed = noise[PositionType.NARROW_INT]
        noise[PositionType.NARROW_INT] = SolutionNoise(
            self.position_drms_m, fixed.vertical_sigma_m, self.velocity_sigma_mps, fixed.vertical_velocity_sigma_mps
        )
        return GnssErrorParams(
            noise=noise,
            correlated_fraction=self.correlated_fraction,
            correlation_time_s=self.correlation_time_s,
            common_fraction=self.common_fraction,
            common_seed=common_seed,
        )

    def relative_sigma_m(self) -> float:
        """1σ per horizontal axis of the A − B position difference (what the baseline heading sees)."""
        return math.sqrt(2.0 * (1.0 - self.common_fraction)) * self.position_drms_m / math.sqrt(2.0)


def straight_truth(duration_s: float = 8.0, speed_kmh: float = 40.0, heading_deg: float = 0.0) -> GroundTruth:
    """Simulator truth at 20 Hz: two straight runs in opposite directions, joined by the simulator's U-turn."""
    back = (heading_deg + 180.0) % 360.0
    drive = Drive(
        [
            make_scenario("straight", speed_kmh=speed_kmh, duration_s=duration_s, heading_deg=heading_deg),
            make_scenario("straight", speed_kmh=speed_kmh, duration_s=duration_s, heading_deg=back),
        ],
        gap_s=2.0,
    )
    return simulate(drive, rate_hz=RATE_HZ)


def gnss_errors(
    params: GnssErrorParams, seeds: np.ndarray, t_s: np.ndarray, *, common: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """RTK-fixed position and velocity errors (ENU) of receivers seeded ``seeds`` at epochs ``t_s`` (s).

    Returns (position (R, n, 3) m, velocity (R, n, 3) m/s), R = len(seeds): realisation r is what
    ``GnssErrorModel(params, seeds[r]).sample`` gives at GPS times ``GPS_T0_NS + t_s`` for NARROW_INT.
    ``common`` is the common-mode process at those epochs (n, 3); computed when not given.
    """
    n = t_s.size
    noise = params.noise_for(PositionType.NARROW_INT)
    sigma = noise.position_sigma_enu
    vsigma = noise.velocity_sigma_enu
    # The model's stream: gm0 (3); then per epoch [GM innovation (3) from the 2nd epoch on], white (3), velocity (3).
    draws = np.stack([np.random.default_rng(int(s)).standard_normal(3 + 9 * n - 3) for s in seeds])
    gm0 = draws[:, :3]
    first = draws[:, 3:9].reshape(-1, 1, 6)
    rest = draws[:, 9:].reshape(-1, n - 1, 9)
    innov = rest[:, :, :3]
    white = np.concatenate([first[:, :, :3], rest[:, :, 3:6]], axis=1)
    vel = np.concatenate([first[:, :, 3:6], rest[:, :, 6:9]], axis=1)
    t_ns = GPS_T0_NS + np.round(t_s * 1e9).astype(np.int64)
    dt = np.diff(t_ns).astype(float) / 1e9
    phi = np.exp(-dt / params.correlation_time_s)
    if np.allclose(phi, phi[0]):
        g = math.sqrt(max(0.0, 1.0 - phi[0] ** 2))
        gm = lfilter([g], [1.0, -phi[0]], innov, axis=1, zi=phi[0] * gm0[:, None, :])[0]
    else:
        gm = np.empty_like(innov)
        prev = gm0
        for k in range(n - 1):
            prev = phi[k] * prev + math.sqrt(max(0.0, 1.0 - phi[k] ** 2)) * innov[:, k]
            gm[:, k] = prev
    gm = np.concatenate([gm0[:, None, :], gm], axis=1)
    cf = params.correlated_fraction
    unit = math.sqrt(cf) * gm + math.sqrt(1.0 - cf) * white
    if params.common_fraction > 0.0:
        if common is None:
            common = common_mode(params, t_s)
        unit = math.sqrt(1.0 - params.common_fraction) * unit + math.sqrt(params.common_fraction) * common[None]
    return sigma * unit, vsigma * vel


def common_mode(params: GnssErrorParams, t_s: np.ndarray) -> np.ndarray:
    """The process shared by all receivers of ``params.common_seed`` at the epochs (n, 3), as the model evaluates it."""
    cm = CommonModeError(params.common_seed, params.correlation_time_s)
    t_ns = GPS_T0_NS + np.round(t_s * 1e9).astype(np.int64)
    week_ns = 7 * 86400 * 10**9
    return np.stack([cm.at((int(t) % week_ns) / 1e9) for t in t_ns])


@dataclass(frozen=True)
class StraightSeries:
    """Heading − course of many noise realisations over the same drive."""

    t: np.ndarray
    """Epoch times (s), shape (n,)."""
    x: np.ndarray
    """Heading − course (rad), shape (R, n), wrapped to (−π, π]."""
    length: np.ndarray
    """Measured antenna separation |A − B| (m) over the whole session, shape (R, n_session)."""
    segments: tuple[Segment, ...]
    offset_rad: float
    case: NoiseCase

    def blocks(self) -> list[np.ndarray]:
        """The samples of each straight run, each (R, n_j)."""
        return [self.x[:, s.mask(self.t)] for s in self.segments]

    def length_blocks(self) -> list[np.ndarray]:
        """The baseline length over the whole session: one block, RTK fixed throughout."""
        return [self.length]


def truth_segments(truth: GroundTruth) -> tuple[Segment, ...]:
    """The straight runs of the noise-free drive (RTK fixed throughout)."""
    ve, vn = truth.point_velocity_enu(*A_XY)
    course = np.mod(np.arctan2(ve, vn), 2.0 * np.pi)
    return tuple(
        find_straight_segments(truth.t, np.hypot(ve, vn), truth.yaw_rate, course, np.ones(len(truth), dtype=bool))
    )


def straight_series(
    truth: GroundTruth,
    case: NoiseCase,
    reps: int,
    *,
    seed: int = 0,
    offset_rad: float = math.radians(0.35),
    segments: tuple[Segment, ...] | None = None,
    session_s: float = 0.0,
) -> StraightSeries:
    """``reps`` realisations of heading − course on ``truth`` under ``case`` (rover seeds from ``seed``).

    ``session_s`` > the drive's duration puts the drive in the middle of a longer RTK-fixed session
    (the car standing still before and after it, as at the start and end of a test) whose baseline
    length ``StraightSeries.length`` covers; the errors run on continuously through it.
    """
    n_drive = len(truth)
    pad = max(0, int(round((session_s - n_drive / RATE_HZ) * RATE_HZ / 2.0)))
    keep = np.concatenate([np.zeros(pad, dtype=int), np.arange(n_drive), np.full(pad, n_drive - 1)])
    t = truth.t[0] + (np.arange(keep.size) - pad) / RATE_HZ
    drive = slice(pad, pad + n_drive)
    ea, na, _ = (v[keep] for v in truth.point_enu(*A_XY, 1.0))
    eb, nb, _ = (v[keep] for v in truth.point_enu(*B_XY, 1.0))
    # B turned about A by −offset: the azimuth B → A turns clockwise by +offset (as tests.calibration.observe).
    c, s = math.cos(-offset_rad), math.sin(-offset_rad)
    de, dn = eb - ea, nb - na
    eb, nb = ea + c * de - s * dn, na + s * de + c * dn
    params = case.params(common_seed=1)
    common = common_mode(params, t) if case.common_fraction > 0.0 else None
    seeds_a = 1_000_003 * (seed + 1) + 2 * np.arange(reps)
    pa, va = gnss_errors(params, seeds_a, t, common=common)
    pb, _ = gnss_errors(params, seeds_a + 1, t, common=common)
    dbe = (ea - eb)[None] + pa[:, :, 0] - pb[:, :, 0]
    dbn = (na - nb)[None] + pa[:, :, 1] - pb[:, :, 1]
    dbu = pa[:, :, 2] - pb[:, :, 2]
    vte, vtn = truth.point_velocity_enu(*A_XY)
    heading = np.arctan2(dbe[:, drive], dbn[:, drive])
    course = np.arctan2(vte[None] + va[:, drive, 0], vtn[None] + va[:, drive, 1])
    x = np.angle(np.exp(1j * (heading - course)))
    segs = segments if segments is not None else truth_segments(truth)
    length = np.sqrt(dbe * dbe + dbn * dbn + dbu * dbu)
    return StraightSeries(t=truth.t, x=x, length=length, segments=segs, offset_rad=offset_rad, case=case)


CASES = (
    NoiseCase(0.2, 0.7),
    NoiseCase(1.0, 0.3),
    NoiseCase(1.0, 0.7),
    NoiseCase(1.0, 0.9),
    NoiseCase(3.0, 0.7),
    NoiseCase(10.0, 0.3),
    NoiseCase(10.0, 0.7),
    NoiseCase(10.0, 0.9),
)
"""The noise models of the coverage table (the demo session's is τ = 1 s, cf = 0.7)."""
