"""True position and velocity of a GNSS antenna: on the simulated car (from the ground truth) or fixed.

A roof antenna sits at the lever arm (x, y, z) from the CG in vehicle axes. Its position follows
:func:`sim_devices.vehicle.geodesy.point_enu_rolled` (body roll swings it sideways and lifts it;
``up`` is measured from the road surface at the ENU origin, the CG riding at ``cg_height_m``), and
its velocity is that point's rigid-body velocity including the roll rate:

    y_r = y cos φ − z sin φ,   z_r = y sin φ + z cos φ,   ẏ_r = −z_r φ̇,   ż_r = y_r φ̇
    v_body = (v_x − r y_r,  v_y + r x + ẏ_r),  then rotated by the yaw ψ into ENU.

Outside the recorded drive the car stands still at its first or last position. The ENU → geodetic
conversion is :class:`~sim_devices.gnss.geodesy.EnuOrigin` (pymap3d's formulas, scalar: it runs at
every solution epoch of every rover).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim_devices.gnss.geodesy import EnuOrigin
from sim_devices.vehicle.truth import GroundTruth

__all__ = ["AntennaState", "AntennaTrack", "FixedAntenna", "TruthAntenna"]


@dataclass(frozen=True, slots=True)
class AntennaState:
    """True antenna position (geodetic, WGS 84, ellipsoidal height) and ENU velocity."""

    lat_deg: float
    lon_deg: float
    height_m: float
    v_east_mps: float
    v_north_mps: float
    v_up_mps: float


class AntennaTrack(Protocol):
    """Anything that gives the true antenna state at a truth time (s)."""

    def state(self, t_s: float) -> AntennaState: ...


class FixedAntenna:
    """A static antenna (a base station) at (``lat_deg``, ``lon_deg``, ellipsoidal ``height_m``)."""

    def __init__(self, lat_deg: float, lon_deg: float, height_m: float) -> None:
        self._state = AntennaState(lat_deg, lon_deg, height_m, 0.0, 0.0, 0.0)

    def state(self, t_s: float) -> AntennaState:
        return self._state


class TruthAntenna:
    """An antenna on the simulated car at ``lever_arm`` (x, y, z) m from the CG, vehicle axes."""

    _FIELDS = ("east", "north", "yaw", "roll", "vx", "vy", "yaw_rate", "roll_rate")

    def __init__(self, truth: GroundTruth, lever_arm: tuple[float, float, float]) -> None:
        if len(truth) == 0:
            raise ValueError("sim GNSS antenna: the ground truth is empty")
        self.truth = truth
        self.lever_arm = (float(lever_arm[0]), float(lever_arm[1]), float(lever_arm[2]))
        cg = truth.meta.get("cg_height_m", 0.0)
        self._cg_height = float(cg) if isinstance(cg, int | float) else 0.0
        self._t = truth.t
        self._t0 = float(truth.t[0])
        self._t1 = float(truth.t[-1])
        # one row per truth sample: the two rows around a time come out in one slice
        self._rows = np.ascontiguousarray(
            np.stack([np.asarray(getattr(truth, name), dtype=np.float64) for name in self._FIELDS], axis=1)
        )
        self._origin = EnuOrigin(truth.lat0_deg, truth.lon0_deg, truth.h0_m)

    def enu(self, t_s: float) -> tuple[float, float, float, float, float, float]:
        """(east, north, up, v_east, v_north, v_up) of the antenna at truth time ``t_s``."""
        t0 = self._t0
        t1 = self._t1
        moving = t0 <= t_s <= t1
        tc = min(max(t_s, t0), t1)
        n = len(self._t)
        if n > 1:
            i = int(np.searchsorted(self._t, tc, side="right")) - 1
            i = min(max(i, 0), n - 2)
            ta, tb = self._t[i : i + 2].tolist()
            w = (tc - ta) / (tb - ta)
            lo, hi = self._rows[i : i + 2].tolist()
            # the same IEEE operations as on the numpy rows, on Python floats
            row = [a * (1.0 - w) + b * w for a, b in zip(lo, hi, strict=True)]
        else:
            row = self._rows[0].tolist()
        east, north, yaw, roll, vx, vy, r, p = row
        if not moving:
            vx = vy = r = p = 0.0
        x, y, z = self.lever_arm
        cr, sr = math.cos(roll), math.sin(roll)
        y_r = y * cr - z * sr
        z_r = y * sr + z * cr
        cy, sy = math.cos(yaw), math.sin(yaw)
        e = east + cy * x - sy * y_r
        n = north + sy * x + cy * y_r
        u = self._cg_height + z_r
        vbx = vx - r * y_r
        vby = vy + r * x - z_r * p
        return e, n, u, cy * vbx - sy * vby, sy * vbx + cy * vby, y_r * p

    def state(self, t_s: float) -> AntennaState:
        e, n, u, ve, vn, vu = self.enu(t_s)
        lat, lon, h = self._origin.to_geodetic(e, n, u)
        return AntennaState(lat, lon, h, ve, vn, vu)
