"""`rig demo --fast` end to end: every stage runs and writes what it says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.cli.main import main


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    main(["demo", "--fast", "--out", str(out)])  # raises SystemExit on any failure
    return out


def test_truth_file_is_a_plausible_drive(demo_out: Path) -> None:
    data = np.genfromtxt(demo_out / "truth.csv", delimiter=",", names=True)
    t = data["t_s"]
    assert np.all(np.diff(t) > 0)
    # the programme starts with a 40 km/h straight run: speed held within 1 %, no sideslip
    first = t < 5.0
    assert np.allclose(data["speed_mps"][first] * 3.6, 40.0, rtol=0.01)
    assert np.max(np.abs(data["beta_cg_deg"][first])) < 0.01
    # and it contains a manoeuvre with real sideslip and load transfer
    assert np.max(np.abs(data["beta_cg_deg"])) > 1.0
    assert np.max(np.abs(data["ltr"])) > 0.3
    assert (demo_out / "truth.png").stat().st_size > 10_000
