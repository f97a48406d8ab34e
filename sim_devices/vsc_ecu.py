"""The simulated VSC (ESC) ECU: the car's CAN traffic, with the errors real sensors and estimators have.

From a :class:`~sim_devices.vehicle.truth.GroundTruth` it produces the messages of
``sim_devices/data/vsc_sim.dbc`` at their DBC cycle times (each message with its own phase and
a little transmit jitter), encoded as cantools encodes them (all frames of a message at once by
``drivers.can.vector_encode``: the ECU thread then only sends), with rolling counters and AUTOSAR CRC-8H2F
checksums (``drivers.can.checks``, algorithm ``vw_mqb_crc8``):

- ``ESC_SensorCluster`` (10 ms): yaw rate, lateral and longitudinal acceleration as a MEMS
  cluster gives them: first-order sensing bandwidth, output latency, constant bias, white noise,
  quantisation to the DBC resolution, quality bits set while the cluster warms up. Lateral
  acceleration is the body-fixed measurement (``ay_meas``: it contains the roll component of
  gravity) at the cluster's mounting point (plus ṙ·x).
- ``SAS_Steering`` (10 ms): steering-wheel angle with a zero offset and 0.1° resolution,
  **positive clockwise** (opposite to ISO 8855, as on many cars; the role file sets ``invert``),
  and its rate as magnitude + sign bit.
- ``ESC_WheelSpeeds`` (20 ms): from a 48-tooth encoder per wheel: tooth edges (with per-tooth
  pitch errors) are found from the integrated wheel rotation and timed with a 1 µs timer; the
  speed is the number of pitches between the first and last edge in the measurement window over
  their time, with the ECU's nominal rolling radius (the true one differs per tyre).
- ``ESC_BrakePressure`` (20 ms): the ground truth has no brake model, so the master-cylinder
  pressure follows the deceleration beyond coasting (≈ 100 bar/g) and the wheel pressures the
  proportioning valve, plus the controller's own intervention pressure (open loop: the
  simulated controller does not act on the simulated car).
- ``VSC_Status`` (20 ms) and ``VSC_Diag`` (100 ms, multiplexed): the controller's state and its
  own sideslip estimate, from :class:`SideslipEstimator` fed with the values the ECU sends.

:func:`frames` is the pure, offline form (``(t_s, can.Message)`` in time order, for writing
sessions fast); :class:`VscEcu` sends the same frames on a python-can bus in real or scaled time
on its own thread; :class:`SimulatedVscBus` gives that ECU its own virtual channel and, for other
processes, a socketcand server on 127.0.0.1 (``rig can sim-ecu`` runs one). Everything is
deterministic given ``VscEcuConfig.seed``.
"""

from __future__ import annotations

import importlib.resources
import logging
import math
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
import numpy.typing as npt
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage
from scipy.signal import lfilter

from drivers.can.checks import ChecksumAlgorithm, get_checksum
from drivers.can.controller import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_CRTL_TX_WARNING,
    CAN_ERR_RESTARTED,
    socketcan_error_frame,
)
from drivers.can.dbc import load_dbc
from drivers.can.vector_encode import MessageEncoder, SignalLayout
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from sim_devices.vehicle.truth import GroundTruth
from vsccore.clock import UNBOUNDED_NS, Clock, Participant, participant
from vsccore.errors import EncodeError, SimulationError

__all__ = [
    "DEFAULT_CHECKSUMS",
    "RUN_ON_STRETCH_S",
    "EcuOutputs",
    "EstimatorParams",
    "EstimatorStep",
    "InertialSensorErrors",
    "MessageSeries",
    "SideslipEstimator",
    "SimulatedVscBus",
    "VscEcu",
    "VscEcuConfig",
    "frames",
    "simulate_ecu",
    "vsc_sim_dbc_path",
]

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

G0 = 9.80665
_DEG = math.pi / 180.0
_KMH = 1.0 / 3.6
_BAR = 1e5

RUN_ON_STRETCH_S = 10.0
"""Seconds past the drive a running-on :class:`VscEcu` has computed ahead (then twice as far each time)."""


def vsc_sim_dbc_path() -> Path:
    """Path of the simulated car's DBC shipped as package data."""
    return Path(str(importlib.resources.files("sim_devices").joinpath("data/vsc_sim.dbc")))


DEFAULT_CHECKSUMS: Mapping[str, str] = {
    "SAS_Steering": "vw_mqb_crc8",
    "ESC_SensorCluster": "vw_mqb_crc8",
    "ESC_BrakePressure": "vw_mqb_crc8",
    "VSC_Status": "vw_mqb_crc8",
}
"""Checksum algorithm (``drivers.can.checks`` name) of each protected message of the sim DBC."""


# --- configuration -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class InertialSensorErrors:
    """Error model of one inertial channel (SI units of the channel: rad/s or m/s²)."""

    bias: float
    """Constant offset added to the output."""
    noise_std: float
    """Standard deviation of white noise on each output sample."""
    bandwidth_hz: float = 20.0
    """Corner frequency of the first-order sensing/anti-alias filter."""
    latency_s: float = 0.010
    """Delay from sensing to the CAN output."""


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """The ECU's own vehicle model and estimator tuning (its "calibration", not the true car)."""

    mass_kg: float = 1550.0
    yaw_inertia_kgm2: float = 2600.0
    cg_to_front_m: float = 1.20
    cg_to_rear_m: float = 1.60
    cornering_stiffness_front_axle_n_per_rad: float = 120_000.0
    cornering_stiffness_rear_axle_n_per_rad: float = 140_000.0
    steering_ratio: float = 16.0
    roll_gradient_rad_per_mps2: float = 0.0070
    """Roll angle per m/s² of lateral acceleration assumed to remove gravity's roll component."""
    mu: float = 1.0
    """Friction assumed to limit the reference yaw rate."""
    observer_pole_rad_s: float = 15.0
    """Both poles of the single-track observer's error dynamics at −this."""
    tau_linear_s: float = 0.3
    """Complementary-filter time constant in the linear range (model trusted)."""
    tau_limit_s: float = 4.0
    """Time constant near the limit (kinematic integration trusted: it drifts)."""
    ay_linear_mps2: float = 4.0
    ay_limit_mps2: float = 7.0
    min_speed_mps: float = 3.0
    """Below this the estimate is reset to 0 and flagged invalid."""
    standstill_mps: float = 0.2
    offset_learn_tau_s: float = 2.0
    """Time constant for learning yaw-rate and lateral-acceleration offsets at standstill."""
    intervention_yaw_error_rad_s: float = 4.0 * _DEG
    intervention_beta_rad: float = 5.0 * _DEG
    intervention_pressure_bar: float = 25.0

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_m + self.cg_to_rear_m


