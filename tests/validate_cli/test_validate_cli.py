"""``rig validate``, ``rig rollover`` and ``rig steering reconstruct`` on a recorded simulated session.

The session (conftest) holds a double lane change and a J-turn. Checks:

- the report folder (HTML with embedded plots, PNGs, metrics JSON/CSV) and the JSON keys;
- offline estimators built from the truth: a known delay and offset are measured as such, and
  the difference between two estimates' biases (which cancels the reference's own error) matches
  an independent computation of the recorded VSC estimate against the simulator's sideslip;
- manoeuvres found automatically and from the operator mark; exit status 1 on FAIL, 2 on errors;
- the LTR against the simulator's wheel loads, the warning timing, the steering reconstruction.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.cli.main import app, main
from rig.data import load_session
from tests.validate_cli import estimators
from tests.validate_cli.conftest import MARK_LEAD_S, Recorded

runner = CliRunner()


def _validate(recorded: Recorded, tmp: Path, *args: str, monkeypatch: pytest.MonkeyPatch | None = None
              ) -> tuple[int, dict[str, Any], str]:
    out = tmp / "metrics.json"
    res = runner.invoke(app, ["validate", str(recorded.path), "--json", str(out), "--no-progress", *args])
    assert res.exit_code in (0, 1), res.output + repr(res.exception)
    return res.exit_code, json.loads(out.read_text()), res.output


@pytest.fixture(scope="module")
def vsc_run(recorded: Recorded, tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict[str, Any], Path, str]:
    tmp = tmp_path_factory.mktemp("vsc")
    code, doc, text = _validate(recorded, tmp, "--report", str(tmp / "report"))
    return code, doc, tmp / "report", text


@pytest.fixture(scope="module")
def offline_runs(recorded: Recorded, tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[int, dict[str, Any]]]:
    mp = pytest.MonkeyPatch()
    mp.setenv("RIG_TEST_SESSION", str(recorded.path))
    try:
        out = {}
        for name in ("ideal", "late_and_high"):
            code, doc, _text = _validate(recorded, tmp_path_factory.mktemp(name), "--estimator",
                                         f"tests.validate_cli.estimators:{name}")
            out[name] = (code, doc)
        return out
    finally:
        mp.undo()


def test_report_files_and_json_keys(vsc_run: tuple[int, dict[str, Any], Path, str]) -> None:
    code, doc, report, text = vsc_run
    assert code == (0 if doc["passed"] else 1)
    assert text.strip().splitlines()[-1].startswith("PASS" if doc["passed"] else "FAIL")
    for key in ("session", "passed", "tolerances", "reference", "reference_valid_fraction", "estimate_source",
                "reference_method", "overall", "per_kind", "per_manoeuvre", "manoeuvres", "truth", "cross_check",
                "steering", "warnings"):
        assert key in doc, key
    assert doc["reference_method"] == "rts" and doc["estimate_source"].startswith("CAN role vsc_beta_estimate")
    assert doc["tolerances"]["rmse_deg"] == pytest.approx(0.5)  # the recorded [validation] table
    overall = doc["overall"]["metrics"]
    for key in ("rmse_deg", "bias_deg", "max_abs_deg", "p95_abs_deg", "lag_s", "ay_bins", "failures", "valid_fraction"):
        assert key in overall, key
    assert sum(b["n"] for b in overall["ay_bins"]) == overall["n_compared"]
    assert 0.6 < doc["reference_valid_fraction"] <= 1.0
    html = (report / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4  # track, β, error, truth
    for name in ("track.png", "beta.png", "error.png", "truth.png"):
        assert (report / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((report / "metrics.json").read_text()) == doc
    with (report / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(doc["per_manoeuvre"])
    assert [r["kind"] for r in rows] == [m["manoeuvre"]["kind"] for m in doc["per_manoeuvre"]]
    for r, m in zip(rows, doc["per_manoeuvre"], strict=True):
        if m["metrics"] is not None:
            assert float(r["rmse_deg"]) == pytest.approx(m["metrics"]["rmse_deg"], rel=1e-9)


def test_manoeuvres_automatic_and_marked(vsc_run: tuple[int, dict[str, Any], Path, str], recorded: Recorded) -> None:
    _code, doc, _report, _text = vsc_run
    mans = doc["manoeuvres"]
    kinds = {m["kind"] for m in mans}
    assert {"straight", "double_lane_change", "j_turn"} <= kinds
    marked = [m for m in mans if m["source"] == "mark"]
    assert [m["label"] for m in marked] == ["j_turn"]
    # the mark was typed MARK_LEAD_S before the steer and closed by the "end" mark 0.5 s before the drive ends
    t0 = doc["manoeuvres"][0]["t_start_s"]
    inp_t0 = _truth_offset(recorded)
    assert marked[0]["t_start_s"] == pytest.approx(recorded.j_turn_start_s - MARK_LEAD_S + inp_t0, abs=0.1)
    assert marked[0]["t_stop_s"] == pytest.approx(float(recorded.truth.t[-1]) - 0.5 + inp_t0, abs=0.1)
    assert t0 == pytest.approx(0.0, abs=0.06)
    dlc = [m for m in mans if m["kind"] == "double_lane_change"]
    assert len(dlc) == 1 and m_contains(dlc[0], _dlc_steer_times(recorded, inp_t0))


def _truth_offset(recorded: Recorded) -> float:
    """Truth t = 0 on the session's time base (s since the first common GNSS epoch)."""
    from rig.data.inputs import load_inputs

    inp = load_inputs(recorded.path, can=False, optical=False)
    tr = inp.require_truth()
    return float(tr.t_s[0] - recorded.truth.t[0])


