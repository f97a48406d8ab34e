"""Accelerometer and gyroscope calibration: bias, scale factors and misalignment by least squares.

Sensor model, per triad (the same as the vehicle profile's ``[calibration.imu]``)::

    measured = M · true + b

with M a 3×3 matrix (scale factors on the diagonal, misalignment / cross-axis sensitivity off
it) and b the bias. Each calibration run gives the *mean* measured vector m_k for a known true
vector a_k, so that m_k = [M | b] · [a_k; 1] is linear in the twelve unknowns; with K runs the
least-squares solution is X = [M | b] = Σ m_k ã_kᵀ (Σ ã_k ã_kᵀ)⁻¹, ã_k = [a_k; 1].

- Accelerometer, six static positions (each axis up and down): at rest the sensor measures the
  specific force f = −g_vector, i.e. +g along the axis that points up. More positions (any known
  orientation) only add equations.
- Gyroscope, turntable runs at known rates about each axis (e.g. ±80, ±90, ±100 °/s) plus
  optionally a static run; the Earth's rotation (≤ 0.004 °/s) ends up in the bias unless given.

Residuals (m_k − X ã_k) are reported per run and axis, and the parameters' standard errors come
from the residual variance (K − 4 degrees of freedom per output axis).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from vsccore.angles import FloatArray
from vsccore.errors import CalibrationError

STANDARD_GRAVITY = 9.80665

_AXES = {"x": 0, "y": 1, "z": 2}


def axis_vector(axis: str | Sequence[float]) -> FloatArray:
    """A unit vector in sensor axes from ``"+x"``, ``"-z"``, ``"y"`` … or from three numbers (normalised).

    Raises:
        CalibrationError: an unknown axis name or a zero vector.
    """
    if isinstance(axis, str):
        text = axis.strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        name = text.lstrip("+-")
        if name not in _AXES:
            raise CalibrationError(f"unknown sensor axis {axis!r}: use +x, -x, +y, -y, +z or -z")
        v = np.zeros(3)
        v[_AXES[name]] = sign
        return v
    v = np.asarray(axis, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or float(np.linalg.norm(v)) == 0.0:
        raise CalibrationError(f"axis must be a name like '+x' or a non-zero 3-vector, got {axis!r}")
    return np.asarray(v / np.linalg.norm(v), dtype=float)


@dataclass(frozen=True, slots=True)
class StaticPosition:
    """Accelerometer samples (n, 3) taken at rest with the sensor axis ``up`` pointing up."""

    samples: FloatArray
    up: str | tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class TurntableRun:
    """Gyroscope samples (n, 3) on a turntable turning at ``rate_rps`` about the sensor axis ``axis``.

    The rate is signed by the right-hand rule about the axis as given (``"+z"`` and 1.5 rad/s is
    the same run as ``"-z"`` and −1.5 rad/s). A static run has rate 0.
    """

    samples: FloatArray
    axis: str | tuple[float, float, float]
    rate_rps: float


@dataclass(frozen=True, slots=True)
class TriadCalibration:
    """Bias, scale and misalignment of a three-axis sensor: measured = matrix · true + bias."""

    matrix: FloatArray
    """M (3×3)."""
    bias: FloatArray
    """b (3,) in the sensor's unit (m/s² or rad/s)."""
    matrix_std: FloatArray
    """Standard errors of the entries of M (3×3); NaN without redundant runs."""
    bias_std: FloatArray
    residuals: FloatArray
    """Per run and axis: mean measured − model (K, 3)."""
    noise_std: FloatArray
    """Per axis: standard deviation of the samples about each run's mean, pooled over runs."""
    n_runs: int

    @property
    def scale_factors(self) -> FloatArray:
        """Diagonal of M (1 = no scale error)."""
        return np.asarray(np.diag(self.matrix), dtype=float)

    @property
    def misalignment(self) -> FloatArray:
        """Cross-axis sensitivities M_ij / M_ii (3×3, zero diagonal): ≈ misalignment angles in rad."""
        m = self.matrix / np.diag(self.matrix)[:, None]
        np.fill_diagonal(m, 0.0)
        return np.asarray(m, dtype=float)

    @property
    def residual_rms(self) -> FloatArray:
        """RMS of the residuals per axis."""
        return np.asarray(np.sqrt(np.mean(self.residuals**2, axis=0)), dtype=float)

    def apply(self, measured: npt.ArrayLike) -> FloatArray:
        """True values from measured ones, shape (n, 3) or (3,): M⁻¹ (measured − b)."""
        m = np.asarray(measured, dtype=float)
        if m.shape[-1] != 3:
            raise CalibrationError(f"apply: expected vectors of 3 components, got shape {m.shape}")
        return np.asarray(np.linalg.solve(self.matrix, (m - self.bias).T).T, dtype=float)

    def apply_axis(self, measured: npt.ArrayLike, axis: str) -> FloatArray:
        """Correct one axis alone (e.g. the yaw rate of a CAN sensor cluster): (m − b_i) / M_ii.

        Cross-axis terms are dropped: they need the other axes, which a vehicle cluster does not
        report; on level ground the other rates are small, so this is the best available.
        """
        i = _AXES.get(axis.strip().lower().lstrip("+"))
        if i is None:
            raise CalibrationError(f"unknown sensor axis {axis!r}: use x, y or z")
        return np.asarray((np.asarray(measured, dtype=float) - self.bias[i]) / self.matrix[i, i], dtype=float)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (in the sensor's units)."""
        return {
            "matrix": self.matrix.tolist(),
            "bias": self.bias.tolist(),
            "matrix_std": self.matrix_std.tolist(),
            "bias_std": self.bias_std.tolist(),
            "scale_factors": self.scale_factors.tolist(),
            "misalignment": self.misalignment.tolist(),
            "residual_rms": self.residual_rms.tolist(),
            "residuals": self.residuals.tolist(),
            "noise_std": self.noise_std.tolist(),
            "n_runs": self.n_runs,
        }


def fit_triad(
    measured_means: npt.ArrayLike, true_vectors: npt.ArrayLike, *, noise_std: npt.ArrayLike | None = None
) -> TriadCalibration:
    """Least-squares [M | b] from K mean measured vectors (K, 3) and the K true vectors (K, 3).

    Raises:
        CalibrationError: fewer than 4 runs, shapes that differ, or true vectors that do not span
            three dimensions (e.g. all runs about one axis).
    """
    m = np.asarray(measured_means, dtype=float)
    a = np.asarray(true_vectors, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or a.shape != m.shape:
        raise CalibrationError(f"fit_triad: need (K, 3) measured and true vectors, got {m.shape} and {a.shape}")
    k = m.shape[0]
    if k < 4:
        raise CalibrationError(f"fit_triad: need at least 4 runs for 12 unknowns, got {k}")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(a))):
        raise CalibrationError("fit_triad: NaN or infinite values in the runs")
    at = np.column_stack([a, np.ones(k)])  # (K, 4)
    if np.linalg.matrix_rank(at) < 4:
        raise CalibrationError(
            "fit_triad: the runs do not excite all three axes in both senses (true vectors must span 3-D "
            "and not all lie on one plane through a point); add positions or rates about the missing axes"
        )
    x, *_ = np.linalg.lstsq(at, m, rcond=None)  # (4, 3): m = at @ x
    resid = m - at @ x
    dof = k - 4
    cov_unit = np.linalg.inv(at.T @ at)
    if dof > 0:
        s2 = np.sum(resid**2, axis=0) / dof  # per output axis
        std = np.sqrt(np.outer(np.diag(cov_unit), s2))  # (4, 3)
    else:
        std = np.full((4, 3), math.nan)
    ns = np.full(3, math.nan) if noise_std is None else np.asarray(noise_std, dtype=float)
    return TriadCalibration(
        matrix=np.asarray(x[:3].T, dtype=float),
        bias=np.asarray(x[3], dtype=float),
        matrix_std=np.asarray(std[:3].T, dtype=float),
        bias_std=np.asarray(std[3], dtype=float),
        residuals=np.asarray(resid, dtype=float),
        noise_std=ns,
        n_runs=k,
    )


