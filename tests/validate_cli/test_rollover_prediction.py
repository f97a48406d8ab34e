"""The roll model, the steering's LTR demand and the ARX predictor behind ``rig rollover``.

Against the vehicle simulator (roll angle, wheel-load LTR), statsmodels (AutoReg with exogenous
inputs: same orders by AIC, same coefficients) and a noise-free synthetic system (exact recovery).
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest
from statsmodels.tsa.ar_model import AutoReg

from rig.analysis.rollover import (
    CONFIRM_S,
    LtrDemandModel,
    LtrExogenous,
    RollModel,
    VehicleLtrModel,
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


# --------------------------------------------------------------------------------------------
# Issue 16: the physics-informed predictor, persistence on the fishhook, confirmed warnings
# --------------------------------------------------------------------------------------------

VEHICLE = VehicleLtrModel.from_vehicle(P)
PUBLISHED_J_TURN = (4.3, 6.2, 10.3)
"""Published AR figures for the J-turn, % of the peak |LTR| at 1 / 2 / 3 s (issue 9)."""


def _measured(tr: GroundTruth, seed: int) -> tuple[np.ndarray, LtrExogenous]:
    """LTR and inputs as ``rig rollover`` sees them: CAN a_y (+0.03 m/s² white), SWA in 0.1° steps, noisy speed, a_x."""
    rng = np.random.default_rng(seed)
    ay_m = tr.ay_meas + rng.standard_normal(len(tr)) * 0.03
    phi, phidd = ROLL.roll_from_body_ay(tr.t, ay_m)
    ltr = ltr_from_lateral(horizontal_ay(ay_m, phi), phi, cg_height_m=P.cg_height_m,
                           roll_axis_height_m=P.roll_axis_height_m, track_m=TRACK, roll_accel_rps2=phidd,
                           roll_inertia_kgm2=P.roll_inertia_kgm2, mass_kg=P.mass_kg)
    swa = np.radians(np.round(np.degrees(tr.swa) / 0.1) * 0.1)
    speed = tr.speed + rng.standard_normal(len(tr)) * 0.03
    ax = tr.ax_meas + rng.standard_normal(len(tr)) * 0.05
    return ltr, LtrExogenous(swa, speed, ax, DEMAND)


def _window_b(tr: GroundTruth) -> dict[str, float]:
    on = float(tr.t[np.flatnonzero(np.abs(tr.swa) > math.radians(5.0))[0]])
    return {"t_start_s": on, "t_stop_s": float(tr.t[-1]), "issued_from_s": on}


@pytest.fixture(scope="module")
def j_turns() -> list[GroundTruth]:
    return [simulate(make_scenario("j_turn", **kw), P, rate_hz=100.0)
            for kw in ({}, {"speed_kmh": 50.0, "turn": "right"}, {"swa_scale": 4.0})]


def test_physics_predictor_reaches_the_published_j_turn_figures(j_turns: list[GroundTruth]) -> None:
    """Mean over three J-turns × three noise seeds, window B (the study's headline): ≤ 4.3 / 6.2 / 10.3 %.

    The ARX model (steady-state demand, 3 s window) scored 6.3 / 8.7 / 12.8 % here; the held-steering floor is
    1.1 / 1.6 / 2.5 % (benchmarks/study_rollover_prediction.py).
    """
    phys, arx = [], []
    for tr in j_turns:
        for seed in (1, 2, 3):
            ltr, ex = _measured(tr, seed)
            pred = predict_ltr(tr.t, ltr, exogenous=dataclasses.replace(ex, vehicle=VEHICLE))
            assert pred.model == "physics"
            phys.append([e.percent_of_peak for e in prediction_errors(pred, tr.t, tr.ltr, **_window_b(tr))])
            if seed == 1:
                old = predict_ltr(tr.t, ltr, exogenous=ex)
                arx.append([e.percent_of_peak for e in prediction_errors(old, tr.t, tr.ltr, **_window_b(tr))])
    mean = np.mean(phys, axis=0)
    print("J-turn, % of peak |LTR| at 1/2/3 s: physics " + " / ".join(f"{x:.1f}" for x in mean)
          + " (worst case " + " / ".join(f"{x:.1f}" for x in np.max(phys, axis=0)) + "), ARX "
          + " / ".join(f"{x:.1f}" for x in np.mean(arx, axis=0)))
    for got, published in zip(mean, PUBLISHED_J_TURN, strict=True):
        assert got <= published
    assert np.all(np.max(phys, axis=0) <= np.asarray(PUBLISHED_J_TURN))  # every J-turn and seed, not only the mean
    # the model foresees the threshold: at 0.6 the prediction crosses it before the true LTR gets there (the steer
    # reaches 0.6 in 0.2 s), and the warning follows once confirmed, 4 epochs (0.2 s) later
    tr = j_turns[0]
    ltr, ex = _measured(tr, 1)
    ex = dataclasses.replace(ex, vehicle=VEHICLE)
    raw = predict_ltr(tr.t, ltr, exogenous=ex, threshold=0.6, confirm_s=0.0).first_warning_s()
    first = predict_ltr(tr.t, ltr, exogenous=ex, threshold=0.6).first_warning_s()
    reached = float(tr.t[np.argmax(np.abs(tr.ltr) >= 0.6)])
    assert raw is not None and first is not None and raw < reached
    assert first == pytest.approx(raw + CONFIRM_S - 0.05, abs=1e-9)


@pytest.mark.parametrize("kw", [{}, {"speed_kmh": 70.0}, {"speed_kmh": 50.0, "turn": "right"}],
                         ids=["60kmh", "70kmh", "50kmh-right"])
def test_physics_predictor_never_worse_than_persistence_on_the_fishhook(kw: dict[str, object]) -> None:
    """Issue 16: the ARX was worse than holding the current LTR at 1 s on the 70 km/h fishhook (40.6 vs 34.2 %).

    Checked on the manoeuvre window (B) and on the whole record (every prediction landing in it, the peak over
    the record), at every horizon.
    """
    tr = simulate(make_scenario("fishhook", **kw), P, rate_hz=100.0)
    ltr, ex = _measured(tr, 9)
    pred = predict_ltr(tr.t, ltr, exogenous=dataclasses.replace(ex, vehicle=VEHICLE))
    held = np.where(np.isnan(pred.predicted), np.nan, np.repeat(pred.ltr[:, None], 3, axis=1))
    persistence = dataclasses.replace(pred, predicted=held, model="persistence")
    for label, span in (("manoeuvre", _window_b(tr)), ("whole record", {})):
        got = prediction_errors(pred, tr.t, tr.ltr, **span)
        base = prediction_errors(persistence, tr.t, tr.ltr, **span)
        print(f"fishhook {kw} ({label}): physics " + " / ".join(f"{e.percent_of_peak:.1f}" for e in got)
              + ", persistence " + " / ".join(f"{e.percent_of_peak:.1f}" for e in base))
        for e, b in zip(got, base, strict=True):
            assert e.n == b.n > 0
            assert e.percent_of_peak <= b.percent_of_peak


def test_a_single_sample_crossing_raises_no_warning() -> None:
    """At the onset of the steering circles one LTR sample crosses the threshold (a glitch): no warning.

    A crossing that holds for the confirmation time is warned of, at the confirming sample.
    """
    tr = simulate(make_scenario("swa_circles", speed_kmh=5.0, swa_max_deg=520.0, swa_step_deg=455.0,
                                direction="forward", swa_rate_dps=180.0, settle_s=0.5, hold_s=5.3), P, rate_hz=20.0)
    ltr, ex = _measured(tr, 4)
    onset = int(np.flatnonzero(np.abs(tr.swa) > math.radians(5.0))[0])
    spiked = ltr.copy()
    spiked[onset] = 0.95  # one sample of the 20 Hz record
    ex_phys = dataclasses.replace(ex, vehicle=VEHICLE)
    for exo in (None, ex, ex_phys):
        pred = predict_ltr(tr.t, spiked, exogenous=exo)
        assert np.any(np.abs(pred.ltr) >= 0.9)  # the crossing is there …
        assert pred.first_warning_s() is None, pred.model  # … and raises nothing
    held = ltr.copy()
    held[onset : onset + 10] = 0.95  # 0.5 s above the threshold
    pred = predict_ltr(tr.t, held, exogenous=ex_phys)
    first = pred.first_warning_s()
    assert first is not None
    assert first == pytest.approx(float(tr.t[onset]) + CONFIRM_S - 0.05, abs=0.051)
    assert predict_ltr(tr.t, spiked, exogenous=ex_phys, confirm_s=0.0).first_warning_s() is not None
    with pytest.raises(AnalysisError, match="confirm_s"):
        predict_ltr(tr.t, ltr, confirm_s=-1.0)