@dataclass(frozen=True, slots=True)
class VscEcuConfig:
    """Errors of the simulated car's sensors and the ECU's settings. Deterministic given ``seed``."""

    seed: int = 0
    yaw_rate: InertialSensorErrors = InertialSensorErrors(bias=0.25 * _DEG, noise_std=0.08 * _DEG)
    lat_accel: InertialSensorErrors = InertialSensorErrors(bias=0.05, noise_std=0.03, bandwidth_hz=15.0)
    long_accel: InertialSensorErrors = InertialSensorErrors(bias=-0.04, noise_std=0.03, bandwidth_hz=15.0)
    cluster_x_m: float = 0.0
    """Sensor-cluster position ahead of the CG (its lateral acceleration includes ṙ·x)."""
    sensor_warmup_s: float = 0.3
    """Quality bits say "substitute value" (and 0 is sent) until then."""
    swa_offset_rad: float = 0.8 * _DEG
    """Steering-angle sensor zero error (ISO sign: added to the true angle)."""
    wheel_teeth: int = 48
    wheel_timer_hz: float = 1e6
    tooth_pitch_error_std: float = 0.003
    """Per-tooth angular position error, as a fraction of the tooth pitch (fixed per wheel)."""
    wheel_window_s: float = 0.020
    """Measurement window of the edge-timing speed measurement (the message period)."""
    wheel_timeout_s: float = 0.2
    """No edge for this long, or edges further apart: speed reported 0 (the lowest measurable speed
    is one tooth pitch per timeout, 0.2 m/s here)."""
    wheel_radius_m: float = 0.31
    """Rolling radius the ECU assumes."""
    tyre_radius_error: tuple[float, float, float, float] = (0.003, -0.002, 0.0015, -0.001)
    """True rolling radius relative to the assumed one, minus 1, FL FR RL RR."""
    brake_gain_bar_per_mps2: float = 10.2
    coast_decel_mps2: float = 0.5
    rear_pressure_ratio: float = 0.85
    pressure_noise_bar: float = 0.3
    transmit_jitter_s: float = 50e-6
    """Standard deviation of each frame's transmit time around its schedule."""
    phases_s: Mapping[str, float] = field(
        default_factory=lambda: {
            "ESC_SensorCluster": 0.0005,
            "SAS_Steering": 0.0031,
            "ESC_WheelSpeeds": 0.0052,
            "ESC_BrakePressure": 0.0077,
            "VSC_Status": 0.0094,
            "VSC_Diag": 0.0413,
        }
    )
    """Offset of each message's first transmission within its period."""
    checksums: Mapping[str, str] = field(default_factory=lambda: dict(DEFAULT_CHECKSUMS))
    estimator: EstimatorParams = EstimatorParams()

    def __post_init__(self) -> None:
        if self.wheel_teeth < 4:
            raise SimulationError(f"VscEcuConfig.wheel_teeth: need at least 4, got {self.wheel_teeth}")
        if self.wheel_window_s <= 0 or self.wheel_timeout_s < self.wheel_window_s:
            raise SimulationError("VscEcuConfig: need 0 < wheel_window_s <= wheel_timeout_s")
        for name, errors in (
            ("yaw_rate", self.yaw_rate),
            ("lat_accel", self.lat_accel),
            ("long_accel", self.long_accel),
        ):
            if errors.noise_std < 0 or errors.bandwidth_hz <= 0 or errors.latency_s < 0:
                raise SimulationError(f"VscEcuConfig.{name}: need noise_std >= 0, bandwidth_hz > 0, latency_s >= 0")


# --- the sideslip estimator --------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class EstimatorStep:
    """Output of one estimator task cycle (SI, ISO 8855)."""

    beta: float
    """Blended sideslip estimate (rad)."""
    valid: bool
    beta_kinematic: float
    """Pure integration of β̇ = a_y/v − r since the last reset (rad): shows the drift."""
    beta_model: float
    """Single-track observer's sideslip (rad)."""
    tau_s: float
    yaw_rate_model: float
    """Observer's yaw rate (rad/s)."""
    yaw_rate_reference: float
    """Driver's intended yaw rate from the steady-state single-track gain (rad/s)."""
    yaw_rate_offset: float
    lat_accel_offset: float
    roll_estimate: float
    speed: float
    active: bool
    intervention: tuple[bool, bool, bool, bool]
    """Wheels braked by the controller, FL FR RL RR."""


class SideslipEstimator:
    """A simple, realistic VSC sideslip estimator, one step per 10 ms task cycle.

    - Offsets: the yaw-rate and lateral-acceleration offsets are learnt while the car stands
      still (as ECUs do); before that the raw sensor bias goes straight into the integration.
    - Kinematics: β̇ = (a_y − a_x·β)/v − r, with a_y cleared of gravity's roll component by a
      nominal roll gradient. Exact in principle, but it integrates every sensor error.
    - Model: a linear single-track (bicycle) observer driven by the road-wheel angle and
      corrected by the measured yaw rate (both error poles at −``observer_pole_rad_s``). Right in
      the linear range, wrong once the tyres saturate (it underestimates |β|).
    - Blend: β̂̇ = β̇_kin + (β_model − β̂)/τ, with τ short in the linear range and long near the
      limit (where the model is not trusted), so the estimate is good in the linear range and
      drifts near the limit, like real ones.
    """

    def __init__(self, params: EstimatorParams, dt_s: float) -> None:
        if dt_s <= 0:
            raise SimulationError(f"estimator step must be > 0 s, got {dt_s}")
        self.p = params
        self.dt = dt_s
        self.beta = 0.0
        self.beta_kin = 0.0
        self.x_beta = 0.0
        self.x_r = 0.0
        self.r_offset = 0.0
        self.ay_offset = 0.0
        self._active = False

    def _matrices(self, v: float) -> tuple[float, float, float, float, float, float]:
        p = self.p
        cf = p.cornering_stiffness_front_axle_n_per_rad
        cr = p.cornering_stiffness_rear_axle_n_per_rad
        m, iz, lf, lr = p.mass_kg, p.yaw_inertia_kgm2, p.cg_to_front_m, p.cg_to_rear_m
        a11 = -(cf + cr) / (m * v)
        a12 = (cr * lr - cf * lf) / (m * v * v) - 1.0
        a21 = (cr * lr - cf * lf) / iz
        a22 = -(cf * lf * lf + cr * lr * lr) / (iz * v)
        b1 = cf / (m * v)
        b2 = cf * lf / iz
        return a11, a12, a21, a22, b1, b2

    def step(self, yaw_rate: float, lat_accel: float, long_accel: float, swa: float, speed: float) -> EstimatorStep:
        """Advance one cycle with the measured yaw rate (rad/s), accelerations (m/s²), steering-wheel
        angle (rad, ISO sign) and reference speed (m/s)."""
        p = self.p
        dt = self.dt
        v = speed
        if v < p.standstill_mps:
            k = dt / (p.offset_learn_tau_s + dt)
            self.r_offset += k * (yaw_rate - self.r_offset)
            self.ay_offset += k * (lat_accel - self.ay_offset)
        r = yaw_rate - self.r_offset
        ay_m = lat_accel - self.ay_offset
        roll = p.roll_gradient_rad_per_mps2 * ay_m / (1.0 + G0 * p.roll_gradient_rad_per_mps2)
        ay = ay_m - G0 * math.sin(roll)
        delta = swa / p.steering_ratio
        wheelbase = p.wheelbase_m
        cf = p.cornering_stiffness_front_axle_n_per_rad
        cr = p.cornering_stiffness_rear_axle_n_per_rad
        k_us = p.mass_kg / wheelbase * (p.cg_to_rear_m / cf - p.cg_to_front_m / cr)
        if v < p.min_speed_mps:
            self.beta = self.beta_kin = self.x_beta = 0.0
            self.x_r = r
            self._active = False
            return EstimatorStep(
                0.0,
                False,
                0.0,
                0.0,
                p.tau_linear_s,
                r,
                0.0,
                self.r_offset,
                self.ay_offset,
                roll,
                v,
                False,
                (False, False, False, False),
            )
        r_ref = v * delta / (wheelbase + k_us * v * v)
        r_max = p.mu * G0 / v
        r_ref = max(-r_max, min(r_max, r_ref))

        # single-track observer, error poles placed at -w0 (double)
        a11, a12, a21, a22, b1, b2 = self._matrices(v)
        w0 = p.observer_pole_rad_s
        l2 = a11 + a22 + 2.0 * w0
        l1 = a12 - (a11 * (a22 - l2) - w0 * w0) / a21 if abs(a21) > 1e-6 else 0.0
        innovation = r - self.x_r
        d_beta = a11 * self.x_beta + a12 * self.x_r + b1 * delta + l1 * innovation
        d_r = a21 * self.x_beta + a22 * self.x_r + b2 * delta + l2 * innovation
        self.x_beta += dt * d_beta
        self.x_r += dt * d_r

        # kinematic rate, and the blend whose time constant grows towards the limit
        beta_dot_kin = (ay - long_accel * self.beta) / v - r
        share = min(max((abs(ay) - p.ay_linear_mps2) / (p.ay_limit_mps2 - p.ay_linear_mps2), 0.0), 1.0)
        tau = p.tau_linear_s + share * (p.tau_limit_s - p.tau_linear_s)
        self.beta += dt * (beta_dot_kin + (self.x_beta - self.beta) / tau)
        self.beta_kin += dt * ((ay - long_accel * self.beta_kin) / v - r)
        self.beta_kin = max(-3.0, min(3.0, self.beta_kin))

        # controller: yaw-rate error with hysteresis, brake one wheel
        error = r - r_ref
        threshold = p.intervention_yaw_error_rad_s + 0.1 * abs(r_ref)
        if self._active:
            self._active = abs(error) > 0.7 * threshold or abs(self.beta) > 0.7 * p.intervention_beta_rad
        else:
            self._active = v > 5.0 and (abs(error) > threshold or abs(self.beta) > p.intervention_beta_rad)
        wheels = (False, False, False, False)
        if self._active:
            turning_left = (r_ref if abs(r_ref) > 1e-3 else r) >= 0.0
            oversteer = abs(r) > abs(r_ref)
            if oversteer:
                wheels = (False, True, False, False) if turning_left else (True, False, False, False)
            else:
                wheels = (False, False, True, False) if turning_left else (False, False, False, True)
        return EstimatorStep(
            beta=self.beta,
            valid=True,
            beta_kinematic=self.beta_kin,
            beta_model=self.x_beta,
            tau_s=tau,
            yaw_rate_model=self.x_r,
            yaw_rate_reference=r_ref,
            yaw_rate_offset=self.r_offset,
            lat_accel_offset=self.ay_offset,
            roll_estimate=roll,
            speed=v,
            active=self._active,
            intervention=wheels,
        )


