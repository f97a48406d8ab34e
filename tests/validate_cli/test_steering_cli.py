"""``rig steering error-model``: the γ(v) table against the closed form, computed here from first principles."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.analysis.steering import SteeringReconstruction
from rig.cli.main import app
from tests.validate_cli.conftest import Recorded

runner = CliRunner()
G = 9.80665


def closed_form(mass: float, l_m: float, c_front: float, c_rear: float, b_over_l: float, deg_per_g: float,
                v_mps: float) -> tuple[float, float | None]:
    """γ(v) and the sign-change speed: single-track understeer gradient with two tyres per axle."""
    k_phi = math.radians(deg_per_g) / G  # rad per m/s²
    m_front = mass * b_over_l  # the front axle carries b/l of the weight
    m_rear = mass * (1.0 - b_over_l)
    k_us = m_front / (2.0 * c_front) - m_rear / (2.0 * c_rear)  # rad per m/s²
    gamma = 1.0 - l_m * (1.0 + G * k_phi) / (l_m + k_us * v_mps**2)
    v0 = math.sqrt(l_m * G * k_phi / k_us) if k_us > 0 and k_phi > 0 else None
    return gamma, v0


ARGS = ["steering", "error-model", "--mass", "1550", "--wheelbase", "2.8", "--cornering-stiffness", "60000",
        "--front-axle-load-share", "0.6", "--roll-gain-deg-per-g", "4.5"]


def test_json_matches_the_closed_form(tmp_path) -> None:
    png = tmp_path / "gamma.png"
    res = runner.invoke(app, [*ARGS, "--speeds", "15,36,50,80,120.5", "--json", "--plot", str(png)])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    speeds = [15.0, 36.0, 50.0, 80.0, 120.5]
    assert [e["speed_kmh"] for e in doc["errors"]] == pytest.approx(speeds)
    for e, v in zip(doc["errors"], speeds, strict=True):
        gamma, _ = closed_form(1550, 2.8, 60000, 60000, 0.6, 4.5, v / 3.6)
        assert e["gamma_percent"] == pytest.approx(100 * gamma, abs=1e-9)
    _, v0 = closed_form(1550, 2.8, 60000, 60000, 0.6, 4.5, 0.0)
    assert v0 is not None
    assert doc["sign_change_speed_kmh"] == pytest.approx(3.6 * v0, rel=1e-12)
    # at the sign-change speed the closed form is zero, on either side it has opposite signs
    assert closed_form(1550, 2.8, 60000, 60000, 0.6, 4.5, v0)[0] == pytest.approx(0.0, abs=1e-12)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert doc["plot"] == str(png)


def test_text_table_and_separate_rear_stiffness() -> None:
    res = runner.invoke(app, [*ARGS, "--cornering-stiffness-rear", "75000", "--speeds", "30,100"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    gamma_100, v0 = closed_form(1550, 2.8, 60000, 75000, 0.6, 4.5, 100 / 3.6)
    assert v0 is not None
    assert f"{3.6 * v0:.1f} km/h" in lines[1]
    row = next(x for x in lines if x.strip().startswith("100.0"))
    assert float(row.split()[1]) == pytest.approx(100 * gamma_100, abs=0.006)  # printed to 0.01 %


def test_oversteer_has_no_sign_change() -> None:
    # rear-heavy with a soft rear axle: K < 0, so γ stays negative and never crosses zero
    res = runner.invoke(app, ["steering", "error-model", "--mass", "1400", "--wheelbase", "2.5",
                              "--cornering-stiffness", "60000", "--cornering-stiffness-rear", "40000",
                              "--front-axle-load-share", "0.4", "--roll-gain-deg-per-g", "5", "--json",
                              "--speeds", "20,60"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["sign_change_speed_kmh"] is None
    for e in doc["errors"]:
        gamma, v0 = closed_form(1400, 2.5, 60000, 40000, 0.4, 5.0, e["speed_kmh"] / 3.6)
        assert v0 is None and e["gamma_percent"] == pytest.approx(100 * gamma, abs=1e-9)


def test_bad_parameters_are_one_line_errors(capsys) -> None:
    from rig.cli.main import main

    with pytest.raises(SystemExit) as exc:
        main([*ARGS[:-2], "--roll-gain-deg-per-g", "4", "--front-axle-load-share", "1.2"])
    assert exc.value.code == 2
    assert "front_axle_load_share" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main([*ARGS, "--speeds", "20,fast"])
    assert exc.value.code == 2
    assert "--speeds" in capsys.readouterr().err


def test_help_shows_the_units_and_per_tyre_wording() -> None:
    """Issue 16 §6: bracketed units such as "[kg]" were Rich markup tags and vanished ("Vehicle mass .")."""
    res = runner.invoke(app, ["steering", "error-model", "--help"], env={"COLUMNS": "300", "NO_COLOR": "1"})
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.replace("│", " ").split())  # the box drawing and the wrapping are Rich's
    for phrase in ("Vehicle mass (kg)", "Wheelbase l (m)", "one front tyre (N/rad per tyre, not per axle",
                   "one rear tyre (N/rad per tyre", "deg of body roll per g of lateral accel.",
                   "speeds (km/h"):
        assert phrase in text, phrase
    assert " ." not in text  # no unit swallowed before a full stop
    res = runner.invoke(app, ["steering", "reconstruct", "--help"], env={"COLUMNS": "300", "NO_COLOR": "1"})
    text = " ".join(res.output.replace("│", " ").split())
    for phrase in ("Lowest speed used (km/h)", "Only from this time (s, as rig validate)"):
        assert phrase in text, phrase


def test_recorded_dlc_reconstruction_to_the_published_figure(recorded: Recorded) -> None:
    """Issue 16 §3: on a recorded session (GNSS speed, CAN a_y with the ECU's bias and noise) the DLC at 50 km/h
    is reconstructed within 0.3° and 8 % at the peaks (the steady-state formula gave 0.51–0.60° / 7.9–10.9 %)."""
    from rig.data.inputs import load_inputs

    tr = recorded.truth
    offset = float(load_inputs(recorded.path, can=False, optical=False).require_truth().t_s[0] - tr.t[0])
    steer = np.flatnonzero(np.abs(tr.swa) > math.radians(10.0))
    steer = steer[tr.t[steer] < recorded.j_turn_start_s]
    start, stop = float(tr.t[steer[0]]) - 2.0 + offset, float(tr.t[steer[-1]]) + 2.0 + offset
    res = runner.invoke(app, ["steering", "reconstruct", str(recorded.path), "--json", "--start", f"{start:.3f}",
                              "--stop", f"{stop:.3f}"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    print(f"steering reconstruction, recorded DLC at 50 km/h ({doc['method']}): mean |error| "
          f"{doc['mean_abs_error_deg']:.3f}°, max {doc['max_abs_error_deg']:.3f}°, max relative error at the peaks "
          f"{doc['max_relative_error_at_peaks_percent']:.2f} %")
    assert doc["method"] == "single-track dynamics, non-linear tyres"
    assert 0.005 < doc["ay_delay_s"] < 0.05  # the ECU's 15 Hz sensing filter and 10 ms output latency
    assert len(doc["peaks_t_s"]) == 4
    assert doc["max_abs_error_deg"] <= 0.3
    assert doc["max_relative_error_at_peaks_percent"] <= 8.0


def test_reconstruct_removes_the_calibrated_sas_zero(recorded: Recorded, tmp_path: Path) -> None:
    """The SWA compared with the reconstruction loses the SAS zero in force (calibrate-steering-ratio records it):
    the simulated sensor reads 0.8° high, 0.05° of road-wheel angle, and the mean signed error goes with it."""
    import shutil

    from rig.core.config import load_session
    from rig.data.sidefiles import update_calibration_file
    from rig.evaluate.validate import steering_session
    from rig.workflows.demo import demo_config_path

    sim = load_session(demo_config_path()).simulation
    assert sim is not None
    for f in recorded.path.parent.glob(recorded.path.name + ".*"):
        shutil.copy(f, tmp_path / f.name)
    copy = tmp_path / recorded.path.name
    before = steering_session(copy).reconstruction
    update_calibration_file(copy, "steering_ratio", {"sas_zero": {"offset_deg": sim.true_swa_offset_deg,
                                                                  "u95_deg": 0.06}})
    after = steering_session(copy).reconstruction

    def bias(r: SteeringReconstruction) -> float:
        assert r.delta_from_swa is not None
        return float(np.nanmean(r.delta - r.delta_from_swa))

    shift = math.radians(sim.true_swa_offset_deg) / 16.0  # ≈ the ratio near centre
    assert bias(after) - bias(before) == pytest.approx(shift, rel=0.1)
