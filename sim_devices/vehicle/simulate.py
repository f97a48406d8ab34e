"""Run a drive (or one scenario) through the vehicle model and return its ground truth.

:func:`simulate` chains the scenarios of a :class:`~sim_devices.vehicle.scenarios.Drive` with
transitions, integrates the model at ≤ 1 ms steps, and assembles a
:class:`~sim_devices.vehicle.truth.GroundTruth` at the requested output rate. Derived signals
(wheel loads, wheel speeds, accelerometer readings, LTR) are computed from the sampled states
with the model's own formulas.

The accelerometer reading: a body-fixed sensor measures the specific force f = a − g. In the
horizontal vehicle frame f = (a_x, a_y, +g); after roll φ (positive right side down, i.e. the
body y axis tilts up by φ) its body-y component is a_y·cos φ + g·sin φ. In a left turn a_y > 0
and the body rolls φ > 0, so the sensor reads more than a_y. Pitch is not modelled, so the
longitudinal reading equals a_x.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator

import numpy as np

from sim_devices.vehicle.driver import DriverNoise, HeadingController, piecewise_speed
from sim_devices.vehicle.model import DynState, Integrator, Phase, Recorder, wheel_loads, wheel_long_forces
from sim_devices.vehicle.params import GRAVITY, VehicleParams
from sim_devices.vehicle.scenarios import Drive, Scenario, ScenarioContext
from sim_devices.vehicle.steering import SteeringGear
from sim_devices.vehicle.truth import GroundTruth
from vsccore.angles import azimuth_to_yaw, wrap_pi
from vsccore.errors import SimulationError

__all__ = ["DEFAULT_ORIGIN", "simulate", "wheel_speeds"]

log = logging.getLogger(__name__)

DEFAULT_ORIGIN = (48.7758, 9.1829, 300.0)
"""Default local ENU origin (lat deg, lon deg, ellipsoidal height m), the rig's example test site."""

_TRANSITION_ACCEL = 2.0
_TRANSITION_AY = 3.0
_TRANSITION_SLACK_S = 60.0