# --- sensor models -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MessageSeries:
    """Transmit times (s from the truth's start) and DBC physical values of one message."""

    name: str
    t: FloatArray
    signals: Mapping[str, FloatArray]


@dataclass(frozen=True, slots=True)
class EcuOutputs:
    """Everything the ECU sends, as arrays (before encoding), plus the estimator's inner states."""

    messages: Mapping[str, MessageSeries]
    estimator_t: FloatArray
    estimator: Mapping[str, FloatArray]
    """``beta``, ``beta_kinematic``, ``beta_model``, ``tau_s``, ``valid``, ``active`` at ``estimator_t`` (SI)."""
    t_end_s: float
    """End of the schedules (s from the truth's start): the truth's end, or later when the car runs on."""


def _quantise(x: FloatArray, lsb: float, lo: float, hi: float) -> FloatArray:
    return np.asarray(np.clip(np.round(x / lsb) * lsb, lo, hi), dtype=np.float64)


def _lowpass(x: FloatArray, dt: float, bandwidth_hz: float) -> FloatArray:
    """First-order low-pass (exact discretisation), started at the first value."""
    a = math.exp(-2.0 * math.pi * bandwidth_hz * dt)
    y = lfilter([1.0 - a], [1.0, -a], x - x[0]) + x[0]
    return np.asarray(y, dtype=np.float64)


def _schedule(period: float, phase: float, t_end: float, jitter: float, rng: np.random.Generator) -> FloatArray:
    n = math.floor((t_end - phase) / period) + 1
    if n <= 0:
        return np.zeros(0)
    t = phase + period * np.arange(n, dtype=np.float64)
    if jitter > 0:
        t = t + np.clip(rng.normal(0.0, jitter, n), -0.2 * period, 0.2 * period)
    t = np.maximum(t, 0.0)
    return np.asarray(np.maximum.accumulate(t), dtype=np.float64)


def _signal_limits(message: DbcMessage, name: str) -> tuple[float, float, float]:
    sig = message.get_signal_by_name(name)
    lsb = float(sig.scale)
    lo = sig.minimum if sig.minimum is not None else -math.inf
    hi = sig.maximum if sig.maximum is not None else math.inf
    return lsb, float(lo), float(hi)


def _wheel_edges(t: FloatArray, angle: FloatArray, teeth: int, pitch_errors: FloatArray, timer_hz: float) -> FloatArray:
    """Times of the encoder's tooth edges from the wheel's cumulative rotation angle (rad)."""
    pitch = 2.0 * math.pi / teeth
    angle = np.maximum.accumulate(angle)
    k0 = math.ceil(angle[0] / pitch)
    k1 = math.floor(angle[-1] / pitch)
    if k1 < k0:
        return np.zeros(0)
    k = np.arange(k0, k1 + 1)
    edge_angles = (k + pitch_errors[np.mod(k, teeth)]) * pitch
    inside = (edge_angles >= angle[0]) & (edge_angles <= angle[-1])
    edges = np.interp(edge_angles[inside], angle, t)
    edges = np.round(edges * timer_hz) / timer_hz
    return np.asarray(np.maximum.accumulate(edges), dtype=np.float64)


def _wheel_speed_measurement(edges: FloatArray, t_meas: FloatArray, cfg: VscEcuConfig) -> FloatArray:
    """Edge-timing speed (m/s, with the ECU's nominal radius) at each measurement instant."""
    arc = 2.0 * math.pi * cfg.wheel_radius_m / cfg.wheel_teeth
    out = np.zeros_like(t_meas)
    if edges.size < 2:
        return out
    last = np.searchsorted(edges, t_meas, side="right") - 1  # last edge at or before t
    first = np.searchsorted(edges, t_meas - cfg.wheel_window_s, side="right")  # first edge inside the window
    for i, (lo, hi) in enumerate(zip(first, last, strict=True)):
        if hi < 1 or t_meas[i] - edges[hi] > cfg.wheel_timeout_s:
            continue
        lo = min(lo, hi - 1)  # fewer than two edges in the window: use the last two
        span = edges[hi] - edges[lo]
        if 0 < span <= cfg.wheel_timeout_s:
            out[i] = (hi - lo) * arc / span
    return out


