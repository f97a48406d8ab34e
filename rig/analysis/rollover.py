"""Rollover index: lateral load-transfer ratio (LTR) and its prediction 1–3 s ahead (AR, ARX, physics-informed).

LTR = (F_z,right − F_z,left) / ΣF_z, positive when the right wheels carry more (a left turn);
|LTR| = 1 means one side has lifted. From the roll-plane moment balance about the track centre
line on the ground, with the body rolling by φ about a roll axis at height h_r:

    (F_R − F_L)·t/2 = m·a_y·h + m·g·(h − h_r)·sin φ
    LTR = (2 / t)·(h·a_y / g + (h − h_r)·sin φ)

with h the CG height, t the track width (mean of front and rear), a_y the lateral acceleration
of the CG in the horizontal plane (a body-fixed accelerometer reads a_y·cos φ + g·sin φ;
:func:`horizontal_ay` undoes that) and φ positive right side down (ISO 8855). The unsprung
masses are neglected. In fast transients the body's roll inertia carries part of the moment:
with the roll acceleration φ̈ and the body's roll inertia I_x about the roll axis, the springs
and dampers (hence the wheels) see I_x·φ̈ less, LTR −= 2·I_x·φ̈ / (m·g·t) (optional).

Roll angle without a roll sensor (:class:`RollModel`): the body rolls about the roll axis under
the specific force its suspended mass feels, which is exactly what a body-fixed lateral
accelerometer reads (a_m = a_y cos φ + g sin φ):

    I_φ·φ̈ + C_φ·φ̇ + K_φ·φ = m·(h − h_r)·a_m

so φ follows from a_m through this linear second-order filter (roll stiffness, damping and
inertia from the vehicle profile); the static roll gain is k_φ = m(h − h_r) / (K_φ − m g (h − h_r)).

Prediction (:func:`predict_ltr`): the LTR record is resampled to ``rate_hz``; on a sliding
window of the last ``window_s`` (growing from ``min_window_s`` at the start) a model is refitted
every ``refit_every_s`` and iterated forward 1, 2 and 3 s. Three models:

- ``ar`` (the classic method): an autoregressive model of the LTR's *increments* (an
  ARIMA(p, 1, 0): a held LTR stays held instead of decaying to the window's mean), its order
  chosen by AIC (as statsmodels ``ar_select_order`` does it; a NumPy re-implementation by
  default for speed, checked against it). It only extrapolates the LTR's own past, so it cannot
  know where the LTR will settle after a steering input.
- ``arx`` (with ``exogenous``): y[k] = Σ a_i·y[k−i] + Σ b_j·u[k−j] on the LTR levels, with the
  exogenous input u the *steady-state LTR demand* of the steering at the current speed
  (:class:`LtrDemandModel`: single-track steady state a_y = v²·δ/(l + K·v²), saturated smoothly
  at μ·g, turned into LTR with the formula above); the orders (n_a ≥ 1, n_b ≥ 0) are chosen
  jointly by AIC. The steering-wheel angle leads the LTR through the tyre and roll dynamics,
  which the fitted a_i, b_j capture; the fit's steady-state gain Σb/(1 − Σa) is held within
  ``_ARX_GAIN_RANGE`` (the demand already is the physical steady state). Forecast: the steering
  is held at its current value (a driver's next input is not known) and the speed extrapolated
  with the measured longitudinal acceleration, so the demand falls as a coasting car slows down.

- ``physics`` (with ``exogenous.vehicle``, the default of ``rig rollover``): the vehicle itself, as a
  model (:class:`VehicleLtrModel`: nonlinear single-track with magic-formula tyres, roll and per-wheel
  loads, from the vehicle profile) tracks the record driven by the measured SWA and speed, and is
  propagated from each epoch over the horizon with the steering held and the driver's longitudinal
  force held; the offset between the measured and the model LTR at the epoch is added, fading with
  ``BIAS_TIME_S``. It is the held-steering floor below computed with the profile's vehicle instead of
  the true one: close to that floor and better than the AR and ARX models at every horizon
  (``benchmarks/study_rollover_prediction.py`` prints the figures).

A fit with a root at or beyond ``_MAX_ROOT`` is rejected in favour of holding the current value
until the next refit. Predictions are clipped to [−1, 1], the physical range.

Warnings: the condition is |LTR| or any |prediction| ≥ ``threshold`` (0.9); a warning is raised only
once the condition has held for ``CONFIRM_S`` = 0.25 s (5 epochs at 20 Hz: raised at the fifth), and
lasts while it holds. A single-sample crossing (a sensor glitch, a one-epoch prediction spike when
the steering starts the low-speed circles) raises nothing; a real one is warned of 0.2 s later than
its first epoch, which the physics predictor's foresight (about 1 s on a J-turn at 0.9) more than pays.

How good can any prediction be? The next steering input of a driver is unknown, so a causal
predictor's error has a floor: on the NHTSA fishhook the counter-steer (0.45 s after the steer
starts) and the return to centre come after most predictions are issued.
``benchmarks/study_rollover_prediction.py`` measures that floor with the simulator itself (the
true vehicle with the steering held from each issue time) next to the AR and ARX figures.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt
from statsmodels.tsa.ar_model import ar_select_order

from rig.analysis.arrays import as_1d, check_time, runs
from vsccore.angles import FloatArray
from vsccore.errors import AnalysisError

__all__ = [
    "CONFIRM_S",
    "LtrDemandModel",
    "LtrExogenous",
    "LtrPrediction",
    "PredictionError",
    "RollModel",
    "VehicleLtrModel",
    "confirmed",
    "horizontal_ay",
    "ltr_from_lateral",
    "predict_ltr",
    "prediction_errors",
]

G = 9.80665
_MAX_ROOT = 0.98
"""Largest modulus of the increments' AR roots accepted (closer to 1 is a near-integrated, runaway forecast)."""
_MAX_ROOT_ARX = 0.995
"""Largest modulus of the ARX's AR roots accepted (levels: the LTR must settle on the input, not drift)."""
_ARX_GAIN_RANGE = (0.7, 1.3)
"""Steady-state gain demand → LTR allowed to a fit (the demand model is within a few per cent of the true
steady state in the linear range, ≈ 7 % high at the tyre limit); fits outside are scaled to the bound.
Without it, fits on a window caught mid-transient claimed gains of 1.4–5 and predicted |LTR| ≥ 0.9
where the true peak was 0.76 (sine with dwell, J-turn: false rollover warnings)."""


def horizontal_ay(ay_body_mps2: npt.ArrayLike, roll_rad: npt.ArrayLike) -> FloatArray:
    """Lateral acceleration in the horizontal plane from a body-fixed accelerometer: (a_m − g sin φ) / cos φ."""
    a = np.asarray(ay_body_mps2, dtype=float)
    phi = np.asarray(roll_rad, dtype=float)
    return np.asarray((a - G * np.sin(phi)) / np.cos(phi), dtype=float)


