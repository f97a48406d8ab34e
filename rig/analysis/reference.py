"""Reference sideslip from a dual-antenna GNSS ("1+2") set-up and from an optical slip sensor.

GNSS reference (all at the GNSS epochs, times in s):

- heading: azimuth of the antenna baseline B → A (A ahead of B) minus the calibrated mounting
  offset (:func:`calibration.mount.apply_mount_offset`); course: azimuth of the velocity of A.
  β_A = heading − course (:func:`vsccore.angles.sideslip_from_azimuths`, ISO 8855 sign).
- β_A is moved to the CG and to any named body point with the yaw rate:
  v_P = v_A + ω × (r_P − r_A) (:func:`vsccore.angles.transfer_velocity`).
- an epoch is invalid (NaN, with an :class:`InvalidReason` bitmask) below a minimum speed, when
  either rover is not RTK fixed, when the measured baseline length is off its nominal value by more
  than the tolerance, when an input is missing, or when the yaw rate is missing.

Three methods (the result says which in ``method``):

- ``raw``: the per-epoch β, with σ from the sensor specs (σ_ψ = √(σ_A⊥² + σ_B⊥²)/L, σ_χ = σ_v/V).
- ``wavelet``: raw β at the CG denoised by :func:`rig.analysis.smoothing.wavelet_denoise`.
- ``rts``: a Kalman filter and Rauch–Tung–Striebel smoother in two decoupled linear channels
  (docs/analysis.md has the derivation):

  * heading, states [ψ, b_r, e_ψ]: ψ[k+1] = ψ[k] + ∫r_m dt − b_r·Δt (gyro increments between
    epochs, yaw-rate bias b_r a random walk); the GNSS heading measures ψ + e_ψ, with e_ψ a
    first-order Gauss–Markov error (σ_e = √2·σ_p/L, correlation time τ of the position errors), so
    the filter does not treat time-correlated baseline noise as independent samples.
  * course, states [ν, s_a, c_a] with ν the direction of the CG velocity (counter-clockwise from
    east, β = ν − ψ): ν̇ = a_n/V, with the normal acceleration a_n from the lateral accelerometer
    (gravity's roll component taken out with the roll model's dynamic roll angle,
    a = (a_y − g·sin φ)/cos φ, or without a roll model with the static gain, a_y/(1 + g·k_φ); then a
    residual scale s_a and bias c_a as random-walk states) and V from GNSS; the measurement is the
    direction of the CG velocity obtained from the velocity at A, the smoothed heading and the
    bias-corrected yaw rate. Without a lateral
    accelerometer the course follows the corrected gyro (ν̇ = r + β̇, β̇ white).

  β = ν − ψ with variance σ_ν² + σ_ψ² (the channels see independent measurement errors).

Before any method: the delay of the IMU time stamps behind the GNSS epochs (sensor filter and CAN
output latency, ≈ 17 ms on the simulated cluster) is estimated from the gyro-integrated yaw against
the GNSS yaw and removed, and the GNSS noise is measured on the session (heading from the scatter of
the baseline length, with its Gauss–Markov/white split fitted to the length's autocorrelation on
records long enough to tell it, else all Gauss–Markov with the specified τ; velocity from second
differences), unless
``imu_delay_s`` / ``noise_from_data=False`` say otherwise.

Body roll: a roof antenna z ≈ 1 m above the CG picks up −p·z of lateral velocity from the roll rate
p (up to ≈ 0.1 m/s, 0.4° of β at 50 km/h in a double lane change). With ``AntennaGeometry.z`` and a
:class:`rig.analysis.rollover.RollModel` (``roll_model``), the roll angle and roll rate come from
that model driven by the body-fixed a_y (no roll rate on CAN), the term is removed from the
velocity at A (ω × r with the rolled lever arm) and its uncertainty (``ImuSpec.roll_rate_rel_sigma``
plus the a_y noise through the model) is added to the course measurement noise.

Optical reference: :func:`optical_sideslip` moves a (zero-corrected) Correvit velocity to the CG;
:func:`cross_check` flags where two references disagree beyond their combined uncertainty.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import pymap3d

from calibration.mount import apply_mount_offset, apply_optical_zero
from rig.analysis.arrays import BoolArray, as_1d, as_bool, check_time, runs
from rig.analysis.smoothing import rts_smooth3, wavelet_denoise
from vsccore.angles import (
    FloatArray,
    azimuth_to_yaw,
    sideslip_from_azimuths,
    sideslip_from_velocity,
    transfer_velocity,
    unwrap,
    wrap_2pi,
    wrap_pi,
    yaw_to_azimuth,
)
from vsccore.errors import AnalysisError

if TYPE_CHECKING:  # rollover imports statsmodels: not at import time of this module
    from rig.analysis.rollover import RollModel

__all__ = [
    "AntennaGeometry",
    "CrossCheck",
    "GnssEpochs",
    "GnssSpec",
    "ImuSeries",
    "ImuSpec",
    "InvalidReason",
    "OpticalSideslip",
    "PositionSource",
    "ReferenceMethod",
    "ReferenceSideslip",
    "choose_position_source",
    "cross_check",
    "epoch_source",
    "optical_sideslip",
    "reference_sideslip",
    "resample_mean",
    "tyre_slip_angles",
    "vehicle_points",
]

G = 9.80665
U8 = npt.NDArray[np.uint8]


class ReferenceMethod(enum.StrEnum):
    """How the reference sideslip was obtained."""

    RAW = "raw"
    WAVELET = "wavelet"
    RTS = "rts"


class InvalidReason(enum.IntFlag):
    """Why an epoch of a reference is invalid (bits of ``ReferenceSideslip.reasons``)."""

    NO_DATA = 1
    """A needed GNSS input is missing (NaN)."""
    LOW_SPEED = 2
    """Speed below the minimum: the course is undefined or too noisy."""
    A_NOT_FIXED = 4
    """Rover A not RTK fixed."""
    B_NOT_FIXED = 8
    """Rover B not RTK fixed."""
    BASELINE_LENGTH = 16
    """Measured antenna separation off its nominal length by more than the tolerance."""
    NO_YAW_RATE = 32
    """No yaw rate at this epoch (needed to move the velocity to the CG)."""


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class AntennaGeometry:
    """Where antenna A sits and what the baseline should measure."""

    a_xy: tuple[float, float]
    """Antenna A from the CG in vehicle axes (m, x forward, y left)."""
    baseline_length_m: float
    """Nominal antenna separation (m)."""
    baseline_tolerance_m: float = 0.03
    mount_offset_rad: float = 0.0
    """Calibrated mounting offset: baseline azimuth − vehicle x-axis azimuth (see calibration.mount)."""
    z: float = 0.0
    """Height of antenna A above the CG (m, z up). With a roll model, the lateral velocity that body
    roll gives the antenna (−z·p) is removed; 0: no roll correction."""

    def __post_init__(self) -> None:
        if not math.isfinite(self.z):
            raise AnalysisError(f"antenna z must be finite, got {self.z}")
        if not self.baseline_length_m > 0.0:
            raise AnalysisError(f"baseline_length_m must be positive, got {self.baseline_length_m}")
        if not self.baseline_tolerance_m > 0.0:
            raise AnalysisError(f"baseline_tolerance_m must be positive, got {self.baseline_tolerance_m}")


@dataclass(frozen=True, slots=True)
class GnssSpec:
    """GNSS error model (1σ), from the receiver specification or a static test."""

    position_sigma_m: float = 0.02
    """Horizontal position error of each antenna, per axis (m)."""
    position_tau_s: float = 1.0
    """Correlation time of the position errors (s)."""
    velocity_sigma_mps: float = 0.03
    """Horizontal velocity error per axis (m/s), taken as white at the epoch rate."""
    relative_sigma_m: float | None = None
    """Per antenna and axis, the part of the position error NOT common to both antennas (m).

    Only this part reaches the baseline: both rovers use the same base, satellites and atmosphere,
    so most of an RTK position error cancels in B → A. None: the errors are taken as independent
    (``position_sigma_m``), which is pessimistic for a real dual-antenna set-up."""
    relative_tau_s: float | None = None
    """Correlation time of the relative part (s); None: ``position_tau_s``."""

    @property
    def baseline_sigma_m(self) -> float:
        """Per-antenna, per-axis σ that reaches the baseline (m)."""
        return self.position_sigma_m if self.relative_sigma_m is None else self.relative_sigma_m

    @property
    def baseline_tau_s(self) -> float:
        """Correlation time of the baseline error (s)."""
        return self.position_tau_s if self.relative_tau_s is None else self.relative_tau_s
    heading_white_sigma_rad: float = 1e-4
    """Small white part of the baseline heading error (rad), on top of the Gauss–Markov part."""


@dataclass(frozen=True, slots=True)
class ImuSpec:
    """Yaw-rate and lateral-acceleration sensor model (CAN sensor cluster or IMU)."""

    yaw_rate_noise_density: float = 3e-4
    """White yaw-rate noise density, rad/s/√Hz (angle random walk)."""
    yaw_rate_bias_sigma_rps: float = math.radians(1.0)
    """Prior 1σ of the yaw-rate bias (rad/s)."""
    yaw_rate_bias_rw: float = math.radians(0.002)
    """Yaw-rate bias random walk, rad/s/√s."""
    yaw_rate_scale_sigma: float = 0.002
    """Relative scale error of the yaw rate, applied to each increment (as white)."""
    ay_noise_density: float = 0.01
    """White lateral-acceleration noise density, m/s²/√Hz."""
    ay_model_density: float = 0.01
    """Unmodelled lateral-acceleration error (roll dynamics, mounting), m/s²/√Hz, treated as white."""
    ay_bias_sigma_mps2: float = 0.3
    ay_bias_rw: float = 0.002
    """m/s²/√s."""
    ay_scale_sigma: float = 0.1
    """Prior 1σ of the residual scale error of a_y (roll gravity component left after the correction)."""
    ay_scale_rw: float = 0.002
    """1/√s."""
    roll_gain_rad_per_mps2: float = 0.0
    """Static roll gain k_φ used to take the gravity component out of a body-fixed a_y."""
    accel_xy: tuple[float, float] = (0.0, 0.0)
    """Accelerometer position from the CG (m)."""
    beta_rate_density: float = 0.05
    """Without a_y: sideslip-rate process noise density, rad/s/√Hz."""
    roll_rate_rel_sigma: float = 0.15
    """Relative 1σ error of the roll rate from the roll model (roll stiffness, damping and inertia of the
    profile known to ≈ 10–20 %); the a_y noise through the model is added on top."""


@dataclass(frozen=True, slots=True)
class GnssEpochs:
    """The dual-antenna observables at common GNSS epochs (t in s, angles in rad)."""

    t: FloatArray
    baseline_azimuth: FloatArray
    """Azimuth of the vector B → A, clockwise from north."""
    baseline_length: FloatArray
    """Measured antenna separation (m, 3-D)."""
    velocity_east: FloatArray
    """Velocity of antenna A (m/s)."""
    velocity_north: FloatArray
    fixed_a: BoolArray
    fixed_b: BoolArray
    position_sigma_a: FloatArray | None = None
    """Optional per-epoch horizontal position σ of A (m, per axis), e.g. from BESTPOS."""
    position_sigma_b: FloatArray | None = None
    source: npt.NDArray[np.str_] | None = None
    """Optional per-epoch position source of the pair A/B (:func:`epoch_source`: ``rtk``, ``ppk``, …)."""

    def __post_init__(self) -> None:
        t = check_time("gnss.t", self.t)
        n = t.size
        for name in ("baseline_azimuth", "baseline_length", "velocity_east", "velocity_north"):
            object.__setattr__(self, name, as_1d(f"gnss.{name}", getattr(self, name), n))
        for name in ("fixed_a", "fixed_b"):
            object.__setattr__(self, name, as_bool(f"gnss.{name}", getattr(self, name), n))
        for name in ("position_sigma_a", "position_sigma_b"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, as_1d(f"gnss.{name}", v, n))
        if self.source is not None:
            src = np.asarray(self.source, dtype=np.str_)
            if src.shape != (n,):
                raise AnalysisError(f"gnss.source: expected {n} values, got shape {src.shape}")
            object.__setattr__(self, "source", src)
        object.__setattr__(self, "t", t)

    @classmethod
    def from_enu(
        cls,
        t: npt.ArrayLike,
        a_enu: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike],
        b_enu: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike],
        velocity_a_en: tuple[npt.ArrayLike, npt.ArrayLike],
        fixed_a: npt.ArrayLike | None = None,
        fixed_b: npt.ArrayLike | None = None,
    ) -> GnssEpochs:
        """From local east/north/up positions of both antennas (m) and the east/north velocity of A."""
        ea, na, ua = (np.asarray(x, dtype=float) for x in a_enu)
        eb, nb, ub = (np.asarray(x, dtype=float) for x in b_enu)
        de, dn, du = ea - eb, na - nb, ua - ub
        tt = check_time("gnss.t", t)
        return cls(
            t=tt,
            baseline_azimuth=np.asarray(wrap_2pi(np.arctan2(de, dn)), dtype=float),
            baseline_length=np.sqrt(de * de + dn * dn + du * du),
            velocity_east=np.asarray(velocity_a_en[0], dtype=float),
            velocity_north=np.asarray(velocity_a_en[1], dtype=float),
            fixed_a=as_bool("fixed_a", fixed_a, tt.size),
            fixed_b=as_bool("fixed_b", fixed_b, tt.size),
        )

    @classmethod
    def from_geodetic(
        cls,
        t: npt.ArrayLike,
        a_llh: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike],
        b_llh: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike],
        track_over_ground_rad: npt.ArrayLike,
        horizontal_speed_mps: npt.ArrayLike,
        fixed_a: npt.ArrayLike | None = None,
        fixed_b: npt.ArrayLike | None = None,
        position_sigma_a: npt.ArrayLike | None = None,
        position_sigma_b: npt.ArrayLike | None = None,
    ) -> GnssEpochs:
        """From BESTPOS (latitude, longitude in degrees, ellipsoidal height in m) of both antennas and BESTVEL of A.

        The baseline is resolved in the local east/north/up frame at antenna A at each epoch (so
        meridian convergence over a long drive does not tilt it).
        """
        lat_a, lon_a, h_a = (np.asarray(x, dtype=float) for x in a_llh)
        lat_b, lon_b, h_b = (np.asarray(x, dtype=float) for x in b_llh)
        # position of A seen from B, in the frame at B (≈ the frame at A: 1.6 m apart)
        de, dn, du = pymap3d.geodetic2enu(lat_a, lon_a, h_a, lat_b, lon_b, h_b)
        de, dn, du = (np.asarray(x, dtype=float) for x in (de, dn, du))
        trk = np.asarray(track_over_ground_rad, dtype=float)
        spd = np.asarray(horizontal_speed_mps, dtype=float)
        tt = check_time("gnss.t", t)
        return cls(
            t=tt,
            baseline_azimuth=np.asarray(wrap_2pi(np.arctan2(de, dn)), dtype=float),
            baseline_length=np.sqrt(de * de + dn * dn + du * du),
            velocity_east=spd * np.sin(trk),
            velocity_north=spd * np.cos(trk),
            fixed_a=as_bool("fixed_a", fixed_a, tt.size),
            fixed_b=as_bool("fixed_b", fixed_b, tt.size),
            position_sigma_a=None if position_sigma_a is None else as_1d("position_sigma_a", position_sigma_a),
            position_sigma_b=None if position_sigma_b is None else as_1d("position_sigma_b", position_sigma_b),
        )


@dataclass(frozen=True, slots=True)
class ImuSeries:
    """Yaw rate (rad/s, + turning left) and optional body-fixed lateral acceleration (m/s²), own time base (s)."""

    t: FloatArray
    yaw_rate: FloatArray
    ay: FloatArray | None = None

    def __post_init__(self) -> None:
        t = check_time("imu.t", self.t, min_samples=2)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "yaw_rate", as_1d("imu.yaw_rate", self.yaw_rate, t.size))
        if self.ay is not None:
            object.__setattr__(self, "ay", as_1d("imu.ay", self.ay, t.size))


# --------------------------------------------------------------------------------------------
# Position source per epoch: live RTK or post-processed (PPK)
# --------------------------------------------------------------------------------------------


class PositionSource(enum.StrEnum):
    """Which solution an antenna's position comes from at an epoch."""

    RTK = "rtk"
    """Live RTK, ambiguities fixed (NARROW_INT …)."""
    PPK = "ppk"
    """Post-processed kinematic (RTKLIB, forward/backward combined), ambiguities fixed (Q = 1)."""
    NONE = "none"
    """Neither fixed: the live solution is kept and the epoch is invalid for the reference."""