def _inputs_to(truth: GroundTruth, t_end: float) -> tuple[FloatArray, dict[str, FloatArray]]:
    """Times and the truth's fields the ECU's sensors measure, up to ``t_end``: past the truth's end
    the car stands where the drive ended, as the simulated receivers show it (their antennas hold the
    last position and attitude, with no motion): no yaw rate, no acceleration (the lateral
    accelerometer reads the gravity component of the last roll angle), the steering wheel held."""
    fields = {"yaw_rate": truth.yaw_rate, "ay_meas": truth.ay_meas, "ax_meas": truth.ax_meas, "ax": truth.ax,
              "swa": truth.swa}
    t = truth.t
    extra = math.ceil((t_end - float(t[-1])) / truth.dt - 1e-9)
    if extra <= 0:
        return t, {k: np.asarray(v, dtype=np.float64) for k, v in fields.items()}
    standing = {"yaw_rate": 0.0, "ay_meas": G0 * math.sin(float(truth.roll[-1])), "ax_meas": 0.0, "ax": 0.0,
                "swa": float(truth.swa[-1])}
    t_in = np.concatenate((t, float(t[-1]) + truth.dt * np.arange(1, extra + 1, dtype=np.float64)))
    return t_in, {k: np.concatenate((np.asarray(v, dtype=np.float64), np.full(extra, standing[k])))
                  for k, v in fields.items()}


