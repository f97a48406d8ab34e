"""Angle conventions (ISO 8855 vehicle axes, clockwise GNSS azimuths): the only place that wraps angles.

- Vehicle axes: x forward, y left, z up; yaw angle ψ counter-clockwise from east in a local ENU
  frame; yaw rate positive turning left.
- GNSS azimuths (heading, course over ground) are clockwise from true north.
- Sideslip β = atan2(v_y, v_x), positive when the velocity points left of the x axis; with
  azimuths, β = heading_azimuth − course_azimuth, wrapped to (−π, π].
"""

from __future__ import annotations

from typing import overload

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

TWO_PI = 2.0 * np.pi


@overload
def wrap_pi(angle: float) -> float: ...
@overload
def wrap_pi(angle: FloatArray) -> FloatArray: ...
def wrap_pi(angle: float | FloatArray) -> float | FloatArray:
    """Wrap an angle (rad) to (−π, π]."""
    wrapped = np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), TWO_PI)
    if np.ndim(wrapped) == 0:
        return float(wrapped)
    return wrapped


@overload
def wrap_2pi(angle: float) -> float: ...
@overload
def wrap_2pi(angle: FloatArray) -> FloatArray: ...
def wrap_2pi(angle: float | FloatArray) -> float | FloatArray:
    """Wrap an angle (rad) to [0, 2π)."""
    wrapped = np.mod(np.asarray(angle, dtype=float), TWO_PI)
    if np.ndim(wrapped) == 0:
        return float(wrapped)
    return wrapped


@overload
def wrap_180(angle_deg: float) -> float: ...
@overload
def wrap_180(angle_deg: FloatArray) -> FloatArray: ...
def wrap_180(angle_deg: float | FloatArray) -> float | FloatArray:
    """Wrap an angle in degrees to (−180, 180]."""
    wrapped = 180.0 - np.mod(180.0 - np.asarray(angle_deg, dtype=float), 360.0)
    if np.ndim(wrapped) == 0:
        return float(wrapped)
    return wrapped


@overload
def azimuth_to_yaw(azimuth: float) -> float: ...
@overload
def azimuth_to_yaw(azimuth: FloatArray) -> FloatArray: ...
def azimuth_to_yaw(azimuth: float | FloatArray) -> float | FloatArray:
    """Clockwise-from-north azimuth (rad) → ISO 8855 yaw angle, counter-clockwise from east (rad)."""
    return wrap_pi(np.pi / 2.0 - np.asarray(azimuth, dtype=float))


@overload
def yaw_to_azimuth(yaw: float) -> float: ...
@overload
def yaw_to_azimuth(yaw: FloatArray) -> FloatArray: ...
def yaw_to_azimuth(yaw: float | FloatArray) -> float | FloatArray:
    """ISO 8855 yaw angle (rad, counter-clockwise from east) → azimuth clockwise from north in [0, 2π)."""
    return wrap_2pi(np.pi / 2.0 - np.asarray(yaw, dtype=float))


@overload
def sideslip_from_azimuths(heading: float, course: float) -> float: ...
@overload
def sideslip_from_azimuths(heading: FloatArray, course: FloatArray) -> FloatArray: ...
def sideslip_from_azimuths(
    heading: float | FloatArray, course: float | FloatArray
) -> float | FloatArray:
    """Sideslip β (rad) = heading azimuth − course azimuth, wrapped to (−π, π].

    Both azimuths clockwise from north; β is positive when the velocity points left of the
    vehicle x axis (ISO 8855).
    """
    return wrap_pi(np.asarray(heading, dtype=float) - np.asarray(course, dtype=float))


@overload
def sideslip_from_velocity(vx: float, vy: float) -> float: ...
@overload
def sideslip_from_velocity(vx: FloatArray, vy: FloatArray) -> FloatArray: ...
def sideslip_from_velocity(vx: float | FloatArray, vy: float | FloatArray) -> float | FloatArray:
    """Sideslip β = atan2(v_y, v_x) (rad) of a velocity given in vehicle axes."""
    beta = np.arctan2(np.asarray(vy, dtype=float), np.asarray(vx, dtype=float))
    if np.ndim(beta) == 0:
        return float(beta)
    return beta


def unwrap(angle: FloatArray) -> FloatArray:
    """Remove 2π jumps from a sampled angle sequence (rad)."""
    return np.unwrap(np.asarray(angle, dtype=float))


def transfer_velocity(
    vx: FloatArray | float,
    vy: FloatArray | float,
    yaw_rate: FloatArray | float,
    from_xy: tuple[float, float],
    to_xy: tuple[float, float],
) -> tuple[FloatArray, FloatArray]:
    """Move a planar rigid-body velocity (vehicle axes) from one body point to another.

    v_to = v_from + ω × (r_to − r_from), with ω = yaw rate about z (rad/s) and r in vehicle axes
    (m, x forward, y left). Returns (vx, vy) at ``to_xy``.
    """
    dx = to_xy[0] - from_xy[0]
    dy = to_xy[1] - from_xy[1]
    r = np.asarray(yaw_rate, dtype=float)
    return (
        np.asarray(vx, dtype=float) - r * dy,
        np.asarray(vy, dtype=float) + r * dx,
    )
