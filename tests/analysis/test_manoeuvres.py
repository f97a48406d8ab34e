"""Automatic manoeuvre segmentation against the simulator's scenario log, and operator marks."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Generator, Mapping
from typing import Any

import numpy as np
import pytest

from rig.analysis.manoeuvres import (
    Manoeuvre,
    ManoeuvreKind,
    Source,
    apply_marks,
    score_manoeuvres,
    segment_manoeuvres,
)
from sim_devices.vehicle import Drive, GroundTruth, make_scenario, simulate
from sim_devices.vehicle.driver import PolylinePath, constant_speed
from sim_devices.vehicle.model import Phase, VehicleState
from sim_devices.vehicle.scenarios import SCENARIOS, Scenario, ScenarioContext, ScenarioSpec
from vsccore.errors import AnalysisError

EXPECTED = {
    "straight": ManoeuvreKind.STRAIGHT,
    "double_lane_change": ManoeuvreKind.DOUBLE_LANE_CHANGE,
    "step_steer": ManoeuvreKind.STEP_STEER,
    "j_turn": ManoeuvreKind.J_TURN,
    "fishhook": ManoeuvreKind.FISHHOOK,
    "steady_state_circle": ManoeuvreKind.STEADY_STATE_CORNERING,
    "sine_with_dwell": ManoeuvreKind.SINE_WITH_DWELL,
    "swa_circles": ManoeuvreKind.LOW_SPEED,
}


def _scenarios(truth: GroundTruth) -> list[tuple[str, float, float]]:
    out = []
    k = 0
    while f"segment.{k}.kind" in truth.meta:
        if truth.meta[f"segment.{k}.kind"] == "scenario":
            out.append((
                str(truth.meta[f"segment.{k}.name"]),
                float(truth.meta[f"segment.{k}.t_start_s"]),
                float(truth.meta[f"segment.{k}.t_end_s"]),
            ))
        k += 1
    return out


def test_every_simulated_manoeuvre_is_recognised(mixed: GroundTruth) -> None:
    mans = segment_manoeuvres(mixed.t, mixed.speed, mixed.swa, mixed.yaw_rate, mixed.ay_meas)
    # a partition of the record
    assert mans[0].start_index == 0 and mans[-1].stop_index == len(mixed)
    assert all(a.stop_index == b.start_index for a, b in zip(mans, mans[1:], strict=False))
    labels = np.empty(len(mixed), dtype=object)
    for m in mans:
        labels[m.start_index : m.stop_index] = m.kind
    scen = _scenarios(mixed)
    assert [s[0] for s in scen] == list(EXPECTED)
    for name, t0, t1 in scen:
        span = (mixed.t >= t0) & (mixed.t < t1)
        want = EXPECTED[name]
        if want in (ManoeuvreKind.STRAIGHT, ManoeuvreKind.LOW_SPEED):
            assert np.mean(labels[span] == want) > 0.9, name
        else:
            # the sample of the largest |a_y| and most of the lateral activity carry the scenario's kind
            peak = np.flatnonzero(span)[np.argmax(np.abs(mixed.ay[span]))]
            assert labels[peak] is want, (name, labels[peak])
            busy = span & (np.abs(mixed.ay) > 1.0)
            assert np.mean(labels[busy] == want) > 0.9, name
    assert mans[1].to_dict()["kind"] == mans[1].kind.value


def test_operator_marks_override(mixed: GroundTruth) -> None:
    mans = segment_manoeuvres(mixed.t, mixed.speed, mixed.swa, mixed.yaw_rate, mixed.ay_meas)
    marked = apply_marks(mixed.t, mans, [(1.0, 3.0, "brake test"), (4.0, 5.0, "Double lane change")])
    kinds = [(m.kind, m.source, round(m.t_start_s, 2)) for m in marked[:4]]
    assert kinds == [
        (ManoeuvreKind.STRAIGHT, Source.AUTO, 0.0),
        (ManoeuvreKind.OTHER, Source.MARK, 1.0),
        (ManoeuvreKind.STRAIGHT, Source.AUTO, 3.01),
        (ManoeuvreKind.DOUBLE_LANE_CHANGE, Source.MARK, 4.0),
    ]
    assert marked[1].label == "brake test"
    assert sum(m.stop_index - m.start_index for m in marked) == len(mixed)
    with pytest.raises(AnalysisError, match="ends"):
        apply_marks(mixed.t, mans, [(5.0, 4.0, "x")])


def test_reference_validity_is_judged_over_the_manoeuvres_that_need_it() -> None:
    """Issue 16: low-speed circles in the middle of a drive (no GNSS sideslip below walking pace) made the demo's
    headline say "reference valid 22 % of the time"; it is judged over the manoeuvres that need it.
    """
    t = np.arange(0.0, 100.0, 0.05)
    n = t.size
    rng = np.random.default_rng(5)
    ref = np.radians(0.5) * np.sin(0.3 * t)
    est = ref + np.radians(0.05) * rng.standard_normal(n)
    low = (t >= 20.0) & (t < 80.0)
    valid = ~low  # the reference is invalid exactly where the car crawls
    i20, i80 = int(np.argmax(t >= 20.0)), int(np.argmax(t >= 80.0))
    mans = [
        Manoeuvre(ManoeuvreKind.STRAIGHT, 0, i20, float(t[0]), float(t[i20 - 1])),
        Manoeuvre(ManoeuvreKind.LOW_SPEED, i20, i80, float(t[i20]), float(t[i80 - 1])),
        Manoeuvre(ManoeuvreKind.STEADY_STATE_CORNERING, i80, n, float(t[i80]), float(t[-1])),
    ]
    _per, kinds, overall = score_manoeuvres(t, est, ref, mans, reference_valid=valid)
    assert overall.metrics is not None
    assert overall.metrics.valid_fraction == pytest.approx(1.0)  # was 0.4 (low-speed samples counted as invalid)
    assert not any("reference valid" in f for f in overall.metrics.failures)
    assert overall.metrics.passed
    # where the reference is needed and missing, it still counts
    valid2 = valid.copy()
    valid2[100:i20] = False
    valid2[i80 + 100 :] = False
    _per, _kinds, overall2 = score_manoeuvres(t, est, ref, mans, reference_valid=valid2)
    assert overall2.metrics is not None
    assert overall2.metrics.valid_fraction == pytest.approx(200 / (i20 + n - i80))
    assert any("reference valid" in f for f in overall2.metrics.failures)
    low_kind = next(k for k in kinds if k.kind is ManoeuvreKind.LOW_SPEED)
    assert low_kind.metrics is None  # nothing to score there


@dataclasses.dataclass(frozen=True)
class _Slalom(Scenario):
    """A slalom for the test (the simulator has none): sinusoidal steering at constant speed, 4 periods."""

    @property
    def spec(self) -> ScenarioSpec:
        def run(values: Mapping[str, Any], ctx: ScenarioContext, st: VehicleState) -> Generator[Phase, Any, None]:
            v = 60.0 / 3.6
            line = PolylinePath.line(st.east, st.north, st.yaw, v * 3.0 + 200.0)
            st = yield Phase(duration_s=2.0, speed=constant_speed(v), controller=ctx.follower(line),
                             label="slalom.lead")
            amp, f = math.radians(60.0), 0.5

            def swa(tau: np.ndarray) -> np.ndarray:
                return np.asarray(amp * np.sin(2.0 * math.pi * f * np.minimum(tau, 4.0 / f)), dtype=float)

            yield Phase(duration_s=4.0 / f + 1.0, speed=constant_speed(v), swa=swa, label="slalom")

        base = SCENARIOS["straight"]
        return dataclasses.replace(base, name="slalom", title="slalom (test)", run=run,
                                   entry=lambda _v: (60.0 / 3.6, None))


def test_slalom_and_single_lane_change_are_recognised() -> None:
    """Issue 16: slalom and lane change kinds, on simulated drives (the simulator labels its scenarios)."""
    drive = Drive([make_scenario("straight", speed_kmh=60.0, duration_s=4.0),
                   _Slalom("straight", make_scenario("straight").values),
                   make_scenario("straight", speed_kmh=60.0, duration_s=4.0)], gap_s=3.0)
    tr = simulate(drive, rate_hz=50.0)
    mans = segment_manoeuvres(tr.t, tr.speed, tr.swa, tr.yaw_rate, tr.ay_meas)
    t0 = float(tr.meta[next(k for k, v in tr.meta.items() if k.endswith(".label") and v == "slalom")
                       .replace(".label", ".t_start_s")])
    busy = (tr.t > t0) & (tr.t < t0 + 8.0) & (np.abs(tr.ay) > 1.0)
    labels = np.empty(len(tr), dtype=object)
    for m in mans:
        labels[m.start_index : m.stop_index] = m.kind
    assert np.mean(labels[busy] == ManoeuvreKind.SLALOM) > 0.9, [(m.kind, m.label) for m in mans]
