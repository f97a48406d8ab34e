"""Antenna kinematics against the vehicle model's own geodesy (positions) and numerical derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from sim_devices.gnss.antenna import TruthAntenna
from sim_devices.vehicle import GroundTruth, point_enu_rolled, point_geodetic

LEVER = (0.6, 0.3, 1.0)


def test_position_matches_point_geodetic(truth: GroundTruth) -> None:
    ant = TruthAntenna(truth, LEVER)
    lat, lon, h = point_geodetic(truth, *LEVER)
    for i in range(0, len(truth), 137):
        st = ant.state(float(truth.t[i]))
        assert st.lat_deg == pytest.approx(lat[i], abs=1e-10)
        assert st.lon_deg == pytest.approx(lon[i], abs=1e-10)
        assert st.height_m == pytest.approx(h[i], abs=1e-6)


def test_velocity_is_the_derivative_of_the_position(truth: GroundTruth) -> None:
    ant = TruthAntenna(truth, LEVER)
    e, n, u = point_enu_rolled(truth, *LEVER)
    de, dn, du = (np.gradient(x, truth.t) for x in (e, n, u))
    idx = range(50, len(truth) - 50, 53)
    v = np.array([ant.enu(float(truth.t[i]))[3:] for i in idx])
    ref = np.array([[de[i], dn[i], du[i]] for i in idx])
    # Central differences at 100 Hz of a smooth trajectory: agreement to a few mm/s.
    np.testing.assert_allclose(v, ref, atol=0.01)
    assert np.max(np.abs(ref[:, 2])) > 0.02  # roll rate moves the antenna vertically: a real check


def test_stands_still_outside_the_drive(truth: GroundTruth) -> None:
    ant = TruthAntenna(truth, LEVER)
    before = ant.enu(-5.0)
    after = ant.enu(float(truth.t[-1]) + 5.0)
    assert before[3:] == (0.0, 0.0, 0.0) and after[3:] == (0.0, 0.0, 0.0)
    assert before[:3] == pytest.approx(ant.enu(float(truth.t[0]))[:3])
