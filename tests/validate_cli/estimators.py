"""Offline estimators for ``rig validate --estimator tests.validate_cli.estimators:NAME`` (test helpers).

``ideal`` returns the simulator's true sideslip at the times it is called with, ``late_and_high`` the
truth 0.2 s late and 0.5° high. An estimator only receives the CAN roles, so these read the truth
of the session named by the environment variable ``RIG_TEST_SESSION`` (set by the tests) on the
same time base (:func:`rig.data.inputs.load_inputs`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from functools import lru_cache

import numpy as np

from rig.data.inputs import load_inputs

DELAY_S = 0.2
BIAS_DEG = 0.5


@lru_cache(maxsize=4)
def _truth(path: str) -> tuple[np.ndarray, np.ndarray]:
    inp = load_inputs(path, can=False, optical=False)
    tr = inp.require_truth()
    return tr.t_s, np.asarray(tr.truth.beta_cg, dtype=float)


def _beta(t: np.ndarray) -> np.ndarray:
    t_tr, beta = _truth(os.environ["RIG_TEST_SESSION"])
    return np.interp(t, t_tr, beta, left=np.nan, right=np.nan)


def ideal(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """The true sideslip at the CG."""
    assert {"yaw_rate", "lat_accel", "swa", "vsc_beta_estimate"} <= set(roles)  # the CAN roles arrive
    return _beta(roles["t"])


def late_and_high(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    """The true sideslip, DELAY_S late and BIAS_DEG high."""
    return _beta(roles["t"] - DELAY_S) + math.radians(BIAS_DEG)


def wrong_length(roles: Mapping[str, np.ndarray]) -> np.ndarray:
    return np.zeros(roles["t"].size + 1)