def _dlc_steer_times(recorded: Recorded, offset: float) -> tuple[float, float]:
    tr = recorded.truth
    steer = np.flatnonzero(np.abs(tr.swa) > math.radians(10.0))
    j = tr.t[steer] < recorded.j_turn_start_s
    return float(tr.t[steer[j][0]] + offset), float(tr.t[steer[j][-1]] + offset)


def m_contains(m: dict[str, Any], span: tuple[float, float]) -> bool:
    return bool(m["t_start_s"] <= span[0] and m["t_stop_s"] >= span[1])


def test_offline_estimator_delay_and_offset_are_measured(offline_runs: dict[str, tuple[int, dict[str, Any]]]) -> None:
    code_i, ideal = offline_runs["ideal"]
    code_l, late = offline_runs["late_and_high"]
    oi, ol = ideal["overall"]["metrics"], late["overall"]["metrics"]
    assert ideal["estimate_source"].startswith("estimator tests.validate_cli.estimators:ideal")
    # the ideal estimate's error is the reference's own error against the truth (same epochs, opposite sign)
    gnss_truth = next(s for s in ideal["truth"] if s["name"].startswith("gnss"))["metrics"]
    assert oi["bias_deg"] == pytest.approx(-gnss_truth["bias_deg"], abs=0.03)
    assert oi["rmse_deg"] == pytest.approx(gnss_truth["rmse_deg"], abs=0.05)
    assert oi["lag_s"] == pytest.approx(0.0, abs=0.03)
    # a 0.2 s delay and a 0.5° offset: the difference of biases cancels the reference's error
    assert ol["bias_deg"] - oi["bias_deg"] == pytest.approx(estimators.BIAS_DEG, abs=0.02)
    assert ol["lag_s"] == pytest.approx(estimators.DELAY_S, abs=0.03)
    assert code_l == 1 and not late["passed"] and ol["failures"]
    assert (abs(ol["bias_deg"]) > 0.3) == any(f.startswith("|bias|") for f in ol["failures"])
    assert code_i == (0 if ideal["passed"] else 1)


def test_recorded_estimate_against_an_independent_truth_computation(
    vsc_run: tuple[int, dict[str, Any], Path, str], offline_runs: dict[str, tuple[int, dict[str, Any]]],
    recorded: Recorded,
) -> None:
    """bias(VSC − ref) − bias(truth − ref) = bias(VSC − truth), the last from the CAN frames and the truth alone."""
    _code, doc, _r, _t = vsc_run
    _ci, ideal = offline_runs["ideal"]
    ds = load_session(recorded.path)
    roles = ds.can_roles("vsc")
    est = roles["vsc_beta_estimate"]
    ok = np.asarray(est.ok, dtype=bool)
    truth = ds.truth()
    tns = np.asarray(est.timestamps_ns)[ok]
    vals = np.asarray(est.values, dtype=float)[ok]
    # the scored span: everything but low-speed driving, on the 20 Hz GNSS epochs (approximated by the CAN frames
    # inside the scored manoeuvres)
    offset_ns = int(truth.time_ns[0])
    t_rel = (tns - offset_ns) / 1e9 + _truth_offset(recorded)
    scored = np.zeros(t_rel.size, dtype=bool)
    for m in doc["manoeuvres"]:
        if m["kind"] != "low_speed":
            scored |= (t_rel >= m["t_start_s"]) & (t_rel <= m["t_stop_s"])
    beta_true = np.interp(tns, truth.time_ns, truth.truth.beta_cg)
    inside = scored & (tns >= truth.time_ns[0]) & (tns <= truth.time_ns[-1])
    independent_bias = math.degrees(float(np.mean(vals[inside] - beta_true[inside])))
    reported = doc["overall"]["metrics"]["bias_deg"] - ideal["overall"]["metrics"]["bias_deg"]
    print(f"VSC estimate bias against the truth: independent {independent_bias:+.3f}°, from rig validate "
          f"{reported:+.3f}°")
    assert reported == pytest.approx(independent_bias, abs=0.05)