def ltr_from_lateral(
    ay_mps2: npt.ArrayLike,
    roll_rad: npt.ArrayLike,
    *,
    cg_height_m: float,
    roll_axis_height_m: float,
    track_m: float,
    roll_accel_rps2: npt.ArrayLike | None = None,
    roll_inertia_kgm2: float = 0.0,
    mass_kg: float | None = None,
) -> FloatArray:
    """LTR from the horizontal lateral acceleration and the roll angle (module docstring).

    With ``roll_accel_rps2`` (e.g. the derivative of a roll rate), ``roll_inertia_kgm2`` and
    ``mass_kg`` the roll-inertia term is included.
    """
    if not (track_m > 0.0 and cg_height_m > 0.0):
        raise AnalysisError(f"ltr: track ({track_m} m) and CG height ({cg_height_m} m) must be positive")
    a = np.asarray(ay_mps2, dtype=float)
    phi = np.asarray(roll_rad, dtype=float)
    ltr = 2.0 / track_m * (cg_height_m * a / G + (cg_height_m - roll_axis_height_m) * np.sin(phi))
    if roll_accel_rps2 is not None and roll_inertia_kgm2 > 0.0:
        if mass_kg is None or not mass_kg > 0.0:
            raise AnalysisError("ltr: the roll-inertia term needs a positive mass_kg")
        ltr = ltr - 2.0 * roll_inertia_kgm2 * np.asarray(roll_accel_rps2, dtype=float) / (mass_kg * G * track_m)
    return np.asarray(ltr, dtype=float)


class VehicleRollParams(Protocol):
    """What :meth:`RollModel.from_vehicle` reads of a vehicle (SI)."""

    @property
    def mass_kg(self) -> float: ...
    @property
    def cg_height_m(self) -> float: ...
    @property
    def roll_axis_height_m(self) -> float: ...
    @property
    def roll_stiffness_front_nm_per_rad(self) -> float: ...
    @property
    def roll_stiffness_rear_nm_per_rad(self) -> float: ...
    @property
    def roll_damping_nms_per_rad(self) -> float: ...
    @property
    def roll_inertia_kgm2(self) -> float: ...


