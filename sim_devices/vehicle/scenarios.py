"""Test scenarios (ISO / NHTSA manoeuvres and calibration drives) and drives composed of them.

A scenario is a named manoeuvre with named, unit-carrying parameters (``SCENARIOS`` lists them,
:func:`make_scenario` builds one). It starts from whatever state the previous part of the drive
left and yields :class:`~sim_devices.vehicle.model.Phase` objects; after each phase it receives
the state the phase ended in, so later phases can be placed relative to it (a lane-change
course starts where the car is, a circle is tangent to the car's path).

Each scenario declares the speed (and optionally the heading) it wants on entry; a
:class:`Drive` joins scenarios with transitions that change speed, turn onto that heading and
straighten the car (at most 3 m/s² lateral, 2 m/s² longitudinal), lasting at least ``gap_s``.

Amplitudes defined "× SWA at 0.3 g" (NHTSA J-turn / fishhook, FMVSS 126 sine with dwell) use the
steering-wheel angle that gives 0.3 g at 80 km/h in the linear single-track model of the car
(the regulation measures it in a slowly-increasing-steer test; the linear value differs from
the measured one by the small nonlinearity at 0.3 g).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Generator, Iterable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from sim_devices.vehicle.driver import (
    CirclePath,
    DriverNoise,
    PathFollower,
    PolylinePath,
    constant_speed,
    piecewise_speed,
)
from sim_devices.vehicle.model import Phase, VehicleState
from sim_devices.vehicle.params import GRAVITY, VehicleParams
from sim_devices.vehicle.steering import SteeringGear
from vsccore.angles import azimuth_to_yaw, wrap_pi
from vsccore.errors import SimulationError

__all__ = [
    "SCENARIOS",
    "DoubleLaneChangeCourse",
    "Drive",
    "ParamSpec",
    "Scenario",
    "ScenarioContext",
    "ScenarioSpec",
    "demo_drive",
    "iso3888_1_course",
    "make_scenario",
    "swa_circle_values_deg",
]

FloatArray = npt.NDArray[np.float64]
ParamValue = float | str | None
PhaseGen = Generator[Phase, VehicleState, None]

KMH = 1.0 / 3.6


# ---------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One scenario parameter: name, default, unit and meaning."""

    name: str
    default: ParamValue
    unit: str
    help: str
    choices: tuple[str, ...] = ()
    minimum: float | None = None
    maximum: float | None = None

    @property
    def optional(self) -> bool:
        """A parameter whose default ``None`` means "chosen automatically"."""
        return self.default is None and not self.choices

    def describe_default(self) -> str:
        if self.default is None:
            return "auto"
        if isinstance(self.default, float):
            return f"{self.default:g}"
        return str(self.default)

    def parse(self, scenario: str, value: object) -> ParamValue:
        """Convert and check a value (numbers, numeric strings, or a choice), or raise SimulationError."""
        where = f"scenario {scenario!r} parameter {self.name!r}"
        if self.choices:
            text = str(value).strip().lower()
            if text not in self.choices:
                raise SimulationError(f"{where} must be one of {', '.join(self.choices)}; got {value!r}")
            return text
        if value is None or (isinstance(value, str) and value.strip().lower() in {"auto", "none", ""}):
            if self.optional:
                return None
            raise SimulationError(f"{where} needs a value ({self.unit or 'number'})")
        if isinstance(value, bool):
            raise SimulationError(f"{where} must be a number ({self.unit}), got {value!r}")
        try:
            number = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise SimulationError(f"{where} must be a number ({self.unit}), got {value!r}") from None
        if not math.isfinite(number):
            raise SimulationError(f"{where} must be finite, got {value!r}")
        if self.minimum is not None and number < self.minimum:
            raise SimulationError(f"{where} must be >= {self.minimum:g} {self.unit}, got {number:g}")
        if self.maximum is not None and number > self.maximum:
            raise SimulationError(f"{where} must be <= {self.maximum:g} {self.unit}, got {number:g}")
        return number