def simulate_ecu(
    truth: GroundTruth,
    config: VscEcuConfig | None = None,
    db: Database | None = None,
    *,
    t_end_s: float | None = None,
) -> EcuOutputs:
    """Compute every message's transmit times and signal values (DBC physical units) from ``truth``.

    The schedules run to ``t_end_s`` (default: the truth's end). Past the truth's end the car stands
    where the drive ended, as the simulated receivers show it (:func:`_inputs_to`; the wheel-speed
    edge timing reads the last speed until its timeout, then 0). The schedules up to a time do not
    depend on ``t_end_s`` (nor do the values, save the wheel pressures' noise and the last truth
    sample's derivatives): a longer run-on appends frames.

    Raises:
        SimulationError: the truth record is too short or not uniformly sampled, or ``t_end_s`` is
            before its end.
    """
    cfg = config or VscEcuConfig()
    db = db or load_dbc(vsc_sim_dbc_path())
    n = len(truth)
    if n < 3:
        raise SimulationError(f"simulated VSC ECU: ground truth has {n} samples, need at least 3")
    t = truth.t
    dt = truth.dt
    if dt <= 0:
        raise SimulationError("simulated VSC ECU: ground-truth time vector is not increasing")
    t_end = float(t[-1])
    if t_end_s is not None:
        if not t_end_s >= t_end:
            raise SimulationError(f"simulated VSC ECU: t_end_s {t_end_s} is before the truth's end {t_end}")
        t_end = float(t_end_s)
    streams = np.random.SeedSequence(cfg.seed).spawn(16)
    rng = [np.random.default_rng(s) for s in streams]

    def msg(name: str) -> DbcMessage:
        return db.get_message_by_name(name)

    def period(name: str) -> float:
        cycle = msg(name).cycle_time
        if not cycle:
            raise SimulationError(f"simulated VSC ECU: message {name} has no GenMsgCycleTime in the DBC")
        return float(cycle) / 1000.0

    def times(name: str, i: int) -> FloatArray:
        return _schedule(period(name), cfg.phases_s.get(name, 0.0), t_end, cfg.transmit_jitter_s, rng[i])

    t_in, inputs = _inputs_to(truth, t_end)

    def sample(x: FloatArray, at: FloatArray) -> FloatArray:
        return np.asarray(np.interp(at, t_in, x), dtype=np.float64)

    series: dict[str, MessageSeries] = {}

    # sensor cluster
    m_sc = msg("ESC_SensorCluster")
    t_sc = times("ESC_SensorCluster", 0)
    yaw_acc = np.gradient(inputs["yaw_rate"], t_in)
    channels = {
        "ESC_YawRate": (inputs["yaw_rate"], cfg.yaw_rate, 1.0 / _DEG, 3),
        "ESC_LatAccel": (inputs["ay_meas"] + yaw_acc * cfg.cluster_x_m, cfg.lat_accel, 1.0 / G0, 4),
        "ESC_LongAccel": (inputs["ax_meas"], cfg.long_accel, 1.0, 5),
    }
    warm = t_sc >= cfg.sensor_warmup_s
    sc: dict[str, FloatArray] = {}
    for name, (x, err, to_dbc, k) in channels.items():
        filtered = _lowpass(np.asarray(x, dtype=np.float64), dt, err.bandwidth_hz)
        value = sample(filtered, t_sc - err.latency_s) + err.bias + rng[k].normal(0.0, err.noise_std, t_sc.size)
        lsb, lo, hi = _signal_limits(m_sc, name)
        sc[name] = np.where(warm, _quantise(value * to_dbc, lsb, lo, hi), 0.0)
    for q in ("ESC_YawRate_QBit", "ESC_LatAccel_QBit", "ESC_LongAccel_QBit"):
        sc[q] = np.where(warm, 0.0, 1.0)
    series["ESC_SensorCluster"] = MessageSeries("ESC_SensorCluster", t_sc, sc)

    # steering-angle sensor: clockwise positive on the wire
    m_sas = msg("SAS_Steering")
    t_sas = times("SAS_Steering", 1)
    swa_rate = np.gradient(inputs["swa"], t_in)
    lsb, lo, hi = _signal_limits(m_sas, "SAS_Angle")
    swa_cw_deg = -(sample(inputs["swa"], t_sas) + cfg.swa_offset_rad) / _DEG
    rate_cw_dps = -sample(_lowpass(swa_rate, dt, 10.0), t_sas) / _DEG
    rlsb, rlo, rhi = _signal_limits(m_sas, "SAS_Rate")
    series["SAS_Steering"] = MessageSeries(
        "SAS_Steering",
        t_sas,
        {
            "SAS_Angle": _quantise(swa_cw_deg, lsb, lo, hi),
            "SAS_Rate": _quantise(np.abs(rate_cw_dps), rlsb, rlo, rhi),
            "SAS_Rate_Sign": (rate_cw_dps < 0).astype(np.float64),
            "SAS_Angle_QBit": np.zeros(t_sas.size),
            "SAS_Calibrated": np.ones(t_sas.size),
        },
    )

    # wheel speeds from tooth edges
    m_ws = msg("ESC_WheelSpeeds")
    t_ws = times("ESC_WheelSpeeds", 2)
    ws: dict[str, FloatArray] = {}
    speeds_mps = np.zeros((4, t_ws.size))
    for w, wheel in enumerate(("FL", "FR", "RL", "RR")):
        r_true = cfg.wheel_radius_m * (1.0 + cfg.tyre_radius_error[w])
        omega = np.abs(truth.wheel_speed[:, w]) / r_true
        angle = np.concatenate(([0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) * np.diff(t))))
        angle += rng[6 + w].uniform(0.0, 2.0 * math.pi)  # where the first tooth happens to sit
        pitch_errors = np.clip(rng[10 + w].normal(0.0, cfg.tooth_pitch_error_std, cfg.wheel_teeth), -0.45, 0.45)
        # (past the drive the wheel stands: no more edges, and the speed falls to 0 at the timeout)
        edges = _wheel_edges(t, angle, cfg.wheel_teeth, pitch_errors, cfg.wheel_timer_hz)
        speeds_mps[w] = _wheel_speed_measurement(edges, t_ws, cfg)
        lsb, lo, hi = _signal_limits(m_ws, f"ESC_WheelSpeed_{wheel}")
        ws[f"ESC_WheelSpeed_{wheel}"] = _quantise(speeds_mps[w] / _KMH, lsb, lo, hi)
    series["ESC_WheelSpeeds"] = MessageSeries("ESC_WheelSpeeds", t_ws, ws)

    # estimator task: one cycle per sensor-cluster frame, on the values the ECU sends
    est = SideslipEstimator(cfg.estimator, period("ESC_SensorCluster"))
    yaw_si = sc["ESC_YawRate"] * _DEG
    ay_si = sc["ESC_LatAccel"] * G0
    ax_si = sc["ESC_LongAccel"]
    swa_iso = -series["SAS_Steering"].signals["SAS_Angle"] * _DEG
    i_sas = np.searchsorted(t_sas, t_sc, side="right") - 1
    i_ws = np.searchsorted(t_ws, t_sc, side="right") - 1
    mean_kmh = np.mean(np.vstack([ws[f"ESC_WheelSpeed_{w}"] for w in ("FL", "FR", "RL", "RR")]), axis=0)
    v_ref = np.where(i_ws >= 0, mean_kmh[np.maximum(i_ws, 0)] * _KMH, 0.0)
    steps: list[EstimatorStep] = []
    for j in range(t_sc.size):
        if not warm[j]:
            steps.append(_invalid_step())  # quality bits set: the ECU does not run on substitutes
            continue
        swa_j = float(swa_iso[i_sas[j]]) if i_sas[j] >= 0 else 0.0
        steps.append(est.step(float(yaw_si[j]), float(ay_si[j]), float(ax_si[j]), swa_j, float(v_ref[j])))
    est_arrays = {
        "beta": np.array([s.beta for s in steps]),
        "beta_kinematic": np.array([s.beta_kinematic for s in steps]),
        "beta_model": np.array([s.beta_model for s in steps]),
        "tau_s": np.array([s.tau_s for s in steps]),
        "valid": np.array([float(s.valid) for s in steps]),
        "active": np.array([float(s.active) for s in steps]),
        "yaw_rate_model": np.array([s.yaw_rate_model for s in steps]),
        "yaw_rate_reference": np.array([s.yaw_rate_reference for s in steps]),
        "yaw_rate_offset": np.array([s.yaw_rate_offset for s in steps]),
        "lat_accel_offset": np.array([s.lat_accel_offset for s in steps]),
        "roll_estimate": np.array([s.roll_estimate for s in steps]),
        "speed": np.array([s.speed for s in steps]),
    }
    interventions = np.array([s.intervention for s in steps], dtype=bool).reshape(-1, 4)

    def latest(at: FloatArray) -> npt.NDArray[np.int64]:
        return np.asarray(np.searchsorted(t_sc, at, side="right") - 1, dtype=np.int64)

    # brake pressures
    m_bp = msg("ESC_BrakePressure")
    t_bp = times("ESC_BrakePressure", 15)
    j_bp = latest(t_bp)
    ok_bp = j_bp >= 0
    j_bp = np.maximum(j_bp, 0)
    decel = -sample(inputs["ax"], t_bp)
    p_mc = cfg.brake_gain_bar_per_mps2 * np.maximum(decel - cfg.coast_decel_mps2, 0.0)
    pr = rng[14].normal(0.0, cfg.pressure_noise_bar, (5, t_bp.size))
    bp: dict[str, FloatArray] = {}
    lsb, lo, hi = _signal_limits(m_bp, "ESC_MC_Pressure")
    bp["ESC_MC_Pressure"] = _quantise(np.maximum(p_mc + pr[0], 0.0), lsb, lo, hi)
    for w, wheel in enumerate(("FL", "FR", "RL", "RR")):
        base = p_mc if w < 2 else cfg.rear_pressure_ratio * p_mc
        extra = np.where(ok_bp & interventions[j_bp, w], cfg.estimator.intervention_pressure_bar, 0.0)
        lsb, lo, hi = _signal_limits(m_bp, f"ESC_WheelPressure_{wheel}")
        bp[f"ESC_WheelPressure_{wheel}"] = _quantise(np.maximum(base + extra + pr[1 + w], 0.0), lsb, lo, hi)
    bp["ESC_Pressure_QBit"] = np.zeros(t_bp.size)
    series["ESC_BrakePressure"] = MessageSeries("ESC_BrakePressure", t_bp, bp)

    # VSC status
    m_st = msg("VSC_Status")
    t_st = times("VSC_Status", 8)
    j_st = latest(t_st)
    ok_st = j_st >= 0
    j_st = np.maximum(j_st, 0)
    valid = ok_st & (est_arrays["valid"][j_st] > 0.5)
    st: dict[str, FloatArray] = {}
    lsb, lo, hi = _signal_limits(m_st, "VSC_BetaEstimate")
    st["VSC_BetaEstimate"] = np.where(valid, _quantise(est_arrays["beta"][j_st] / _DEG, lsb, lo, hi), 0.0)
    st["VSC_Beta_QBit"] = np.where(valid, 0.0, 1.0)
    lsb, lo, hi = _signal_limits(m_st, "VSC_VehicleSpeed")
    st["VSC_VehicleSpeed"] = np.where(ok_st, _quantise(v_ref[j_st] / _KMH, lsb, lo, hi), 0.0)
    err_dps = (yaw_si - est_arrays["yaw_rate_offset"] - est_arrays["yaw_rate_reference"]) / _DEG
    lsb, lo, hi = _signal_limits(m_st, "VSC_YawRateError")
    st["VSC_YawRateError"] = np.where(valid, _quantise(err_dps[j_st], lsb, lo, hi), 0.0)
    st["VSC_Active"] = (ok_st & (est_arrays["active"][j_st] > 0.5)).astype(np.float64)
    st["VSC_Off"] = np.zeros(t_st.size)
    st["ABS_Active"] = np.zeros(t_st.size)
    st["TCS_Active"] = np.zeros(t_st.size)
    for w, wheel in enumerate(("FL", "FR", "RL", "RR")):
        st[f"VSC_Intervention_{wheel}"] = (ok_st & interventions[j_st, w]).astype(np.float64)
    series["VSC_Status"] = MessageSeries("VSC_Status", t_st, st)

    # diagnostics, multiplexed: pages alternate
    m_dg = msg("VSC_Diag")
    t_dg = times("VSC_Diag", 9)
    j_dg = np.maximum(latest(t_dg), 0)
    page = (np.arange(t_dg.size) % 2).astype(np.float64)
    dg: dict[str, FloatArray] = {"VSC_Diag_Page": page}
    diag_values = {
        "VSC_YawRateOffset": est_arrays["yaw_rate_offset"] / _DEG,
        "VSC_LatAccelOffset": est_arrays["lat_accel_offset"],
        "VSC_RollAngleEst": est_arrays["roll_estimate"] / _DEG,
        "VSC_BetaKinematic": est_arrays["beta_kinematic"] / _DEG,
        "VSC_BetaModel": est_arrays["beta_model"] / _DEG,
        "VSC_BlendTau": est_arrays["tau_s"],
        "VSC_YawRateModel": est_arrays["yaw_rate_model"] / _DEG,
    }
    for name, values in diag_values.items():
        lsb, lo, hi = _signal_limits(m_dg, name)
        dg[name] = _quantise(values[j_dg], lsb, lo, hi)
    series["VSC_Diag"] = MessageSeries("VSC_Diag", t_dg, dg)

    return EcuOutputs(messages=series, estimator_t=t_sc, estimator=est_arrays, t_end_s=t_end)


