"""The dashboard's live LTR (rig.analysis.live_ltr.LiveLtr): the roll model and AR prediction on its last seconds
of CAN lateral acceleration, the prediction of the newest epochs only (the same figures as over the whole
window), computed again only when samples came."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rig.analysis.live_ltr import LiveLtr
from rig.core.config import load_session
from sim_devices.vehicle import make_scenario, simulate

REPO = Path(__file__).resolve().parents[2]
CFG = load_session(REPO / "examples" / "sim.toml")


def test_live_figures_are_the_offline_ones_and_come_again_only_with_new_samples() -> None:
    tr = simulate(make_scenario("fishhook"), rate_hz=100.0)
    live = LiveLtr(CFG.profile.vehicle)
    t_ns = np.round(tr.t * 1e9).astype(np.int64)
    ay = 1.6 * np.asarray(tr.ay_meas, dtype=np.float64)  # harder than the sim car's fishhook: LTR through 0.9
    warned = compared = 0
    for k in range(t_ns.size):
        live.add(int(t_ns[k]), float(ay[k]))
        if k % 10 or tr.t[k] < 2.5:
            continue
        got = live.figures()
        lo = int(np.searchsorted(t_ns, t_ns[k] - 4_000_000_000))  # the live history: 4 s
        want = live._compute(list(zip(t_ns[lo : k + 1].tolist(), ay[lo : k + 1].tolist(), strict=True)),
                             whole_window=True)
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
