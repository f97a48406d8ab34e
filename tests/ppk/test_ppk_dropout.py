"""Acceptance (issue 18 §1): a correction dropout of more than 60 s around a double lane change.

One simulated session is recorded through the real recording path (base and two rovers with the
correction relay, the VSC ECU, the DAQ) with the rovers logging RANGECMPB at 20 Hz, GPSEPHEMB and
GLOEPHEMERISB; the
rovers' correction ports are unplugged (the radio link drops, the base's RTCM is still recorded) from
before the lane change until well after it. Then:

- live RTK is not fixed and the live reference is invalid during the dropout;
- ``rig ppk`` fixes every rover epoch with RTKLIB and writes ``<session>.ppk.parquet``;
- the reference (``rig validate``'s) then covers the dropout with PPK positions, with β RMS vs the
  simulator's truth ≤ 0.05° and coverage ≥ 95 %, and says which solution each epoch took;
- GPS + GLONASS solves with more satellites than GPS alone on the same session, and fixes and
  scores β at least as well.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.analysis.reference import PositionSource, ReferenceSideslip
from rig.cli.main import app
from rig.core.config import load_session
from rig.data.inputs import SessionInputs, load_inputs
from rig.data.sidefiles import PPK_COLUMNS, ppk_file_path, read_ppk_file
from rig.evaluate.validate import validate_session, validation_lines
from rig.sim.record import record_simulated
from rig.sim.world import SimWorld
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, make_scenario, simulate

pytestmark = [
    pytest.mark.skipif(shutil.which("rnx2rtkp") is None or shutil.which("convbin") is None,
                       reason="RTKLIB not installed (apt-get install rtklib)"),
    # The module's fixture records a governed simulated session with a 64 s dropout (about 3 min on an idle
    # 2-core machine, 197 s measured); on a busy one the governed clock slows it down by design, and it passed
    # the suite's 300 s hang guard in a CI run on 4 workers. Widened for this module only.
    pytest.mark.timeout(1200),
]

FAST_RTK = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=1.0,
                     time_to_fix_s=3.0)
ROVER_A_LOGS = [{"name": "BESTPOSB", "period_s": 0.05}, {"name": "BESTVELB", "period_s": 0.05},
                {"name": "TIMEB", "period_s": 1.0}, {"name": "MARKPOSB", "trigger": "onnew"},
                {"name": "MARKTIMEB", "trigger": "onnew"}, {"name": "RANGECMPB", "period_s": 0.05},
                {"name": "GPSEPHEMB", "trigger": "onchanged"}, {"name": "GLOEPHEMERISB", "trigger": "onchanged"}]
ROVER_B_LOGS = [{"name": "BESTPOSB", "period_s": 0.05}, {"name": "BESTVELB", "period_s": 0.05},
                {"name": "TIMEB", "period_s": 1.0}, {"name": "RANGECMPB", "period_s": 0.05},
                {"name": "GPSEPHEMB", "trigger": "onchanged"}, {"name": "GLOEPHEMERISB", "trigger": "onchanged"}]
ROVERS = ("rover_a", "rover_b")
UNPLUG_S = 6.0
"""Truth time at which the correction link drops."""
DROPOUT_S = 64.0
REFIX_S = 12.0
"""Drive time after the link is back (live RTK fixes again within FAST_RTK.time_to_fix_s)."""


@dataclass(frozen=True)
class Dropout:
    path: Path
    live: SessionInputs
    """The session read before ``rig ppk`` (live RTK only)."""
    ppk_output: str
    ppk: SessionInputs
    """The session read after ``rig ppk``."""
    window_s: tuple[float, float]
    """Dropout on the session time base (s)."""
    dlc_s: tuple[float, float]
    """The double lane change on the session time base (s)."""


def _segment(truth: GroundTruth, kind: str) -> tuple[float, float]:
    for key, value in truth.meta.items():
        if key.startswith("segment.") and key.endswith(".name") and value == kind:
            base = key.removesuffix(".name")
            return float(truth.meta[base + ".t_start_s"]), float(truth.meta[base + ".t_end_s"])
    raise AssertionError(f"no segment {kind!r} in the drive")


def _unplug(world: SimWorld, _session: object) -> None:
    for r in ROVERS:
        world.receivers[r].unplug("COM2")


def _replug(world: SimWorld, _session: object) -> None:
    for r in ROVERS:
        world.receivers[r].replug("COM2")


@pytest.fixture(scope="module")
def dropout(tmp_path_factory: pytest.TempPathFactory) -> Dropout:
    cfg = load_session(demo_config_path(), {"simulation.true_mount_offset_deg": 0.0,
                                            "receivers.1.logs": ROVER_A_LOGS, "receivers.2.logs": ROVER_B_LOGS})
    sim = cfg.simulation
    assert sim is not None
    params = VehicleParams.from_mapping(cfg.profile.vehicle.model_dump())
    # the lane change in the middle of the dropout, and time after it for live RTK to fix again
    first = make_scenario("straight", speed_kmh=50.0, duration_s=20.0)
    dlc = make_scenario("double_lane_change", speed_kmh=50.0)
    probe = simulate(Drive([first, dlc], gap_s=2.0), params, rate_hz=100.0,
                     origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                     initial_heading_deg=sim.initial_heading_deg, seed=sim.seed)
    tail_s = UNPLUG_S + DROPOUT_S + REFIX_S - float(probe.t[-1]) - 2.0
    drive = Drive([first, dlc, make_scenario("straight", speed_kmh=50.0, duration_s=tail_s)], gap_s=2.0)
    truth = simulate(drive, params, rate_hz=1000.0, origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                     initial_heading_deg=sim.initial_heading_deg, seed=sim.seed)
    dlc_truth = _segment(truth, "double_lane_change")
    assert dlc_truth[0] > UNPLUG_S + 5.0 and dlc_truth[1] + 5.0 < UNPLUG_S + DROPOUT_S
    out = tmp_path_factory.mktemp("ppk_dropout")
    rec = record_simulated(cfg, out, name="dropout", drive=drive, truth=truth, speed=2.0, rtk=FAST_RTK,
                           config_path=demo_config_path(),
                           actions=[(UNPLUG_S, _unplug), (UNPLUG_S + DROPOUT_S, _replug)])
    assert rec.completed and rec.summary.recording.finalized, rec.summary
    path = Path(out) / "dropout"
    live = load_inputs(path, optical=False)
    res = CliRunner().invoke(app, ["ppk", str(path)])
    assert res.exit_code == 0, res.output
    ppk = load_inputs(path, optical=False)
    assert ppk.truth is not None
    tt = ppk.truth
    window = np.interp([UNPLUG_S, UNPLUG_S + DROPOUT_S], tt.truth.t, tt.t_s)
    dlc_s = np.interp(dlc_truth, tt.truth.t, tt.t_s)
    return Dropout(path, live, res.output, ppk, (float(window[0]), float(window[1])),
                   (float(dlc_s[0]), float(dlc_s[1])))


def _in(t: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    return (t >= span[0]) & (t <= span[1])


def test_live_rtk_is_invalid_during_the_dropout(dropout: Dropout) -> None:
    g = dropout.live.require_gnss()
    assert g.a.source is None  # no PPK file yet
    lo, hi = dropout.window_s
    assert hi - lo >= 60.0 and lo < dropout.dlc_s[0] and dropout.dlc_s[1] < hi
    # fixed before the link drops
    assert np.all(g.rtk_fixed_both[_in(g.t_s, (lo - 3.0, lo))])
    # after the receivers' correction age limit, no fix and no valid live reference during the dropout
    after_age = (lo + FAST_RTK.max_correction_age_s + 1.0, hi)
    assert not np.any(g.rtk_fixed_both[_in(g.t_s, after_age)])
    ref = validate_session(dropout.live).reference
    assert not np.any(ref.valid[_in(ref.t, after_age)])


def test_rig_ppk_fixes_every_rover(dropout: Dropout) -> None:
    print("\n" + dropout.ppk_output)
    for r in ROVERS:
        assert f"{r}: fix ratio " in dropout.ppk_output
    sols = read_ppk_file(ppk_file_path(dropout.path))
    assert set(sols) == set(ROVERS)
    g = dropout.live.require_gnss()
    for r in ROVERS:
        s = sols[r]
        # every live epoch has a PPK epoch, and ≥ 95 % of them are fixed
        assert np.isin(g.gps_time_ns, s.gps_time_ns).mean() >= 0.99
        assert s.fixed.mean() >= 0.95, f"{r}: PPK fix ratio {s.fixed.mean():.3f}"
    import pyarrow.parquet as pq

    assert tuple(pq.read_schema(ppk_file_path(dropout.path)).names) == PPK_COLUMNS


def _score(inp: SessionInputs, ref: ReferenceSideslip, span: tuple[float, float]) -> tuple[float, float, float, int]:
    assert inp.truth is not None
    tr = inp.truth
    truth = np.interp(ref.t, tr.t_s, tr.truth.beta_cg, left=np.nan, right=np.nan)
    e = ref.beta - truth
    moving = _in(ref.t, span) & (ref.speed >= 10.0 / 3.6)
    m = moving & ref.valid & np.isfinite(e)
    rms = math.degrees(float(np.sqrt(np.mean(e[m] ** 2))))
    return rms, float(np.mean(ref.valid[moving])), float(np.mean(np.abs(e[m]) <= ref.u95[m])), int(np.count_nonzero(m))


def test_ppk_reference_covers_the_dropout(dropout: Dropout) -> None:
    sv = validate_session(dropout.ppk)
    ref = sv.reference
    rms, coverage, within_u95, n = _score(dropout.ppk, ref, dropout.window_s)
    rms_dlc, cov_dlc, _, n_dlc = _score(dropout.ppk, ref, dropout.dlc_s)
    print(f"\n  dropout {dropout.window_s[1] - dropout.window_s[0]:.1f} s: β RMS {rms:.4f}° coverage {coverage:.3f} "
          f"within U95 {within_u95:.3f} (n = {n}); lane change: RMS {rms_dlc:.4f}° coverage {cov_dlc:.3f} "
          f"(n = {n_dlc})\n  {ref.source_summary()}")
    assert n >= 0.95 * 20 * 60
    assert rms <= 0.05
    assert coverage >= 0.95
    assert rms_dlc <= 0.05 and cov_dlc >= 0.95
    # it says which solution each epoch took: PPK in the dropout, live RTK where live RTK is fixed
    assert ref.source is not None
    inside = _in(ref.t, (dropout.window_s[0] + FAST_RTK.max_correction_age_s + 1.0, dropout.window_s[1])) & ref.valid
    assert np.all(ref.source[inside] == PositionSource.PPK.value)
    g = dropout.ppk.require_gnss()
    live_fixed = dropout.live.require_gnss().rtk_fixed_both
    assert np.all(ref.source[live_fixed & ref.valid] == PositionSource.RTK.value)
    assert g.a.source is not None and set(np.unique(g.a.position_type[g.a.source == "ppk"])) == {"PPK_FIXED"}
    summary = ref.source_summary()
    assert "PPK fixed on both antennas (live RTK not fixed)" in summary and "live RTK fixed" in summary
    assert summary in validation_lines(sv)
    assert ref.to_dict()["position_sources"] == ref.source_counts()


def test_validate_report_states_the_sources(dropout: Dropout, tmp_path: Path) -> None:
    import html

    from rig.evaluate.report import write_validation_report

    sv = validate_session(dropout.ppk)
    files = write_validation_report(sv, tmp_path / "report")
    assert html.escape(sv.reference.source_summary()) in files.html.read_text(encoding="utf-8")


def test_glonass_adds_satellites_and_is_at_least_as_good_as_gps_only(dropout: Dropout, tmp_path: Path) -> None:
    """The same session post-processed with GPS only (a copy, so its side file is its own): GPS + GLONASS has more
    satellites, fixes at least as many epochs, and its β RMS over the dropout is no worse (within 0.002°)."""
    from rig.ppk.rtklib import run_ppk

    for part in dropout.path.parent.glob(dropout.path.name + ".*"):
        if not part.name.endswith(".ppk.parquet"):
            shutil.copy(part, tmp_path / part.name)
    gps_path = tmp_path / dropout.path.name
    run = run_ppk(gps_path, systems=("G",))
    gps = load_inputs(gps_path, optical=False)
    both_sols, gps_sols = read_ppk_file(ppk_file_path(dropout.path)), read_ppk_file(run.out)
    rms_both, cov_both, _, _ = _score(dropout.ppk, validate_session(dropout.ppk).reference, dropout.window_s)
    rms_gps, cov_gps, _, _ = _score(gps, validate_session(gps).reference, dropout.window_s)
    import pyarrow.parquet as pq

    def ns_median(path: Path, rover: str) -> float:
        t = pq.read_table(path, columns=["rover", "ns"]).to_pandas()
        return float(t.loc[t["rover"] == rover, "ns"].median())

    lines = []
    for r in ROVERS:
        b, g = both_sols[r], gps_sols[r]
        ns_b, ns_g = ns_median(ppk_file_path(dropout.path), r), ns_median(run.out, r)
        lines.append(f"{r}: fixed {b.fixed.mean():.3f}, median {ns_b:g} satellites (GPS only {g.fixed.mean():.3f}, "
                     f"{ns_g:g})")
        assert ns_b >= ns_g + 4, r
        assert b.fixed.sum() >= g.fixed.sum(), r
    print(f"\n  β RMS over the dropout: GPS+GLONASS {rms_both:.4f}° (coverage {cov_both:.3f}), GPS only {rms_gps:.4f}° "
          f"(coverage {cov_gps:.3f}); " + "; ".join(lines))
    assert rms_both <= rms_gps + 0.002 and cov_both >= cov_gps - 0.005
