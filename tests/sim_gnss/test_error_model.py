"""Error model statistics and the RTK state machine's transitions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.novatel import PositionType
from sim_devices.gnss import DEFAULT_SOLUTION_NOISE, GnssErrorModel, GnssErrorParams, RtkParams, RtkStateMachine

S = 1_000_000_000


def _draw(model: GnssErrorModel, pos_type: PositionType, n: int, dt_s: float) -> np.ndarray:
    return np.array([model.sample(round(k * dt_s * S), pos_type).position_enu_m for k in range(n)])


@pytest.mark.parametrize("pos_type", [PositionType.NARROW_INT, PositionType.NARROW_FLOAT, PositionType.PSRDIFF,
                                      PositionType.SINGLE])
def test_position_sigma_matches_solution_type(pos_type: PositionType) -> None:
    # Samples 5 τ apart are nearly independent: the sample σ must match the configured σ (±8 %).
    model = GnssErrorModel(GnssErrorParams(correlation_time_s=1.0), seed=3)
    err = _draw(model, pos_type, 4000, 5.0)
    want = DEFAULT_SOLUTION_NOISE[pos_type].position_sigma_enu
    np.testing.assert_allclose(err.std(axis=0), want, rtol=0.08)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=4 * want.max() / math.sqrt(4000))


def test_narrow_int_horizontal_error_below_5cm_99pct() -> None:
    model = GnssErrorModel(seed=11)
    err = _draw(model, PositionType.NARROW_INT, 8000, 0.5)
    horizontal = np.hypot(err[:, 0], err[:, 1])
    assert np.percentile(horizontal, 99) < 0.05
    assert 0.010 < np.sqrt(np.mean(horizontal**2)) < 0.020  # about 1.5 cm drms


def test_error_is_time_correlated() -> None:
    # Lag-1 autocorrelation of a 0.05 s series = f·exp(−dt/τ) (white part uncorrelated).
    params = GnssErrorParams(correlated_fraction=0.7, correlation_time_s=2.0)
    err = _draw(GnssErrorModel(params, seed=5), PositionType.NARROW_INT, 10000, 0.05)[:, 0]
    rho = np.corrcoef(err[:-1], err[1:])[0, 1]
    assert rho == pytest.approx(0.7 * math.exp(-0.05 / 2.0), abs=0.03)


def test_same_seed_same_errors() -> None:
    a = _draw(GnssErrorModel(seed=9), PositionType.SINGLE, 50, 0.1)
    b = _draw(GnssErrorModel(seed=9), PositionType.SINGLE, 50, 0.1)
    np.testing.assert_array_equal(a, b)


def test_rtk_state_machine_progression_and_fallback() -> None:
    p = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=2.0,
                  time_to_fix_s=10.0)
    rtk = RtkStateMachine(p)
    t0 = 1_000 * S
    assert rtk.state(t0).pos_type is PositionType.SINGLE
    rtk.on_frame(t0, 1077, 12, t0)  # observations before any station message: no differential
    assert rtk.state(t0).pos_type is PositionType.SINGLE
    for k in range(20):
        t = t0 + k * S
        rtk.on_frame(t, 1006, 12)
        rtk.on_frame(t + 100_000_000, 1077, 12, epoch_gps_ns=t)
    types = {k: rtk.state(t0 + k * S + 500_000_000).pos_type for k in range(20)}
    assert types[1] is PositionType.PSRDIFF
    assert types[3] is PositionType.NARROW_FLOAT
    assert types[12] is PositionType.NARROW_INT
    last = t0 + 19 * S + 100_000_000
    st = rtk.state(last + 400_000_000)
    assert st.pos_type is PositionType.NARROW_INT
    assert st.station_id == "12"
    assert st.diff_age_s == pytest.approx(0.5)  # solution time − base epoch
    assert rtk.state(last + 4 * S).pos_type is PositionType.NARROW_INT
    assert rtk.state(last + 6 * S).pos_type is PositionType.NARROW_FLOAT
    assert rtk.state(last + 20 * S).pos_type is PositionType.PSRDIFF
    assert rtk.state(last + 20 * S).diff_age_s == pytest.approx(20.1)
    assert rtk.state(last + 31 * S).pos_type is PositionType.SINGLE
    # Corrections resume after the gap: the time to fix starts again.
    t1 = last + 40 * S
    for k in range(12):
        rtk.on_frame(t1 + k * S, 1077, 12, epoch_gps_ns=t1 + k * S)
    assert rtk.state(t1 + 5 * S).pos_type is PositionType.NARROW_FLOAT
    assert rtk.state(t1 + 10 * S).pos_type is PositionType.NARROW_INT


def test_rtk_ignores_non_observation_messages() -> None:
    rtk = RtkStateMachine(RtkParams(time_to_float_s=0.0, time_to_fix_s=0.0))
    rtk.on_frame(0, 1005, 1)
    for k in range(10):
        rtk.on_frame(k * S, 1033, 1)
        rtk.on_frame(k * S, 1230, 1)
    assert rtk.state(10 * S).pos_type is PositionType.SINGLE