def simulate(
    drive: Drive | Scenario,
    params: VehicleParams | None = None,
    *,
    rate_hz: float = 1000.0,
    origin: tuple[float, float, float] = DEFAULT_ORIGIN,
    initial_heading_deg: float | None = None,
    seed: int | None = 0,
    driver_noise_deg: float = 0.0,
) -> GroundTruth:
    """Drive ``drive`` with the car ``params`` and return the ground truth sampled at ``rate_hz``.

    The car starts at the ENU origin, at the first scenario's entry speed, heading
    ``initial_heading_deg`` (azimuth clockwise from north; default: the first scenario's entry
    heading, else north). ``driver_noise_deg`` adds a random, band-limited steering-wheel motion
    (standard deviation in deg, seeded by ``seed``) to the closed-loop driver; 0 keeps the run
    deterministic. Raises SimulationError for invalid input or if the model diverges.
    """
    if isinstance(drive, Scenario):
        drive = Drive([drive], gap_s=0.0)
    if not isinstance(drive, Drive):
        raise SimulationError(f"simulate() takes a Drive or a Scenario, got {type(drive).__name__}")
    params = VehicleParams() if params is None else params
    lat0, lon0, h0 = (float(x) for x in origin)
    if not (-90.0 <= lat0 <= 90.0 and -180.0 <= lon0 <= 360.0 and math.isfinite(h0)):
        raise SimulationError(f"origin must be (lat deg, lon deg, height m), got {origin!r}")
    if not (math.isfinite(driver_noise_deg) and driver_noise_deg >= 0.0):
        raise SimulationError(f"driver_noise_deg must be >= 0, got {driver_noise_deg!r}")
    gear = SteeringGear(params)
    integ = Integrator(params, gear, rate_hz)
    noise = DriverNoise(math.radians(driver_noise_deg), seed) if driver_noise_deg > 0.0 else None
    ctx = ScenarioContext(params=params, gear=gear, noise=noise)

    first_speed, first_yaw = drive.scenarios[0].entry()
    if initial_heading_deg is not None:
        yaw0 = azimuth_to_yaw(math.radians(initial_heading_deg))
    else:
        yaw0 = first_yaw if first_yaw is not None else math.pi / 2.0
    st = DynState(yaw=yaw0, vx=first_speed)
    rec = Recorder()
    meta: dict[str, float | str] = {
        "scenario": "+".join(s.name for s in drive.scenarios),
        "rate_hz": float(rate_hz),
        "gap_s": drive.gap_s,
        "cg_height_m": params.cg_height_m,
        "vehicle_name": params.name,
        "driver_noise_deg": float(driver_noise_deg),
    }
    segment = 0

    def run_segment(kind: str, label: str, phases: Iterator[Phase] | None, first: Phase | None = None) -> None:
        nonlocal segment
        t_start = st.step * integ.dt
        prefix = f"segment.{segment}"
        meta[f"{prefix}.kind"] = kind
        meta[f"{prefix}.name"] = label
        meta[f"{prefix}.t_start_s"] = t_start
        n_phase = 0

        def record(phase: Phase) -> None:
            nonlocal n_phase
            t0 = st.step * integ.dt
            integ.run(st, phase, rec)
            pre = f"{prefix}.phase.{n_phase}"
            meta[f"{pre}.label"] = phase.label
            meta[f"{pre}.t_start_s"] = t0
            meta[f"{pre}.t_end_s"] = st.step * integ.dt
            for key, value in phase.meta.items():
                meta[f"{pre}.{key}"] = value
            n_phase += 1

        if first is not None:
            record(first)
        if phases is not None:
            gen = phases
            try:
                phase = next(gen)
                while True:
                    record(phase)
                    phase = gen.send(st.snapshot(integ.dt))  # type: ignore[attr-defined]
            except StopIteration:
                pass
        meta[f"{prefix}.t_end_s"] = st.step * integ.dt
        segment += 1

    for i, scenario in enumerate(drive.scenarios):
        speed, yaw = scenario.entry()
        needs_turn = yaw is not None and abs(wrap_pi(yaw - st.yaw)) > math.radians(0.3)
        needs_speed = abs(st.vx - speed) > 0.05
        if i > 0 or needs_turn or needs_speed:
            transition = _transition(ctx, st, speed, yaw, drive.gap_s)
            run_segment("transition", f"to {scenario.name}", None, transition)
            if transition.controller is not None and not transition.controller.done:
                log.warning(
                    "transition to %s did not settle (heading/yaw rate) within %.0f s; continuing",
                    scenario.name,
                    transition.duration_s,
                )
        for key, value in scenario.values.items():
            meta[f"segment.{segment}.param.{key}"] = "auto" if value is None else value
        run_segment("scenario", scenario.name, scenario.phases(ctx, st.snapshot(integ.dt)))

    return _assemble(params, integ, rec, (lat0, lon0, h0), meta)


def _transition(ctx: ScenarioContext, st: DynState, speed: float, yaw: float | None, gap_s: float) -> Phase:
    """Change speed, turn onto ``yaw`` (if given) and straighten the car; lasts at least ``gap_s``."""
    t_ramp = abs(speed - st.vx) / _TRANSITION_ACCEL
    turn_s = 0.0
    if yaw is not None:
        v_turn = max(min(abs(st.vx), abs(speed)), 3.0)
        turn_s = abs(wrap_pi(yaw - st.yaw)) * v_turn / _TRANSITION_AY + 5.0
    min_time = max(gap_s, t_ramp + 0.5)
    target = None if yaw is None else st.yaw + wrap_pi(yaw - st.yaw)
    controller = HeadingController(ctx.params, ctx.gear, target, min_time_s=min_time, noise=ctx.noise)
    return Phase(
        duration_s=min_time + turn_s + _TRANSITION_SLACK_S,
        speed=piecewise_speed([0.0, t_ramp], [st.vx, speed]),
        controller=controller,
        label="transition",
    )


