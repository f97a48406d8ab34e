"""Common-mode GNSS error: two rovers on one roof share most of their error; their baseline is precise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.novatel.enums import PositionType
from sim_devices.gnss.error_model import CommonModeError, GnssErrorModel, GnssErrorParams

NS = 1_000_000_000


def _errors(model: GnssErrorModel, times_ns: np.ndarray) -> np.ndarray:
    return np.array([model.sample(int(t), PositionType.NARROW_INT).position_enu_m for t in times_ns])


def test_relative_error_is_the_independent_share_only() -> None:
    params = GnssErrorParams(common_fraction=0.95, common_seed=7, correlation_time_s=2.0)
    times = np.arange(0, 1000 * NS, NS // 10)  # 1000 s at 10 Hz
    a = _errors(GnssErrorModel(params, seed=1), times)
    b = _errors(GnssErrorModel(params, seed=2), times)
    sigma_h = params.noise_for(PositionType.NARROW_INT).horizontal_rms_m / math.sqrt(2.0)
    # each receiver alone keeps its stated 1σ (within sampling error of a correlated series)
    assert np.std(a[:, 0]) == pytest.approx(sigma_h, rel=0.15)
    # the difference carries only the independent variance: 2·(1 − f)·σ²
    expected = math.sqrt(2.0 * (1.0 - 0.95)) * sigma_h
    assert np.std(a[:, 0] - b[:, 0]) == pytest.approx(expected, rel=0.15)
    assert np.std(a[:, 0] - b[:, 0]) < 0.4 * np.std(a[:, 0])


def test_without_common_seed_sharing_errors_are_independent() -> None:
    times = np.arange(0, 1000 * NS, NS // 10)
    def params(common_seed: int) -> GnssErrorParams:
        return GnssErrorParams(common_fraction=0.95, common_seed=common_seed, correlation_time_s=1.0)

    a = _errors(GnssErrorModel(params(1), seed=1), times)
    b = _errors(GnssErrorModel(params(2), seed=2), times)
    corr = np.corrcoef(a[:, 1], b[:, 1])[0, 1]  # ~500 independent samples: sd of corr ≈ 0.045
    assert abs(corr) < 0.2


def test_common_process_has_unit_variance_and_exponential_correlation() -> None:
    tau = 3.0
    proc = CommonModeError(seed=11, tau_s=tau)
    t = np.arange(0.0, 12000.0, 1.0)
    x = np.array([proc.at(float(ti))[0] for ti in t])
    assert np.var(x) == pytest.approx(1.0, rel=0.25)
    lag = int(tau)
    r = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert r == pytest.approx(math.exp(-1.0), abs=0.15)

