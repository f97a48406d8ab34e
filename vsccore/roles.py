"""The rig's signal roles and the SI unit each role's values carry.

Shared by the CAN decoder (:mod:`drivers.can.roles`, which checks a DBC mapping against it) and the
session file's topic schemas (:mod:`rig.core.topics`), which must not pay for importing cantools and
python-can just to name the roles.
"""

from __future__ import annotations

import types
from collections.abc import Mapping

ROLE_SI_UNITS: Mapping[str, str] = types.MappingProxyType(
    {
        "yaw_rate": "rad/s",
        "lat_accel": "m/s^2",
        "long_accel": "m/s^2",
        "swa": "rad",
        "swa_rate": "rad/s",
        "wheel_speed_fl": "m/s",
        "wheel_speed_fr": "m/s",
        "wheel_speed_rl": "m/s",
        "wheel_speed_rr": "m/s",
        "vehicle_speed": "m/s",
        "mc_pressure": "Pa",
        "wheel_pressure_fl": "Pa",
        "wheel_pressure_fr": "Pa",
        "wheel_pressure_rl": "Pa",
        "wheel_pressure_rr": "Pa",
        "vsc_beta_estimate": "rad",
        "vsc_active": "1",
    }
)
"""Roles the rig knows, with the SI unit their values must have. Other role names are allowed."""