def test_bad_estimator_is_an_error_with_exit_2(recorded: Recorded, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["validate", str(recorded.path), "--no-progress", "--estimator", "tests.validate_cli.estimators:nope"])
    assert exc.value.code == 2
    assert "has no attribute 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["validate", str(recorded.path / "missing"), "--no-progress"])
    assert exc.value.code == 2


def test_rollover_against_the_wheel_loads(recorded: Recorded, tmp_path: Path) -> None:
    png = tmp_path / "ltr.png"
    res = runner.invoke(app, ["rollover", str(recorded.path), "--json", "--plot", str(png), "--threshold", "0.6"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    tr = recorded.truth
    peak = float(np.max(np.abs(tr.ltr)))
    assert doc["model"] == "physics" and doc["truth"] is not None
    assert doc["truth"]["peak_abs_ltr"] == pytest.approx(peak, rel=1e-6)
    assert doc["peak_abs_ltr"] == pytest.approx(peak, abs=0.03)
    assert doc["truth"]["ltr_error_rms"] < 0.01
    # the largest error is in the 0.2 s steer of the J-turn (|dLTR/dt| ≈ 3.5 /s): the CAN sensor's bandwidth
    # and latency (tens of ms) lag it by a few hundredths
    assert doc["truth"]["ltr_error_max"] < 0.1
    errs = doc["truth"]["prediction_errors"]
    assert [e["horizon_s"] for e in errs] == [1.0, 2.0, 3.0] and all(e["n"] > 0 for e in errs)
    # the warning at 0.6 starts no later than its confirmation time (rollover.CONFIRM_S, 0.25 s) after the true
    # |LTR| first reaches 0.6 (the prediction crosses 0.6 before the LTR does; confirming it takes 0.2 s)
    t_reach = float(tr.t[np.argmax(np.abs(tr.ltr) >= 0.6)]) + _truth_offset(recorded)
    assert doc["first_warning_s"] is not None and doc["first_warning_s"] <= t_reach + 0.25 + 0.02
    assert doc["first_warning_s"] >= recorded.j_turn_start_s + _truth_offset(recorded) - 3.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = runner.invoke(app, ["rollover", str(recorded.path)])
    assert text.exit_code == 0 and "no warning" in text.output and "LTR = (2/t)" in text.output


def test_steering_reconstruction(recorded: Recorded, vsc_run: tuple[int, dict[str, Any], Path, str]) -> None:
    """Issue 9: δ from GNSS speed and a_y on the double lane change at 50 km/h (linear range)."""
    dlc = next(m for m in vsc_run[1]["manoeuvres"] if m["kind"] == "double_lane_change")
    res = runner.invoke(app, ["steering", "reconstruct", str(recorded.path), "--json", "--start",
                              str(dlc["t_start_s"]), "--stop", str(dlc["t_stop_s"])])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    print(f"steering reconstruction, recorded DLC at 50 km/h: mean |error| {doc['mean_abs_error_deg']:.3f}°, "
          f"max {doc['max_abs_error_deg']:.3f}°, max relative error at the peaks "
          f"{doc['max_relative_error_at_peaks_percent']:.1f} %")
    assert doc["mean_abs_error_deg"] < 0.3  # ≈ 4–8 % of road-wheel angles of up to ≈ 4°
    assert doc["max_relative_error_at_peaks_percent"] < 15.0
    assert len(doc["peaks_t_s"]) >= 3 and all(dlc["t_start_s"] <= t <= dlc["t_stop_s"] for t in doc["peaks_t_s"])
    whole = json.loads(runner.invoke(app, ["steering", "reconstruct", str(recorded.path), "--json"]).output)
    assert whole["max_abs_error_deg"] > doc["max_abs_error_deg"]  # the J-turn at the tyre limit is worse
