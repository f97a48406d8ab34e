"""LTR from a_y and roll against the simulator's wheel loads; AR prediction 1–3 s ahead on J-turn and fishhook."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from statsmodels.tsa.ar_model import ar_select_order

from rig.analysis.rollover import (
    CONFIRM_S,
    LtrPrediction,
    horizontal_ay,
    ltr_from_lateral,
    predict_ltr,
    prediction_errors,
)
from sim_devices.vehicle import GRAVITY, GroundTruth, VehicleParams, make_scenario, simulate
from vsccore.errors import AnalysisError

P = VehicleParams()
GEOM = {
    "cg_height_m": P.cg_height_m,
    "roll_axis_height_m": P.roll_axis_height_m,
    "track_m": 0.5 * (P.track_front_m + P.track_rear_m),
}


@pytest.fixture(scope="module", params=["j_turn", "fishhook"])
def rollover_drive(request: pytest.FixtureRequest) -> GroundTruth:
    return simulate(make_scenario(request.param), rate_hz=100.0)


def _ltr(tr: GroundTruth, inertia: bool = True) -> np.ndarray:
    ay = horizontal_ay(tr.ay_meas, tr.roll)
    if not inertia:
        return ltr_from_lateral(ay, tr.roll, **GEOM)
    return ltr_from_lateral(ay, tr.roll, roll_accel_rps2=np.gradient(tr.roll_rate, tr.t),
                            roll_inertia_kgm2=P.roll_inertia_kgm2, mass_kg=P.mass_kg, **GEOM)


def test_steady_state_ltr_by_hand() -> None:
    # 0.5 g and 3° of roll on a 1.555 m track, h = 0.55 m, roll axis 0.10 m
    ltr = ltr_from_lateral(0.5 * GRAVITY, math.radians(3.0), **GEOM)
    assert float(ltr) == pytest.approx(2 / 1.555 * (0.55 * 0.5 + 0.45 * math.sin(math.radians(3.0))), rel=1e-12)
    # a body-fixed sensor reads a_y cos φ + g sin φ
    phi = math.radians(4.0)
    assert float(horizontal_ay(3.0 * math.cos(phi) + GRAVITY * math.sin(phi), phi)) == pytest.approx(3.0)


def test_ltr_against_simulated_wheel_loads(rollover_drive: GroundTruth) -> None:
    tr = rollover_drive
    peak = float(np.max(np.abs(tr.ltr)))
    full = np.abs(_ltr(tr) - tr.ltr)
    quasi_static = np.abs(_ltr(tr, inertia=False) - tr.ltr)
    print(f"{tr.meta['scenario']}: peak |LTR| {peak:.3f}; |error| max {full.max():.4f} with the roll-inertia term, "
          f"{quasi_static.max():.4f} without (RMS {np.sqrt(np.mean(quasi_static**2)):.4f})")
    assert full.max() < 0.02 * peak
    assert np.sqrt(np.mean(quasi_static**2)) < 0.08 * peak


def test_prediction_errors_against_truth(rollover_drive: GroundTruth) -> None:
    """Mean |error| 1, 2, 3 s ahead as % of the manoeuvre's peak |LTR|, and a persistence baseline.

    Two spans: (A) every prediction landing after the steering onset; (B) only those also issued
    after it. The steering itself is not predictable, so (A) is dominated by predictions made
    before the steer; on these short, fast manoeuvres the AR model is about as good as holding
    the current value (figures in the report).
    """
    tr = rollover_drive
    pred = predict_ltr(tr.t, _ltr(tr))
    onset = float(tr.t[np.flatnonzero(np.abs(tr.swa) > math.radians(5.0))[0]])
    held = np.where(np.isnan(pred.predicted), np.nan, np.repeat(pred.ltr[:, None], 3, axis=1))  # same epochs
    hold = LtrPrediction(pred.t, pred.ltr, pred.horizons_s, held, pred.order, pred.warning, pred.threshold)
    for label, kw in (("A", {"t_start_s": onset}), ("B", {"t_start_s": onset, "issued_from_s": onset})):
        errs = prediction_errors(pred, tr.t, tr.ltr, **kw)
        base = prediction_errors(hold, tr.t, tr.ltr, **kw)
        print(f"{tr.meta['scenario']} ({label}): AR "
              + ", ".join(f"{e.horizon_s:.0f} s {e.percent_of_peak:.1f} %" for e in errs)
              + "; persistence " + ", ".join(f"{e.percent_of_peak:.1f} %" for e in base))
        for e, b in zip(errs, base, strict=True):
            assert e.percent_of_peak < b.percent_of_peak + 3.0
            assert e.n > 0
    if tr.meta["scenario"] == "j_turn":
        b1 = prediction_errors(pred, tr.t, tr.ltr, t_start_s=onset, issued_from_s=onset)[0]
        assert b1.percent_of_peak < 12.0
    assert np.max(pred.order) >= 1


def test_numpy_engine_equals_statsmodels(rollover_drive: GroundTruth) -> None:
    """The default NumPy AIC selection and fit give statsmodels' ar_select_order result, epoch by epoch."""
    tr = rollover_drive
    ltr = _ltr(tr) + np.random.default_rng(0).standard_normal(len(tr)) * 0.005  # sensor noise
    fast = predict_ltr(tr.t, ltr)
    ref = predict_ltr(tr.t, ltr, engine="statsmodels")
    np.testing.assert_array_equal(fast.order, ref.order)
    np.testing.assert_allclose(fast.predicted, ref.predicted, atol=1e-9)


