"""Sessions shared by the calibration-command tests (recorded once per test run)."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.core.config import SessionConfig, load_session
from rig.data.sidefiles import update_calibration_file
from tests.calib_cli.synth import (
    SIM_TOML,
    circles,
    overrides_low_noise,
    record_sim,
    simulate_truth,
    straights,
    write_truth_session,
)

TRUE_OFFSET_DEG = 0.35
"""Injected antenna mounting offset (rig/examples/sim.toml has the same value)."""
TRUE_OPTICAL_ZERO_DEG = 0.25
"""The simulated optical sensor's true zero (rig/examples/sim.toml [simulation].true_optical_zero_deg.body)."""


@pytest.fixture(scope="session")
def sim_cfg() -> SessionConfig:
    return load_session(SIM_TOML)


@pytest.fixture(scope="session")
def straights_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Full simulated recording (pty receivers, virtual CAN, simulated DAQ, 3× real time — faster starves the
    simulated DAQ in the one shared process and it overflows): two 7 s straight
    runs at 40 km/h in opposite directions, RTK-level noise, injected mounting offset 0.35°."""
    out = tmp_path_factory.mktemp("straights")
    return record_sim(out, "straights", straights(40.0, 7.0), overrides_low_noise(TRUE_OFFSET_DEG), speed=3.0)


@pytest.fixture(scope="session")
def truth_straights(tmp_path_factory: pytest.TempPathFactory, sim_cfg: SessionConfig) -> Path:
    """Two 7 s straight runs at 40 km/h in opposite directions written from simulator truth (no device timing
    involved, so deterministic): 0.7 mm per axis and rover (1 mm 2-D RMS), Gauss–Markov τ = 0.2 s, offset 0.35°."""
    out = tmp_path_factory.mktemp("truth_straights")
    truth = simulate_truth(sim_cfg, straights(40.0, 7.0))
    return write_truth_session(out, "tstraights", sim_cfg, truth, offset_deg=TRUE_OFFSET_DEG, noise_m=0.0007,
                               correlation_s=0.2)


@pytest.fixture(scope="session")
def circles_session(tmp_path_factory: pytest.TempPathFactory, sim_cfg: SessionConfig) -> Path:
    """Constant-SWA circles (±260 … ±520°, forward and reverse, 5 km/h) written from simulator truth, with the
    mounting offset already calibrated (recorded in the session's calibration file)."""
    out = tmp_path_factory.mktemp("circles")
    truth = simulate_truth(sim_cfg, circles(swa_max_deg=520.0, swa_step_deg=130.0, hold_s=12.0))
    path = write_truth_session(out, "circles", sim_cfg, truth, offset_deg=TRUE_OFFSET_DEG, noise_m=0.002)
    update_calibration_file(path, "mount_offset", {"offset_deg": TRUE_OFFSET_DEG, "u95_deg": 0.01,
                                                   "date": "2025-01-01", "session": "straights"})
    return path