SOURCE_TEXT = {
    "rtk": "live RTK fixed on both antennas",
    "ppk": "PPK fixed on both antennas (live RTK not fixed)",
    "rtk/ppk": "live RTK on A, PPK on B (B's live RTK not fixed)",
    "ppk/rtk": "PPK on A (A's live RTK not fixed), live RTK on B",
}
"""Why an epoch's source was taken, for :meth:`ReferenceSideslip.source_summary`."""


def choose_position_source(rtk_fixed: npt.ArrayLike, ppk_fixed: npt.ArrayLike) -> npt.NDArray[np.str_]:
    """Per epoch, the better fixed solution of one antenna (:class:`PositionSource` values).

    Live RTK fixed is taken where it is (a fixed RTK position is as precise as a fixed PPK one on a
    short baseline, and keeps the reference equal to the live one); PPK fixed where live RTK is not
    (a correction dropout, a float stretch); ``none`` where neither is fixed.
    """
    rtk = np.asarray(rtk_fixed, dtype=bool)
    ppk = np.asarray(ppk_fixed, dtype=bool)
    if rtk.shape != ppk.shape:
        raise AnalysisError(f"choose_position_source: rtk_fixed {rtk.shape} and ppk_fixed {ppk.shape} differ")
    return np.where(rtk, PositionSource.RTK.value, np.where(ppk, PositionSource.PPK.value, PositionSource.NONE.value))


