"""Geodetic positions of the ground truth against pymap3d's ENU ↔ geodetic conversion."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from sim_devices.vehicle import (
    GroundTruth,
    VehicleParams,
    make_scenario,
    point_enu_rolled,
    point_geodetic,
    simulate,
    truth_columns,
)

PARAMS = VehicleParams()
ORIGIN = (-33.9, 151.2, 42.0)  # southern and eastern hemisphere, on purpose


@pytest.fixture(scope="module")
def turn() -> GroundTruth:
    scenario = make_scenario("step_steer", speed_kmh=60.0, ay_mps2=6.0, hold_s=3.0, lead_s=1.0)
    return simulate(scenario, PARAMS, rate_hz=100.0, origin=ORIGIN, initial_heading_deg=30.0)


def test_origin_and_heading(turn: GroundTruth) -> None:
    assert (turn.lat0_deg, turn.lon0_deg, turn.h0_m) == ORIGIN
    assert turn.east[0] == 0.0 and turn.north[0] == 0.0
    assert math.degrees(turn.heading_azimuth[0]) == pytest.approx(30.0, abs=1e-9)


def test_lat_lon_columns_invert_to_enu(turn: GroundTruth) -> None:
    cols = truth_columns(turn)
    e, n, u = pymap3d.geodetic2enu(cols["lat_deg"], cols["lon_deg"], cols["height_m"], *ORIGIN)
    np.testing.assert_allclose(e, turn.east, atol=1e-3)
    np.testing.assert_allclose(n, turn.north, atol=1e-3)
    np.testing.assert_allclose(u, PARAMS.cg_height_m, atol=1e-3)


def test_track_length_on_the_ellipsoid(turn: GroundTruth) -> None:
    """The distance between geodetic fixes (pymap3d.vincenty_dist) equals the ENU distance driven."""
    pymap3d_vincenty = pytest.importorskip("pymap3d.vincenty")
    cols = truth_columns(turn)
    step = 50
    lat, lon = cols["lat_deg"][::step], cols["lon_deg"][::step]
    dist, _ = pymap3d_vincenty.vdist(lat[:-1], lon[:-1], lat[1:], lon[1:])
    enu = np.hypot(np.diff(turn.east[::step]), np.diff(turn.north[::step]))
    np.testing.assert_allclose(dist, enu, rtol=1e-4, atol=1e-3)


def test_roof_point_leans_out_with_roll(turn: GroundTruth) -> None:
    """A point 1 m above the CG moves sideways by sin(φ) and its geodetic height drops by 1 − cos(φ)."""
    z = 1.0
    e0, n0, _ = point_enu_rolled(turn, 0.0, 0.0, 0.0)
    e1, n1, u1 = point_enu_rolled(turn, 0.0, 0.0, z)
    lateral = -np.sin(turn.yaw) * (e1 - e0) + np.cos(turn.yaw) * (n1 - n0)  # along body y (left)
    np.testing.assert_allclose(lateral, -z * np.sin(turn.roll), atol=1e-9)  # positive roll: top moves right
    assert np.max(turn.roll) > math.radians(2.0)
    lat, lon, h = point_geodetic(turn, 0.0, 0.0, z)
    e, n, u = pymap3d.geodetic2enu(lat, lon, h, *ORIGIN)
    np.testing.assert_allclose(e, e1, atol=1e-3)
    np.testing.assert_allclose(n, n1, atol=1e-3)
    np.testing.assert_allclose(u, PARAMS.cg_height_m + z * np.cos(turn.roll), atol=1e-3)
    np.testing.assert_allclose(u1, u, atol=1e-3)
