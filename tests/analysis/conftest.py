"""Simulated drives shared by the analysis tests (simulated once per test session)."""

from __future__ import annotations

import pytest

from sim_devices.vehicle import Drive, GroundTruth, make_scenario, simulate


@pytest.fixture(scope="session")
def dlc() -> GroundTruth:
    """ISO 3888-1 double lane change at 50 km/h, ground truth at 1 kHz."""
    return simulate(make_scenario("double_lane_change", speed_kmh=50.0))


@pytest.fixture(scope="session")
def circle() -> GroundTruth:
    """Steady-state circle, 40 m radius, 40 → 50 km/h (β and the yaw rate are large and steady)."""
    return simulate(
        make_scenario("steady_state_circle", radius_m=40.0, speed_start_kmh=40.0, speed_end_kmh=50.0,
                      ay_rate_mps3=0.5, settle_s=4.0, hold_s=2.0),
        rate_hz=200.0,
    )


MIXED_SCENARIOS: tuple[tuple[str, dict[str, float | str]], ...] = (
    ("straight", {"speed_kmh": 60.0, "duration_s": 6.0}),
    ("double_lane_change", {"speed_kmh": 60.0}),
    ("step_steer", {"speed_kmh": 80.0}),
    ("j_turn", {}),
    ("fishhook", {}),
    ("steady_state_circle", {"radius_m": 40.0, "speed_start_kmh": 30.0, "speed_end_kmh": 50.0,
                             "ay_rate_mps3": 0.5, "settle_s": 3.0, "hold_s": 2.0}),
    ("sine_with_dwell", {}),
    ("swa_circles", {"swa_step_deg": 260.0, "hold_s": 6.0, "settle_s": 2.0, "direction": "forward"}),
)


@pytest.fixture(scope="session")
def mixed() -> GroundTruth:
    """One drive through every manoeuvre kind, joined by 4 s transitions, at 100 Hz (≈ 155 s)."""
    drive = Drive([make_scenario(name, **kw) for name, kw in MIXED_SCENARIOS], gap_s=4.0)
    return simulate(drive, rate_hz=100.0)