def epoch_source(source_a: npt.ArrayLike, source_b: npt.ArrayLike) -> npt.NDArray[np.str_]:
    """The pair's source per epoch: ``rtk`` or ``ppk`` when both antennas agree, else ``A/B`` (``rtk/ppk`` …)."""
    a = np.asarray(source_a, dtype=np.str_)
    b = np.asarray(source_b, dtype=np.str_)
    return np.where(a == b, a, np.char.add(np.char.add(a, "/"), b))


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ReferenceSideslip:
    """Reference sideslip at the CG (and at named points) on the GNSS epochs."""

    t: FloatArray
    beta: FloatArray
    """Sideslip at the CG (rad), NaN where invalid."""
    sigma: FloatArray
    """Standard uncertainty of ``beta`` (rad), NaN where invalid."""
    valid: BoolArray
    reasons: U8
    """:class:`InvalidReason` bits per epoch (0 where valid)."""
    method: ReferenceMethod
    speed: FloatArray
    """Speed over ground of the CG (m/s)."""
    yaw_rate: FloatArray
    """Yaw rate used for the lever arms (rad/s; bias-corrected by the RTS method)."""
    heading: FloatArray
    """Vehicle x-axis azimuth, clockwise from north (rad; smoothed by the RTS method)."""
    points: Mapping[str, FloatArray] = field(default_factory=dict)
    """Sideslip (rad) at each named body point, NaN where invalid."""
    coverage_factor: float = 2.0
    """k for the stated expanded uncertainty U = k·σ (≈ 95 % for a normal error)."""
    diagnostics: Mapping[str, float] = field(default_factory=dict)
    source: npt.NDArray[np.str_] | None = None
    """Per-epoch position source of antennas A/B (:func:`epoch_source`; None: live RTK only, no PPK file)."""

    def source_counts(self) -> dict[str, int]:
        """Valid epochs per position source (``{}`` without a source column)."""
        if self.source is None:
            return {}
        vals, counts = np.unique(self.source[self.valid], return_counts=True)
        return {str(v): int(c) for v, c in zip(vals, counts, strict=True)}

    def source_summary(self) -> str:
        """One line: which solution the valid epochs took, and why (empty without a source column)."""
        counts = self.source_counts()
        if self.source is None:
            return ""
        n = int(np.count_nonzero(self.valid))
        parts = [f"{c} {SOURCE_TEXT.get(k, k)}" for k, c in sorted(counts.items(), key=lambda kv: -kv[1])]
        return (f"reference positions per valid epoch ({n}): " + (", ".join(parts) if parts else "none")
                + "; live RTK fixed is taken where it is, PPK fixed (RTKLIB Q=1) where live RTK is not")

    @property
    def u95(self) -> FloatArray:
        """Expanded (≈ 95 %) uncertainty k·σ (rad)."""
        return self.coverage_factor * self.sigma

    @property
    def valid_fraction(self) -> float:
        """Fraction of epochs with a valid reference."""
        return float(np.mean(self.valid)) if self.valid.size else 0.0

    def reason_counts(self) -> dict[str, int]:
        """How many epochs each reason made invalid (an epoch may have several)."""
        return {r.name or str(int(r)): int(np.count_nonzero(self.reasons & int(r))) for r in InvalidReason}

    def to_dict(self) -> dict[str, object]:
        """JSON-able summary (no arrays; angles in degrees)."""
        ok = self.valid
        return {
            "method": str(self.method),
            "n_epochs": int(self.t.size),
            "valid_fraction": self.valid_fraction,
            "invalid_reasons": self.reason_counts(),
            "median_sigma_deg": float(np.degrees(np.median(self.sigma[ok]))) if np.any(ok) else None,
            "coverage_factor": self.coverage_factor,
            "points": sorted(self.points),
            "diagnostics": dict(self.diagnostics),
            "position_sources": self.source_counts(),
        }


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def vehicle_points(
    cg_to_front_axle_m: float,
    cg_to_rear_axle_m: float,
    track_front_m: float,
    track_rear_m: float,
    extra: Mapping[str, tuple[float, float]] | None = None,
) -> dict[str, tuple[float, float]]:
    """Axle centres and wheel centres (FL FR RL RR) relative to the CG, plus ``extra`` points."""
    a, b = cg_to_front_axle_m, cg_to_rear_axle_m
    pts = {
        "front_axle": (a, 0.0),
        "rear_axle": (-b, 0.0),
        "fl": (a, track_front_m / 2.0),
        "fr": (a, -track_front_m / 2.0),
        "rl": (-b, track_rear_m / 2.0),
        "rr": (-b, -track_rear_m / 2.0),
    }
    if extra:
        pts.update({k: (float(v[0]), float(v[1])) for k, v in extra.items()})
    return pts


def _cumulative(t: FloatArray, x: FloatArray) -> FloatArray:
    """Cumulative trapezoid integral of x over t, starting at 0."""
    inc = 0.5 * (x[1:] + x[:-1]) * np.diff(t)
    return np.concatenate(([0.0], np.cumsum(inc)))