def _invalid_step() -> EstimatorStep:
    return EstimatorStep(0.0, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, (False, False, False, False))


# --- encoding ----------------------------------------------------------------------------------


class _Encoder:
    """Encodes one message's rows, its rolling counter and its checksum, all rows at once
    (:class:`drivers.can.vector_encode.MessageEncoder` packs the signals)."""

    def __init__(self, message: DbcMessage, algorithm: ChecksumAlgorithm | None) -> None:
        self.message = message
        self.algorithm = algorithm
        names = {s.name for s in message.signals}
        self.counter = "COUNTER" if "COUNTER" in names else None
        self.checksum = "CHECKSUM" if "CHECKSUM" in names else None
        if algorithm is not None and self.checksum is None:
            raise SimulationError(f"simulated VSC ECU: {message.name} has a checksum algorithm but no CHECKSUM signal")
        if self.checksum is not None:
            sig = message.get_signal_by_name(self.checksum)
            if sig.byte_order != "little_endian" or sig.start != 0 or sig.length != 8:
                raise SimulationError(f"simulated VSC ECU: {message.name}.CHECKSUM must be byte 0 (Intel, 8 bits)")
        self.count = 0
        try:
            self._packer = MessageEncoder(message)
        except EncodeError as exc:
            raise SimulationError(f"simulated VSC ECU: {exc}") from exc

    @property
    def _layouts(self) -> list[SignalLayout] | None:
        return self._packer.layouts

    def encode(self, values: dict[str, float]) -> bytes:
        """One row (advances the rolling counter by one)."""
        row = {k: np.asarray([v], dtype=np.float64) for k, v in values.items()}
        return bytes(self.encode_many(row, 1)[0])

    def encode_many(self, signals: Mapping[str, FloatArray], n: int) -> npt.NDArray[np.uint8]:
        """``n`` rows of physical values (one array per signal) → ``(n, length)`` payload bytes.

        The rolling counter continues from the previous call. Raises SimulationError naming the
        message and signal for a missing signal or a value the DBC cannot carry.
        """
        values: dict[str, npt.ArrayLike] = dict(signals)
        counter = (self.count + np.arange(n, dtype=np.int64)) % 16
        self.count += n
        if self.counter is not None:
            values[self.counter] = counter.astype(np.float64)
        if self.checksum is not None:
            values[self.checksum] = np.zeros(n)
        try:
            data = self._packer.encode_many(values, n)
        except EncodeError as exc:
            raise SimulationError(f"simulated VSC ECU: {exc}") from exc
        if self.algorithm is not None:
            data[:, 0] = self.algorithm.compute_many(self.message.frame_id, data).astype(np.uint8)
        return data


@dataclass(frozen=True, slots=True)
class _FrameTable:
    """Every frame of the drive in transmit order: time (s from the truth's start), identifier, payload."""

    t: FloatArray
    frame_id: npt.NDArray[np.int64]
    payload: list[bytes]
    row: npt.NDArray[np.int64]
    """Index of each frame among its message's frames."""

    def after(self, sent: Mapping[int, int]) -> _FrameTable:
        """The frames past the first ``sent[frame_id]`` of each message (in transmit order)."""
        keep = self.row >= np.asarray([sent.get(f, 0) for f in self.frame_id.tolist()], dtype=np.int64)
        idx = np.flatnonzero(keep)
        return _FrameTable(self.t[idx], self.frame_id[idx], [self.payload[k] for k in idx.tolist()], self.row[idx])


def _frame_table(out: EcuOutputs, cfg: VscEcuConfig, db: Database) -> _FrameTable:
    """Encode all messages and merge them in time order (ties: identifier, name, row)."""
    ts: list[FloatArray] = []
    ids: list[npt.NDArray[np.int64]] = []
    ranks: list[npt.NDArray[np.int64]] = []
    rows: list[npt.NDArray[np.int64]] = []
    payload: list[bytes] = []
    for rank, name in enumerate(sorted(out.messages)):
        series = out.messages[name]
        message = db.get_message_by_name(name)
        algo_name = cfg.checksums.get(name)
        algorithm = get_checksum(algo_name, where=f"VscEcuConfig.checksums.{name}") if algo_name else None
        n = int(series.t.size)
        data = _Encoder(message, algorithm).encode_many(series.signals, n)
        ts.append(np.asarray(series.t, dtype=np.float64))
        ids.append(np.full(n, int(message.frame_id), dtype=np.int64))
        ranks.append(np.full(n, rank, dtype=np.int64))
        rows.append(np.arange(n, dtype=np.int64))
        blob = data.tobytes()
        width = data.shape[1]
        payload.extend(blob[k : k + width] for k in range(0, n * width, width))
    if not ts:
        return _FrameTable(np.zeros(0), np.zeros(0, dtype=np.int64), [], np.zeros(0, dtype=np.int64))
    t = np.concatenate(ts)
    fid = np.concatenate(ids)
    row = np.concatenate(rows)
    order = np.lexsort((row, np.concatenate(ranks), fid, t))
    return _FrameTable(t[order], fid[order], [payload[k] for k in order.tolist()], row[order])


def frames(
    truth: GroundTruth,
    config: VscEcuConfig | None = None,
    *,
    t0_s: float = 0.0,
    outputs: EcuOutputs | None = None,
    db: Database | None = None,
) -> Iterator[tuple[float, can.Message]]:
    """The ECU's frames in transmit order as ``(t_s, message)``; ``t_s`` is seconds from the truth's
    start and ``message.timestamp = t0_s + t_s``. Pure: nothing is sent anywhere."""
    cfg = config or VscEcuConfig()
    db = db or load_dbc(vsc_sim_dbc_path())
    out = outputs or simulate_ecu(truth, cfg, db)
    table = _frame_table(out, cfg, db)
    for t, frame_id, data in zip(table.t.tolist(), table.frame_id.tolist(), table.payload, strict=True):
        yield (
            t,
            can.Message(
                timestamp=t0_s + t,
                arbitration_id=frame_id,
                is_extended_id=False,
                data=data,
                dlc=len(data),
            ),
        )


_new_message = can.Message.__new__


