"""How well can the LTR be predicted 1, 2 and 3 s ahead on J-turns and fishhooks? AR, ARX, persistence and a floor.

Issue 9 asks for the mean absolute prediction error at 1, 2 and 3 s as a percentage of the
manoeuvre's peak |LTR| (published figures for the AR method: 5.1 / 7.4 / 11.2 % fishhook,
4.3 / 6.2 / 10.3 % J-turn). This script measures, on the vehicle simulator:

- ``persistence``: the current LTR held (the baseline any predictor must beat);
- ``ar``: the issue's method (:func:`rig.analysis.rollover.predict_ltr` without inputs: AR on the
  LTR increments, order by AIC, 3 s sliding window refitted every 0.25 s);
- ``arx``: the same window with the steering demand as exogenous input (steering held, speed
  extrapolated; see the module docstring of :mod:`rig.analysis.rollover`);
- ``physics``: the physics-informed predictor (``LtrExogenous.vehicle``: the profile's vehicle model
  tracking the measured SWA and speed, propagated with the steering held; ``rig rollover``'s default);
- ``floor``: the simulator itself, restarted for every issue time with the steering held at its
  value at that time from then on: the best a predictor can do without knowing the driver's next
  steering input. It is not a method, it is the bound.

Measurements (fixed seed): the LTR is computed as ``rig rollover`` does it, from a body-fixed lateral
accelerometer (truth + white noise 0.03 m/s², 100 Hz) with the roll angle from the vehicle's roll
model; SWA quantised to 0.1°; speed (+ white 0.03 m/s) and longitudinal acceleration (+ white
0.05 m/s²). Errors are against the simulator's true LTR from the wheel loads.

Evaluation window (stated once, used for every method): the manoeuvre runs from the steering
onset t_on (first |SWA| > 5°) to the end of the scenario t_end (end of the hold, or of the
post-steer time of the fishhook). Window **B** (the headline): predictions issued at t ≥ t_on whose
target time t + h ≤ t_end; window **A**: every prediction whose target lies in [t_on, t_end],
including those issued up to h before the onset (nothing can foresee the steer then); **whole**: every
prediction landing anywhere in the record (lead-in, manoeuvre, run-out), the peak over the record
(the published figures were likely averaged over whole test drives). Predictions are issued at 20 Hz;
the peak is max |true LTR| over the span.

Run: ``/work/venv/bin/python benchmarks/study_rollover_prediction.py [--no-floor]``
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Callable, Generator, Mapping
from typing import Any

import numpy as np

from rig.analysis.rollover import (
    LtrDemandModel,
    LtrExogenous,
    LtrPrediction,
    RollModel,
    VehicleLtrModel,
    horizontal_ay,
    ltr_from_lateral,
    predict_ltr,
    prediction_errors,
)
from sim_devices.vehicle import GroundTruth, VehicleParams, make_scenario, simulate
from sim_devices.vehicle.model import Phase, VehicleState
from sim_devices.vehicle.scenarios import SCENARIOS, Scenario, ScenarioContext, ScenarioSpec

P = VehicleParams()
TRACK = 0.5 * (P.track_front_m + P.track_rear_m)
ROLL = RollModel.from_vehicle(P)
VEHICLE = VehicleLtrModel.from_vehicle(P)
DEMAND = LtrDemandModel(P.wheelbase_m, P.understeer_gradient_rad_per_mps2, P.tyre_peak_mu, P.cg_height_m,
                        P.roll_axis_height_m, TRACK, ROLL.roll_gain_rad_per_mps2,
                        tuple(P.steering_ratio_swa_deg), tuple(P.steering_ratio))
MANOEUVRES: list[tuple[str, dict[str, object]]] = [
    ("j_turn", {}),
    ("j_turn", {"speed_kmh": 50.0, "turn": "right"}),
    ("j_turn", {"swa_scale": 4.0}),
    ("fishhook", {}),
    ("fishhook", {"speed_kmh": 70.0}),
    ("fishhook", {"speed_kmh": 50.0, "turn": "right"}),
]
HORIZONS = (1.0, 2.0, 3.0)


@dataclasses.dataclass(frozen=True)
class HeldSteering(Scenario):
    """The scenario with its steering held from ``hold_after_s`` into its main phase on (the floor)."""

    hold_after_s: float = 0.0
    extra_s: float = 3.5

    @property
    def spec(self) -> ScenarioSpec:
        base = SCENARIOS[self.name]
        label, hold, extra = self.name, self.hold_after_s, self.extra_s

        def run(values: Mapping[str, Any], ctx: ScenarioContext, st: VehicleState) -> Generator[Phase, Any, None]:
            gen = base.run(values, ctx, st)
            phase = next(gen)
            while True:
                if phase.label == label:
                    orig = phase.swa
                    assert orig is not None

                    def held(tau: np.ndarray, o: Callable[[np.ndarray], np.ndarray] = orig) -> np.ndarray:
                        return o(np.minimum(tau, hold))

                    yield dataclasses.replace(phase, swa=held, duration_s=max(phase.duration_s, hold + extra))
                    return
                st = yield phase
                try:
                    phase = gen.send(st)
                except StopIteration:
                    return

        return dataclasses.replace(base, run=run)


def measured_ltr(tr: GroundTruth, rng: np.random.Generator) -> tuple[np.ndarray, LtrExogenous]:
    ay_m = tr.ay_meas + rng.standard_normal(len(tr)) * 0.03
    phi, phidd = ROLL.roll_from_body_ay(tr.t, ay_m)
    ltr = ltr_from_lateral(horizontal_ay(ay_m, phi), phi, cg_height_m=P.cg_height_m,
                           roll_axis_height_m=P.roll_axis_height_m, track_m=TRACK, roll_accel_rps2=phidd,
                           roll_inertia_kgm2=P.roll_inertia_kgm2, mass_kg=P.mass_kg)
    swa = np.radians(np.round(np.degrees(tr.swa) / 0.1) * 0.1)
    speed = tr.speed + rng.standard_normal(len(tr)) * 0.03
    ax = tr.ax_meas + rng.standard_normal(len(tr)) * 0.05
    return ltr, LtrExogenous(swa, speed, ax, DEMAND)


def floor_prediction(sc: Scenario, tr: GroundTruth, issue_t: np.ndarray) -> LtrPrediction:
    t_phase = next(float(tr.meta[k.replace(".label", ".t_start_s")]) for k, v in tr.meta.items()
                   if k.endswith(".label") and v == sc.name)
    pred = np.full((issue_t.size, len(HORIZONS)), np.nan)
    cache: dict[float, GroundTruth] = {}
    for k, ti in enumerate(issue_t):
        hold = max(0.0, round(float(ti - t_phase), 6))  # before the manoeuvre: the lead-in's steering, held
        if hold not in cache:
            cache[hold] = simulate(HeldSteering(sc.name, sc.values, hold_after_s=hold), P, rate_hz=100.0)
        held = cache[hold]
        pred[k] = np.interp(ti + np.asarray(HORIZONS), held.t, held.ltr, right=np.nan)
    x = np.interp(issue_t, tr.t, tr.ltr)
    z = np.zeros(issue_t.size, dtype=np.int64)
    return LtrPrediction(issue_t, x, HORIZONS, pred, z, np.zeros(issue_t.size, dtype=bool), 0.9, "floor")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--no-floor", action="store_true", help="Skip the (slow) held-steering floor.")
    ap.add_argument("--seed", type=int, default=9)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    sums: dict[tuple[str, str, str], list[np.ndarray]] = {}
    print(f"{'manoeuvre':<34} {'method':<12} {'window B: 1 s / 2 s / 3 s [% of peak]':<40} "
          f"{'window A':<22} {'whole record':<22} {'n (B)':<12} time")
    for name, kw in MANOEUVRES:
        sc = make_scenario(name, **kw)
        tr = simulate(sc, P, rate_hz=100.0)
        ltr, ex = measured_ltr(tr, rng)
        on = float(tr.t[np.flatnonzero(np.abs(tr.swa) > math.radians(5.0))[0]])
        end = float(tr.t[-1])
        label = f"{name} {', '.join(f'{k}={v}' for k, v in kw.items()) or 'defaults'}"
        t0 = time.perf_counter()
        ar = predict_ltr(tr.t, ltr)
        t_ar = time.perf_counter() - t0
        t0 = time.perf_counter()
        arx = predict_ltr(tr.t, ltr, exogenous=ex)
        t_arx = time.perf_counter() - t0
        t0 = time.perf_counter()
        phys = predict_ltr(tr.t, ltr, exogenous=dataclasses.replace(ex, vehicle=VEHICLE))
        t_phys = time.perf_counter() - t0
        held = np.where(np.isnan(ar.predicted), np.nan, np.repeat(ar.ltr[:, None], len(HORIZONS), axis=1))
        persist = dataclasses.replace(ar, predicted=held, model="persistence")
        methods: list[tuple[str, LtrPrediction, float]] = [("persistence", persist, 0.0), ("ar", ar, t_ar),
                                                           ("arx", arx, t_arx), ("physics", phys, t_phys)]
        if not args.no_floor:
            t0 = time.perf_counter()
            methods.append(("floor", floor_prediction(sc, tr, ar.t), time.perf_counter() - t0))
        for mname, pred, el in methods:
            b = prediction_errors(pred, tr.t, tr.ltr, t_start_s=on, t_stop_s=end, issued_from_s=on)
            a = prediction_errors(pred, tr.t, tr.ltr, t_start_s=on, t_stop_s=end)
            w = prediction_errors(pred, tr.t, tr.ltr)
            pb = np.array([e.percent_of_peak for e in b])
            pa = np.array([e.percent_of_peak for e in a])
            pw = np.array([e.percent_of_peak for e in w])
            sums.setdefault((name, mname, "B"), []).append(pb)
            sums.setdefault((name, mname, "A"), []).append(pa)
            sums.setdefault((name, mname, "W"), []).append(pw)
            print(f"{label:<34} {mname:<12} {' / '.join(f'{x:5.1f}' for x in pb):<40} "
                  f"{' / '.join(f'{x:.1f}' for x in pa):<22} {' / '.join(f'{x:.1f}' for x in pw):<22} "
                  f"{'/'.join(str(e.n) for e in b):<12} {el:.2f} s")
    print("\nmean over the variants of each manoeuvre (window B; window A and the whole record in brackets):")
    for name in dict.fromkeys(n for n, _ in MANOEUVRES):
        for mname in ("persistence", "ar", "arx", "physics", "floor"):
            if (name, mname, "B") not in sums:
                continue
            mb = np.mean(sums[(name, mname, "B")], axis=0)
            ma = np.mean(sums[(name, mname, "A")], axis=0)
            mw = np.mean(sums[(name, mname, "W")], axis=0)
            print(f"  {name:<9} {mname:<12} {' / '.join(f'{x:5.1f}' for x in mb)}   "
                  f"(A {' / '.join(f'{x:.1f}' for x in ma)}; whole {' / '.join(f'{x:.1f}' for x in mw)})")
    if not args.no_floor:
        print("\nphysics / floor and physics / persistence, window B, worst variant (issue 16: within 10 % of the "
              "floor on the fishhook, never worse than persistence):")
        for name in dict.fromkeys(n for n, _ in MANOEUVRES):
            ratio = np.asarray(sums[(name, "physics", "B")]) / np.asarray(sums[(name, "floor", "B")])
            worst = np.asarray(sums[(name, "physics", "B")]) / np.asarray(sums[(name, "persistence", "B")])
            print(f"  {name:<9} to the floor {' / '.join(f'{x:.3f}' for x in ratio.max(axis=0))}; "
                  f"to persistence {' / '.join(f'{x:.3f}' for x in worst.max(axis=0))}")
    print("published (issue 9): fishhook 5.1 / 7.4 / 11.2, J-turn 4.3 / 6.2 / 10.3")


if __name__ == "__main__":
    main()
