"""Geodetic positions (lat, lon, ellipsoidal height) of body points from the ground truth.

The ground truth's ENU frame has its origin at (``lat0_deg``, ``lon0_deg``, ``h0_m``) on the road
surface; the CG moves in the plane ``up = cg_height_m`` (flat road, no pitch). A body point
(x, y, z) given relative to the CG in vehicle axes is rotated by the body roll before it is placed,
so a roof antenna swings outwards in a turn. The ENU → geodetic conversion is pymap3d's (WGS 84).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pymap3d

from sim_devices.vehicle.truth import GroundTruth

__all__ = ["point_enu_rolled", "point_geodetic"]

FloatArray = npt.NDArray[np.float64]


def _cg_height(truth: GroundTruth) -> float:
    value = truth.meta.get("cg_height_m", 0.0)
    return float(value) if isinstance(value, int | float) else 0.0


def point_enu_rolled(
    truth: GroundTruth, x: float = 0.0, y: float = 0.0, z: float = 0.0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ENU position (m) of the body point (x, y, z) m from the CG, with body roll, relative to the origin.

    ``up`` is measured from the road surface at the origin (the CG is at ``cg_height_m``).
    """
    c_r, s_r = np.cos(truth.roll), np.sin(truth.roll)
    # Roll about the body x axis: positive roll (right side down) lifts points on the left.
    y_r = y * c_r - z * s_r
    z_r = y * s_r + z * c_r
    c, s = np.cos(truth.yaw), np.sin(truth.yaw)
    east = truth.east + c * x - s * y_r
    north = truth.north + s * x + c * y_r
    up = _cg_height(truth) + z_r
    return east, north, np.asarray(up, dtype=float)


def point_geodetic(
    truth: GroundTruth, x: float = 0.0, y: float = 0.0, z: float = 0.0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Latitude (deg), longitude (deg) and ellipsoidal height (m) of the body point (x, y, z) from the CG."""
    east, north, up = point_enu_rolled(truth, x, y, z)
    lat, lon, h = pymap3d.enu2geodetic(east, north, up, truth.lat0_deg, truth.lon0_deg, truth.h0_m)
    return (
        np.asarray(lat, dtype=np.float64),
        np.asarray(lon, dtype=np.float64),
        np.asarray(h, dtype=np.float64),
    )