class _SentFrame(can.Message):
    """A frame the ECU sends: python-can's virtual bus deep-copies every frame for every receiver,
    and ``Message.__deepcopy__`` (generic ``deepcopy`` of its payload) cost the ECU thread a third of
    its time. The copy here is a plain :class:`can.Message` with its own copy of the payload."""

    __slots__ = ()

    def __deepcopy__(self, memo: dict[int, object] | None) -> can.Message:
        m = _new_message(can.Message)
        m.timestamp = self.timestamp
        m.arbitration_id = self.arbitration_id
        m.is_extended_id = self.is_extended_id
        m.is_remote_frame = self.is_remote_frame
        m.is_error_frame = self.is_error_frame
        m.channel = self.channel
        m.dlc = self.dlc
        m.data = bytearray(self.data)
        m.is_fd = self.is_fd
        m.is_rx = self.is_rx
        m.bitrate_switch = self.bitrate_switch
        m.error_state_indicator = self.error_state_indicator
        return m


# --- the running ECU ---------------------------------------------------------------------------


class VscEcu:
    """Sends the simulated ECU's frames on a python-can bus, paced by a clock.

    GroundTruth time 0 is clock time ``t0_ns``; a frame due at ``t`` is sent at
    ``t0_ns + t·1e9`` on ``clock`` (a :class:`~vsccore.clock.ScaledClock` runs the drive faster
    than real time) and carries that time as ``msg.timestamp`` (open the bus with
    ``preserve_timestamps=True`` for a virtual bus to keep it). Frames already more than
    ``max_lag_s`` late when their turn comes are skipped, as a real ECU that was already running
    would not have them queued. The bus is not closed here: it belongs to the caller.

    With ``run_on`` the ECU does not stop with the drive: it sends on until :meth:`stop`, the car
    standing where the drive ended (:func:`simulate_ecu` past the truth's end), as a real car's bus
    runs until the recorder stops and as the other simulated devices go on. ``outputs`` computed
    to a later ``t_end_s`` are sent first; then each further stretch is computed when the last one
    has been sent (:data:`RUN_ON_STRETCH_S` past the drive, then twice as far each time).

    On a governed clock (:class:`~vsccore.clock.ClockGovernor`) the ECU is a participant called
    ``name``: simulated time waits for it, and, when ``reader`` names the participant that reads the
    bus (publishing the stamp of each frame it takes), for that reader too: the ECU announces each
    frame as it sends it, and simulated time stands still while the reader owes a frame more than
    the governor's budget old, so a starved reader holds the clock instead of receiving its frames
    late (and the clock runs on the moment it has taken them).

    The constructor computes the whole drive (:func:`simulate_ecu`; with ``run_on``, to
    :data:`RUN_ON_STRETCH_S` past its end), which takes a while for long drives; pass ``outputs``
    computed beforehand (with the same ``config``) when ``t0_ns`` is close.
    """

    def __init__(
        self,
        truth: GroundTruth,
        bus: can.BusABC,
        clock: Clock,
        t0_ns: int,
        config: VscEcuConfig | None = None,
        *,
        db: Database | None = None,
        max_lag_s: float = 0.5,
        outputs: EcuOutputs | None = None,
        reader: str | None = None,
        name: str = "ecu",
        run_on: bool = False,
    ) -> None:
        self.config = config or VscEcuConfig()
        self._reader = reader
        self._name = name
        self._run_on = run_on
        self._db = db or load_dbc(vsc_sim_dbc_path())
        self.truth = truth
        t_end_s = float(truth.t[-1]) + RUN_ON_STRETCH_S if run_on and len(truth) else None
        self.outputs = (outputs if outputs is not None
                        else simulate_ecu(truth, self.config, self._db, t_end_s=t_end_s))
        self._table = _frame_table(self.outputs, self.config, self._db)
        self._bus = bus
        self._clock = clock
        self._t0_ns = t0_ns
        self._max_lag_ns = int(max_lag_s * 1e9)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.finished = threading.Event()
        """Set when the drive has been sent to its end (never, when running on), stopped, or failed."""
        self.frames_sent = 0
        self.frames_skipped = 0
        self.frames_lost_bus_off = 0
        """Frames not sent because the bus was off (:meth:`bus_off`)."""
        self.failure: BaseException | None = None
        self._fault_lock = threading.Lock()
        self._bus_off_request: tuple[int, threading.Event] | None = None
        self._bus_off_until: int | None = None
        self._bus_off_done: threading.Event | None = None

    def start(self) -> None:
        """Start sending on a thread (see :meth:`run`)."""
        if self._thread is not None:
            raise RuntimeError("simulated VSC ECU already started")
        self._thread = threading.Thread(target=self._thread_main, name="vsc-ecu")
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop sending and join the thread (the bus stays open)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise SimulationError(f"simulated VSC ECU: thread did not stop within {timeout_s} s")

    def __enter__(self) -> VscEcu:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def bus_off(self, duration_s: float) -> threading.Event:
        """Put the bus into bus-off for ``duration_s`` (clock time), from the ECU's next transmit slot.

        The reading side sees it as a SocketCAN interface reports a controller driven off the bus
        (``linux/can/error.h``): error frames for error warning and error passive (TEC 96, 128), then
        ``CAN_ERR_BUSOFF``; no frame for the span (the ECU's frames due then are lost, counted in
        :attr:`frames_lost_bus_off`); then ``CAN_ERR_RESTARTED`` at the span's end, as the kernel sends
        it after ``restart-ms``, and the frames resume. The error frames carry their times as stamps,
        like every frame the ECU sends. Returns an event set once the bus is back.

        Raises:
            SimulationError: ``duration_s`` is not positive, or a bus-off is already pending or running.
        """
        if not duration_s > 0:
            raise SimulationError(f"simulated VSC ECU: bus-off duration must be > 0 s, got {duration_s}")
        done = threading.Event()
        with self._fault_lock:
            if self._bus_off_request is not None or self._bus_off_until is not None:
                raise SimulationError("simulated VSC ECU: a bus-off is already pending or running")
            self._bus_off_request = (round(duration_s * 1e9), done)
        return done

    def _fault_step(self, me: Participant, due_ns: int) -> bool:
        """Start a requested bus-off at this transmit slot; True while the bus is off."""
        with self._fault_lock:
            request = self._bus_off_request
            if request is None or self._bus_off_until is not None:
                return self._bus_off_until is not None
            self._bus_off_request = None
            duration_ns, self._bus_off_done = request
            self._bus_off_until = due_ns + duration_ns
        stamp = due_ns / 1e9
        for frame in (
            socketcan_error_frame(CAN_ERR_CRTL, status=CAN_ERR_CRTL_TX_WARNING, tx_errors=96, rx_errors=0,
                                  timestamp=stamp),
            socketcan_error_frame(CAN_ERR_CRTL, status=CAN_ERR_CRTL_TX_PASSIVE, tx_errors=128, rx_errors=0,
                                  timestamp=stamp),
            socketcan_error_frame(CAN_ERR_BUSOFF, timestamp=stamp),
        ):
            me.sent(due_ns)
            self._bus.send(frame)
        log.info("simulated VSC ECU: bus-off for %.3f s", duration_ns / 1e9)
        return True

    def _bus_restarted(self, me: Participant, until_ns: int) -> None:
        me.sent(until_ns)
        self._bus.send(socketcan_error_frame(CAN_ERR_RESTARTED, timestamp=until_ns / 1e9))
        with self._fault_lock:
            self._bus_off_until = None
            done, self._bus_off_done = self._bus_off_done, None
        log.info("simulated VSC ECU: bus restarted after bus-off")
        if done is not None:
            done.set()

    def _thread_main(self) -> None:
        try:
            self.run()
        except can.CanError as exc:
            log.warning("simulated VSC ECU: bus send failed, stopping: %s", exc)
            self.failure = exc
        finally:
            self.finished.set()

    def run(self) -> None:
        """Send every frame at its time until the drive ends (with ``run_on``: on, in the car's last
        state) or :meth:`stop` is called (blocking).

        Raises:
            can.CanError: the bus refused a frame.
        """
        table = self._table
        clock = self._clock
        first = self._t0_ns + round(float(table.t[0]) * 1e9) if table.t.size else UNBOUNDED_NS
        with participant(clock, self._name, progress_ns=first) as me:
            if self._reader is not None:
                me.feeds(self._reader)
            while self._send_all(table, me) and self._run_on:
                # (while this stretch is computed, the governed clock stands at the last frame sent)
                table = self._next_stretch()
        self.finished.set()

    def _send_all(self, table: _FrameTable, me: Participant) -> bool:
        """Send ``table``'s frames at their times; False if stopped first."""
        clock = self._clock
        send = self._bus.send
        max_lag = self._max_lag_ns
        due = (self._t0_ns + np.round(table.t * 1e9).astype(np.int64)).tolist()
        # simulated time stands still at the next frame's time until it is sent (not the budget past
        # it): otherwise every late wake-up puts the frame's receive time the budget late
        hold = me.budget_ns
        for due_ns, frame_id, data in zip(due, table.frame_id.tolist(), table.payload, strict=True):
            until = self._bus_off_until
            if until is not None and due_ns >= until:  # the restart comes at its own time, before this frame
                me.at(until - hold)
                if not clock.sleep_until_ns(until, self._stop):
                    return False
                self._bus_restarted(me, until)
            me.at(due_ns - hold)
            if not clock.sleep_until_ns(due_ns, self._stop):
                return False
            if (self._bus_off_request is not None or self._bus_off_until is not None) and self._fault_step(me, due_ns):
                self.frames_lost_bus_off += 1
                continue
            if clock.now_ns() - due_ns > max_lag:
                self.frames_skipped += 1
                continue
            me.sent(due_ns)  # before the frame can reach the reader: from now on it owes it
            send(_SentFrame(timestamp=due_ns / 1e9, arbitration_id=frame_id, is_extended_id=False, data=data,
                            dlc=len(data)))
            self.frames_sent += 1
        until = self._bus_off_until
        if until is not None and not self._stop.is_set():  # a bus-off running past the last frame ends too
            me.at(until - hold)
            if clock.sleep_until_ns(until, self._stop):
                self._bus_restarted(me, until)
        return not self._stop.is_set()

    def _next_stretch(self) -> _FrameTable:
        """The frames after those of :attr:`outputs`, the car running on: the outputs recomputed to
        twice as far past the drive (at least :data:`RUN_ON_STRETCH_S` further), less the frames of
        each message already in the previous outputs (rolling counters go on where they were)."""
        prev = self.outputs
        truth_end = float(self.truth.t[-1])
        t_end_s = prev.t_end_s + max(RUN_ON_STRETCH_S, prev.t_end_s - truth_end)
        sent = {int(self._db.get_message_by_name(name).frame_id): int(series.t.size)
                for name, series in prev.messages.items()}
        self.outputs = simulate_ecu(self.truth, self.config, self._db, t_end_s=t_end_s)
        return _frame_table(self.outputs, self.config, self._db).after(sent)