def _means(name: str, runs: Sequence[StaticPosition | TurntableRun]) -> tuple[FloatArray, FloatArray]:
    means: list[FloatArray] = []
    ss = np.zeros(3)
    dof = 0
    for i, run in enumerate(runs):
        x: FloatArray = np.asarray(run.samples, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] == 0:
            raise CalibrationError(f"{name} run {i}: samples must have shape (n, 3), got {x.shape}")
        x = x[np.all(np.isfinite(x), axis=1)]
        if x.shape[0] == 0:
            raise CalibrationError(f"{name} run {i}: no finite sample")
        mu = np.mean(x, axis=0)
        means.append(mu)
        ss += np.sum((x - mu) ** 2, axis=0)
        dof += x.shape[0] - 1
    noise = np.sqrt(ss / dof) if dof > 0 else np.full(3, math.nan)
    return np.asarray(means, dtype=float), np.asarray(noise, dtype=float)


def calibrate_accelerometer(
    positions: Sequence[StaticPosition], *, gravity_mps2: float = STANDARD_GRAVITY
) -> TriadCalibration:
    """Accelerometer bias, scale and misalignment from static positions (at least the classic six).

    ``gravity_mps2`` is the local gravity (≈ 9.78 at the equator to 9.83 at the poles; the
    standard value by default): an error in it is an error in every scale factor.

    Raises:
        CalibrationError: too few or degenerate positions, or malformed samples (the message says which).
    """
    means, noise = _means("accelerometer", positions)
    true = np.array([gravity_mps2 * axis_vector(p.up) for p in positions])
    return fit_triad(means, true, noise_std=noise)


def calibrate_gyroscope(runs: Sequence[TurntableRun]) -> TriadCalibration:
    """Gyroscope bias, scale and misalignment from turntable runs at known rates about each axis.

    Raises:
        CalibrationError: too few or degenerate runs, or malformed samples (the message says which).
    """
    means, noise = _means("gyroscope", runs)
    true = np.array([r.rate_rps * axis_vector(r.axis) for r in runs])
    return fit_triad(means, true, noise_std=noise)
