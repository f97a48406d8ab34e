"""A user's sideslip estimator, loaded by name in the tests as ``--estimator`` would load it."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sim_devices.vehicle import VehicleParams

_P = VehicleParams()


def steady_state_beta(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """Single-track steady state: β = b·r/v − m·a·a_y / (l·C_r), C_r the rear axle's cornering stiffness."""
    v = np.maximum(roles["speed"], 1.0)
    c_r = 2.0 * _P.cornering_stiffness_rear_n_per_rad
    return (
        _P.cg_to_rear_axle_m * roles["yaw_rate"] / v
        - _P.mass_kg * _P.cg_to_front_axle_m * roles["ay"] / (_P.wheelbase_m * c_r)
    )


def broken(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """Returns one value too few."""
    return np.zeros(roles["t"].size - 1)
