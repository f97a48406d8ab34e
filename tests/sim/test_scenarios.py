"""Every scenario runs, alone and composed into one drive; parameters are checked with clear messages."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_devices.vehicle import (
    GRAVITY,
    SCENARIOS,
    Drive,
    GroundTruth,
    VehicleParams,
    make_scenario,
    simulate,
    swa_circle_values_deg,
)
from sim_devices.vehicle.scenarios import demo_drive
from vsccore.angles import wrap_pi
from vsccore.errors import RigError, SimulationError

PARAMS = VehicleParams()

# Every scenario with short timings (keeps the test fast); a new scenario must be added here.
SHORT: dict[str, dict[str, object]] = {
    "straight": {"speed_kmh": 60.0, "duration_s": 2.0, "heading_deg": 90.0},
    "steady_state_circle": {"speed_start_kmh": 20.0, "speed_end_kmh": 25.0, "settle_s": 2.0, "hold_s": 1.0,
                            "ay_rate_mps3": 0.5},
    "double_lane_change": {"lead_in_m": 10.0, "exit_m": 5.0},
    "step_steer": {"lead_s": 0.5, "hold_s": 1.0},
    "swa_circles": {"swa_max_deg": 90.0, "swa_step_deg": 90.0, "settle_s": 1.0, "hold_s": 1.0},
    "j_turn": {"lead_s": 0.5, "hold_s": 1.0},
    "fishhook": {"lead_s": 0.5, "hold_s": 1.0, "post_s": 0.5},
    "sine_with_dwell": {"lead_s": 0.5, "post_s": 0.5},
}
RATE_HZ = 200.0


def test_every_scenario_is_covered() -> None:
    assert set(SHORT) == set(SCENARIOS)


@pytest.fixture(scope="module")
def drive_truth() -> GroundTruth:
    drive = Drive([make_scenario(name, **values) for name, values in SHORT.items()], gap_s=1.0)
    return simulate(drive, PARAMS, rate_hz=RATE_HZ)


def _segments(truth: GroundTruth) -> dict[str, tuple[float, float]]:
    out = {}
    i = 0
    while f"segment.{i}.name" in truth.meta:
        if truth.meta[f"segment.{i}.kind"] == "scenario":
            out[str(truth.meta[f"segment.{i}.name"])] = (
                float(truth.meta[f"segment.{i}.t_start_s"]),
                float(truth.meta[f"segment.{i}.t_end_s"]),
            )
        i += 1
    return out


def test_drive_contains_every_scenario_in_order(drive_truth: GroundTruth) -> None:
    segments = _segments(drive_truth)
    assert list(segments) == list(SHORT)
    starts = [t0 for t0, _ in segments.values()]
    assert starts == sorted(starts)
    for name, (t0, t1) in segments.items():
        assert t1 > t0, name


def test_truth_is_finite_and_uniform(drive_truth: GroundTruth) -> None:
    truth = drive_truth
    n = len(truth)
    np.testing.assert_allclose(np.diff(truth.t), 1.0 / RATE_HZ, atol=1e-9)
    for name in ("east", "north", "yaw", "vx", "vy", "yaw_rate", "ax", "ay", "ax_meas", "ay_meas", "roll",
                 "roll_rate", "road_wheel_angle", "swa", "ltr"):
        values = getattr(truth, name)
        assert values.shape == (n,), name
        assert np.all(np.isfinite(values)), name
    assert truth.wheel_speed.shape == (n, 4) and np.all(np.isfinite(truth.wheel_speed))
    np.testing.assert_allclose(truth.wheel_load.sum(axis=1), PARAMS.mass_kg * GRAVITY, rtol=1e-12)


def test_state_is_continuous_across_transitions(drive_truth: GroundTruth) -> None:
    """No jumps: positions advance by at most v·dt, velocities by at most the largest acceleration·dt."""
    truth = drive_truth
    dt = truth.dt
    step = np.hypot(np.diff(truth.east), np.diff(truth.north))
    assert np.all(step <= np.maximum(truth.speed[:-1], truth.speed[1:]) * dt * 1.02 + 1e-9)
    for name in ("vx", "vy"):
        assert np.max(np.abs(np.diff(getattr(truth, name)))) < 15.0 * dt, name
    assert np.max(np.abs(np.diff(truth.yaw))) < 2.0 * dt  # rad/s · s
    assert np.max(np.abs(truth.ay)) < 1.3 * PARAMS.tyre_peak_mu * GRAVITY


def test_each_scenario_starts_at_its_entry_speed(drive_truth: GroundTruth) -> None:
    truth = drive_truth
    for name, (t0, _) in _segments(truth).items():
        speed, yaw = make_scenario(name, **SHORT[name]).entry()
        i = truth.index_at(t0)
        assert truth.vx[i] == pytest.approx(speed, abs=0.1), name
        if yaw is not None:
            assert abs(wrap_pi(truth.yaw[i] - yaw)) < math.radians(0.5), name


def test_straight_heading(drive_truth: GroundTruth) -> None:
    t0, t1 = _segments(drive_truth)["straight"]
    sel = (drive_truth.t >= t0) & (drive_truth.t < t1)
    np.testing.assert_allclose(np.degrees(drive_truth.heading_azimuth[sel]), 90.0, atol=0.01)
    np.testing.assert_allclose(drive_truth.speed[sel] * 3.6, 60.0, atol=0.1)


def test_open_loop_steering_reaches_its_amplitude(drive_truth: GroundTruth) -> None:
    truth = drive_truth
    for key, value in truth.meta.items():
        if not key.endswith(".swa_amplitude_deg"):
            continue
        prefix = key[: -len(".swa_amplitude_deg")]
        sel = (truth.t >= float(truth.meta[prefix + ".t_start_s"])) & (truth.t < float(truth.meta[prefix + ".t_end_s"]))
        swa_deg = np.degrees(truth.swa[sel])
        peak = swa_deg.max() if float(value) > 0 else swa_deg.min()
        assert peak == pytest.approx(float(value), abs=0.01), key


def test_swa_circles_forward_and_reverse(drive_truth: GroundTruth) -> None:
    """Held set points: the car drives at ±5 km/h and yaws with the sign of SWA × direction of travel."""
    truth = drive_truth
    held = 0
    for key, value in truth.meta.items():
        if not key.endswith(".swa_values_deg"):
            continue
        prefix = key[: -len(".swa_values_deg")]
        t_phase = float(truth.meta[prefix + ".t_start_s"])
        starts = [float(x) for x in str(truth.meta[prefix + ".hold_start_s"]).split(",")]
        hold = float(truth.meta[prefix + ".hold_s"])
        for swa_deg, start in zip((float(x) for x in str(value).split(",")), starts, strict=True):
            sel = (truth.t >= t_phase + start) & (truth.t < t_phase + start + hold)
            np.testing.assert_allclose(np.degrees(truth.swa[sel]), swa_deg, atol=1e-9)
            np.testing.assert_allclose(np.abs(truth.vx[sel]) * 3.6, 5.0, atol=0.1)
            direction = np.sign(truth.vx[sel])
            if swa_deg != 0.0:
                assert np.all(np.sign(truth.yaw_rate[sel]) == np.sign(swa_deg) * direction)
            held += 1
    assert held == 2 * 3  # −90, 0, +90 forward and reverse


def test_swa_circle_values() -> None:
    values = swa_circle_values_deg(520.0, 30.0)
    assert values[0] == -520.0 and values[-1] == 520.0 and 0.0 in values
    assert len(values) == 2 * 18 + 1
    assert np.all(np.diff(values) > 0) and np.max(np.diff(values)) <= 30.0


def test_unknown_scenario_suggests_a_name() -> None:
    pattern = r"unknown scenario 'double_lane_chnage'.*did you mean 'double_lane_change'"
    with pytest.raises(SimulationError, match=pattern):
        make_scenario("double_lane_chnage")


def test_unknown_parameter_suggests_a_name() -> None:
    with pytest.raises(SimulationError, match=r"no parameter 'speed_kph'.*did you mean 'speed_kmh'"):
        make_scenario("j_turn", speed_kph=50)


@pytest.mark.parametrize(
    ("name", "params", "pattern"),
    [
        ("j_turn", {"speed_kmh": "fast"}, r"'speed_kmh' must be a number \(km/h\), got 'fast'"),
        ("j_turn", {"speed_kmh": 0.1}, r"'speed_kmh' must be >= 1 km/h"),
        ("j_turn", {"turn": "up"}, r"'turn' must be one of left, right"),
        ("steady_state_circle", {"speed_start_kmh": 50, "speed_end_kmh": 40}, r"speed_end_kmh must be >= speed_start"),
        ("straight", {"duration_s": float("nan")}, r"'duration_s' must be finite"),
    ],
)
def test_bad_values_are_rig_errors(name: str, params: dict[str, object], pattern: str) -> None:
    with pytest.raises(SimulationError, match=pattern) as info:
        make_scenario(name, **params)
    assert isinstance(info.value, RigError) and isinstance(info.value, ValueError)


def test_string_values_are_parsed() -> None:
    scenario = make_scenario("step_steer", speed_kmh="72.5", swa_deg="auto", turn="RIGHT")
    assert scenario.values["speed_kmh"] == 72.5
    assert scenario.values["swa_deg"] is None
    assert scenario.values["turn"] == "right"


def test_drive_rejects_bad_input() -> None:
    with pytest.raises(SimulationError, match="at least one scenario"):
        Drive([])
    with pytest.raises(SimulationError, match="gap_s"):
        Drive([make_scenario("straight")], gap_s=-1.0)


def test_demo_drive_is_short_and_complete() -> None:
    drive = demo_drive()
    names = [s.name for s in drive.scenarios]
    assert names.count("straight") == 2
    for required in ("swa_circles", "steady_state_circle", "double_lane_change", "j_turn"):
        assert required in names
    circles = next(s for s in drive.scenarios if s.name == "swa_circles")
    assert circles.values["direction"] == "both"
    swa_max, swa_step = circles.values["swa_max_deg"], circles.values["swa_step_deg"]
    assert isinstance(swa_max, float) and isinstance(swa_step, float)
    assert len(swa_circle_values_deg(swa_max, swa_step)) == 5


@pytest.fixture(scope="module")
def demo_truth() -> GroundTruth:
    return simulate(demo_drive(), PARAMS, rate_hz=100.0)


def test_demo_drive_runs(demo_truth: GroundTruth) -> None:
    truth = demo_truth
    assert truth.t[-1] <= 150.0
    straights = [
        (float(truth.meta[f"segment.{i}.t_start_s"]), float(truth.meta[f"segment.{i}.t_end_s"]))
        for i in range(40)
        if truth.meta.get(f"segment.{i}.name") == "straight"
    ]
    assert len(straights) == 2
    headings = []
    for t0, t1 in straights:
        assert t1 - t0 >= 8.0
        sel = (truth.t >= t0) & (truth.t < t1)
        np.testing.assert_allclose(truth.speed[sel] * 3.6, 40.0, atol=0.2)
        headings.append(float(np.mean(truth.heading_azimuth[sel])))
    assert abs(wrap_pi(headings[1] - headings[0])) == pytest.approx(math.pi, abs=math.radians(0.1))
    segments = _segments(truth)
    t0, t1 = segments["double_lane_change"]
    sel = (truth.t >= t0) & (truth.t < t1)
    np.testing.assert_allclose(truth.speed[sel] * 3.6, 50.0, atol=0.5)
    assert np.all(np.isfinite(truth.beta_cg))