@dataclass(frozen=True, slots=True)
class ScenarioContext:
    """What a scenario needs to know about the car: parameters, steering gear, driver noise."""

    params: VehicleParams
    gear: SteeringGear
    noise: DriverNoise | None = None

    def swa_for_ay(self, speed: float, ay: float) -> float:
        """Steady-state SWA (rad) for lateral acceleration ``ay`` at ``speed`` (linear single-track model)."""
        delta = math.atan(self.params.wheelbase_m * ay / (speed * speed)) + (
            self.params.understeer_gradient_rad_per_mps2 * ay
        )
        return float(self.gear.swa_from_road_wheel(delta))

    def swa_03g(self) -> float:
        """SWA (rad) giving 0.3 g at 80 km/h in the linear model (NHTSA/FMVSS 126 reference amplitude)."""
        return self.swa_for_ay(80.0 * KMH, 0.3 * GRAVITY)

    def follower(self, path: PolylinePath | CirclePath, **kwargs: float) -> PathFollower:
        return PathFollower(path, self.params, self.gear, noise=self.noise, **kwargs)


Values = Mapping[str, ParamValue]


@dataclass(frozen=True, slots=True)
class ScenarioSpec:
    """A kind of scenario: its parameters and how it is driven."""

    name: str
    title: str
    reference: str
    params: tuple[ParamSpec, ...]
    entry: Callable[[Values], tuple[float, float | None]]
    """(entry speed m/s, entry yaw rad or None) for the given parameter values."""
    run: Callable[[Values, ScenarioContext, VehicleState], PhaseGen]
    check: Callable[[Values], None] | None = None

    def param(self, name: str) -> ParamSpec:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)


@dataclass(frozen=True, slots=True)
class Scenario:
    """A scenario with its parameter values resolved (build with :func:`make_scenario`)."""

    name: str
    values: Mapping[str, ParamValue]

    @property
    def spec(self) -> ScenarioSpec:
        return SCENARIOS[self.name]

    def entry(self) -> tuple[float, float | None]:
        """Speed (m/s) and yaw (rad, or None for "any") the scenario wants on entry."""
        return self.spec.entry(self.values)

    def phases(self, ctx: ScenarioContext, state: VehicleState) -> PhaseGen:
        """The phases of the scenario, starting from ``state`` (send back the state after each)."""
        return self.spec.run(self.values, ctx, state)

    def describe(self) -> str:
        args = ", ".join(f"{k}={_fmt(v)}" for k, v in self.values.items())
        return f"{self.name}({args})"


def _fmt(value: ParamValue) -> str:
    if value is None:
        return "auto"
    return f"{value:g}" if isinstance(value, float) else str(value)


