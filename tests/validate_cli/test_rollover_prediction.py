"""The roll model, the steering's LTR demand and the ARX predictor behind ``rig rollover``.

Against the vehicle simulator (roll angle, wheel-load LTR), statsmodels (AutoReg with exogenous
inputs: same orders by AIC, same coefficients) and a noise-free synthetic system (exact recovery).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from statsmodels.tsa.ar_model import AutoReg

from rig.analysis.rollover import (
    LtrDemandModel,
    LtrExogenous,
    RollModel,
    _fit_arx,
    _forecast_arx,
    horizontal_ay,
    ltr_from_lateral,
    predict_ltr,
    prediction_errors,
)
from sim_devices.vehicle import GRAVITY, GroundTruth, VehicleParams, make_scenario, simulate
from vsccore.errors import AnalysisError

P = VehicleParams()
TRACK = 0.5 * (P.track_front_m + P.track_rear_m)
K_ROLL = P.roll_stiffness_front_nm_per_rad + P.roll_stiffness_rear_nm_per_rad
ROLL = RollModel.from_vehicle(P)
DEMAND = LtrDemandModel(P.wheelbase_m, P.understeer_gradient_rad_per_mps2, P.tyre_peak_mu, P.cg_height_m,
                        P.roll_axis_height_m, TRACK, ROLL.roll_gain_rad_per_mps2, tuple(P.steering_ratio_swa_deg),
                        tuple(P.steering_ratio))


@pytest.fixture(scope="module")
def j_turn() -> GroundTruth:
    return simulate(make_scenario("j_turn"), P, rate_hz=100.0)


def _measured_ltr(tr: GroundTruth) -> np.ndarray:
    ay_m = tr.ay_meas + np.random.default_rng(3).standard_normal(len(tr)) * 0.03  # CAN sensor noise
    phi, phidd = ROLL.roll_from_body_ay(tr.t, ay_m)
    return ltr_from_lateral(horizontal_ay(ay_m, phi), phi, cg_height_m=P.cg_height_m,
                            roll_axis_height_m=P.roll_axis_height_m, track_m=TRACK, roll_accel_rps2=phidd,
                            roll_inertia_kgm2=P.roll_inertia_kgm2, mass_kg=P.mass_kg)


def test_roll_model_follows_the_simulated_body(j_turn: GroundTruth) -> None:
    tr = j_turn
    # static gain from the moment balance K·φ = m·h'·(a_y + g·φ)
    h = P.cg_height_m - P.roll_axis_height_m
    assert ROLL.roll_gain_rad_per_mps2 == pytest.approx(P.mass_kg * h / (K_ROLL - P.mass_kg * GRAVITY * h), rel=1e-12)
    phi, _ = ROLL.roll_from_body_ay(tr.t, tr.ay_meas)
    err = np.degrees(np.abs(phi - tr.roll))
    print(f"roll from a_m on the J-turn: max error {err.max():.4f}° of {np.degrees(np.abs(tr.roll)).max():.2f}°")
    assert err.max() < 0.05
    ltr = _measured_ltr(tr)
    assert np.max(np.abs(ltr - tr.ltr)) < 0.02 * np.max(np.abs(tr.ltr)) + 0.01
    with pytest.raises(AnalysisError, match="uniform"):
        ROLL.roll_from_body_ay(np.r_[0.0, 0.01, 0.03], np.zeros(3))


def test_demand_is_the_steady_state_ltr() -> None:
    """On a slowly accelerating circle (quasi steady state) the demand equals the wheel-load LTR in the linear range."""
    tr = simulate(make_scenario("steady_state_circle", radius_m=40.0, speed_start_kmh=30.0, speed_end_kmh=60.0,
                                ay_rate_mps3=0.3), P, rate_hz=50.0)
    d = DEMAND.demand(tr.swa, tr.speed)
    lin = (np.abs(tr.ay) >= 2.0) & (np.abs(tr.ay) <= 4.0) & (tr.t > 5.0)  # after the steer into the circle
    assert np.count_nonzero(lin) > 100
    rel = d[lin] / tr.ltr[lin] - 1.0
    print(f"demand / LTR − 1 for 2–4 m/s²: {rel.min():+.3f} … {rel.max():+.3f}")
    assert np.max(np.abs(rel)) < 0.03
    # saturation: the steady-state a_y never exceeds μ·g, however large the steer
    assert np.all(np.abs(DEMAND.lateral_acceleration(np.radians([720.0, -720.0]), 30.0)) <= P.tyre_peak_mu * GRAVITY)


def test_arx_orders_and_coefficients_match_statsmodels(j_turn: GroundTruth) -> None:
    tr = j_turn
    t = np.arange(tr.t[0], tr.t[-1], 0.05)
    y = np.interp(t, tr.t, _measured_ltr(tr))
    u = np.interp(t, tr.t, DEMAND.demand(tr.swa, tr.speed))
    k = int(np.argmax(t >= 2.6))  # a 2.5 s window holding the run-up, the steer (at 2 s) and the response
    yw, uw = y[k - 49 : k + 1], u[k - 49 : k + 1]
    a, b = _fit_arx(yw, uw, 3, 3)
    m = 3  # samples held back: max(n_a, n_b − 1)
    best = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for na in range(1, 4):
            for nb in range(4):
                # u[k − j] as exogenous columns (the held-back first rows are not used)
                exog = np.column_stack([np.r_[np.zeros(j), uw[: uw.size - j]] for j in range(nb)]) if nb else None
                res = AutoReg(yw, lags=na, trend="n", exog=exog, hold_back=m).fit()
                if best is None or res.aic < best[0] - 1e-9:
                    best = (res.aic, na, nb, np.asarray(res.params))
    assert best is not None
    _aic, na, nb, params = best
    assert (a.size, b.size) == (na, nb)
    # statsmodels orders the parameters: AR lags, then the exogenous columns
    np.testing.assert_allclose(np.r_[a, b], params, rtol=1e-6, atol=1e-9)


def test_arx_recovers_a_known_system_and_forecasts_it() -> None:
    """An ARX(2, 2) with a small equation error: AIC picks (2, 2), the fit returns the coefficients."""
    rng = np.random.default_rng(1)
    u = np.repeat(rng.uniform(-1.0, 1.0, 12), 8)  # a staircase input
    e = rng.standard_normal(u.size) * 1e-3
    y = np.zeros(u.size)
    for k in range(2, u.size):
        y[k] = 1.2 * y[k - 1] - 0.4 * y[k - 2] + 0.15 * u[k] + 0.05 * u[k - 1] + e[k]
    a, b = _fit_arx(y[:80], u[:80], 3, 3)
    assert (a.size, b.size) == (2, 2)
    np.testing.assert_allclose(a, [1.2, -0.4], atol=0.01)
    np.testing.assert_allclose(b, [0.15, 0.05], atol=0.005)
    # with the input's future known, the forecast follows the system up to the accumulated equation error
    path = _forecast_arx(a, b, y[:80], u[:80], u[80:])
    clean = y[:80].tolist()
    for k in range(80, u.size):
        clean.append(1.2 * clean[-1] - 0.4 * clean[-2] + 0.15 * u[k] + 0.05 * u[k - 1])
    np.testing.assert_allclose(path, clean[80:], atol=0.01)
    # a flat window gives no model, and the forecast holds the last value
    a0, b0 = _fit_arx(np.full(60, 0.3), np.zeros(60), 3, 3)
    assert a0.size == 0 and np.all(_forecast_arx(a0, b0, np.full(60, 0.3), np.zeros(60), np.ones(5)) == 0.3)


def test_arx_beats_ar_on_the_j_turn(j_turn: GroundTruth) -> None:
    """Window: issued at or after the steering onset, landing before the end of the manoeuvre (the study's window B)."""
    tr = j_turn
    ltr = _measured_ltr(tr)
    ex = LtrExogenous(tr.swa, tr.speed, tr.ax_meas, DEMAND)
    on = float(tr.t[np.flatnonzero(np.abs(tr.swa) > math.radians(5.0))[0]])
    span = {"t_start_s": on, "t_stop_s": float(tr.t[-1]), "issued_from_s": on}
    ar = prediction_errors(predict_ltr(tr.t, ltr), tr.t, tr.ltr, **span)
    pred = predict_ltr(tr.t, ltr, exogenous=ex)
    arx = prediction_errors(pred, tr.t, tr.ltr, **span)
    print("J-turn, % of peak |LTR| at 1/2/3 s: AR " + " / ".join(f"{e.percent_of_peak:.1f}" for e in ar)
          + ", ARX " + " / ".join(f"{e.percent_of_peak:.1f}" for e in arx))
    assert pred.model == "arx" and pred.input_order is not None and np.max(pred.input_order) >= 1
    for e_arx, e_ar in zip(arx[1:], ar[1:], strict=True):
        assert e_arx.percent_of_peak < e_ar.percent_of_peak - 2.0
    assert arx[2].percent_of_peak < 15.0
    assert np.all(np.abs(pred.predicted[np.isfinite(pred.predicted)]) <= 1.0)
