"""The dashboard's live LTR (rig.session_devices.LiveLtr): the offline roll model and AR prediction on its last
seconds of CAN lateral acceleration, computed again only when samples came."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rig.analysis.rollover import RollModel, horizontal_ay, ltr_from_lateral, predict_ltr
from rig.config import load_session
from rig.session_devices import LiveLtr
from sim_devices.vehicle import make_scenario, simulate

REPO = Path(__file__).resolve().parents[2]


CFG = load_session(REPO / "examples" / "sim.toml")


def _offline(t_ns: np.ndarray, ay: np.ndarray) -> dict[str, float | bool]:
    """The figures as the whole-window computation gives them (no tail, no cache)."""
    v = CFG.profile.vehicle
    t = (t_ns - t_ns[0]) / 1e9
    grid = np.arange(0.0, t[-1], 1.0 / 50.0)
    a = np.interp(grid, t, ay)
    roll, _ = RollModel.from_vehicle(v).roll_from_body_ay(grid, a)
    ltr = ltr_from_lateral(horizontal_ay(a, roll), roll, cg_height_m=v.cg_height_m,
                           roll_axis_height_m=v.roll_axis_height_m, track_m=0.5 * (v.track_front_m + v.track_rear_m))
    recent = grid >= grid[-1] - 3.5
    pred = predict_ltr(grid[recent], ltr[recent], window_s=3.0)
    last = pred.predicted[-1]
    return {"ltr": float(ltr[-1]), "ltr_predicted": float(last[np.nanargmax(np.abs(last))]),
            "ltr_warning": bool(pred.warning[-1])}


def test_live_figures_are_the_offline_ones_and_come_again_only_with_new_samples() -> None:
    tr = simulate(make_scenario("fishhook"), rate_hz=100.0)
    live = LiveLtr(CFG)
    t_ns = np.round(tr.t * 1e9).astype(np.int64)
    ay = 1.6 * np.asarray(tr.ay_meas, dtype=np.float64)  # harder than the sim car's fishhook: LTR through 0.9
    warned = compared = 0
    for k in range(t_ns.size):
        live.add(int(t_ns[k]), float(ay[k]))
        if k % 10 or tr.t[k] < 2.5:
            continue
        got = live.figures()
        lo = int(np.searchsorted(t_ns, t_ns[k] - 4_000_000_000))  # the live history: 4 s
        want = _offline(t_ns[lo : k + 1], ay[lo : k + 1])
        assert got["ltr"] == pytest.approx(want["ltr"], abs=1e-12)
        assert got["ltr_predicted"] == pytest.approx(want["ltr_predicted"], abs=1e-12)
        assert got["ltr_warning"] == want["ltr_warning"]
        warned += int(bool(got["ltr_warning"]))
        compared += 1
    assert compared > 20 and 0 < warned < compared  # figures with and without the warning were compared
    # no sample since: the same figures without computing them again
    got = live.figures()
    computed = []
    live._compute = lambda data: computed.append(data) or {}  # type: ignore[method-assign]
    before = live.figures()
    assert before == got and computed == []
    live.add(int(t_ns[-1]) + 10_000_000, float(ay[-1]))
    live.figures()
    assert len(computed) == 1 and not math.isnan(before["ltr"])
