"""Offline estimators for ``rig campaign --estimator tests.campaign.estimators:NAME`` (test helpers).

They see only the CAN roles (no truth), so they work on any session and in any worker process.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

UNDERSTEER_RAD_PER_MPS2 = 0.0055
"""Steady-state sideslip gain of the simulated car at speed, −m·l_f/(l·C_r) (rad per m/s²), rounded."""


def zero(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """β = 0: the error is the sideslip itself."""
    return np.zeros_like(roles["t"])


def linear_ay(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """β = −k·a_y: the steady-state single-track sideslip at speed, wrong in transients."""
    return -UNDERSTEER_RAD_PER_MPS2 * np.nan_to_num(roles["lat_accel"])


def broken(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """Raises: the campaign reports it per session."""
    raise RuntimeError("estimator crashed on purpose")
