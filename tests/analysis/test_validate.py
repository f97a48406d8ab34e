"""End to end on a simulated drive: reference from noisy GNSS, an estimate with known errors, scores per manoeuvre."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.analysis.manoeuvres import ManoeuvreKind
from rig.analysis.metrics import Tolerances
from rig.analysis.reference import AntennaGeometry, reference_sideslip
from rig.analysis.scoring import load_estimator, run_estimator, validate_estimate
from sim_devices.vehicle import GroundTruth
from tests.analysis.obs import A_XY, BASELINE_M, RtkNoise, gnss_spec_for, observe_reference_inputs
from vsccore.errors import AnalysisError

DELAY_S = 0.15
BIAS = math.radians(0.2)


def test_known_estimate_errors_are_measured(mixed: GroundTruth) -> None:
    gnss, imu, idx = observe_reference_inputs(mixed, seed=4)
    ref = reference_sideslip(gnss, imu, AntennaGeometry(A_XY, BASELINE_M), gnss_spec=gnss_spec_for(RtkNoise()))
    t = ref.t
    # a VSC estimate that is 0.15 s late and reads 0.2° high
    estimate = np.interp(t - DELAY_S, mixed.t, mixed.beta_cg) + BIAS
    res = validate_estimate(
        ref, estimate, speed_mps=mixed.speed[idx], swa_rad=mixed.swa[idx], yaw_rate_rps=mixed.yaw_rate[idx],
        ay_mps2=mixed.ay_meas[idx], truth_rad=mixed.beta_cg[idx],
        tolerances=Tolerances.from_degrees(rmse_deg=0.5, max_abs_deg=3.0, bias_deg=0.3),
    )
    overall = res.overall.metrics
    assert overall is not None
    assert math.degrees(overall.bias_rad) == pytest.approx(0.2, abs=0.03)
    assert overall.lag_s == pytest.approx(DELAY_S, abs=0.03)
    kinds = {s.kind for s in res.per_kind}
    assert {ManoeuvreKind.DOUBLE_LANE_CHANGE, ManoeuvreKind.FISHHOOK, ManoeuvreKind.LOW_SPEED} <= kinds
    # the delay hurts where β changes fast: the sine with dwell scores worse than the straight
    by_kind = {s.kind: s.metrics for s in res.per_kind if s.metrics is not None}
    assert by_kind[ManoeuvreKind.SINE_WITH_DWELL].rmse_rad > 3 * by_kind[ManoeuvreKind.STRAIGHT].rmse_rad
    assert math.degrees(by_kind[ManoeuvreKind.STRAIGHT].bias_rad) == pytest.approx(0.2, abs=0.03)
    # the reference itself against the simulator's truth (issue 9: "scores each reference against the truth")
    (truth_score,) = res.truth
    print(f"GNSS reference vs truth over the mixed drive: RMS {math.degrees(truth_score.metrics.rmse_rad):.4f}°, "
          f"coverage {truth_score.coverage:.3f}, valid {res.reference_valid_fraction:.2f}")
    assert math.degrees(truth_score.metrics.rmse_rad) < 0.1
    assert truth_score.coverage >= 0.95
    rows = res.table_rows()
    assert len(rows) == len(res.manoeuvres) and {"rmse_deg", "lag_s", "passed"} <= set(rows[0])
    d = res.to_dict()
    assert d["passed"] is res.passed and d["overall"]["metrics"]["n_compared"] > 0  # type: ignore[index]


def test_offline_estimator_by_name(mixed: GroundTruth) -> None:
    t = mixed.t[::5]
    roles = {"yaw_rate": mixed.yaw_rate[::5], "ay": mixed.ay[::5], "speed": mixed.speed[::5]}
    beta = run_estimator("tests.analysis.estimators:steady_state_beta", t, roles)
    assert beta.shape == t.shape
    # the steady-state formula is right in steady cornering (the circle's last seconds)
    assert mixed.meta["segment.10.name"] == "steady_state_circle"
    t_end = float(mixed.meta["segment.10.t_end_s"])
    hold = (t > t_end - 2.0) & (t < t_end)
    assert np.max(np.abs(beta[hold] - mixed.beta_cg[::5][hold])) < math.radians(0.3)
    with pytest.raises(AnalysisError, match=r"expected 'package\.module:function'"):
        load_estimator("no_colon")
    with pytest.raises(AnalysisError, match="cannot import"):
        load_estimator("no_such_module_xyz:f")
    with pytest.raises(AnalysisError, match="has no attribute"):
        load_estimator("tests.analysis.estimators:missing")
    with pytest.raises(AnalysisError, match="one β per sample"):
        run_estimator("tests.analysis.estimators:broken", t, roles)