def test_forecast_matches_statsmodels(rollover_drive: GroundTruth) -> None:
    """The fast forecast recursion reproduces statsmodels' own forecast of the fitted increments model."""
    tr = rollover_drive
    pred = predict_ltr(tr.t, _ltr(tr), refit_every_s=0.05, engine="statsmodels")
    k = int(np.argmax(pred.t >= pred.t[0] + 4.0))
    window = pred.ltr[k - 59 : k + 1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sel = ar_select_order(np.diff(window), maxlag=8, ic="aic", trend="n")
        fc = sel.model.fit().forecast(60)
    if pred.order[k] == 0:
        pytest.skip("the fit at this epoch was rejected as explosive (persistence used)")
    expected = np.clip(window[-1] + np.cumsum(fc), -1, 1)[[19, 39, 59]]
    np.testing.assert_allclose(pred.predicted[k], expected, atol=1e-9)


def test_warning_fires_at_the_threshold(rollover_drive: GroundTruth) -> None:
    tr = rollover_drive
    ltr = _ltr(tr)
    pred = predict_ltr(tr.t, ltr, threshold=0.6)
    first = pred.first_warning_s()
    reached = float(tr.t[np.argmax(np.abs(tr.ltr) >= 0.6)])
    # the steering is fast (720–1000 °/s): the LTR crosses 0.6 within 0.3 s of the steer, so the AR's warning can
    # only come with the next prediction epoch (20 Hz), not seconds ahead, and then once confirmed (CONFIRM_S)
    assert first is not None and first <= reached + CONFIRM_S + 0.05 + 1e-9
    assert pred.warning_intervals[0][0] == first
    assert predict_ltr(tr.t, ltr).first_warning_s() is None  # 0.9 is never reached nor predicted here
    with pytest.raises(AnalysisError, match="shorter than"):
        predict_ltr(tr.t[:50], ltr[:50])  # 0.5 s


def test_tail_prediction_is_the_whole_records_tail(rollover_drive: GroundTruth) -> None:
    """``tail_s`` predicts the last epochs only, with the fits the whole record uses there: the same values,
    NaN before, and the newest warning the same, at every end of the record (through the warning's onset)."""
    tr = rollover_drive
    ltr = _ltr(tr)
    full = predict_ltr(tr.t, ltr, threshold=0.6)
    first = full.first_warning_s()
    assert first is not None
    checked = 0
    for end_s in np.arange(2.0, tr.t[-1], 0.05):
        n = int(np.searchsorted(tr.t, end_s)) + 1
        whole = predict_ltr(tr.t[:n], ltr[:n], threshold=0.6)
        tail = predict_ltr(tr.t[:n], ltr[:n], threshold=0.6, tail_s=CONFIRM_S)
        inside = whole.t >= whole.t[-1] - CONFIRM_S - 1e-9
        assert np.array_equal(tail.predicted[inside], whole.predicted[inside])
        assert np.all(np.isnan(tail.predicted[~inside]))
        assert tail.warning[-1] == whole.warning[-1]
        checked += int(whole.warning[-1])
    assert checked > 0  # ends inside the warning were among them
    with pytest.raises(AnalysisError, match="tail_s"):
        predict_ltr(tr.t, ltr, tail_s=-1.0)