@dataclass(frozen=True, slots=True)
class RollModel:
    """Roll of the body about the roll axis (module docstring), from the vehicle profile (SI)."""

    mass_kg: float
    cg_height_m: float
    roll_axis_height_m: float
    roll_stiffness_nm_per_rad: float
    """Front + rear."""
    roll_damping_nms_per_rad: float
    roll_inertia_kgm2: float
    """Of the body about the roll axis."""

    @classmethod
    def from_vehicle(cls, v: VehicleRollParams) -> RollModel:
        """From a vehicle description with the profile's field names (``rig.core.config.VehicleConfig``,
        the simulator's ``VehicleParams``): the two axles' roll stiffnesses add."""
        return cls(
            mass_kg=v.mass_kg, cg_height_m=v.cg_height_m, roll_axis_height_m=v.roll_axis_height_m,
            roll_stiffness_nm_per_rad=v.roll_stiffness_front_nm_per_rad + v.roll_stiffness_rear_nm_per_rad,
            roll_damping_nms_per_rad=v.roll_damping_nms_per_rad, roll_inertia_kgm2=v.roll_inertia_kgm2,
        )

    def __post_init__(self) -> None:
        m_h = self.mass_kg * G * (self.cg_height_m - self.roll_axis_height_m)
        if not (self.mass_kg > 0 and self.roll_inertia_kgm2 > 0 and self.roll_damping_nms_per_rad >= 0):
            raise AnalysisError("roll model: mass and roll inertia must be positive, damping not negative")
        if not self.roll_stiffness_nm_per_rad > m_h:
            raise AnalysisError(
                f"roll model: roll stiffness {self.roll_stiffness_nm_per_rad:.0f} N·m/rad must exceed "
                f"m·g·(h − h_r) = {m_h:.0f} N·m/rad (the body would be unstable in roll)"
            )

    @property
    def roll_gain_rad_per_mps2(self) -> float:
        """Static k_φ = m(h − h_r) / (K_φ − m g (h − h_r)): roll per unit (horizontal) lateral acceleration."""
        mh = self.mass_kg * (self.cg_height_m - self.roll_axis_height_m)
        return mh / (self.roll_stiffness_nm_per_rad - mh * G)

    def roll_from_body_ay(self, t_s: npt.ArrayLike, ay_body_mps2: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Roll angle (rad) and roll acceleration (rad/s²) driven by a body-fixed lateral accelerometer.

        ``t_s`` must be uniform (resample first); the filter starts in the static state of the
        first sample. NaN samples are held at the previous value.

        Raises:
            AnalysisError: non-uniform or too short time base.
        """
        from scipy import signal

        dt, a = _uniform_held("roll_from_body_ay", t_s, ay_body_mps2)
        mh = self.mass_kg * (self.cg_height_m - self.roll_axis_height_m)
        b, d, zi1 = _discrete_filter(
            (mh,), (self.roll_inertia_kgm2, self.roll_damping_nms_per_rad, self.roll_stiffness_nm_per_rad), dt
        )
        phi = np.asarray(signal.lfilter(b, d, a, zi=zi1 * a[0])[0], dtype=float)
        # the roll equation itself gives the roll acceleration from φ, φ̇ and a_m
        phid = np.gradient(phi, dt)
        phidd = (mh * a - self.roll_damping_nms_per_rad * phid - self.roll_stiffness_nm_per_rad * phi) / (
            self.roll_inertia_kgm2
        )
        return phi, np.asarray(phidd, dtype=float)

    def roll_and_rate_from_body_ay(
        self, t_s: npt.ArrayLike, ay_body_mps2: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Roll angle (rad) and roll rate (rad/s) driven by a body-fixed lateral accelerometer.

        The roll rate is the model's own state derivative (transfer function s·m(h − h_r) / (I s² + C s + K),
        discretised like the angle), not a numerical derivative. Same time-base rules as
        :meth:`roll_from_body_ay`.

        Raises:
            AnalysisError: non-uniform or too short time base, or no finite sample.
        """
        from scipy import signal

        dt, a = _uniform_held("roll_and_rate_from_body_ay", t_s, ay_body_mps2)
        mh = self.mass_kg * (self.cg_height_m - self.roll_axis_height_m)
        den_c = (self.roll_inertia_kgm2, self.roll_damping_nms_per_rad, self.roll_stiffness_nm_per_rad)
        out = []
        for num_c in ((mh,), (mh, 0.0)):
            b, d, zi1 = _discrete_filter(num_c, den_c, dt)
            out.append(np.asarray(signal.lfilter(b, d, a, zi=zi1 * a[0])[0], dtype=float))
        return out[0], out[1]


def _uniform_held(where: str, t_s: npt.ArrayLike, ay_mps2: npt.ArrayLike) -> tuple[float, FloatArray]:
    """(dt, acceleration with NaN samples held at the previous value, leading ones at the first finite).

    Raises:
        AnalysisError: non-uniform or too short time base, or no finite sample.
    """
    t = check_time("t_s", t_s, min_samples=2)
    a = as_1d("ay_body_mps2", ay_mps2, t.size)
    dt = float(np.median(np.diff(t)))
    if np.max(np.abs(np.diff(t) - dt)) > 0.01 * dt:
        raise AnalysisError(f"{where}: the time base must be uniform (resample first)")
    ok = np.isfinite(a)
    if not np.any(ok):
        raise AnalysisError(f"{where}: no finite lateral acceleration")
    idx = np.where(ok, np.arange(a.size), 0)
    np.maximum.accumulate(idx, out=idx)
    a = a[idx]
    if not ok[0]:
        a[: int(np.argmax(ok))] = a[int(np.argmax(ok))]
    return dt, a


@functools.lru_cache(maxsize=64)
def _discrete_filter(
    num_c: tuple[float, ...], den_c: tuple[float, ...], dt: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Bilinear discretisation (b, a) of num_c/den_c at ``dt`` and its steady state for a unit input (lfilter_zi).

    Cached: the live dashboard asks for the same filter at every refresh, and each of scipy's small
    linear solves here wakes the BLAS thread pool, which then spins on the recording's other core.
    """
    from scipy import signal

    num, den, _ = signal.cont2discrete((list(num_c), list(den_c)), dt, method="bilinear")
    b = np.asarray(num, dtype=float).ravel()
    d = np.asarray(den, dtype=float).ravel()
    zi = np.asarray(signal.lfilter_zi(b, d), dtype=float)
    for arr in (b, d, zi):
        arr.setflags(write=False)
    return b, d, zi


@dataclass(frozen=True, slots=True)
class LtrDemandModel:
    """Steady-state LTR that a steering-wheel angle asks for at a speed (the ARX model's input).

    a_y = v²·δ / (l + K·v²) (single-track steady state, K the understeer gradient), saturated
    smoothly at μ·g (μ·g·tanh(a_y / μ·g): a real axle's force saturates gradually, and a hard clip
    would make the demand far too sensitive to speed at the limit); δ = SWA / ratio(SWA) with the
    steering ratio interpolated over ``ratio_swa_deg``; then LTR = (2/t)·(h·a_y/g + (h − h_r)·sin(k_φ·a_y)).
    """

    wheelbase_m: float
    understeer_gradient_rad_per_mps2: float
    peak_mu: float
    cg_height_m: float
    roll_axis_height_m: float
    track_m: float
    roll_gain_rad_per_mps2: float
    ratio_swa_deg: tuple[float, ...] = (0.0,)
    ratio: tuple[float, ...] = (16.0,)

    def __post_init__(self) -> None:
        if len(self.ratio_swa_deg) != len(self.ratio) or not self.ratio or min(self.ratio) <= 0:
            raise AnalysisError("LTR demand model: steering ratio breakpoints and positive ratios must pair up")
        if not (self.wheelbase_m > 0 and self.track_m > 0 and self.peak_mu > 0):
            raise AnalysisError("LTR demand model: wheelbase, track and μ must be positive")

    def road_wheel_angle(self, swa_rad: npt.ArrayLike) -> FloatArray:
        """δ = SWA / ratio(SWA) (rad)."""
        swa = np.asarray(swa_rad, dtype=float)
        r = np.interp(np.degrees(swa), self.ratio_swa_deg, self.ratio)
        return np.asarray(swa / r, dtype=float)

    def lateral_acceleration(self, swa_rad: npt.ArrayLike, speed_mps: npt.ArrayLike) -> FloatArray:
        """Steady-state a_y (m/s²) for the SWA at the speed, saturated smoothly at μ·g."""
        v = np.asarray(speed_mps, dtype=float)
        ay = v * v * self.road_wheel_angle(swa_rad) / (self.wheelbase_m + self.understeer_gradient_rad_per_mps2 * v * v)
        lim = self.peak_mu * G
        return np.asarray(lim * np.tanh(ay / lim), dtype=float)

    def demand(self, swa_rad: npt.ArrayLike, speed_mps: npt.ArrayLike) -> FloatArray:
        """Steady-state LTR for the SWA at the speed."""
        ay = self.lateral_acceleration(swa_rad, speed_mps)
        phi = self.roll_gain_rad_per_mps2 * ay
        return ltr_from_lateral(ay, phi, cg_height_m=self.cg_height_m, roll_axis_height_m=self.roll_axis_height_m,
                                track_m=self.track_m)


class VehicleDynamicsParams(VehicleRollParams, Protocol):
    """What :meth:`VehicleLtrModel.from_vehicle` reads of a vehicle (SI; the profile's field names):
    the roll model's parameters and these."""

    @property
    def yaw_inertia_kgm2(self) -> float: ...
    @property
    def cg_to_front_axle_m(self) -> float: ...
    @property
    def cg_to_rear_axle_m(self) -> float: ...
    @property
    def track_front_m(self) -> float: ...
    @property
    def track_rear_m(self) -> float: ...
    @property
    def cornering_stiffness_front_n_per_rad(self) -> float: ...
    @property
    def cornering_stiffness_rear_n_per_rad(self) -> float: ...
    @property
    def tyre_peak_mu(self) -> float: ...
    @property
    def tyre_shape_c(self) -> float: ...
    @property
    def tyre_curvature_e(self) -> float: ...
    @property
    def steering_ratio_swa_deg(self) -> Sequence[float]: ...
    @property
    def steering_ratio(self) -> Sequence[float]: ...


@dataclass(frozen=True, slots=True)
class _ModelState:
    """States of :class:`VehicleLtrModel` (arrays: one element per trajectory)."""

    vx: FloatArray
    vy: FloatArray
    r: FloatArray
    phi: FloatArray
    phid: FloatArray
    ax: FloatArray
    """Longitudinal acceleration of the previous step (wheel loads)."""
    ay: FloatArray
    """Lateral acceleration of the previous step (wheel loads)."""


@dataclass(frozen=True, slots=True)
class VehicleLtrModel:
    """Nonlinear single-track model with roll and per-wheel loads: the LTR a steering input leads to (SI).

    The physics-informed predictor (:func:`predict_ltr` with ``LtrExogenous.vehicle``) propagates it over
    the horizon with the steering held. Equations (ISO 8855; the classic textbook set, e.g. Rajamani,
    *Vehicle Dynamics and Control*, ch. 2 and 5):

    - planar: m(v̇_y + r·v_x) = F_yf·cos δ + F_yr,  I_z·ṙ = a·F_yf·cos δ − b·F_yr − (t_f/2)·ΔF_yf·sin δ;
      v̇_x = a_x,other − F_yf·sin δ / m + r·v_y (the front tyres' drag in a steer; ``a_x,other`` — drive,
      brakes, rolling and air resistance — is held at its value when the prediction is issued);
    - roll: I_x·φ̈ = m·h′·(a_y·cos φ + g·sin φ) − K_φ·φ − C_φ·φ̇ (h′ = h − h_r);
    - wheel loads: static + m·a_x·h/l longitudinally; per axle (m·a_y·(axle share)·h_r + K_φ,axle·φ +
      C_φ,axle·φ̇)/t laterally (dampers split like the springs), clipped at zero per wheel;
      LTR = (ΣF_z,right − ΣF_z,left)/(m·g);
    - tyres, per wheel at its load: Pacejka's magic formula F_y = −μ(F_z)·F_z·sin(C·atan(Bα − E(Bα − atan Bα))),
      B = C_α(F_z)/(C·μ·F_z), with C_α(F_z) ∝ sin(2·atan(F_z/(k·F_z0))) (the stiffness peaks at k times the
      static load) and μ(F_z) = μ₀·(1 − ε·(F_z − F_z0)/F_z0): an axle loses grip under load transfer;
    - steering: δ = ∫₀^SWA dθ / i(θ) with the ratio table i(θ) = dθ/dδ;
    - below ``kinematic_speed_mps`` (parking, steering-ratio circles) the slip-angle equations are
      ill-conditioned: the lateral states blend into the no-slip ones (r = v_x·tan δ / l, v_y = b·r).

    ``tyre_mu_load_sensitivity`` (ε) and ``tyre_stiffness_peak_load_ratio`` (k) are not in the vehicle
    profile; the defaults are typical of passenger-car tyres.
    """

    mass_kg: float
    yaw_inertia_kgm2: float
    roll_inertia_kgm2: float
    cg_to_front_axle_m: float
    cg_to_rear_axle_m: float
    track_front_m: float
    track_rear_m: float
    cg_height_m: float
    roll_axis_height_m: float
    roll_stiffness_front_nm_per_rad: float
    roll_stiffness_rear_nm_per_rad: float
    roll_damping_nms_per_rad: float
    cornering_stiffness_front_n_per_rad: float
    """Per tyre, at its static load."""
    cornering_stiffness_rear_n_per_rad: float
    """Per tyre, at its static load."""
    tyre_peak_mu: float
    tyre_shape_c: float
    tyre_curvature_e: float
    steering_ratio_swa_deg: tuple[float, ...]
    steering_ratio: tuple[float, ...]
    tyre_mu_load_sensitivity: float = 0.10
    tyre_stiffness_peak_load_ratio: float = 2.0
    kinematic_speed_mps: tuple[float, float] = (2.0, 4.0)
    """Below the first speed the lateral states are kinematic, above the second fully dynamic."""

    @classmethod
    def from_vehicle(cls, v: VehicleDynamicsParams) -> VehicleLtrModel:
        """From a vehicle description with the profile's field names (``rig.core.config.VehicleConfig``, the
        simulator's ``VehicleParams``); the two tyre constants are read too when the description has them."""
        tyre = ("tyre_mu_load_sensitivity", "tyre_stiffness_peak_load_ratio")
        extra = {name: float(getattr(v, name)) for name in tyre if hasattr(v, name)}
        return cls(
            mass_kg=v.mass_kg, yaw_inertia_kgm2=v.yaw_inertia_kgm2, roll_inertia_kgm2=v.roll_inertia_kgm2,
            cg_to_front_axle_m=v.cg_to_front_axle_m, cg_to_rear_axle_m=v.cg_to_rear_axle_m,
            track_front_m=v.track_front_m, track_rear_m=v.track_rear_m, cg_height_m=v.cg_height_m,
            roll_axis_height_m=v.roll_axis_height_m, roll_stiffness_front_nm_per_rad=v.roll_stiffness_front_nm_per_rad,
            roll_stiffness_rear_nm_per_rad=v.roll_stiffness_rear_nm_per_rad,
            roll_damping_nms_per_rad=v.roll_damping_nms_per_rad,
            cornering_stiffness_front_n_per_rad=v.cornering_stiffness_front_n_per_rad,
            cornering_stiffness_rear_n_per_rad=v.cornering_stiffness_rear_n_per_rad,
            tyre_peak_mu=v.tyre_peak_mu, tyre_shape_c=v.tyre_shape_c, tyre_curvature_e=v.tyre_curvature_e,
            steering_ratio_swa_deg=tuple(float(x) for x in v.steering_ratio_swa_deg),
            steering_ratio=tuple(float(x) for x in v.steering_ratio),
            tyre_mu_load_sensitivity=extra.get("tyre_mu_load_sensitivity", 0.10),
            tyre_stiffness_peak_load_ratio=extra.get("tyre_stiffness_peak_load_ratio", 2.0),
        )

    def __post_init__(self) -> None:
        positive = ("mass_kg", "yaw_inertia_kgm2", "roll_inertia_kgm2", "cg_to_front_axle_m", "cg_to_rear_axle_m",
                    "track_front_m", "track_rear_m", "cg_height_m", "roll_stiffness_front_nm_per_rad",
                    "roll_stiffness_rear_nm_per_rad", "cornering_stiffness_front_n_per_rad",
                    "cornering_stiffness_rear_n_per_rad", "tyre_peak_mu", "tyre_shape_c",
                    "tyre_stiffness_peak_load_ratio")
        for name in positive:
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value > 0.0):
                raise AnalysisError(f"vehicle LTR model: {name} must be positive, got {value!r}")
        if len(self.steering_ratio_swa_deg) != len(self.steering_ratio) or not self.steering_ratio:
            raise AnalysisError("vehicle LTR model: steering_ratio_swa_deg and steering_ratio must pair up")
        if min(self.steering_ratio) <= 0.0 or np.any(np.diff(self.steering_ratio_swa_deg) <= 0.0):
            raise AnalysisError("vehicle LTR model: steering ratios must be positive, their SWA breakpoints increasing")
        lo, hi = self.kinematic_speed_mps
        if not 0.0 < lo < hi:
            raise AnalysisError(f"vehicle LTR model: kinematic_speed_mps must be 0 < low < high, got {lo}, {hi}")
        h = self.mass_kg * G * (self.cg_height_m - self.roll_axis_height_m)
        if not self.roll_stiffness_front_nm_per_rad + self.roll_stiffness_rear_nm_per_rad > h:
            raise AnalysisError("vehicle LTR model: the roll stiffness must exceed m·g·(h − h_r)")

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_axle_m + self.cg_to_rear_axle_m

    def road_wheel_angle(self, swa_rad: npt.ArrayLike) -> FloatArray:
        """δ (rad) = ∫₀^SWA dθ / i(θ), the ratio i held beyond the table's ends."""
        grid, delta = _steering_table(self.steering_ratio_swa_deg, self.steering_ratio)
        return np.asarray(np.interp(np.asarray(swa_rad, dtype=float), grid, delta), dtype=float)

    def initial_state(self, speed_mps: npt.ArrayLike) -> _ModelState:
        """Straight running at the given speeds."""
        v = np.atleast_1d(np.asarray(speed_mps, dtype=float)).copy()
        z = np.zeros_like(v)
        return _ModelState(v, z.copy(), z.copy(), z.copy(), z.copy(), z.copy(), z.copy())

    def step(
        self, s: _ModelState, delta: FloatArray, dt: float, *, ax_other: FloatArray | None = None,
        ax_mps2: FloatArray | None = None,
    ) -> tuple[_ModelState, FloatArray, FloatArray]:
        """One semi-implicit Euler step of ``dt`` (s) at road-wheel angles ``delta``.

        Either ``ax_other`` (prediction: the held driver/resistance part of the longitudinal
        acceleration; v_x is integrated) or ``ax_mps2`` (tracking a record: the measured longitudinal
        acceleration; v_x is kept, the caller sets it from the measured speed). Returns (new state,
        LTR at the step's start, a_x,other = a_x + F_yf·sin δ / m at this step).
        """
        m, g = self.mass_kg, G
        a, b = self.cg_to_front_axle_m, self.cg_to_rear_axle_m
        ell = a + b
        w = m * g
        kf, kr = self.roll_stiffness_front_nm_per_rad, self.roll_stiffness_rear_nm_per_rad
        kphi = kf + kr
        cphi = self.roll_damping_nms_per_rad
        hp = self.cg_height_m - self.roll_axis_height_m
        vx, vy, r, phi, phid = s.vx, s.vy, s.r, s.phi, s.phid
        # wheel loads from the previous step's accelerations
        fzf = np.clip(w * b / ell - m * self.cg_height_m / ell * s.ax, 0.0, w)
        half_f, half_r = 0.5 * fzf, 0.5 * (w - fzf)
        d_f = np.clip((m * (b / ell) * self.roll_axis_height_m * s.ay + kf * phi + cphi * kf / kphi * phid)
                      / self.track_front_m, -half_f, half_f)
        d_r = np.clip((m * (a / ell) * self.roll_axis_height_m * s.ay + kr * phi + cphi * kr / kphi * phid)
                      / self.track_rear_m, -half_r, half_r)
        ltr = 2.0 * (d_f + d_r) / w
        avx = np.abs(vx)
        cd, sd = np.cos(delta), np.sin(delta)
        vyf = vy + a * r
        al_f = np.arctan2(vyf * cd - vx * sd, np.abs(vx * cd + vyf * sd))
        al_r = np.arctan2(vy - b * r, avx)
        fz0f, fz0r = 0.5 * w * b / ell, 0.5 * w * a / ell
        fy_fl = self._tyre(al_f, half_f - d_f, fz0f, self.cornering_stiffness_front_n_per_rad)
        fy_fr = self._tyre(al_f, half_f + d_f, fz0f, self.cornering_stiffness_front_n_per_rad)
        fy_rl = self._tyre(al_r, half_r - d_r, fz0r, self.cornering_stiffness_rear_n_per_rad)
        fy_rr = self._tyre(al_r, half_r + d_r, fz0r, self.cornering_stiffness_rear_n_per_rad)
        fyw_f = fy_fl + fy_fr
        fy_front = fyw_f * cd
        fy_rear = fy_rl + fy_rr
        mz = a * fy_front - b * fy_rear - 0.5 * self.track_front_m * (fy_fr - fy_fl) * sd
        vyd = (fy_front + fy_rear) / m - r * vx
        rd = mz / self.yaw_inertia_kgm2
        drag = fyw_f * sd / m  # the front tyres' lateral force resists the motion when steered
        if ax_other is not None:
            ax_now = ax_other - drag
        elif ax_mps2 is not None:
            ax_now = ax_mps2
        else:
            raise AnalysisError("vehicle LTR model: step needs ax_other or ax_mps2")
        ax_other_now = ax_now + drag
        vxd = ax_now + r * vy
        lo, hi = self.kinematic_speed_mps
        wdyn = np.clip((avx - lo) / (hi - lo), 0.0, 1.0)
        ay = vyd + r * vx
        phidd = (m * hp * (ay * np.cos(phi) + g * np.sin(phi)) - kphi * phi - cphi * phid) / self.roll_inertia_kgm2
        vy_n = vy + vyd * dt
        r_n = r + rd * dt
        if np.any(wdyn < 1.0):
            r_k = vx * np.tan(delta) / ell
            vy_n = wdyn * vy_n + (1.0 - wdyn) * b * r_k
            r_n = wdyn * r_n + (1.0 - wdyn) * r_k
            ay = wdyn * ay + (1.0 - wdyn) * r_k * vx
        vx_n = vx + vxd * dt if ax_other is not None else vx
        phid_n = phid + phidd * dt
        phi_n = phi + phid_n * dt
        return _ModelState(vx_n, vy_n, r_n, phi_n, phid_n, ax_now, ay), ltr, ax_other_now

    def _tyre(self, alpha: FloatArray, fz: FloatArray, fz0: float, c_alpha0: float) -> FloatArray:
        fz = np.maximum(fz, 0.0)
        k = self.tyre_stiffness_peak_load_ratio
        x0 = 1.0 / k
        norm = 2.0 * x0 / (1.0 + x0 * x0)
        mu = np.maximum(self.tyre_peak_mu * (1.0 - self.tyre_mu_load_sensitivity * (fz - fz0) / fz0),
                        0.1 * self.tyre_peak_mu)
        x = fz / (k * fz0)
        bb = c_alpha0 * 2.0 / (k * fz0) / ((1.0 + x * x) * norm * self.tyre_shape_c * mu)
        ba = bb * alpha
        e = self.tyre_curvature_e
        return np.asarray(-mu * fz * np.sin(self.tyre_shape_c * np.arctan(ba - e * (ba - np.arctan(ba)))), dtype=float)


@functools.lru_cache(maxsize=16)
def _steering_table(bp_deg: tuple[float, ...], ratio: tuple[float, ...]) -> tuple[FloatArray, FloatArray]:
    """(SWA grid, δ) in rad: δ(θ) = ∫₀^θ dθ'/i(θ') on a 0.25° grid out to ±1080° (trapezoids on a finer grid)."""
    fine = np.radians(np.arange(-1080.0, 1080.0 + 1e-9, 0.05))
    inv = 1.0 / np.interp(np.degrees(fine), bp_deg, ratio)
    cum = np.concatenate(([0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(fine))))
    cum -= np.interp(0.0, fine, cum)
    grid, delta = fine[::5].copy(), cum[::5].copy()
    grid.setflags(write=False)
    delta.setflags(write=False)
    return grid, delta


@dataclass(frozen=True, slots=True)
class LtrExogenous:
    """Inputs of the ARX and physics predictors, on the LTR's time base."""

    swa_rad: FloatArray
    speed_mps: FloatArray
    ax_mps2: FloatArray | None
    """Longitudinal acceleration for the speed extrapolation (None: the derivative of the speed)."""
    model: LtrDemandModel | None
    """The ARX model's steady-state demand (None with ``vehicle``)."""
    vehicle: VehicleLtrModel | None = None
    """With it, the physics-informed predictor is used (module docstring)."""


@dataclass(frozen=True, slots=True)
class LtrPrediction:
    """Predictions issued at each epoch ``t`` for ``t + horizon``."""

    t: FloatArray
    """Issue times (s), uniform at the prediction rate."""
    ltr: FloatArray
    """The LTR at the issue times (resampled)."""
    horizons_s: tuple[float, ...]
    predicted: FloatArray
    """(n, len(horizons)): the LTR predicted for t + horizon; NaN for the first ``min_window_s``."""
    order: npt.NDArray[np.int64]
    """AR order in use at each epoch (0: none yet)."""
    warning: npt.NDArray[np.bool_]
    """True where |LTR| or any |prediction| has reached the threshold for the confirmation time."""
    threshold: float
    model: str = "ar"
    """``ar`` (LTR alone) or ``arx`` (with the steering demand as exogenous input)."""
    input_order: npt.NDArray[np.int64] | None = None
    """ARX: number of input terms n_b in use at each epoch."""

    @property
    def warning_intervals(self) -> list[tuple[float, float]]:
        """(start, end) times (s) of the warning."""
        return [(float(self.t[a]), float(self.t[b - 1])) for a, b in runs(self.warning)]

    def first_warning_s(self) -> float | None:
        """Time of the first warning, or None."""
        i = np.flatnonzero(self.warning)
        return float(self.t[i[0]]) if i.size else None


CONFIRM_S = 0.25
"""Confirmation time of a rollover warning (s): the condition must hold this long before it is raised."""


def confirmed(raw: npt.ArrayLike, n_confirm: int) -> npt.NDArray[np.bool_]:
    """A warning condition confirmed over ``n_confirm`` samples.

    The warning is raised at the ``n_confirm``-th consecutive sample of the condition (0 or 1: at the
    first) and lasts while the condition holds; a run shorter than that (a single-sample crossing,
    a glitch) raises nothing.
    """
    r = np.asarray(raw, dtype=bool)
    out = np.zeros(r.size, dtype=bool)
    for a, b in runs(r):
        if b - a >= max(1, n_confirm):
            out[a + max(1, n_confirm) - 1 : b] = True
    return out


def _forecast(coef: FloatArray, history: FloatArray, steps: int) -> FloatArray:
    """Levels ``steps`` ahead: the last value plus the AR(p) increments Δx[k] = Σ a_i Δx[k−i] iterated forward."""
    p = coef.size
    level = float(history[-1])
    if p == 0:
        return np.full(steps, level)
    inc = list(np.diff(history)[-p:])
    out = np.empty(steps)
    for k in range(steps):
        d = float(np.dot(coef, inc[::-1]))
        level += d
        out[k] = level
        inc.append(d)
        inc.pop(0)
    return out


def _select_numpy(d: FloatArray, maxlag: int) -> tuple[FloatArray, int]:
    """AIC order selection and OLS fit of a zero-mean AR on ``d``, as statsmodels' ``ar_select_order`` does it.

    All orders 0 … maxlag are fitted on the same samples (the first ``maxlag`` held back);
    AIC = −2·llf + 2·(p + 1) with the Gaussian log-likelihood at σ² = SSR / nobs; the smallest wins.
    """
    y = d[maxlag:]
    nobs = y.size
    x_full = np.column_stack([d[maxlag - i : d.size - i] for i in range(1, maxlag + 1)])
    best_aic, best_p = math.inf, 0
    for p in range(maxlag + 1):
        coef: FloatArray
        if p == 0:
            coef = np.zeros(0)
            ssr = float(np.dot(y, y))
        else:
            sol = np.linalg.lstsq(x_full[:, :p], y, rcond=None)[0]
            coef = np.asarray(sol, dtype=np.float64)
            r = y - x_full[:, :p] @ coef
            ssr = float(np.dot(r, r))
        if ssr <= 0.0:
            return np.asarray(coef, dtype=float), p
        llf = -0.5 * nobs * (math.log(2.0 * math.pi) + math.log(ssr / nobs) + 1.0)
        aic = -2.0 * llf + 2.0 * (p + 1)
        if aic < best_aic - 1e-12:
            best_aic, best_p = aic, p
    if best_p == 0:
        return np.zeros(0), 0
    # refit the chosen order on all available samples, as statsmodels' final fit does
    y2 = d[best_p:]
    x2 = np.column_stack([d[best_p - i : d.size - i] for i in range(1, best_p + 1)])
    coef2, *_ = np.linalg.lstsq(x2, y2, rcond=None)
    return np.asarray(coef2, dtype=float), best_p


def _select_statsmodels(d: FloatArray, maxlag: int) -> tuple[FloatArray, int]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # statsmodels warns on near-singular fits of short windows
        sel = ar_select_order(d, maxlag=maxlag, ic="aic", trend="n")
        lags = sel.ar_lags or []
        if not lags:
            return np.zeros(0), 0
        res = sel.model.fit()
    order = int(max(lags))
    coef = np.zeros(order)
    for lag, value in zip(lags, np.asarray(res.params, dtype=float), strict=True):
        coef[int(lag) - 1] = float(value)
    return coef, order


def _fit(window: FloatArray, max_order: int, engine: str = "numpy") -> tuple[FloatArray, int]:
    """AR coefficients (lag 1 first) of the increments, order by AIC; none if flat or explosive.

    ``engine`` "statsmodels" uses ``ar_select_order``; "numpy" (default) the same computation
    in plain least squares, ≈ 50× faster (the tests check that both agree). A fit whose
    characteristic roots reach the unit circle would extrapolate a transient without bound: it is
    rejected and the LTR is held (persistence) until the next refit.
    """
    d = np.diff(window)
    if d.size < 4 or float(np.max(np.abs(d))) < 1e-9:
        return np.zeros(0), 0
    maxlag = int(min(max_order, max(1, d.size // 4)))
    coef, order = _select_statsmodels(d, maxlag) if engine == "statsmodels" else _select_numpy(d, maxlag)
    if order and np.any(np.abs(np.roots(np.concatenate(([1.0], -coef)))) >= _MAX_ROOT):
        return np.zeros(0), 0
    return coef, order


def _fit_arx(y: FloatArray, u: FloatArray, max_na: int, max_nb: int) -> tuple[FloatArray, FloatArray]:
    """ARX y[k] = Σ_{i=1..n_a} a_i y[k−i] + Σ_{j=0..n_b−1} b_j u[k−j] by least squares, orders by AIC.

    Every order pair (1 ≤ n_a ≤ max_na, 0 ≤ n_b ≤ max_nb) is fitted on the same samples (the first
    max(n_a, n_b − 1) held back); AIC = N·ln(SSR/N) + 2·(n_a + n_b) (the Gaussian AIC up to a
    constant), the smallest wins. The fits are solved from one Gram matrix (sub-blocks per order
    pair), so a refit costs a few microseconds. Returns (a, b); empty ``a`` when no usable fit
    exists (too short or flat window, or a root ≥ ``_MAX_ROOT_ARX``).
    """
    m = max(max_na, max_nb - 1, 1)
    n = y.size
    if n - m < 2 * (max_na + max_nb) or float(np.ptp(y)) < 1e-9:
        return np.zeros(0), np.zeros(0)
    target = y[m:]
    cols = [y[m - i : n - i] for i in range(1, max_na + 1)] + [u[m - j : n - j] for j in range(max_nb)]
    x = np.column_stack(cols)
    gram = x.T @ x
    xty = x.T @ target
    yty = float(np.dot(target, target))
    nobs = target.size
    best_aic, best = math.inf, (np.zeros(0), np.zeros(0))
    for na in range(1, max_na + 1):
        for nb in range(max_nb + 1):
            sel = list(range(na)) + list(range(max_na, max_na + nb))
            g = gram[np.ix_(sel, sel)]
            c = xty[sel]
            theta = np.linalg.lstsq(g, c, rcond=None)[0]
            ssr = yty - 2.0 * float(theta @ c) + float(theta @ g @ theta)
            aic = nobs * math.log(max(ssr, 1e-300) / nobs) + 2.0 * (na + nb)
            if aic < best_aic - 1e-9:
                best_aic, best = aic, (np.asarray(theta[:na], dtype=float), np.asarray(theta[na:], dtype=float))
    a, b = best
    if a.size and np.any(np.abs(np.roots(np.concatenate(([1.0], -a)))) >= _MAX_ROOT_ARX):
        return np.zeros(0), np.zeros(0)
    if b.size:
        # steady-state gain from the demand to the LTR: the demand already is the physical steady state,
        # so a fit on a window caught mid-transient that claims much more (or less) is not believed
        gain = float(np.sum(b)) / (1.0 - float(np.sum(a)))
        lo, hi = _ARX_GAIN_RANGE
        if not (math.isfinite(gain) and gain > 0.0):
            return np.zeros(0), np.zeros(0)
        if not lo <= gain <= hi:
            b = b * (min(max(gain, lo), hi) / gain)
    return a, b


def _forecast_arx(a: FloatArray, b: FloatArray, y: FloatArray, u: FloatArray, u_future: FloatArray) -> FloatArray:
    """Iterate the ARX forward over ``u_future`` (the input at k+1, k+2, …); hold y without a model."""
    steps = u_future.size
    if a.size == 0:
        return np.full(steps, float(y[-1]))
    na, nb = a.size, b.size
    yh = list(y[-na:])
    uh = list(u[-nb:]) if nb else []
    out = np.empty(steps)
    for s in range(steps):
        if nb:
            uh.append(float(u_future[s]))
            uh.pop(0)
        val = float(np.dot(a, yh[::-1]))
        if nb:
            val += float(np.dot(b, uh[::-1]))
        out[s] = val
        yh.append(val)
        yh.pop(0)
    return out


def predict_ltr(
    t_s: npt.ArrayLike,
    ltr: npt.ArrayLike,
    *,
    horizons_s: Sequence[float] = (1.0, 2.0, 3.0),
    rate_hz: float = 20.0,
    window_s: float = 3.0,
    min_window_s: float = 1.0,
    max_order: int = 8,
    refit_every_s: float | None = None,
    threshold: float = 0.9,
    engine: str = "numpy",
    exogenous: LtrExogenous | None = None,
    max_input_order: int = 3,
    confirm_s: float = CONFIRM_S,
    tail_s: float | None = None,
) -> LtrPrediction:
    """Predict the LTR ``horizons_s`` ahead: AR, ARX or physics-informed (module docstring).

    ``engine``: "numpy" (default, fast) or "statsmodels" (``ar_select_order``; the same result) for
    the AR model. With ``exogenous`` (arrays on ``t_s``) the ARX model is used: AR orders up to
    ``min(max_order, 3)``, input orders up to ``max_input_order``; with ``exogenous.vehicle`` the
    physics-informed predictor (the window and order settings do not apply). ``refit_every_s``:
    default 0.25 s for AR, every epoch for ARX (its fit is cheap and the input changes fast).
    ``confirm_s``: a warning is raised only once its condition has held this long (:func:`confirmed`).
    ``tail_s`` (AR model only): predict the epochs of the record's last ``tail_s`` only, the others
    NaN, with the fits the whole record would use at those epochs (so the same values); the warnings
    hold from ``confirm_s`` into the tail. A live display that shows the newest prediction passes
    ``confirm_s`` and computes a few epochs instead of the whole window.

    Raises:
        AnalysisError: malformed arrays, a record shorter than the window, or bad settings.
    """
    t_in = check_time("t_s", t_s, min_samples=2)
    x_in = as_1d("ltr", ltr, t_in.size)
    if refit_every_s is None:
        refit_every_s = 0.25 if exogenous is None else 1.0 / rate_hz
    if not (math.isfinite(confirm_s) and confirm_s >= 0.0):
        raise AnalysisError(f"predict_ltr: confirm_s must be a finite number ≥ 0 s, got {confirm_s!r}")
    if not (rate_hz > 0.0 and window_s > 0.0 and refit_every_s > 0.0 and max_order >= 1):
        raise AnalysisError("predict_ltr: rate_hz, window_s, refit_every_s must be positive and max_order ≥ 1")
    if engine not in ("numpy", "statsmodels"):
        raise AnalysisError(f"predict_ltr: engine must be 'numpy' or 'statsmodels', got {engine!r}")
    if tail_s is not None and not (math.isfinite(tail_s) and tail_s >= 0.0):
        raise AnalysisError(f"predict_ltr: tail_s must be a finite number ≥ 0 s, got {tail_s!r}")
    if tail_s is not None and exogenous is not None:
        raise AnalysisError("predict_ltr: tail_s applies to the AR model only (no exogenous inputs)")
    hs = tuple(float(h) for h in horizons_s)
    if not hs or min(hs) <= 0.0:
        raise AnalysisError(f"predict_ltr: horizons must be positive, got {hs}")
    dt = 1.0 / rate_hz
    t = np.arange(t_in[0], t_in[-1] + 0.5 * dt, dt)
    ok = np.isfinite(x_in)
    if np.count_nonzero(ok) < 2:
        raise AnalysisError("predict_ltr: fewer than two finite LTR samples")
    x = np.interp(t, t_in[ok], x_in[ok])
    w = int(round(window_s * rate_hz))
    if t.size < max(2, int(round(min_window_s * rate_hz))):
        raise AnalysisError(
            f"predict_ltr: record of {t[-1] - t[0]:.1f} s is shorter than the {min_window_s} s minimum window"
        )
    steps = [max(1, int(round(h * rate_hz))) for h in hs]
    n_ahead = max(steps)
    refit = max(1, int(round(refit_every_s * rate_hz)))
    pred = np.full((t.size, len(hs)), np.nan)
    order = np.zeros(t.size, dtype=np.int64)
    k0 = min(w, max(2, int(round(min_window_s * rate_hz)))) - 1
    if exogenous is not None and exogenous.vehicle is not None:
        in_order = None
        _predict_physics(t_in, t, x, exogenous, exogenous.vehicle, k0, steps, pred, order)
    elif exogenous is not None:
        in_order = _predict_arx(t_in, t, x, exogenous, w, k0, refit, steps, min(max_order, 3), max_input_order,
                                pred, order)
    else:
        in_order = None
        coef, p = np.zeros(0), 0
        first = k0 if tail_s is None else max(k0, int(np.searchsorted(t, t[-1] - tail_s - 1e-9 * dt)))
        fitted = -1  # the epoch of the fit in use
        for k in range(first, t.size):
            window = x[max(0, k - w + 1) : k + 1]  # grows to the full window at the start of the record
            kf = k - (k - k0) % refit  # the fit epoch of k: every refit epochs from k0
            if kf != fitted:
                coef, p = _fit(x[max(0, kf - w + 1) : kf + 1], max_order, engine)
                fitted = kf
            path = _forecast(coef, window, n_ahead)
            pred[k] = np.clip(path[[s - 1 for s in steps]], -1.0, 1.0)
            order[k] = p
    with np.errstate(invalid="ignore"):
        raw = (np.abs(x) >= threshold) | np.any(np.abs(pred) >= threshold, axis=1)
    warn = confirmed(raw, int(round(confirm_s * rate_hz)))
    return LtrPrediction(t=t, ltr=x, horizons_s=hs, predicted=pred, order=order, warning=warn, threshold=threshold,
                         model=_model_name(exogenous), input_order=in_order)


def _model_name(ex: LtrExogenous | None) -> str:
    if ex is None:
        return "ar"
    return "physics" if ex.vehicle is not None else "arx"


def _predict_arx(
    t_in: FloatArray,
    t: FloatArray,
    x: FloatArray,
    ex: LtrExogenous,
    w: int,
    k0: int,
    refit: int,
    steps: list[int],
    max_na: int,
    max_nb: int,
    pred: FloatArray,
    order: npt.NDArray[np.int64],
) -> npt.NDArray[np.int64]:
    """The ARX loop of :func:`predict_ltr` (fills ``pred`` and ``order``; returns the input orders)."""
    if ex.model is None:
        raise AnalysisError("predict_ltr: the ARX model needs the steering demand model (LtrExogenous.model)")
    swa, v, ax = _inputs_on_grid(t_in, t, ex)
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    u = ex.model.demand(swa, v)
    n_ahead = max(steps)
    ahead = dt * np.arange(1, n_ahead + 1)
    in_order = np.zeros(t.size, dtype=np.int64)
    a, b = np.zeros(0), np.zeros(0)
    pick = [s - 1 for s in steps]
    for k in range(k0, t.size):
        lo = max(0, k - w + 1)
        if (k - k0) % refit == 0:
            a, b = _fit_arx(x[lo : k + 1], u[lo : k + 1], max_na, max_nb)
        # steering held, speed extrapolated with the current longitudinal acceleration (never below 0)
        v_future = np.maximum(v[k] + ax[k] * ahead, 0.0)
        u_future = ex.model.demand(np.full(n_ahead, swa[k]), v_future)
        path = _forecast_arx(a, b, x[lo : k + 1], u[lo : k + 1], u_future)
        pred[k] = np.clip(path[pick], -1.0, 1.0)
        order[k] = a.size
        in_order[k] = b.size
    return in_order


def _inputs_on_grid(t_in: FloatArray, t: FloatArray, ex: LtrExogenous) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(SWA, speed, longitudinal acceleration) on the prediction grid; gaps interpolated."""
    n_in = t_in.size

    def on_grid(name: str, v: npt.ArrayLike) -> FloatArray:
        a = as_1d(name, v, n_in)
        ok = np.isfinite(a)
        if np.count_nonzero(ok) < 2:
            raise AnalysisError(f"predict_ltr: exogenous {name} has fewer than two finite samples")
        return np.asarray(np.interp(t, t_in[ok], a[ok]), dtype=float)

    swa = on_grid("swa_rad", ex.swa_rad)
    v = on_grid("speed_mps", ex.speed_mps)
    if ex.ax_mps2 is not None:
        ax = on_grid("ax_mps2", ex.ax_mps2)
    else:
        ax = np.gradient(v, float(t[1] - t[0])) if v.size > 1 else np.zeros_like(v)
    return swa, v, ax


_PHYSICS_SUBSTEPS = 10
"""Integration steps of the vehicle model per prediction epoch (5 ms at 20 Hz: resolves the yaw and roll modes)."""
_CHUNK_S = 4.0
_WARMUP_S = 3.0
BIAS_TIME_S = 1.5
"""Time constant with which the physics predictor's offset to the measured LTR fades over the horizon."""


def _predict_physics(
    t_in: FloatArray,
    t: FloatArray,
    x: FloatArray,
    ex: LtrExogenous,
    model: VehicleLtrModel,
    k0: int,
    steps: list[int],
    pred: FloatArray,
    order: npt.NDArray[np.int64],
) -> None:
    """The physics-informed predictor of :func:`predict_ltr` (fills ``pred``; ``order`` stays 0).

    1. The vehicle model tracks the record, driven by the measured SWA (as road-wheel angle) and speed.
    2. From its state at each epoch it is propagated over the horizon with the steering held at the
       epoch's value and the longitudinal driver/resistance force held (all epochs at once, vectorised).
    3. The model's offset to the measured LTR at the epoch, e = LTR_meas − LTR_model (unmodelled
       effects: a tyre, μ or mass that differs from the profile, a road bank), is added, fading with
       ``BIAS_TIME_S``: a standing offset persists, a transient one does not.
    """
    swa, v, ax = _inputs_on_grid(t_in, t, ex)
    dt = float(t[1] - t[0])
    h = dt / _PHYSICS_SUBSTEPS
    delta = model.road_wheel_angle(swa)
    n = t.size
    names = ("vx", "vy", "r", "phi", "phid", "ax", "ay")
    hist = {name: np.empty(n) for name in names}
    ltr_model = np.empty(n)
    ax_other = np.empty(n)
    # Tracking, in chunks run side by side (one vectorised pass instead of a scalar loop over the record):
    # each chunk starts _WARMUP_S early from straight running at the measured speed; the lateral and roll
    # modes (≈ 0.1–0.5 s) have forgotten that start by the time the chunk's own epochs begin.
    chunk = max(1, int(round(_CHUNK_S / dt)))
    warm = int(round(_WARMUP_S / dt))
    first = np.arange(0, n, chunk)
    start = np.maximum(first - warm, 0)
    stop = np.minimum(first + chunk, n)
    st = model.initial_state(v[start])
    for e in range(int(np.max(stop - start))):
        k = np.minimum(start + e, n - 1)
        st = dataclasses.replace(st, vx=v[k])
        rec = (k >= first) & (start + e < stop)
        kr = k[rec]
        for name in names:
            hist[name][kr] = getattr(st, name)[rec]
        k1 = np.minimum(k + 1, n - 1)
        for j in range(_PHYSICS_SUBSTEPS):
            f = j / _PHYSICS_SUBSTEPS
            st, l_k, axo = model.step(st, delta[k] + f * (delta[k1] - delta[k]), h,
                                      ax_mps2=ax[k] + f * (ax[k1] - ax[k]))
            if j == 0:
                ltr_model[kr] = l_k[rec]
                ax_other[kr] = axo[rec]
    idx = np.arange(k0, n)
    if idx.size == 0:
        return
    st = _ModelState(*(hist[name][idx].copy() for name in names))
    d_hold = delta[idx]
    a_hold = ax_other[idx]
    want = {s: j for j, s in enumerate(steps)}
    out = np.empty((idx.size, len(steps)))
    for s in range(1, max(steps) + 1):
        for _ in range(_PHYSICS_SUBSTEPS):
            st, l_s, _ = model.step(st, d_hold, h, ax_other=a_hold)
        if s in want:
            # the LTR at the end of step s: the loads of the next step's start
            _, l_s, _ = model.step(st, d_hold, h, ax_other=a_hold)
            out[:, want[s]] = l_s
    bias = x[idx] - ltr_model[idx]
    fade = np.exp(-np.asarray(steps, dtype=float) * dt / BIAS_TIME_S)
    pred[idx] = np.clip(out + bias[:, None] * fade[None, :], -1.0, 1.0)
    order[idx] = 0


@dataclass(frozen=True, slots=True)
class PredictionError:
    """Mean absolute prediction error at one horizon, over the epochs evaluated."""

    horizon_s: float
    mean_abs_error: float
    percent_of_peak: float
    """mean_abs_error / max |LTR| over the evaluated span, in per cent."""
    n: int


def prediction_errors(
    pred: LtrPrediction,
    t_truth_s: npt.ArrayLike,
    ltr_truth: npt.ArrayLike,
    *,
    t_start_s: float | None = None,
    t_stop_s: float | None = None,
    issued_from_s: float | None = None,
) -> list[PredictionError]:
    """Score the predictions against a true LTR record over [t_start, t_stop] (target times).

    A prediction issued at t for t + h counts when t + h lies in the span, the prediction exists
    and (with ``issued_from_s``) t ≥ issued_from_s; the peak is the largest true |LTR| in the span.

    Raises:
        AnalysisError: nothing to score.
    """
    tt = check_time("t_truth_s", t_truth_s, min_samples=2)
    lt = as_1d("ltr_truth", ltr_truth, tt.size)
    a = tt[0] if t_start_s is None else t_start_s
    b = tt[-1] if t_stop_s is None else t_stop_s
    span = (tt >= a) & (tt <= b)
    if not np.any(span):
        raise AnalysisError(f"prediction_errors: no truth sample in [{a}, {b}] s")
    peak = float(np.max(np.abs(lt[span])))
    out: list[PredictionError] = []
    for j, h in enumerate(pred.horizons_s):
        target = pred.t + h
        m = (target >= a) & (target <= b) & np.isfinite(pred.predicted[:, j]) & (target <= tt[-1])
        if issued_from_s is not None:
            m &= pred.t >= issued_from_s
        if not np.any(m):
            raise AnalysisError(f"prediction_errors: no prediction {h} s ahead lands in [{a}, {b}] s")
        truth = np.interp(target[m], tt, lt)
        mae = float(np.mean(np.abs(pred.predicted[m, j] - truth)))
        out.append(PredictionError(h, mae, 100.0 * mae / peak if peak > 0 else math.nan, int(np.count_nonzero(m))))
    return out
