"""Ground truth of a simulated drive: the contract between the vehicle model and every simulated sensor.

All arrays share the time vector ``t`` (s from the start of the drive, uniform, 1 kHz by default)
and are SI, ISO 8855 axes (x forward, y left, z up; yaw counter-clockwise from east in the local
ENU frame; yaw rate positive turning left). Wheel order everywhere is FL, FR, RL, RR.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from vsccore.angles import sideslip_from_velocity, yaw_to_azimuth

FloatArray = npt.NDArray[np.float64]

WHEELS = ("fl", "fr", "rl", "rr")


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """Sampled true state of the simulated vehicle (see module docstring for conventions)."""

    t: FloatArray
    """Time since the start of the drive (s)."""
    east: FloatArray
    """CG position east of the local origin (m)."""
    north: FloatArray
    """CG position north of the local origin (m)."""
    yaw: FloatArray
    """Yaw angle ψ, counter-clockwise from east (rad, unwrapped)."""
    vx: FloatArray
    """CG velocity along the body x axis (m/s)."""
    vy: FloatArray
    """CG velocity along the body y axis (m/s)."""
    yaw_rate: FloatArray
    """Yaw rate r (rad/s), positive turning left."""
    ax: FloatArray
    """True longitudinal acceleration of the CG in the horizontal vehicle frame (m/s²)."""
    ay: FloatArray
    """True lateral acceleration of the CG in the horizontal vehicle frame (m/s²)."""
    ax_meas: FloatArray
    """Longitudinal acceleration as a body-fixed accelerometer at the CG measures it (m/s²)."""
    ay_meas: FloatArray
    """Lateral acceleration as a body-fixed accelerometer measures it, incl. the roll component of gravity (m/s²)."""
    roll: FloatArray
    """Body roll angle φ (rad), positive right side down (ISO 8855, x forward)."""
    roll_rate: FloatArray
    """Roll rate (rad/s)."""
    road_wheel_angle: FloatArray
    """Front road-wheel steering angle δ (rad), positive to the left."""
    swa: FloatArray
    """Steering-wheel angle (rad), positive to the left (counter-clockwise)."""
    wheel_speed: FloatArray
    """Wheel circumferential speeds ω·r_e, shape (n, 4), FL FR RL RR (m/s)."""
    wheel_load: FloatArray
    """Vertical wheel loads, shape (n, 4), FL FR RL RR (N)."""
    ltr: FloatArray
    """True lateral load-transfer ratio (F_right − F_left) / ΣF; positive when the right wheels carry more."""
    lat0_deg: float = 0.0
    """Latitude of the local ENU origin (deg)."""
    lon0_deg: float = 0.0
    """Longitude of the local ENU origin (deg)."""
    h0_m: float = 0.0
    """Ellipsoidal height of the local ENU origin (m)."""
    meta: dict[str, float | str] = field(default_factory=dict)
    """Scenario name, parameters and anything else a consumer may want to record."""

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def dt(self) -> float:
        """Sample period (s)."""
        return float(self.t[1] - self.t[0]) if len(self) > 1 else 0.0

    @property
    def speed(self) -> FloatArray:
        """Speed over ground of the CG (m/s)."""
        return np.asarray(np.hypot(self.vx, self.vy), dtype=np.float64)

    @property
    def beta_cg(self) -> FloatArray:
        """Sideslip angle at the CG (rad)."""
        return sideslip_from_velocity(self.vx, self.vy)

    @property
    def heading_azimuth(self) -> FloatArray:
        """Vehicle x-axis azimuth, clockwise from north in [0, 2π) (rad)."""
        return yaw_to_azimuth(self.yaw)

    def point_velocity(self, x: float, y: float) -> tuple[FloatArray, FloatArray]:
        """Velocity (vx, vy) in vehicle axes of the body point (x, y) m from the CG."""
        return self.vx - self.yaw_rate * y, self.vy + self.yaw_rate * x

    def point_sideslip(self, x: float, y: float) -> FloatArray:
        """Sideslip angle (rad) at the body point (x, y) m from the CG."""
        vx, vy = self.point_velocity(x, y)
        return sideslip_from_velocity(vx, vy)

    def point_enu(self, x: float, y: float, z: float = 0.0) -> tuple[FloatArray, FloatArray, FloatArray]:
        """ENU position (m) of the body point (x, y, z) from the CG (roll and pitch ignored for x, y)."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        east = self.east + c * x - s * y
        north = self.north + s * x + c * y
        up = np.full_like(east, z)
        return east, north, up

    def point_velocity_enu(self, x: float, y: float) -> tuple[FloatArray, FloatArray]:
        """Velocity over ground (east, north) in m/s of the body point (x, y)."""
        vx, vy = self.point_velocity(x, y)
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return c * vx - s * vy, s * vx + c * vy

    def index_at(self, t: float) -> int:
        """Index of the last sample at or before time ``t`` (clipped to the record)."""
        i = int(np.searchsorted(self.t, t, side="right")) - 1
        return min(max(i, 0), len(self) - 1)

    def interp(self, name: str, t: FloatArray | float) -> FloatArray:
        """Linearly interpolate a 1-D field (by attribute name) at times ``t`` (s)."""
        values = getattr(self, name)
        return np.asarray(np.interp(t, self.t, values), dtype=np.float64)