class SimulatedVscBus:
    """The simulated ECU on a python-can virtual channel of its own, optionally served by socketcand.

    In-process consumers open ``can.Bus(interface="virtual", channel=self.channel)`` (or a
    :class:`~drivers.can.bus.CanBusLink` with interface ``virtual``); other processes connect
    with python-can's ``socketcand`` interface to :attr:`address`, bus name ``bus_name``. GroundTruth
    time 0 is ``t0_ns`` on ``clock`` (see :class:`VscEcu`). ``port=0`` picks a free port, which
    :attr:`address` tells after :meth:`start`. :meth:`stop` stops the ECU, the server and closes
    the ECU's bus. Channel names are python-can's process-wide virtual channels: give each
    simulated car its own.
    """

    def __init__(
        self,
        truth: GroundTruth,
        *,
        clock: Clock,
        t0_ns: int,
        channel: str = "vsc-sim",
        config: VscEcuConfig | None = None,
        serve: bool = True,
        host: str = "127.0.0.1",
        port: int = 0,
        bus_name: str = "vsc0",
        db: Database | None = None,
    ) -> None:
        self.truth = truth
        self.channel = channel
        self.bus_name = bus_name
        self._clock = clock
        self._t0_ns = t0_ns
        self._config = config
        self._db = db
        self._serve = serve
        self._host = host
        self._port = port
        self._bus: can.BusABC | None = None
        self._server: SocketcandServer | None = None
        self.ecu: VscEcu | None = None

    @property
    def address(self) -> tuple[str, int] | None:
        """``(host, port)`` of the socketcand server (None when not serving or not started)."""
        return None if self._server is None else self._server.address

    @property
    def finished(self) -> threading.Event:
        """Set when the ECU has sent its whole drive (or stopped). Raises RuntimeError before start."""
        if self.ecu is None:
            raise RuntimeError("simulated VSC bus not started")
        return self.ecu.finished

    def bus_off(self, duration_s: float) -> threading.Event:
        """Put the bus into bus-off for ``duration_s`` (see :meth:`VscEcu.bus_off`); the event is set
        once it is back. Raises RuntimeError before start."""
        if self.ecu is None:
            raise RuntimeError("simulated VSC bus not started")
        return self.ecu.bus_off(duration_s)

    def start(self) -> None:
        """Open the ECU's bus, start the socketcand server (if serving) and the ECU.

        Raises:
            DeviceError: the server cannot listen on ``host:port``.
            RuntimeError: already started.
        """
        if self._bus is not None:
            raise RuntimeError(f"simulated VSC bus {self.channel!r} already started")
        self._bus = can.Bus(interface="virtual", channel=self.channel, preserve_timestamps=True)
        try:
            if self._serve:
                self._server = SocketcandServer(
                    virtual_channel_opener({self.bus_name: self.channel}), host=self._host, port=self._port
                )
                self._server.start()
            self.ecu = VscEcu(self.truth, self._bus, self._clock, self._t0_ns, self._config, db=self._db)
            self.ecu.start()
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        """Stop the ECU and the server and close the ECU's bus (each step runs even if one fails)."""
        try:
            if self.ecu is not None:
                self.ecu.stop()
        finally:
            server, self._server = self._server, None
            bus, self._bus = self._bus, None
            try:
                if server is not None:
                    server.stop()
            finally:
                if bus is not None:
                    bus.shutdown()

    def __enter__(self) -> SimulatedVscBus:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