def resample_mean(t_src: npt.ArrayLike, x: npt.ArrayLike, t_dst: npt.ArrayLike) -> FloatArray:
    """Average ``x`` (sampled at ``t_src``) over a window of one destination period centred on each ``t_dst``.

    Used to bring 1 kHz channels (optical sensor) onto the GNSS epochs without aliasing their
    noise. NaN source samples are left out; a window without samples gives NaN.
    """
    ts = check_time("t_src", t_src)
    xs = as_1d("x", x, ts.size)
    td = check_time("t_dst", t_dst)
    if td.size == 1:
        return np.asarray([np.interp(td[0], ts, xs)], dtype=float)
    half = 0.5 * np.gradient(td)
    lo = np.searchsorted(ts, td - half, side="left")
    hi = np.searchsorted(ts, td + half, side="left")
    ok = np.isfinite(xs)
    cs = np.concatenate(([0.0], np.cumsum(np.where(ok, xs, 0.0))))
    cn = np.concatenate(([0], np.cumsum(ok)))
    cnt = cn[hi] - cn[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (cs[hi] - cs[lo]) / cnt
    return np.asarray(np.where(cnt > 0, out, np.nan), dtype=float)


def _at_epochs(t_imu: FloatArray, x: FloatArray, t: FloatArray, max_gap_s: float) -> tuple[FloatArray, BoolArray]:
    """Linear interpolation of an IMU channel onto the epochs; False where no sample lies within max_gap_s."""
    ok = np.isfinite(x)
    if not np.any(ok):
        return np.full(t.size, np.nan), np.zeros(t.size, dtype=bool)
    ti, xi = t_imu[ok], x[ok]
    v = np.interp(t, ti, xi)
    # good where the epoch lies between two samples at most max_gap_s apart, or within max_gap_s / 2 of one
    j = np.searchsorted(ti, t, side="right")
    left = ti[np.clip(j - 1, 0, ti.size - 1)]
    right = ti[np.clip(j, 0, ti.size - 1)]
    inside = (j > 0) & (j < ti.size) & (right - left <= max_gap_s)
    near = np.minimum(np.abs(t - left), np.abs(right - t)) <= 0.5 * max_gap_s
    good = inside | near
    return np.asarray(np.where(good, v, np.nan), dtype=float), good


def _increments(
    t_imu: FloatArray, x: FloatArray, t: FloatArray, max_gap_s: float
) -> tuple[FloatArray, BoolArray]:
    """∫ x dt over each epoch interval [t_k, t_k+1] and whether the interval was covered by samples."""
    ok = np.isfinite(x)
    xf = np.where(ok, x, 0.0)
    cum = _cumulative(t_imu, xf)
    theta = np.interp(t, t_imu, cum)
    inc = np.diff(theta)
    # an interval is bad if it holds a missing sample, a gap in the IMU record, or lies outside it
    bad_sample = (~ok).astype(float)
    gaps = np.concatenate(([0.0], (np.diff(t_imu) > max_gap_s).astype(float)))
    cb = np.concatenate(([0.0], np.cumsum(bad_sample + gaps)))
    i0 = np.searchsorted(t_imu, t[:-1], side="left")
    i1 = np.searchsorted(t_imu, t[1:], side="right")
    covered = (cb[np.minimum(i1 + 1, cb.size - 1)] - cb[np.maximum(i0, 0)]) == 0
    covered &= (t[:-1] >= t_imu[0]) & (t[1:] <= t_imu[-1])
    return inc, covered


@dataclass(frozen=True, slots=True)
class _NoiseEstimate:
    """GNSS noise measured on the session itself (see :func:`_noise_from_data`)."""

    heading_sigma_rad: float
    gm_share: float
    tau_s: float
    velocity_sigma_mps: float
    n_baseline: int

    def to_dict(self) -> dict[str, float]:
        return {
            "data_heading_sigma_deg": math.degrees(self.heading_sigma_rad),
            "data_heading_gm_share": self.gm_share,
            "data_heading_tau_s": self.tau_s,
            "data_velocity_sigma_mps": self.velocity_sigma_mps,
            "data_n_baseline": float(self.n_baseline),
        }


def _robust_std(x: FloatArray) -> float:
    return _MAD_TO_SIGMA * float(np.median(np.abs(x - np.median(x)))) if x.size else math.nan


_MAD_TO_SIGMA = 1.482602218505602
_MIN_NOISE_SAMPLES = 40


def _acf(e: FloatArray, t: FloatArray, period: float, lags: npt.NDArray[np.int_]) -> FloatArray:
    """Sample autocorrelation of ``e`` (NaN: no sample) at ``lags`` nominal periods (NaN: too few pairs)."""
    c0 = float(np.nanmean(e * e))
    rho = np.full(lags.size, np.nan)
    for i, lag in enumerate(lags):
        if lag >= e.size:
            break
        prod = e[lag:] * e[:-lag]
        # only pairs ``lag`` nominal periods apart
        same = np.abs(t[lag:] - t[:-lag] - lag * period) < 0.25 * period
        pr = prod[same & np.isfinite(prod)]
        if pr.size >= _MIN_NOISE_SAMPLES and c0 > 0.0:
            rho[i] = float(np.mean(pr)) / c0
    return rho


def _noise_from_data(gnss: GnssEpochs, ok: BoolArray, baseline_m: float, prior_tau_s: float) -> _NoiseEstimate | None:
    """Heading and velocity noise from the session (None: too few usable epochs).

    - Heading: the relative position error of B → A along the baseline shows in the measured
      length, the one across it in the azimuth; both have the same statistics (the relative
      error is isotropic in the horizontal plane), so σ_ψ = σ(length)/L, robustly (MAD), corrected
      for the variance of the record's own mean that the scatter about it misses.
    - Its split into a first-order Gauss–Markov share a with correlation time τ and white noise: a
      least-squares fit to the length's autocorrelation (:func:`_fit_gauss_markov_acf`) when the
      record holds at least ``_MIN_FIT_SPAN_S`` of usable epochs. A shorter record holds too few
      correlation times to tell a and τ (on 20 s recorded sessions of a τ = 1 s process the fit gave
      τ from 0.2 to 18 s and a from 0.24 to 1): the heading noise is then taken as all Gauss–Markov
      with the specified ``prior_tau_s``, for a given scatter the reading with the most power at the
      low frequencies that no smoothing removes.
    - Velocity (per axis): white Doppler noise of σ gives second differences of σ·√6 while a
      car's velocity at 10–20 Hz is smooth on that scale; pooled over east and north, robustly.
    """
    t = gnss.t
    if t.size < _MIN_NOISE_SAMPLES:
        return None
    length = gnss.baseline_length
    m = ok & np.isfinite(length)
    if np.count_nonzero(m) < _MIN_NOISE_SAMPLES:
        return None
    period = float(np.median(np.diff(t)))
    resid = np.where(m, length - np.median(length[m]), np.nan)
    sig = _robust_std(resid[m])
    # reject outliers (a ±4σ window) before the autocorrelations
    use = m & (np.abs(np.nan_to_num(resid, nan=np.inf)) <= 4.0 * max(sig, 1e-9))
    e = np.where(use, resid - np.mean(resid[use]), np.nan)
    n_use = int(np.count_nonzero(use))
    max_lag = max(2, min(round(_ACF_MAX_LAG_S / period), n_use // 4))
    lags = np.arange(1, max_lag + 1)
    if n_use * period >= _MIN_FIT_SPAN_S:
        share, phi, v_mean = _fit_gauss_markov_acf(lags, [(_acf(e, t, period, lags), n_use, 1)], period)
    else:
        share, phi = 1.0, math.exp(-period / max(prior_tau_s, 1e-3))
        v_mean = ((1.0 - share) + share * (1.0 + phi) / (1.0 - phi)) / n_use
    # the record's own mean was removed: its variance (v_mean·σ²) is missing from the scatter
    sig = sig / math.sqrt(max(1.0 - v_mean, 0.25))
    tau = -period / math.log(phi)
    # velocity
    ve, vn = gnss.velocity_east, gnss.velocity_north
    d2 = []
    for v in (ve, vn):
        dd = v[2:] - 2.0 * v[1:-1] + v[:-2]
        even = np.abs(t[2:] - t[:-2] - 2.0 * period) < 0.25 * period
        dd = dd[even & ok[1:-1] & np.isfinite(dd)]
        d2.append(dd)
    dv = np.concatenate(d2)
    sig_v = _robust_std(dv) / math.sqrt(6.0) if dv.size >= _MIN_NOISE_SAMPLES else math.nan
    return _NoiseEstimate(sig / baseline_m, share, tau, sig_v, int(np.count_nonzero(m)))


_ACF_MAX_LAG_S = 4.0
_TAU_GRID_MAX_S = 20.0
_MIN_FIT_SPAN_S = 120.0
"""Usable heading epochs (s) below which the Gauss–Markov split is not fitted (:func:`_noise_from_data`)."""


def _fit_gauss_markov_acf(
    lags: npt.NDArray[np.int_], series: list[tuple[FloatArray, int, int]], period: float
) -> tuple[float, float, float]:
    """Share a and lag-1 coefficient φ of a Gauss–Markov + white noise from sample autocorrelations.

    ``series``: (ρ̂ at ``lags``, samples per fitted run n, parameters p fitted per run: 1 for a mean,
    2 for a straight line). Least squares over every lag of every series (not just lags 1 and 2, whose
    ratio φ = ρ2/ρ1 is hopelessly noisy on a short record: it gave τ = 50 s or 0.4 s for a 1 s process
    on 20 s sessions). The sample autocorrelation about a fitted mean (line) is biased low by the
    variance that fit absorbed, ≈ p·v with v = [(1 − a) + a(1 + φ)/(1 − φ)]/n the variance of a mean
    of n samples (relative to σ²); the model is ρ̂(L) = (a·φ^L − p·v)/(1 − p·v). Grid search over
    τ = −period/ln φ (half a period to 20 s) and a; returns (a, φ, v) with v for the first series.
    """
    taus = np.geomspace(0.5 * period, _TAU_GRID_MAX_S, 80)
    phis = np.exp(-period / taus)
    shares = np.linspace(0.0, 1.0, 51)
    a = shares[:, None, None]
    ph = phis[None, :, None]
    sse = np.zeros((shares.size, phis.size))
    v_first = np.zeros((shares.size, phis.size))
    used = 0
    for k, (rho, n, p) in enumerate(series):
        ok = np.isfinite(rho)
        if np.count_nonzero(ok) < 2:
            continue
        L = lags[ok].astype(float)
        v = ((1.0 - a) + a * (1.0 + ph) / (1.0 - ph)) / max(n, 1)
        pv = np.minimum(p * v, 0.75)
        model = (a * ph ** L[None, None, :] - pv) / (1.0 - pv)
        sse += np.sum((model - rho[ok][None, None, :]) ** 2, axis=2)
        if k == 0:
            v_first = v[:, :, 0]
        used += 1
    if not used:
        return 0.0, math.exp(-2.0), 0.0
    i, j = np.unravel_index(int(np.argmin(sse)), sse.shape)
    return float(shares[i]), float(phis[j]), float(v_first[i, j])


_DELAY_LAG_S = 0.5
_MAX_DELAY_S = 0.25


def _estimate_imu_delay(
    gnss: GnssEpochs, imu: ImuSeries, geometry: AntennaGeometry, ok: BoolArray, max_gap_s: float
) -> tuple[float, float]:
    """Delay d (s) of the IMU time stamps behind the GNSS epochs, and its standard error.

    If the yaw rate is stamped d late, the gyro-integrated yaw θ lags the GNSS yaw ψ by r·d, so
    over a lag L: (ψ − θ)(t+L) − (ψ − θ)(t) = d·(r(t+L) − r(t)) + b·L + noise (b the gyro bias).
    Least squares over all pairs of valid epochs L apart; d = 0 when the drive does not excite it
    (standard error above 20 ms) or the fit is outside ±0.25 s.
    """
    t = gnss.t
    m = ok & np.isfinite(gnss.baseline_azimuth)
    if np.count_nonzero(m) < _MIN_NOISE_SAMPLES or t.size < 3:
        return 0.0, math.nan
    d_theta, covered = _increments(imu.t, imu.yaw_rate, t, max_gap_s)
    theta = np.concatenate(([0.0], np.cumsum(d_theta)))
    cov_cum = np.concatenate(([0], np.cumsum(~covered)))
    r_ep, r_ok = _at_epochs(imu.t, imu.yaw_rate, t, max_gap_s)
    psi = np.asarray(azimuth_to_yaw(gnss.baseline_azimuth), dtype=float)
    e = np.full(t.size, np.nan)
    mm = m & r_ok
    if np.count_nonzero(mm) < _MIN_NOISE_SAMPLES:
        return 0.0, math.nan
    e[mm] = theta[mm] + unwrap(np.asarray(wrap_pi(psi[mm] - theta[mm]), dtype=float)) - theta[mm]
    period = float(np.median(np.diff(t)))
    lag = max(1, round(_DELAY_LAG_S / period))
    if t.size <= lag:
        return 0.0, math.nan
    de = e[lag:] - e[:-lag]
    dr = r_ep[lag:] - r_ep[:-lag]
    dt = t[lag:] - t[:-lag]
    good = np.isfinite(de) & np.isfinite(dr) & (cov_cum[lag:] == cov_cum[:-lag]) & (np.abs(dt - lag * period) < period)
    if np.count_nonzero(good) < _MIN_NOISE_SAMPLES:
        return 0.0, math.nan
    a = np.column_stack((dr[good], dt[good]))
    y = de[good]
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    # overlapping pairs are correlated over the lag: count lag-independent pairs only
    n_eff = max(float(np.count_nonzero(good)) / lag, 2.0)
    try:
        cov = np.linalg.inv(a.T @ a) * float(np.mean(res * res)) * lag
    except np.linalg.LinAlgError:
        return 0.0, math.nan
    se = math.sqrt(max(float(cov[0, 0]), 0.0))
    d = float(coef[0])
    if n_eff < 10.0 or not math.isfinite(se) or se > 0.02 or abs(d) > _MAX_DELAY_S:
        return 0.0, se
    # below a quarter of the IMU sample period the trapezoid integration itself is that uncertain
    imu_period = float(np.median(np.diff(imu.t)))
    # A fit that is merely not 3σ away from 0 is still the best estimate: on a steady circle (one turn-in
    # to excite it, σ ≈ 7 ms) zeroing an 18 ms delay left r·d ≈ 0.3° between the gyro-propagated yaw and
    # the GNSS yaw for the whole circle, which the smoother turned into heading error.
    if abs(d) < 0.25 * imu_period:
        return 0.0, se
    return d, se


@dataclass(frozen=True, slots=True)
class _RollCorrection:
    """What body roll adds to the velocity of antenna A, at the GNSS epochs (see :func:`_roll_correction`)."""

    roll: FloatArray
    """Roll angle φ (rad, + right side down)."""
    roll_rate: FloatArray
    """p = φ̇ (rad/s)."""
    roll_rate_sigma: FloatArray
    """1σ of p (rad/s)."""
    y_rolled: FloatArray
    """Lateral offset of A from the CG's x axis with roll: y cos φ − z sin φ (m)."""
    z_rolled: FloatArray
    """Height of A above the CG's x axis with roll: y sin φ + z cos φ (m)."""

    def apply(self, vx_cg: FloatArray, vy_cg: FloatArray, r: FloatArray, y_a: float) -> tuple[FloatArray, FloatArray]:
        """CG velocity from a transfer that ignored roll (lever arm (x, y) flat) → with the roll terms."""
        return vx_cg + r * (self.y_rolled - y_a), vy_cg + self.z_rolled * self.roll_rate

    def vy_sigma(self) -> FloatArray:
        """1σ of the lateral-velocity correction (m/s)."""
        return np.asarray(np.abs(self.z_rolled) * self.roll_rate_sigma, dtype=float)


def _roll_on_imu(imu: ImuSeries, model: RollModel | None) -> tuple[FloatArray, FloatArray] | None:
    """Roll angle φ and roll rate p (rad, rad/s) on the IMU time base from the roll model driven by the
    body-fixed a_y (None without a model or a_y). The model runs on a uniform grid at the IMU's median
    period (its discretisation needs one) and is interpolated back."""
    if model is None or imu.ay is None:
        return None
    ok = np.isfinite(imu.ay)
    if np.count_nonzero(ok) < 2:
        return None
    ti, ai = imu.t[ok], imu.ay[ok]
    dt = float(np.median(np.diff(ti)))
    grid = np.linspace(float(ti[0]), float(ti[-1]), max(2, int(round((ti[-1] - ti[0]) / dt)) + 1))
    # the accelerometer's reading drives the model (its small lever arm to the CG is neglected here)
    a_grid = np.interp(grid, ti, ai)
    phi_g, p_g = model.roll_and_rate_from_body_ay(grid, a_grid)
    return np.asarray(np.interp(imu.t, grid, phi_g), dtype=float), np.asarray(np.interp(imu.t, grid, p_g), dtype=float)


def _roll_correction(
    imu: ImuSeries,
    t: FloatArray,
    geometry: AntennaGeometry,
    model: RollModel | None,
    ispec: ImuSpec,
    on_imu: tuple[FloatArray, FloatArray] | None,
) -> _RollCorrection | None:
    """Roll angle and roll rate at the GNSS epochs from the roll model driven by the body-fixed a_y.

    Rigid body, ISO 8855 (x forward, y left, z up, roll p about x, + right side down): the antenna at
    r = (x, y_r, z_r) from the CG (y_r, z_r: its lever arm turned by the roll φ) moves at
    v_A = v_CG + ω × r with ω = (p, 0, r) in the yaw frame, so
    v_A,x = v_x − r·y_r and v_A,y = v_y + r·x − p·z_r (v_A,z = p·y_r, not used).
    A roof antenna 1 m above the CG sees up to ≈ 0.1 m/s of −p·z in a double lane change.
    σ_p² = (rel·p)² + N²·m²(h − h_r)²/(4·I·C): a relative model error (``ispec.roll_rate_rel_sigma``) and
    the white a_y noise (density N) through the roll filter (its noise bandwidth, closed form).
    None when there is nothing to correct (z = 0, no roll model or no a_y).
    """
    if model is None or geometry.z == 0.0 or on_imu is None:
        return None
    phi = np.interp(t, imu.t, on_imu[0])
    p = np.interp(t, imu.t, on_imu[1])
    mh = model.mass_kg * (model.cg_height_m - model.roll_axis_height_m)
    if model.roll_damping_nms_per_rad > 0.0:
        var_noise = ispec.ay_noise_density**2 * mh**2 / (4.0 * model.roll_inertia_kgm2 * model.roll_damping_nms_per_rad)
    else:
        var_noise = math.inf
    sig_p = np.sqrt((ispec.roll_rate_rel_sigma * p) ** 2 + var_noise)
    y, z = geometry.a_xy[1], geometry.z
    c, s = np.cos(phi), np.sin(phi)
    return _RollCorrection(
        roll=np.asarray(phi, dtype=float),
        roll_rate=np.asarray(p, dtype=float),
        roll_rate_sigma=np.asarray(sig_p, dtype=float),
        y_rolled=np.asarray(y * c - z * s, dtype=float),
        z_rolled=np.asarray(y * s + z * c, dtype=float),
    )


# --------------------------------------------------------------------------------------------
# GNSS reference
# --------------------------------------------------------------------------------------------


def reference_sideslip(
    gnss: GnssEpochs,
    imu: ImuSeries,
    geometry: AntennaGeometry,
    *,
    method: ReferenceMethod | str = ReferenceMethod.RTS,
    points: Mapping[str, tuple[float, float]] | None = None,
    gnss_spec: GnssSpec | None = None,
    imu_spec: ImuSpec | None = None,
    min_speed_mps: float = 10.0 / 3.6,
    max_imu_gap_s: float = 0.1,
    coverage_factor: float = 2.0,
    imu_delay_s: float | None = None,
    noise_from_data: bool = True,
    roll_model: RollModel | None = None,
) -> ReferenceSideslip:
    """Reference sideslip at the CG (and at ``points``) from dual-antenna GNSS and the yaw rate.

    ``imu_delay_s``: how much later the IMU (CAN sensor cluster) time stamps are than the motion
    they describe (sensor filter and CAN output latency); None estimates it from the data
    (:func:`_estimate_imu_delay`), 0 takes the stamps as they are. ``noise_from_data``: the
    GNSS noise comes from the session itself (:func:`_noise_from_data`: heading noise from the
    scatter of the measured baseline length, velocity noise from the high-frequency scatter of
    the velocity) instead of ``gnss_spec`` and the receiver-reported σ; ``gnss_spec`` stays the
    fallback where the data are too few. ``roll_model``: with the antenna height ``geometry.z`` and
    a body-fixed a_y in ``imu``, the lateral velocity that body roll gives antenna A is removed
    (:func:`_roll_correction`) and its uncertainty added to the course measurement noise.

    Raises:
        AnalysisError: bad arrays, an unknown method, or no valid epoch at all.
    """
    try:
        meth = ReferenceMethod(method)
    except ValueError as exc:
        raise AnalysisError(f"unknown reference method {method!r} (raw, wavelet, rts)") from exc
    gspec = gnss_spec or GnssSpec()
    ispec = imu_spec or ImuSpec()
    t = gnss.t
    n = t.size

    speed_a = np.hypot(gnss.velocity_east, gnss.velocity_north)
    course_az = np.asarray(wrap_2pi(np.arctan2(gnss.velocity_east, gnss.velocity_north)), dtype=float)
    heading_az = apply_mount_offset(gnss.baseline_azimuth, geometry.mount_offset_rad)
    r_ep, r_ok = _at_epochs(imu.t, imu.yaw_rate, t, max_imu_gap_s)

    reasons = np.zeros(n, dtype=np.uint8)
    missing = ~(
        np.isfinite(gnss.baseline_azimuth)
        & np.isfinite(gnss.baseline_length)
        & np.isfinite(gnss.velocity_east)
        & np.isfinite(gnss.velocity_north)
    )
    with np.errstate(invalid="ignore"):
        low = speed_a < min_speed_mps
        off = np.abs(gnss.baseline_length - geometry.baseline_length_m) > geometry.baseline_tolerance_m
    reasons[missing] |= np.uint8(InvalidReason.NO_DATA)
    reasons[low & ~missing] |= np.uint8(InvalidReason.LOW_SPEED)
    reasons[~gnss.fixed_a] |= np.uint8(InvalidReason.A_NOT_FIXED)
    reasons[~gnss.fixed_b] |= np.uint8(InvalidReason.B_NOT_FIXED)
    reasons[off & ~missing] |= np.uint8(InvalidReason.BASELINE_LENGTH)
    reasons[~r_ok] |= np.uint8(InvalidReason.NO_YAW_RATE)
    valid = reasons == 0
    if not np.any(valid):
        raise AnalysisError(f"reference sideslip: no valid epoch among {n} ({_reason_text(reasons)})")

    diagnostics: dict[str, float] = {}
    heading_ok = valid | (reasons == int(InvalidReason.LOW_SPEED))
    if imu_delay_s is None:
        delay, delay_se = _estimate_imu_delay(gnss, imu, geometry, heading_ok, max_imu_gap_s)
    else:
        delay, delay_se = float(imu_delay_s), math.nan
    diagnostics["imu_delay_s"] = delay
    diagnostics["imu_delay_se_s"] = delay_se
    if delay != 0.0:
        # the IMU samples describe the motion ``delay`` before their time stamps
        imu = ImuSeries(imu.t - delay, imu.yaw_rate, imu.ay)
        r_ep, r_ok = _at_epochs(imu.t, imu.yaw_rate, t, max_imu_gap_s)
        bad_r = ~r_ok & ((reasons & np.uint8(InvalidReason.NO_YAW_RATE)) == 0)
        reasons[bad_r] |= np.uint8(InvalidReason.NO_YAW_RATE)
        reasons[r_ok] &= np.uint8(~int(InvalidReason.NO_YAW_RATE) & 0xFF)
        valid = reasons == 0
        if not np.any(valid):
            raise AnalysisError(f"reference sideslip: no valid epoch among {n} ({_reason_text(reasons)})")

    # position σ per antenna per axis → heading σ (cross-baseline components of both errors)
    # (receiver-reported σ, when given, describe each antenna alone: scale them to the relative part)
    est = None
    if noise_from_data:
        est = _noise_from_data(gnss, heading_ok, geometry.baseline_length_m, gspec.baseline_tau_s)
    gm_share = 1.0
    if est is not None:
        sig_heading = np.full(n, est.heading_sigma_rad)
        gm_share = est.gm_share
        gspec = replace(gspec, relative_tau_s=est.tau_s, heading_white_sigma_rad=gspec.heading_white_sigma_rad,
                        velocity_sigma_mps=est.velocity_sigma_mps if math.isfinite(est.velocity_sigma_mps)
                        else gspec.velocity_sigma_mps)
        diagnostics.update(est.to_dict())
    else:
        rel = gspec.baseline_sigma_m / gspec.position_sigma_m if gspec.position_sigma_m > 0 else 1.0
        sp_a = (gnss.position_sigma_a * rel if gnss.position_sigma_a is not None
                else np.full(n, gspec.baseline_sigma_m))
        sp_b = (gnss.position_sigma_b * rel if gnss.position_sigma_b is not None
                else np.full(n, gspec.baseline_sigma_m))
        sig_heading = np.sqrt(sp_a**2 + sp_b**2) / geometry.baseline_length_m
    with np.errstate(divide="ignore", invalid="ignore"):
        sig_course = gspec.velocity_sigma_mps / speed_a

    roll_imu = _roll_on_imu(imu, roll_model)
    roll = _roll_correction(imu, t, geometry, roll_model, ispec, roll_imu)
    diagnostics["roll_corrected"] = 0.0 if roll is None else 1.0
    if roll is not None:
        diagnostics["max_roll_rate_deg_s"] = math.degrees(float(np.max(np.abs(roll.roll_rate))))
        diagnostics["max_roll_vy_mps"] = float(np.max(np.abs(roll.z_rolled * roll.roll_rate)))

    # raw β at A and at the CG
    beta_a = np.asarray(sideslip_from_azimuths(heading_az, course_az), dtype=float)
    vx_a, vy_a = speed_a * np.cos(beta_a), speed_a * np.sin(beta_a)

    if meth is ReferenceMethod.RTS:
        beta_cg, sigma, r_used, psi, speed_cg, rts_diag = _rts_reference(
            gnss, imu, geometry, gspec, ispec, reasons, speed_a, r_ep, sig_heading, max_imu_gap_s, gm_share, roll,
            roll_imu,
        )
        diagnostics.update(rts_diag)
        heading_out = np.asarray(yaw_to_azimuth(psi), dtype=float)
    else:
        vx_cg, vy_cg = transfer_velocity(vx_a, vy_a, r_ep, geometry.a_xy, (0.0, 0.0))
        if roll is not None:
            vx_cg, vy_cg = roll.apply(vx_cg, vy_cg, r_ep, geometry.a_xy[1])
            with np.errstate(divide="ignore", invalid="ignore"):
                sig_course = np.sqrt(sig_course**2 + (roll.vy_sigma() / speed_a) ** 2)
        beta_raw = np.asarray(sideslip_from_velocity(vx_cg, vy_cg), dtype=float)
        speed_cg = np.hypot(vx_cg, vy_cg)
        sig_raw = np.sqrt(sig_heading**2 + sig_course**2)
        r_used = r_ep
        heading_out = heading_az
        if meth is ReferenceMethod.RAW:
            beta_cg, sigma = beta_raw, sig_raw
        else:
            # bootstrap with the specified noise (the residual would miss slow, correlated baseline noise)
            period = float(np.median(np.diff(t))) if n > 1 else 1.0
            phi_h = math.exp(-period / gspec.baseline_tau_s) if gspec.baseline_tau_s > 0.0 else 0.0
            wres = wavelet_denoise(
                np.where(valid, beta_raw, np.nan), noise_model=[(sig_heading, phi_h), (sig_course, 0.0)]
            )
            beta_cg = wres.x
            # segments too short to denoise keep their raw value and raw uncertainty
            sigma = np.where(np.isfinite(wres.sigma), wres.sigma, sig_raw)
            diagnostics.update({"noise_sigma_deg": math.degrees(wres.noise_sigma), "level": float(wres.level)})

    beta_cg = np.where(valid, beta_cg, np.nan)
    sigma = np.where(valid, sigma, np.nan)
    vx_cg = speed_cg * np.cos(beta_cg)
    vy_cg = speed_cg * np.sin(beta_cg)
    pts: dict[str, FloatArray] = {}
    for name, xy in (points or {}).items():
        vx_p, vy_p = transfer_velocity(vx_cg, vy_cg, r_used, (0.0, 0.0), (float(xy[0]), float(xy[1])))
        pts[name] = np.asarray(sideslip_from_velocity(vx_p, vy_p), dtype=float)
    return ReferenceSideslip(
        t=t,
        beta=beta_cg,
        sigma=sigma,
        valid=valid,
        reasons=reasons,
        method=meth,
        speed=speed_cg,
        yaw_rate=r_used,
        heading=heading_out,
        points=pts,
        coverage_factor=coverage_factor,
        diagnostics=diagnostics,
        source=gnss.source,
    )


def _reason_text(reasons: U8) -> str:
    parts = []
    for r in InvalidReason:
        c = int(np.count_nonzero(reasons & int(r)))
        if c:
            parts.append(f"{r.name}: {c}")
    return ", ".join(parts) or "none"


def _rts_reference(
    gnss: GnssEpochs,
    imu: ImuSeries,
    geometry: AntennaGeometry,
    gspec: GnssSpec,
    ispec: ImuSpec,
    reasons: U8,
    speed_a: FloatArray,
    r_ep: FloatArray,
    sig_heading: FloatArray,
    max_gap_s: float,
    gm_share: float = 1.0,
    roll: _RollCorrection | None = None,
    roll_imu: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, dict[str, float]]:
    """The two-channel smoother (module docstring). Returns β, σ, r̂, ψ̂, V_cg at the epochs, diagnostics."""
    t = gnss.t
    n = t.size
    dt = np.diff(t)

    # ---- heading channel: [ψ, b_r, e_ψ] --------------------------------------------------
    heading_bits = InvalidReason.NO_DATA | InvalidReason.A_NOT_FIXED | InvalidReason.B_NOT_FIXED
    heading_bits |= InvalidReason.BASELINE_LENGTH
    h_ok = (reasons & int(heading_bits)) == 0
    d_theta, covered = _increments(imu.t, imu.yaw_rate, t, max_gap_s)
    theta = np.concatenate(([0.0], np.cumsum(d_theta)))
    psi_meas = np.asarray(azimuth_to_yaw(apply_mount_offset(gnss.baseline_azimuth, geometry.mount_offset_rad)))
    # unwrap the GNSS yaw along the gyro-integrated yaw so that a gap cannot slip a turn
    z_h = np.full(n, np.nan)
    if np.any(h_ok):
        resid = np.asarray(wrap_pi(psi_meas[h_ok] - theta[h_ok]), dtype=float)
        z_h[h_ok] = theta[h_ok] + unwrap(resid)
    tau = max(gspec.baseline_tau_s, 1e-6)
    phi_e = np.exp(-dt / tau)
    # the heading error: a Gauss–Markov share (state e_ψ) and a white share (measurement noise)
    sig_gm = sig_heading * math.sqrt(gm_share)
    finite_sig = sig_gm[np.isfinite(sig_gm)]
    sig_e_default = math.sqrt(2.0 * gm_share) * gspec.baseline_sigma_m / geometry.baseline_length_m
    sig_e = float(np.median(finite_sig)) if finite_sig.size else sig_e_default
    sig_e_step = np.where(np.isfinite(sig_gm[1:]), sig_gm[1:], sig_e)
    q_h = np.empty((n - 1, 3))
    big = (2.0 * dt) ** 2  # an uncovered interval: up to 2 rad/s of unknown rotation
    q_h[:, 0] = np.where(
        covered,
        ispec.yaw_rate_noise_density**2 * dt + (ispec.yaw_rate_scale_sigma * d_theta) ** 2,
        big,
    )
    q_h[:, 1] = ispec.yaw_rate_bias_rw**2 * dt + 1e-18
    q_h[:, 2] = sig_e_step**2 * (1.0 - phi_e**2) + 1e-18
    first = int(np.argmax(h_ok)) if np.any(h_ok) else 0
    x0_psi = float(z_h[first]) if np.any(h_ok) else 0.0
    # the prior on ψ at epoch 0 is diffuse; referred to epoch 0 through the gyro increments
    x0_psi -= float(theta[first])
    sig_e0 = float(sig_gm[first]) if np.isfinite(sig_gm[first]) else float(sig_e)
    white_h = np.where(np.isfinite(sig_heading), sig_heading, 0.0) ** 2 * (1.0 - gm_share)
    r_h = white_h + gspec.heading_white_sigma_rad**2
    res_h = rts_smooth3(
        f01=-dt,
        f02=np.zeros(n - 1),
        f22=phi_e,
        g=np.where(covered, d_theta, 0.0),
        q=q_h,
        h2=1.0,
        z=z_h,
        r=r_h,
        x0=(x0_psi, 0.0, 0.0),
        p0=(1.0, ispec.yaw_rate_bias_sigma_rps**2, sig_e0**2),
    )
    psi = res_h.x[:, 0]
    bias = res_h.x[:, 1]
    var_psi = res_h.var[:, 0]
    r_hat = r_ep - bias
    bias_imu = np.interp(imu.t, t, bias)
    r_imu = imu.yaw_rate - bias_imu

    # ---- course channel: [ν, s_a, c_a] ----------------------------------------------------
    c, s = np.cos(psi), np.sin(psi)
    ve, vn = gnss.velocity_east, gnss.velocity_north
    vx_a = c * ve + s * vn
    vy_a = -s * ve + c * vn
    vx_cg, vy_cg = transfer_velocity(vx_a, vy_a, r_hat, geometry.a_xy, (0.0, 0.0))
    if roll is not None:
        vx_cg, vy_cg = roll.apply(vx_cg, vy_cg, r_hat, geometry.a_xy[1])
    speed_cg = np.hypot(vx_cg, vy_cg)
    beta_m = np.asarray(sideslip_from_velocity(vx_cg, vy_cg), dtype=float)
    course_bits = InvalidReason.NO_DATA | InvalidReason.LOW_SPEED | InvalidReason.A_NOT_FIXED
    course_bits |= InvalidReason.NO_YAW_RATE
    c_ok = ((reasons & int(course_bits)) == 0) & np.isfinite(beta_m)
    z_c = np.where(c_ok, psi + beta_m, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_c = np.where(c_ok, (gspec.velocity_sigma_mps / speed_a) ** 2, np.nan)
        if roll is not None:
            r_c = r_c + (roll.vy_sigma() / speed_a) ** 2
    # speed on the IMU time base (held positive; only used where the course is measured)
    v_fill = np.where(c_ok, speed_cg, np.nan)
    if np.any(c_ok):
        v_fill = np.interp(t, t[c_ok], speed_cg[c_ok])
    else:
        v_fill = np.full(n, 1.0)
    v_fill = np.maximum(v_fill, 0.5)
    v_imu = np.interp(imu.t, t, v_fill)
    inv_v = 1.0 / v_imu
    w_inc, _ = _increments(imu.t, inv_v, t, max_gap_s)
    q_c = np.empty((n - 1, 3))
    v_mid = 0.5 * (v_fill[1:] + v_fill[:-1])
    if imu.ay is not None:
        # lateral acceleration of the CG in the horizontal plane
        if roll_imu is not None:
            # the roll model's φ(t): the gravity component follows the body's roll dynamics, which lag a_y
            # in transients (≈ 0.1 m/s² at 0.7 Hz, 0.3 g) where the static gain would leave it in the course
            phi_i = roll_imu[0]
            ay = (imu.ay - G * np.sin(phi_i)) / np.cos(phi_i)
        else:
            ay = imu.ay / (1.0 + G * ispec.roll_gain_rad_per_mps2)
        rx, ry = ispec.accel_xy
        if rx or ry:
            r_dot = np.gradient(r_imu, imu.t)
            ay = ay - r_dot * rx + r_imu**2 * ry
        # a_n = (a_y − a_t sin β)/cos β, with a_t the rate of change of the GNSS speed
        a_t = np.gradient(v_fill, t)
        if n >= 5:
            a_t = np.convolve(np.pad(a_t, 2, mode="edge"), np.full(5, 0.2), mode="valid")
        beta_i = np.interp(imu.t, t, np.where(np.isfinite(beta_m), beta_m, 0.0))
        a_n = (ay - np.interp(imu.t, t, a_t) * np.sin(beta_i)) / np.cos(beta_i)
        u_inc, a_cov = _increments(imu.t, a_n * inv_v, t, max_gap_s)
        dens2 = ispec.ay_noise_density**2 + ispec.ay_model_density**2
        q_c[:, 0] = np.where(a_cov, dens2 * dt / v_mid**2, (2.0 * dt) ** 2)
        q_c[:, 1] = ispec.ay_scale_rw**2 * dt + 1e-18
        q_c[:, 2] = ispec.ay_bias_rw**2 * dt + 1e-18
        f01, f02 = np.where(a_cov, u_inc, 0.0), np.where(a_cov, w_inc, 0.0)
        g_c = np.where(a_cov, u_inc, 0.0)
        p0_c = (1.0, ispec.ay_scale_sigma**2, ispec.ay_bias_sigma_mps2**2)
    else:
        # ν̇ = r̂ + β̇ with β̇ white
        r_inc, r_cov = _increments(imu.t, r_imu, t, max_gap_s)
        q_c[:, 0] = np.where(r_cov, ispec.beta_rate_density**2 * dt, (2.0 * dt) ** 2)
        q_c[:, 1] = 1e-18
        q_c[:, 2] = 1e-18
        f01 = np.zeros(n - 1)
        f02 = np.zeros(n - 1)
        g_c = np.where(r_cov, r_inc, 0.0)
        p0_c = (1.0, 1e-6, 1e-6)
    first_c = int(np.argmax(c_ok)) if np.any(c_ok) else 0
    nu_prior = float(z_c[first_c]) if np.any(c_ok) else float(psi[0])
    # refer the prior back to epoch 0 along the prediction (diffuse anyway)
    nu_prior -= float(np.sum(g_c[:first_c]))
    res_c = rts_smooth3(
        f01=f01, f02=f02, f22=np.ones(n - 1), g=g_c, q=q_c, h2=0.0, z=z_c, r=np.where(c_ok, r_c, 1.0),
        x0=(nu_prior, 0.0, 0.0), p0=p0_c,
    )
    nu = res_c.x[:, 0]
    beta = np.asarray(wrap_pi(nu - psi), dtype=float)
    sigma = np.sqrt(res_c.var[:, 0] + var_psi)
    diagnostics = {
        "heading_nis_mean": float(np.nanmean(res_h.nis)) if np.any(np.isfinite(res_h.nis)) else math.nan,
        "course_nis_mean": float(np.nanmean(res_c.nis)) if np.any(np.isfinite(res_c.nis)) else math.nan,
        "yaw_rate_bias_deg_s": math.degrees(float(np.median(bias))),
        "ay_scale_error": float(np.median(res_c.x[:, 1])),
        "ay_bias_mps2": float(np.median(res_c.x[:, 2])),
        "median_sigma_heading_deg": math.degrees(float(np.median(np.sqrt(var_psi)))),
        "median_sigma_course_deg": math.degrees(float(np.median(np.sqrt(res_c.var[:, 0])))),
    }
    return beta, sigma, r_hat, psi, speed_cg, diagnostics


# --------------------------------------------------------------------------------------------
# Optical sensor, tyre slip, cross-check
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class OpticalSideslip:
    """Sideslip at the CG from an optical sensor (rad), on the sensor's (or a resampled) time base."""

    t: FloatArray
    beta: FloatArray
    sigma: FloatArray
    valid: BoolArray
    sensor: str = "optical"


def optical_sideslip(
    t: npt.ArrayLike,
    vx_mps: npt.ArrayLike,
    vy_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    sensor_xy_m: tuple[float, float],
    *,
    zero_rad: float = 0.0,
    min_speed_mps: float = 10.0 / 3.6,
    valid: npt.ArrayLike | None = None,
    sigma_rad: float = math.radians(0.1),
    sensor: str = "optical",
) -> OpticalSideslip:
    """Move a body-mounted optical sensor's velocity (vehicle axes, zero-corrected) to the CG.

    ``zero_rad`` is the calibrated slip zero (:func:`calibration.mount.estimate_optical_zero`);
    the corrected slip is measured − zero. The yaw rate must be on the same time base. A sensor
    that reports slip angle and speed instead of vx, vy: pass speed·cos α and speed·sin α.
    """
    tt = check_time("optical.t", t)
    n = tt.size
    vx0, vy0 = as_1d("optical.vx", vx_mps, n), as_1d("optical.vy", vy_mps, n)
    r = as_1d("optical.yaw_rate", yaw_rate_rps, n)
    vx, vy = apply_optical_zero(vx0, vy0, zero_rad)
    vx_cg, vy_cg = transfer_velocity(vx, vy, r, sensor_xy_m, (0.0, 0.0))
    beta = np.asarray(sideslip_from_velocity(vx_cg, vy_cg), dtype=float)
    ok = as_bool("optical.valid", valid, n) & np.isfinite(beta) & (np.hypot(vx_cg, vy_cg) >= min_speed_mps)
    return OpticalSideslip(
        t=tt,
        beta=np.where(ok, beta, np.nan),
        sigma=np.where(ok, sigma_rad, np.nan),
        valid=ok,
        sensor=sensor,
    )


def tyre_slip_angles(
    ref: ReferenceSideslip,
    steer_rad: Mapping[str, npt.ArrayLike | float],
) -> dict[str, FloatArray]:
    """Tyre slip angle α = β_wheel − δ_wheel (rad) at each wheel point of ``ref``.

    ``steer_rad`` maps a wheel point name (as given to :func:`reference_sideslip`'s ``points``) to
    its road-wheel angle on ``ref.t`` (rad, + left); wheels not in the map (rear) have δ = 0. With
    ISO 8855 signs the lateral tyre force is about −C·α.
    """
    out: dict[str, FloatArray] = {}
    for name, beta_w in ref.points.items():
        delta = as_1d(f"steer_rad[{name!r}]", steer_rad.get(name, 0.0), ref.t.size)
        out[name] = np.asarray(wrap_pi(beta_w - delta), dtype=float)
    return out


@dataclass(frozen=True, slots=True)
class CrossCheck:
    """Agreement of two sideslip references on common epochs."""

    n_compared: int
    mean_diff_rad: float
    rms_diff_rad: float
    max_abs_diff_rad: float
    fraction_disagree: float
    """Fraction of compared epochs where |Δ| > k·√(σ_a² + σ_b²)."""
    coverage_factor: float
    segments: tuple[tuple[float, float], ...]
    """(t_start, t_stop) in s of runs of disagreement at least ``min_segment_s`` long."""

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (angles in degrees)."""
        return {
            "n_compared": self.n_compared,
            "mean_diff_deg": math.degrees(self.mean_diff_rad),
            "rms_diff_deg": math.degrees(self.rms_diff_rad),
            "max_abs_diff_deg": math.degrees(self.max_abs_diff_rad),
            "fraction_disagree": self.fraction_disagree,
            "coverage_factor": self.coverage_factor,
            "segments_s": [list(s) for s in self.segments],
        }


def cross_check(
    t: npt.ArrayLike,
    beta_a: npt.ArrayLike,
    sigma_a: npt.ArrayLike,
    beta_b: npt.ArrayLike,
    sigma_b: npt.ArrayLike,
    *,
    coverage_factor: float = 2.0,
    min_segment_s: float = 0.5,
) -> CrossCheck:
    """Compare two references on the same epochs (e.g. GNSS and optical at the CG, or at a wheel).

    Raises:
        AnalysisError: no common valid epoch.
    """
    tt = check_time("t", t)
    n = tt.size
    a, b = as_1d("beta_a", beta_a, n), as_1d("beta_b", beta_b, n)
    sa, sb = as_1d("sigma_a", sigma_a, n), as_1d("sigma_b", sigma_b, n)
    d = np.asarray(wrap_pi(a - b), dtype=float)
    u = coverage_factor * np.sqrt(sa**2 + sb**2)
    ok = np.isfinite(d) & np.isfinite(u)
    if not np.any(ok):
        raise AnalysisError("cross_check: the two references have no common valid epoch")
    bad = np.zeros(n, dtype=bool)
    bad[ok] = np.abs(d[ok]) > u[ok]
    period = float(np.median(np.diff(tt))) if n > 1 else 0.0
    segs = tuple(
        (float(tt[i]), float(tt[j - 1]))
        for i, j in runs(bad)
        if (j - i) * period >= min_segment_s
    )
    dd = d[ok]
    return CrossCheck(
        n_compared=int(dd.size),
        mean_diff_rad=float(np.mean(dd)),
        rms_diff_rad=float(np.sqrt(np.mean(dd * dd))),
        max_abs_diff_rad=float(np.max(np.abs(dd))),
        fraction_disagree=float(np.count_nonzero(bad) / dd.size),
        coverage_factor=coverage_factor,
        segments=segs,
    )