def make_scenario(name: str, **params: object) -> Scenario:
    """Build scenario ``name`` with parameters (numbers, numeric strings or choices; others default).

    Raises SimulationError for an unknown scenario or parameter (with a "did you mean" hint) or a
    bad value.
    """
    spec = SCENARIOS.get(name)
    if spec is None:
        close = difflib.get_close_matches(name, list(SCENARIOS), n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SimulationError(f"unknown scenario {name!r}{hint}; known: {', '.join(SCENARIOS)}")
    names = [p.name for p in spec.params]
    for key in params:
        if key not in names:
            close = difflib.get_close_matches(key, names, n=1, cutoff=0.5)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SimulationError(
                f"scenario {name!r} has no parameter {key!r}{hint}; parameters: {', '.join(names)}"
            )
    values: dict[str, ParamValue] = {}
    for p in spec.params:
        values[p.name] = p.parse(name, params[p.name]) if p.name in params else p.default
    if spec.check is not None:
        spec.check(values)
    return Scenario(name=name, values=MappingProxyType(values))


@dataclass(frozen=True, slots=True)
class Drive:
    """Scenarios driven one after the other, with transitions of at least ``gap_s`` between them."""

    scenarios: tuple[Scenario, ...]
    gap_s: float = 5.0

    def __init__(self, scenarios: Iterable[Scenario], gap_s: float = 5.0) -> None:
        items = tuple(scenarios)
        if not items:
            raise SimulationError("a drive needs at least one scenario")
        for s in items:
            if not isinstance(s, Scenario):
                raise SimulationError(f"a drive takes Scenario objects (see make_scenario), got {s!r}")
        if not (math.isfinite(gap_s) and gap_s >= 0.0):
            raise SimulationError(f"gap_s must be a finite number >= 0, got {gap_s!r}")
        object.__setattr__(self, "scenarios", items)
        object.__setattr__(self, "gap_s", float(gap_s))


# ---------------------------------------------------------------------------------------------
# Helpers shared by the manoeuvres
# ---------------------------------------------------------------------------------------------


def _turn(values: Values) -> int:
    return 1 if values.get("turn", "left") == "left" else -1


def _lead_in(ctx: ScenarioContext, state: VehicleState, speed: float, duration: float, label: str) -> Phase:
    """Straight driving along the current heading (closed loop), e.g. before an open-loop steer."""
    line = PolylinePath.line(state.east, state.north, state.yaw, speed * duration + 200.0)
    return Phase(duration_s=duration, speed=constant_speed(speed), controller=ctx.follower(line), label=label)


def _ramp_profile(knots_t: list[float], knots_swa: list[float]) -> Callable[[FloatArray], FloatArray]:
    t = np.asarray(knots_t, dtype=float)
    s = np.asarray(knots_swa, dtype=float)

    def profile(tau: FloatArray) -> FloatArray:
        return np.asarray(np.interp(tau, t, s), dtype=float)

    return profile


def _hold_profile(swa: float) -> Callable[[FloatArray], FloatArray]:
    def profile(tau: FloatArray) -> FloatArray:
        return np.full_like(tau, swa)

    return profile


def _amplitude(values: Values, ctx: ScenarioContext) -> float:
    """SWA amplitude (rad, positive) from ``swa_deg`` or ``swa_scale`` × SWA at 0.3 g."""
    swa_deg = values.get("swa_deg")
    if swa_deg is not None:
        return math.radians(abs(float(swa_deg)))
    return float(values["swa_scale"]) * ctx.swa_03g()  # type: ignore[arg-type]


def _num(values: Values, name: str) -> float:
    value = values[name]
    if not isinstance(value, float | int):
        raise SimulationError(f"parameter {name!r} must be a number, got {value!r}")
    return float(value)


# ---------------------------------------------------------------------------------------------
# Straight run
# ---------------------------------------------------------------------------------------------


def _straight_entry(v: Values) -> tuple[float, float | None]:
    heading = v["heading_deg"]
    yaw = None if heading is None else azimuth_to_yaw(math.radians(float(heading)))
    return _num(v, "speed_kmh") * KMH, yaw


def _straight_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    duration = _num(v, "duration_s")
    _, yaw = _straight_entry(v)
    line_yaw = st.yaw if yaw is None else st.yaw + wrap_pi(yaw - st.yaw)
    line = PolylinePath.line(st.east, st.north, line_yaw, speed * duration + 200.0)
    yield Phase(duration_s=duration, speed=constant_speed(speed), controller=ctx.follower(line), label="straight")


# ---------------------------------------------------------------------------------------------
# Steady-state circle (ISO 4138, constant radius, slowly increasing speed)
# ---------------------------------------------------------------------------------------------


def _circle_check(v: Values) -> None:
    if _num(v, "speed_end_kmh") < _num(v, "speed_start_kmh"):
        raise SimulationError("scenario 'steady_state_circle': speed_end_kmh must be >= speed_start_kmh")


def _circle_entry(v: Values) -> tuple[float, float | None]:
    return _num(v, "speed_start_kmh") * KMH, None


def _circle_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    radius = _num(v, "radius_m")
    turn = _turn(v)
    v0 = _num(v, "speed_start_kmh") * KMH
    v1 = _num(v, "speed_end_kmh") * KMH
    jerk = _num(v, "ay_rate_mps3")
    settle = _num(v, "settle_s")
    hold = _num(v, "hold_s")
    # Circle tangent to the car's heading, on the side of the turn.
    cx = st.east - turn * radius * math.sin(st.yaw)
    cy = st.north + turn * radius * math.cos(st.yaw)
    theta0 = math.atan2(st.north - cy, st.east - cx)
    path = CirclePath(cx, cy, radius, turn, theta0)
    ay0, ay1 = v0 * v0 / radius, v1 * v1 / radius
    t_ramp = (ay1 - ay0) / jerk

    def speed(tau: FloatArray) -> tuple[FloatArray, FloatArray]:
        ramp_t = np.clip(tau - settle, 0.0, t_ramp)
        vv = np.sqrt(radius * (ay0 + jerk * ramp_t))
        on_ramp = (tau >= settle) & (tau < settle + t_ramp)
        acc = np.where(on_ramp, radius * jerk / (2.0 * np.maximum(vv, 1e-3)), 0.0)
        return vv, acc

    yield Phase(
        duration_s=settle + t_ramp + hold,
        speed=speed,
        controller=ctx.follower(path, preview_time_s=0.6, min_preview_m=4.0, integral_gain=0.01),
        label="circle",
        meta={"circle_east_m": cx, "circle_north_m": cy, "radius_m": radius},
    )


# ---------------------------------------------------------------------------------------------
# ISO 3888-1 double lane change
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DoubleLaneChangeCourse:
    """ISO 3888-1 course in its own frame: x along the entry heading from the entry point, y to the left."""

    sections: tuple[tuple[float, float, float, float], ...]
    """Coned lanes as (x_start, x_end, y_centre, width) for sections 1, 3 and 5 (m)."""
    cones: FloatArray
    """Cone positions (n, 2) on the lane boundaries (m)."""
    transitions: tuple[tuple[float, float, float, float], ...]
    """Reference-path lane changes as (x_start, x_end, y_from, y_to) (m)."""
    end_x: float
    """x where the run ends (m)."""

    def reference_y(self, x: FloatArray) -> FloatArray:
        """Lateral position of the reference path (lane centres joined by half-cosine blends)."""
        x = np.asarray(x, dtype=float)
        y = np.full_like(x, self.transitions[0][2])
        for x0, x1, y0, y1 in self.transitions:
            u = np.clip((x - x0) / (x1 - x0), 0.0, 1.0)
            y = np.where(x >= x0, y0 + (y1 - y0) * 0.5 * (1.0 - np.cos(np.pi * u)), y)
        return y


def iso3888_1_course(
    vehicle_width_m: float, *, lane_offset_m: float = 3.5, lead_in_m: float = 50.0, exit_m: float = 40.0, turn: int = 1
) -> DoubleLaneChangeCourse:
    """The ISO 3888-1 double lane change for a car of width ``vehicle_width_m``.

    Sections (length, width): 1: 15 m, 1.1·w + 0.25; 2: 30 m; 3: 25 m, 1.2·w + 0.25; 4: 25 m;
    5: 15 m, 1.3·w + 0.25. Section 3 is offset by ``lane_offset_m`` (3.5 m), taken here between
    the right-hand cone lines of sections 1 and 3 (for a lane change to the left); the right-hand
    lines of sections 1 and 5 are aligned. Cones every 3.75 m (sections 1, 5) and 5 m (section 3).
    """
    w = vehicle_width_m
    s = 1 if turn >= 0 else -1
    wa, wb, wc = 1.1 * w + 0.25, 1.2 * w + 0.25, 1.3 * w + 0.25
    x1 = lead_in_m
    x2, x3 = x1 + 15.0, x1 + 45.0
    x4, x5, x6 = x3 + 25.0, x3 + 50.0, x3 + 65.0
    ya = 0.0
    yb = s * (lane_offset_m + 0.5 * (wb - wa))
    yc = s * 0.5 * (wc - wa)
    sections = ((x1, x2, ya, wa), (x3, x4, yb, wb), (x5, x6, yc, wc))
    cones = []
    for (xs, xe, yc_, wid), n in zip(sections, (5, 6, 5), strict=True):
        for x in np.linspace(xs, xe, n):
            cones.append((x, yc_ + 0.5 * wid))
            cones.append((x, yc_ - 0.5 * wid))
    return DoubleLaneChangeCourse(
        sections=sections,
        cones=np.asarray(cones, dtype=float),
        transitions=((x2, x3, ya, yb), (x4, x5, yb, yc)),
        end_x=x6 + exit_m,
    )


def _dlc_entry(v: Values) -> tuple[float, float | None]:
    return _num(v, "speed_kmh") * KMH, None


def _dlc_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    course = iso3888_1_course(
        ctx.params.body_width_m,
        lane_offset_m=_num(v, "lane_offset_m"),
        lead_in_m=_num(v, "lead_in_m"),
        exit_m=_num(v, "exit_m"),
        turn=_turn(v),
    )
    x = np.arange(0.0, course.end_x + 60.0, 0.1)
    y = course.reference_y(x)
    c, s = math.cos(st.yaw), math.sin(st.yaw)
    path = PolylinePath(st.east + c * x - s * y, st.north + s * x + c * y, ds=0.1)
    follower = ctx.follower(path, end_s=course.end_x)
    yield Phase(
        duration_s=course.end_x / speed + 10.0,
        speed=constant_speed(speed),
        controller=follower,
        label="double_lane_change",
        meta={"course_east_m": st.east, "course_north_m": st.north, "course_yaw_rad": st.yaw},
    )


# ---------------------------------------------------------------------------------------------
# Open-loop steering manoeuvres
# ---------------------------------------------------------------------------------------------


def _speed_entry(v: Values) -> tuple[float, float | None]:
    return _num(v, "speed_kmh") * KMH, None


def _step_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    st = yield _lead_in(ctx, st, speed, _num(v, "lead_s"), "step_steer.lead")
    if v["swa_deg"] is None:
        amp = ctx.swa_for_ay(speed, _num(v, "ay_mps2"))
    else:
        amp = math.radians(abs(_num(v, "swa_deg")))
    target = _turn(v) * amp
    rise = _num(v, "rise_s")
    hold = _num(v, "hold_s")
    yield Phase(
        duration_s=rise + hold,
        speed=constant_speed(speed),
        swa=_ramp_profile([0.0, rise], [st.swa, target]),
        label="step_steer",
        meta={"swa_amplitude_deg": math.degrees(target)},
    )


def _j_turn_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    st = yield _lead_in(ctx, st, speed, _num(v, "lead_s"), "j_turn.lead")
    target = _turn(v) * _amplitude(v, ctx)
    rate = math.radians(_num(v, "rate_dps"))
    t_ramp = abs(target - st.swa) / rate
    yield Phase(
        duration_s=t_ramp + _num(v, "hold_s"),
        speed=None,
        swa=_ramp_profile([0.0, t_ramp], [st.swa, target]),
        label="j_turn",
        meta={"swa_amplitude_deg": math.degrees(target)},
    )


def _fishhook_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    st = yield _lead_in(ctx, st, speed, _num(v, "lead_s"), "fishhook.lead")
    amp = _turn(v) * _amplitude(v, ctx)
    rate = math.radians(_num(v, "rate_dps"))
    t1 = abs(amp - st.swa) / rate
    t2 = t1 + _num(v, "dwell_s")
    t3 = t2 + 2.0 * abs(amp) / rate
    t4 = t3 + _num(v, "hold_s")
    t5 = t4 + abs(amp) / rate
    yield Phase(
        duration_s=t5 + _num(v, "post_s"),
        speed=None,
        swa=_ramp_profile([0.0, t1, t2, t3, t4, t5], [st.swa, amp, amp, -amp, -amp, 0.0]),
        label="fishhook",
        meta={"swa_amplitude_deg": math.degrees(amp)},
    )


def _swd_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    st = yield _lead_in(ctx, st, speed, _num(v, "lead_s"), "sine_with_dwell.lead")
    amp = _turn(v) * _amplitude(v, ctx)
    f = _num(v, "frequency_hz")
    dwell = _num(v, "dwell_s")
    w = 2.0 * math.pi * f
    t_dwell = 0.75 / f
    t_end = 1.0 / f + dwell
    swa0 = st.swa

    def profile(tau: FloatArray) -> FloatArray:
        ts = np.where(tau < t_dwell, tau, np.where(tau < t_dwell + dwell, t_dwell, tau - dwell))
        out = amp * np.sin(w * ts)
        out = np.where(tau >= t_end, 0.0, out)
        # Fade out whatever small angle the lead-in left over the first 0.1 s.
        return np.asarray(out + swa0 * np.clip(1.0 - tau / 0.1, 0.0, 1.0), dtype=float)

    yield Phase(
        duration_s=t_end + _num(v, "post_s"),
        speed=None,
        swa=profile,
        label="sine_with_dwell",
        meta={"swa_amplitude_deg": math.degrees(amp)},
    )


# ---------------------------------------------------------------------------------------------
# Constant-SWA circles at walking speed, forward and reverse (steering-ratio calibration)
# ---------------------------------------------------------------------------------------------


def swa_circle_values_deg(swa_max_deg: float, swa_step_deg: float) -> list[float]:
    """SWA set points (deg): 0, ±step, ±2·step, … below ``swa_max_deg``, and ±``swa_max_deg``, ascending."""
    k = math.floor(swa_max_deg / swa_step_deg + 1e-9)
    pos = [i * swa_step_deg for i in range(1, k + 1) if i * swa_step_deg < swa_max_deg - 1e-9]
    pos.append(swa_max_deg)
    return sorted([-x for x in pos] + [0.0] + pos)


def _circles_check(v: Values) -> None:
    if _num(v, "swa_step_deg") > _num(v, "swa_max_deg"):
        raise SimulationError("scenario 'swa_circles': swa_step_deg must not exceed swa_max_deg")


def _circles_entry(v: Values) -> tuple[float, float | None]:
    if v["direction"] == "reverse":
        return 0.0, None
    return _num(v, "speed_kmh") * KMH, None


def _circles_run(v: Values, ctx: ScenarioContext, st: VehicleState) -> PhaseGen:
    speed = _num(v, "speed_kmh") * KMH
    lock_deg = math.degrees(ctx.gear.lock_swa)
    if _num(v, "swa_max_deg") > lock_deg + 1e-9:
        raise SimulationError(
            f"scenario 'swa_circles': swa_max_deg {_num(v, 'swa_max_deg'):g} is beyond the steering lock "
            f"({lock_deg:g}°)"
        )
    values = swa_circle_values_deg(_num(v, "swa_max_deg"), _num(v, "swa_step_deg"))
    rate = math.radians(_num(v, "swa_rate_dps"))
    settle, hold = _num(v, "settle_s"), _num(v, "hold_s")
    direction = v["direction"]
    legs: list[tuple[str, float, list[float]]] = []
    if direction in ("forward", "both"):
        legs.append(("forward", speed, values))
    if direction in ("reverse", "both"):
        legs.append(("reverse", -speed, values[::-1] if direction == "both" else values))
    for name, v_leg, order in legs:
        if abs(st.vx - v_leg) > 0.05:
            # Stop (if needed), then get to the leg's speed; the steering stays where it is.
            t_stop = abs(st.vx) / 1.0
            t_go = t_stop + 1.0 + abs(v_leg) / 1.0
            swa_now = st.swa
            st = yield Phase(
                duration_s=t_go + 1.0,
                speed=piecewise_speed([0.0, t_stop, t_stop + 1.0, t_go], [st.vx, 0.0, 0.0, v_leg]),
                swa=_hold_profile(swa_now),
                label=f"swa_circles.{name}.start",
            )
        knots_t, knots_s = [0.0], [st.swa]
        t = 0.0
        for target in order:
            t += abs(math.radians(target) - knots_s[-1]) / rate
            knots_t.append(t)
            knots_s.append(math.radians(target))
            t += settle + hold
            knots_t.append(t)
            knots_s.append(math.radians(target))
        st = yield Phase(
            duration_s=t,
            speed=constant_speed(v_leg),
            swa=_ramp_profile(knots_t, knots_s),
            label=f"swa_circles.{name}",
            meta={
                "swa_values_deg": ",".join(f"{x:g}" for x in order),
                "hold_start_s": ",".join(f"{knots_t[2 * i + 1] + settle:.3f}" for i in range(len(order))),
                "hold_s": hold,
            },
        )


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------

_TURN = ParamSpec("turn", "left", "", "direction of the (first) steer", choices=("left", "right"))
_SPEED_MIN = 1.0


def _speed(default: float) -> ParamSpec:
    return ParamSpec("speed_kmh", default, "km/h", "test speed", minimum=_SPEED_MIN, maximum=250.0)


def _lead(default: float = 2.0) -> ParamSpec:
    return ParamSpec("lead_s", default, "s", "straight driving before the steering input", minimum=0.0)


_SWA_DEG = ParamSpec("swa_deg", None, "deg", "steering-wheel amplitude; auto = swa_scale × SWA at 0.3 g", minimum=0.0)

_SPECS = (
    ScenarioSpec(
        name="straight",
        title="Straight run at constant speed",
        reference="",
        params=(
            _speed(80.0),
            ParamSpec(
                "heading_deg", None, "deg", "azimuth clockwise from north; auto = keep the current heading",
                minimum=-360.0, maximum=360.0,
            ),
            ParamSpec("duration_s", 20.0, "s", "length of the run", minimum=0.1),
        ),
        entry=_straight_entry,
        run=_straight_run,
    ),
    ScenarioSpec(
        name="steady_state_circle",
        title="Steady-state circular driving, constant radius, slowly increasing speed (closed loop on radius)",
        reference="ISO 4138",
        params=(
            ParamSpec("radius_m", 20.0, "m", "circle radius (CG path)", minimum=5.0),
            _TURN,
            ParamSpec("speed_start_kmh", 10.0, "km/h", "speed at the start", minimum=_SPEED_MIN, maximum=250.0),
            ParamSpec("speed_end_kmh", 45.0, "km/h", "speed at the end", minimum=_SPEED_MIN, maximum=250.0),
            ParamSpec("ay_rate_mps3", 0.1, "m/s^3", "rate of increase of v²/R during the ramp", minimum=1e-3),
            ParamSpec("settle_s", 10.0, "s", "time at the start speed before the ramp", minimum=0.0),
            ParamSpec("hold_s", 2.0, "s", "time at the end speed", minimum=0.0),
        ),
        entry=_circle_entry,
        run=_circle_run,
        check=_circle_check,
    ),
    ScenarioSpec(
        name="double_lane_change",
        title="Double lane change through the coned course (closed-loop path follower)",
        reference="ISO 3888-1",
        params=(
            _speed(50.0),
            ParamSpec("turn", "left", "", "direction of the first lane change", choices=("left", "right")),
            ParamSpec("lane_offset_m", 3.5, "m", "offset of section 3 (between right-hand cone lines)", minimum=0.0),
            ParamSpec("lead_in_m", 50.0, "m", "straight approach before section 1", minimum=5.0),
            ParamSpec("exit_m", 40.0, "m", "straight run after section 5", minimum=0.0),
        ),
        entry=_dlc_entry,
        run=_dlc_run,
    ),
    ScenarioSpec(
        name="step_steer",
        title="Step steer at constant speed",
        reference="ISO 7401",
        params=(
            _speed(80.0),
            ParamSpec("ay_mps2", 4.0, "m/s^2", "steady lateral acceleration the step aims at", minimum=0.1),
            ParamSpec("swa_deg", None, "deg", "steering-wheel step; auto = from ay_mps2 (linear model)", minimum=0.0),
            _TURN,
            ParamSpec("rise_s", 0.15, "s", "time of the steering ramp", minimum=0.001),
            _lead(),
            ParamSpec("hold_s", 4.0, "s", "time the step is held", minimum=0.0),
        ),
        entry=_speed_entry,
        run=_step_run,
    ),
    ScenarioSpec(
        name="j_turn",
        title="J-turn: fast steer and hold with the throttle released",
        reference="NHTSA rollover resistance (J-turn)",
        params=(
            _speed(60.0),
            ParamSpec("swa_scale", 8.0, "", "amplitude as a multiple of the SWA at 0.3 g", minimum=0.0),
            _SWA_DEG,
            _TURN,
            ParamSpec("rate_dps", 1000.0, "deg/s", "steering rate", minimum=1.0),
            _lead(),
            ParamSpec("hold_s", 4.0, "s", "time the steer is held", minimum=0.0),
        ),
        entry=_speed_entry,
        run=_j_turn_run,
    ),
    ScenarioSpec(
        name="fishhook",
        title="Fishhook: steer, dwell, counter-steer and hold with the throttle released",
        reference="NHTSA fishhook 1a",
        params=(
            _speed(60.0),
            ParamSpec("swa_scale", 6.5, "", "amplitude as a multiple of the SWA at 0.3 g", minimum=0.0),
            _SWA_DEG,
            _TURN,
            ParamSpec("rate_dps", 720.0, "deg/s", "steering rate", minimum=1.0),
            ParamSpec("dwell_s", 0.25, "s", "dwell at the first peak", minimum=0.0),
            ParamSpec("hold_s", 3.0, "s", "time the counter-steer is held", minimum=0.0),
            ParamSpec("post_s", 1.0, "s", "time after the steering is back at zero", minimum=0.0),
            _lead(),
        ),
        entry=_speed_entry,
        run=_fishhook_run,
    ),
    ScenarioSpec(
        name="sine_with_dwell",
        title="Sine with dwell with the throttle released",
        reference="FMVSS 126 / UN R140",
        params=(
            _speed(80.0),
            ParamSpec("swa_scale", 5.0, "", "amplitude as a multiple of the SWA at 0.3 g", minimum=0.0),
            _SWA_DEG,
            _TURN,
            ParamSpec("frequency_hz", 0.7, "Hz", "frequency of the sine", minimum=0.05, maximum=5.0),
            ParamSpec("dwell_s", 0.5, "s", "dwell at the second peak", minimum=0.0),
            ParamSpec("post_s", 3.0, "s", "time after the steering is back at zero", minimum=0.0),
            _lead(),
        ),
        entry=_speed_entry,
        run=_swd_run,
    ),
    ScenarioSpec(
        name="swa_circles",
        title="Constant steering-wheel-angle circles at walking speed, forward and reverse (steering ratio)",
        reference="",
        params=(
            ParamSpec("speed_kmh", 5.0, "km/h", "driving speed (reverse legs drive backwards at it)", minimum=0.5,
                      maximum=20.0),
            ParamSpec("swa_max_deg", 520.0, "deg", "largest steering-wheel angle either side", minimum=1.0),
            ParamSpec("swa_step_deg", 30.0, "deg", "spacing of the set points", minimum=0.5),
            ParamSpec("direction", "both", "", "forward, reverse, or both", choices=("forward", "reverse", "both")),
            ParamSpec("swa_rate_dps", 60.0, "deg/s", "steering rate between set points", minimum=1.0),
            ParamSpec("settle_s", 4.0, "s", "settling time after each change", minimum=0.0),
            ParamSpec("hold_s", 8.0, "s", "steady time at each set point", minimum=0.0),
        ),
        entry=_circles_entry,
        run=_circles_run,
        check=_circles_check,
    ),
)

SCENARIOS: Mapping[str, ScenarioSpec] = MappingProxyType({s.name: s for s in _SPECS})
"""All scenarios by name."""



# ---------------------------------------------------------------------------------------------
# The demo session drive
# ---------------------------------------------------------------------------------------------


def demo_drive(
    *,
    straight_kmh: float = 40.0,
    straight_s: float = 8.0,
    heading_deg: float = 0.0,
    swa_max_deg: float = 520.0,
    swa_step_deg: float = 455.0,
    swa_settle_s: float = 0.5,
    swa_hold_s: float = 5.3,
    gap_s: float = 3.0,
) -> Drive:
    """A short test day for the demo and CI (about 150 s of driving at the defaults).

    In order: a straight run at ``straight_kmh`` on ``heading_deg`` (azimuth) for ``straight_s``;
    constant-SWA circles at 5 km/h forward and in reverse at 0, ±``swa_step_deg``, … ±``swa_max_deg``
    (0, ±390 and ±520° at the defaults: 5.8 s at each is ≈ 78° of the 5.9 m rear-axle circle at 390°
    and ≈ 114° of the 4.1 m one at 520°, enough for ``rig calibrate-steering-ratio``; smaller angles
    need longer holds, the radius grows as 1/δ); the same straight run in the opposite direction; a
    steady-state circle (R = 20 m, 20 → 40 km/h); an ISO 3888-1 double lane change at 50 km/h; a J-turn at 60 km/h.
    Transitions of at least ``gap_s`` join them. Raises SimulationError for bad values.
    """
    opposite = heading_deg + 180.0 if heading_deg < 180.0 else heading_deg - 180.0
    return Drive(
        [
            make_scenario("straight", speed_kmh=straight_kmh, duration_s=straight_s, heading_deg=heading_deg),
            make_scenario(
                "swa_circles",
                speed_kmh=5.0,
                swa_max_deg=swa_max_deg,
                swa_step_deg=swa_step_deg,
                direction="both",
                swa_rate_dps=180.0,
                settle_s=swa_settle_s,
                hold_s=swa_hold_s,
            ),
            make_scenario("straight", speed_kmh=straight_kmh, duration_s=straight_s, heading_deg=opposite),
            make_scenario(
                "steady_state_circle",
                radius_m=20.0,
                speed_start_kmh=20.0,
                speed_end_kmh=40.0,
                ay_rate_mps3=0.4,
                settle_s=3.0,
                hold_s=1.0,
            ),
            make_scenario("double_lane_change", speed_kmh=50.0, lead_in_m=20.0, exit_m=20.0),
            make_scenario("j_turn", speed_kmh=60.0, lead_s=1.5, hold_s=3.0),
        ],
        gap_s=gap_s,
    )
