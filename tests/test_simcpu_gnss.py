"""The simulated receivers' cheaper per-epoch maths against pymap3d and the error model's own parameters.

``sim_devices.gnss.geodesy.EnuOrigin`` replaces pymap3d's ``enu2geodetic`` in the antenna of every
rover (it was most of a rover thread's time); these tests hold it to pymap3d within 1e-9° and 1 µm
over the globe and along a simulated drive (the brief's bound for "identical" outputs).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from drivers.novatel.enums import PositionType
from sim_devices.gnss import SimRover, SimTimeBase
from sim_devices.gnss.antenna import TruthAntenna
from sim_devices.gnss.commands import Trigger, parse_command
from sim_devices.gnss.error_model import GnssErrorModel, GnssErrorParams, SolutionNoise
from sim_devices.gnss.geodesy import EnuOrigin, ecef_to_geodetic
from sim_devices.vehicle import GroundTruth, make_scenario, simulate

DEG_TOL = 1e-9
M_TOL = 1e-6


@pytest.fixture(scope="module")
def lane_change() -> GroundTruth:
    return simulate(make_scenario("double_lane_change"), seed=0)


def test_enu_to_geodetic_matches_pymap3d_over_the_globe() -> None:
    rng = np.random.default_rng(5)
    for _ in range(3000):
        lat0, lon0, h0 = rng.uniform(-89.9, 89.9), rng.uniform(-180.0, 180.0), rng.uniform(-400.0, 9000.0)
        e, n, u = rng.uniform(-20_000.0, 20_000.0, 3)
        got = EnuOrigin(lat0, lon0, h0).to_geodetic(e, n, u)
        want = [float(v) for v in pymap3d.enu2geodetic(e, n, u, lat0, lon0, h0)]
        assert got[0] == pytest.approx(want[0], abs=DEG_TOL)
        assert math.remainder(got[1] - want[1], 360.0) == pytest.approx(0.0, abs=DEG_TOL)
        assert got[2] == pytest.approx(want[2], abs=M_TOL)


@pytest.mark.parametrize(
    "xyz",
    [
        (0.0, 0.0, 6_356_752.31424518 + 10.0),  # above the north pole
        (0.0, 0.0, -6_356_752.31424518 - 10.0),  # south pole
        (6_378_137.0 - 50.0, 0.0, 0.0),  # inside the ellipsoid on the equator: negative height
        (4_000_000.0, -3_000_000.0, 3_500_000.0),
    ],
)
def test_ecef_edge_cases_match_pymap3d(xyz: tuple[float, float, float]) -> None:
    got = ecef_to_geodetic(*xyz)
    want = [float(v) for v in pymap3d.ecef2geodetic(*xyz)]
    assert got[0] == pytest.approx(want[0], abs=DEG_TOL)
    assert got[1] == pytest.approx(want[1], abs=DEG_TOL)
    assert got[2] == pytest.approx(want[2], abs=M_TOL)


def test_antenna_state_along_a_drive_matches_pymap3d(lane_change: GroundTruth) -> None:
    truth = lane_change
    ant = TruthAntenna(truth, (-1.6, 0.1, 1.45))
    # off the truth grid (interpolated), before the start and after the end (standing still)
    times = np.concatenate([[-3.0], np.arange(0.0, float(truth.t[-1]), 0.0137), [float(truth.t[-1]) + 2.0]])
    worst = [0.0, 0.0, 0.0]
    for t in times.tolist():
        st = ant.state(t)
        e, n, u, ve, vn, vu = ant.enu(t)
        want = [float(v) for v in pymap3d.enu2geodetic(e, n, u, truth.lat0_deg, truth.lon0_deg, truth.h0_m)]
        for k, (a, b) in enumerate(zip((st.lat_deg, st.lon_deg, st.height_m), want, strict=True)):
            worst[k] = max(worst[k], abs(a - b))
        assert (st.v_east_mps, st.v_north_mps, st.v_up_mps) == (ve, vn, vu)
    assert worst[0] < DEG_TOL and worst[1] < DEG_TOL and worst[2] < M_TOL, worst


def test_antenna_interpolation_is_linear_between_truth_samples(lane_change: GroundTruth) -> None:
    truth = lane_change
    ant = TruthAntenna(truth, (0.0, 0.0, 1.4))
    i = len(truth) // 2
    t0, t1 = float(truth.t[i]), float(truth.t[i + 1])
    a, b = np.asarray(ant.enu(t0)), np.asarray(ant.enu(t1))
    mid = np.asarray(ant.enu(0.5 * (t0 + t1)))
    # the lever arm turns with yaw and roll between samples: the midpoint lies within a µm of the chord
    np.testing.assert_allclose(mid[:3], 0.5 * (a[:3] + b[:3]), atol=1e-6)


def test_error_model_sigmas_follow_the_solution_type_and_replaced_parameters() -> None:
    model = GnssErrorModel(seed=4)
    fixed = model.sample(1_000_000_000, PositionType.NARROW_INT)
    single = model.sample(1_050_000_000, PositionType.SINGLE)
    assert fixed.position_sigma_enu_m[0] == pytest.approx(0.015 / math.sqrt(2.0))
    assert single.position_sigma_enu_m[2] == pytest.approx(2.5)
    with pytest.raises(ValueError, match="read-only"):
        fixed.position_sigma_enu_m[0] = 1.0  # shared by every epoch of that type: never changed in place
    noise = dict(model.params.noise)
    noise[PositionType.SINGLE] = SolutionNoise(3.0, 4.0, 0.1, 0.2)
    model.params = GnssErrorParams(noise=noise)
    again = model.sample(1_100_000_000, PositionType.SINGLE)
    assert again.position_sigma_enu_m[2] == pytest.approx(4.0)
    assert again.velocity_sigma_enu_mps[0] == pytest.approx(0.1)


def test_error_model_draws_are_unchanged_by_the_sigma_cache() -> None:
    """The same seed gives the same errors whether the sigmas come from the cache or are built anew."""
    cached = GnssErrorModel(seed=9)
    fresh = GnssErrorModel(seed=9)
    types = [PositionType.SINGLE, PositionType.PSRDIFF, PositionType.NARROW_FLOAT, PositionType.NARROW_INT]
    for k in range(400):
        pos_type = types[(k // 50) % len(types)]
        a = cached.sample(k * 50_000_000, pos_type)
        fresh._sigmas.clear()  # built anew for every epoch
        b = fresh.sample(k * 50_000_000, pos_type)
        np.testing.assert_array_equal(a.position_enu_m, b.position_enu_m)
        np.testing.assert_array_equal(a.velocity_enu_mps, b.velocity_enu_mps)
        noise = GnssErrorParams().noise_for(pos_type)
        np.testing.assert_array_equal(a.position_sigma_enu_m, noise.position_sigma_enu)


def test_epoch_schedule_cache_follows_every_change_of_the_logs(lane_change: GroundTruth, tmp_path: Path) -> None:
    """Whether solution epochs are needed is cached; LOG, UNLOG, UNLOGALL, RESET and a spent ONNEXT renew it."""
    rover = SimRover("rover_a", truth=lane_change, lever_arm=(0.0, 0.0, 1.4), link_dir=tmp_path,
                     timebase=SimTimeBase.from_gps_start(2400, 345600.0, leap_seconds=18))
    known = rover.known_logs()

    def apply(line: str) -> bool:
        rover._apply(parse_command(line, known), "COM1")
        return rover._needs_epochs()

    def fresh() -> bool:  # the uncached answer
        return any(e.trigger in (Trigger.ONNEW, Trigger.ONCHANGED, Trigger.ONNEXT) and e.name not in rover.ASYNC_LOGS
                   for e in rover._entries.values())

    assert not rover._needs_epochs()
    assert apply("LOG COM1 BESTPOSB ONTIME 0.05") is False
    assert apply("LOG COM1 BESTVELB ONNEW") is True
    assert apply("UNLOG COM1 BESTVELB") is False
    assert apply("LOG COM1 MARKPOSB ONNEW") is False  # asynchronous: fires on events, not epochs
    assert apply("LOG COM1 BESTVELB ONCHANGED") is True
    assert apply("UNLOGALL COM1") is False
    assert apply("LOG COM1 TIMEB ONNEXT") is True
    now = rover.gps_now_ns()
    rover._produce(now + 2 * rover.solution_period_ns)  # the ONNEXT log is sent once and removed
    assert rover._needs_epochs() is False and fresh() is False
    assert apply("LOG COM1 BESTPOSB ONNEW") is True
    rover._restore([])  # RESET to an empty saved configuration
    assert rover._needs_epochs() is False and fresh() is False
