"""ENU → geodetic (WGS 84) around a fixed origin, for one point at a time, fast.

The simulated receivers convert the true antenna position of every solution epoch; pymap3d's
``enu2geodetic`` does the same maths on numpy arrays (with ``isclose`` tests and the ellipsoid looked
up per call), which costs a receiver thread more than everything else it does per epoch. Here the
origin's ECEF position and rotation are computed once and the conversion is scalar ``math``, with
the same formulas as pymap3d (ENU → ECEF by the origin's rotation; ECEF → geodetic by You (2000),
"Transformation of Cartesian to Geodetic Coordinates without Iterations", J. Surv. Eng., with one
correction step), so the results agree with pymap3d to rounding (tested against it).
"""

from __future__ import annotations

import math

__all__ = ["WGS84_A", "WGS84_B", "EnuOrigin"]

WGS84_A = 6378137.0
"""Semi-major axis (m), as pymap3d's ``wgs84``."""
WGS84_B = 6356752.31424518
"""Semi-minor axis (m), as pymap3d's ``wgs84``."""

_E2 = WGS84_A * WGS84_A - WGS84_B * WGS84_B  # linear eccentricity squared
_E = math.sqrt(_E2)
_LIM_PI2 = math.pi / 2 - 2.220446049250313e-16


class EnuOrigin:
    """A local ENU frame at (``lat0_deg``, ``lon0_deg``, ellipsoidal ``h0_m``) on WGS 84."""

    __slots__ = ("_cl", "_clon", "_sl", "_slon", "_x0", "_y0", "_z0", "h0_m", "lat0_deg", "lon0_deg")

    def __init__(self, lat0_deg: float, lon0_deg: float, h0_m: float) -> None:
        self.lat0_deg = float(lat0_deg)
        self.lon0_deg = float(lon0_deg)
        self.h0_m = float(h0_m)
        lat = math.radians(self.lat0_deg)
        lon = math.radians(self.lon0_deg)
        self._sl, self._cl = math.sin(lat), math.cos(lat)
        self._slon, self._clon = math.sin(lon), math.cos(lon)
        n = WGS84_A * WGS84_A / math.hypot(WGS84_A * self._cl, WGS84_B * self._sl)
        self._x0 = (n + self.h0_m) * self._cl * self._clon
        self._y0 = (n + self.h0_m) * self._cl * self._slon
        self._z0 = (n * (WGS84_B / WGS84_A) ** 2 + self.h0_m) * self._sl

    def to_ecef(self, east: float, north: float, up: float) -> tuple[float, float, float]:
        """ECEF (m) of an ENU offset (m) from the origin."""
        t = self._cl * up - self._sl * north
        w = self._sl * up + self._cl * north
        u = self._clon * t - self._slon * east
        v = self._slon * t + self._clon * east
        return self._x0 + u, self._y0 + v, self._z0 + w

    def to_geodetic(self, east: float, north: float, up: float) -> tuple[float, float, float]:
        """(lat deg, lon deg, ellipsoidal height m) of an ENU offset (m) from the origin."""
        return ecef_to_geodetic(*self.to_ecef(east, north, up))


def ecef_to_geodetic(x: float, y: float, z: float) -> tuple[float, float, float]:
    """(lat deg, lon deg, ellipsoidal height m) of an ECEF point (m) on WGS 84 (You 2000, as pymap3d)."""
    r2 = x * x + y * y + z * z
    u = math.sqrt(0.5 * (r2 - _E2) + 0.5 * math.hypot(r2 - _E2, 2.0 * _E * z))
    hxy = math.hypot(x, y)
    hue = math.hypot(u, _E)
    if abs(u) <= 1e-8 or abs(hxy) <= 1e-8:  # pymap3d: isclose(·, 0) with its default atol
        beta = 0.0 if abs(z) <= 1e-8 else (math.pi / 2 if z > 0 else -math.pi / 2)
    else:
        beta = math.atan(hue / u * z / hxy)
        beta += ((WGS84_B * u - WGS84_A * hue + _E2) * math.sin(beta)) / (
            WGS84_A * hue * 1 / math.cos(beta) - _E2 * math.cos(beta)
        )
    lat = math.atan(WGS84_A / WGS84_B * math.tan(beta))
    cos_beta = math.cos(beta)
    if beta >= _LIM_PI2:
        lat, cos_beta = math.pi / 2, 0.0
    elif beta <= -_LIM_PI2:
        lat, cos_beta = -math.pi / 2, 0.0
    lon = math.atan2(y, x)
    alt = math.hypot(z - WGS84_B * math.sin(beta), hxy - WGS84_A * cos_beta)
    if (x * x + y * y) / (WGS84_A * WGS84_A) + z * z / (WGS84_B * WGS84_B) < 1:
        alt = -alt  # inside the ellipsoid
    return math.degrees(lat), math.degrees(lon), alt