def wheel_speeds(
    params: VehicleParams,
    vx: np.ndarray,
    vy: np.ndarray,
    yaw_rate: np.ndarray,
    delta: np.ndarray,
    loads: np.ndarray,
    fx_wheels: np.ndarray,
) -> np.ndarray:
    """Wheel circumferential speeds ω·r (n, 4) FL FR RL RR (m/s), signed (negative when reversing).

    Free-rolling speed = wheel-centre velocity along the wheel heading (front wheels at their
    Ackermann angles), plus the longitudinal slip κ = F_x/(C_κ·F_z) of a driven or braked wheel.
    """
    L = params.wheelbase_m
    a, b = params.cg_to_front_axle_m, params.cg_to_rear_axle_m
    htf, htr = 0.5 * params.track_front_m, 0.5 * params.track_rear_m
    tan_d = np.tan(delta)
    # Ackermann: tan δ_side = L tan δ / (L ∓ (t/2) tan δ); finite for any |δ| < 90°.
    d_left = np.arctan2(L * tan_d, L - htf * tan_d)
    d_right = np.arctan2(L * tan_d, L + htf * tan_d)
    d_left = np.where(np.abs(d_left) > math.pi / 2, d_left - np.sign(d_left) * math.pi, d_left)
    d_right = np.where(np.abs(d_right) > math.pi / 2, d_right - np.sign(d_right) * math.pi, d_right)
    out = np.empty((vx.shape[0], 4))
    for j, (x, y, steer) in enumerate(((a, htf, d_left), (a, -htf, d_right), (-b, htr, 0.0), (-b, -htr, 0.0))):
        wvx = vx - yaw_rate * y
        wvy = vy + yaw_rate * x
        roll_v = wvx * np.cos(steer) + wvy * np.sin(steer)
        with np.errstate(divide="ignore", invalid="ignore"):
            kappa = np.where(
                loads[:, j] > 0.0, fx_wheels[:, j] / (params.tyre_long_slip_stiffness_per_load * loads[:, j]), 0.0
            )
        kappa = np.clip(kappa, -0.2, 0.2)
        out[:, j] = roll_v + kappa * np.abs(roll_v)
    return out


def _assemble(
    params: VehicleParams,
    integ: Integrator,
    rec: Recorder,
    origin: tuple[float, float, float],
    meta: dict[str, float | str],
) -> GroundTruth:
    arr = rec.arrays()
    n = len(rec)
    if n == 0:
        raise SimulationError("the drive produced no samples (all durations zero?)")
    t = np.arange(n, dtype=np.float64) / integ.rate_hz
    loads = wheel_loads(params, arr["ax"], arr["ay"], arr["roll"], arr["roll_rate"])
    fxw = wheel_long_forces(params, arr["fx"], arr["vx"], loads)
    ws = wheel_speeds(params, arr["vx"], arr["vy"], arr["yaw_rate"], arr["delta"], loads, fxw)
    total = loads.sum(axis=1)
    ltr = (loads[:, 1] + loads[:, 3] - loads[:, 0] - loads[:, 2]) / total
    ay_meas = arr["ay"] * np.cos(arr["roll"]) + GRAVITY * np.sin(arr["roll"])
    meta["duration_s"] = float(n / integ.rate_hz)
    return GroundTruth(
        t=t,
        east=arr["east"],
        north=arr["north"],
        yaw=arr["yaw"],
        vx=arr["vx"],
        vy=arr["vy"],
        yaw_rate=arr["yaw_rate"],
        ax=arr["ax"],
        ay=arr["ay"],
        ax_meas=arr["ax"].copy(),
        ay_meas=ay_meas,
        roll=arr["roll"],
        roll_rate=arr["roll_rate"],
        road_wheel_angle=arr["delta"],
        swa=arr["swa"],
        wheel_speed=ws,
        wheel_load=loads,
        ltr=ltr,
        lat0_deg=origin[0],
        lon0_deg=origin[1],
        h0_m=origin[2],
        meta=meta,
    )
