"""Accelerometer six-position and gyroscope turntable calibration: injected errors are recovered."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.imu import (
    STANDARD_GRAVITY,
    StaticPosition,
    TurntableRun,
    axis_vector,
    calibrate_accelerometer,
    calibrate_gyroscope,
    fit_triad,
)
from vsccore.errors import CalibrationError


def _rot(rx: float, ry: float, rz: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    return (
        np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        @ np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    )


# scale errors of −2 … +1.5 %, a 0.5–1° misaligned mounting and a little non-orthogonality
M_TRUE = np.diag([1.015, 0.98, 1.007]) @ _rot(math.radians(0.5), math.radians(-1.0), math.radians(0.7))
M_TRUE[0, 1] += 0.003


def test_accelerometer_six_positions() -> None:
    rng = np.random.default_rng(1)
    bias = np.array([0.12, -0.08, 0.25])
    sigma = 0.02
    positions = []
    for up in ("+x", "-x", "+y", "-y", "+z", "-z"):
        true = STANDARD_GRAVITY * axis_vector(up)
        samples = (M_TRUE @ true + bias) + rng.standard_normal((2000, 3)) * sigma
        positions.append(StaticPosition(samples, up))
    cal = calibrate_accelerometer(positions)
    # each mean has σ/√2000 ≈ 0.45 mm/s²; bias and scale come from sums/differences of two of them
    np.testing.assert_allclose(cal.bias, bias, atol=1e-3)
    np.testing.assert_allclose(cal.scale_factors, np.diag(M_TRUE), atol=2e-4)
    np.testing.assert_allclose(cal.matrix, M_TRUE, atol=2e-4)
    assert np.all(np.abs(cal.matrix - M_TRUE) < 5 * cal.matrix_std + 1e-12)
    np.testing.assert_allclose(cal.noise_std, sigma, rtol=0.05)
    assert np.all(cal.residual_rms < 2e-3) and cal.n_runs == 6
    # applying the calibration gives back the true specific force
    true = np.array([[1.0, -2.0, 9.0], [0.0, 0.0, STANDARD_GRAVITY]])
    np.testing.assert_allclose(cal.apply((M_TRUE @ true.T).T + bias), true, atol=3e-3)
    np.testing.assert_allclose(cal.misalignment[1, 0], M_TRUE[1, 0] / M_TRUE[1, 1], atol=3e-4)
    assert cal.to_dict()["n_runs"] == 6


def test_gyroscope_turntable() -> None:
    rng = np.random.default_rng(2)
    bias = np.radians([0.3, -0.2, 0.45])
    sigma = math.radians(0.1)
    runs = [TurntableRun(rng.standard_normal((1000, 3)) * sigma + bias, "+z", 0.0)]
    for axis in ("x", "y", "z"):
        for rate_dps in (80.0, 90.0, 100.0, -80.0, -90.0, -100.0):
            omega = math.radians(rate_dps) * axis_vector(axis)
            samples = (M_TRUE @ omega + bias) + rng.standard_normal((1000, 3)) * sigma
            runs.append(TurntableRun(samples, "+" + axis, math.radians(rate_dps)))
    cal = calibrate_gyroscope(runs)
    np.testing.assert_allclose(cal.bias, bias, atol=math.radians(0.005))
    np.testing.assert_allclose(cal.matrix, M_TRUE, atol=3e-4)
    assert np.all(np.abs(cal.matrix - M_TRUE) < 5 * cal.matrix_std + 1e-12)
    # the yaw rate of a vehicle cluster corrected on its own axis
    r_true = math.radians(20.0)
    r_meas = M_TRUE[2, 2] * r_true + bias[2]
    assert float(cal.apply_axis(np.array([r_meas]), "z")[0]) == pytest.approx(r_true, abs=math.radians(0.01))


def test_degenerate_runs_are_refused() -> None:
    rng = np.random.default_rng(3)
    only_z = [TurntableRun(rng.standard_normal((10, 3)), "+z", r) for r in (1.0, 1.5, 2.0, -1.0)]
    with pytest.raises(CalibrationError, match="do not excite all three axes"):
        calibrate_gyroscope(only_z)
    with pytest.raises(CalibrationError, match="at least 4 runs"):
        fit_triad(np.zeros((3, 3)), np.eye(3))
    with pytest.raises(CalibrationError, match="unknown sensor axis"):
        axis_vector("+w")
    with pytest.raises(CalibrationError, match=r"accelerometer run 1: samples must have shape \(n, 3\)"):
        calibrate_accelerometer([StaticPosition(np.zeros((5, 3)), "+x"), StaticPosition(np.zeros((5, 2)), "-x")])
