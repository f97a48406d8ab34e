"""Campaign sessions made cheaply from simulator truth (no devices, no real time).

Each session is written with the real Recorder by :func:`tests.calib_cli.synth.write_truth_session`: 20 Hz GNSS on
both rovers, 50 Hz CAN (yaw rate, a_y, SWA and the VSC's own sideslip estimate), ``/sim/truth``. Sessions differ in
drive (a straight run, then a double lane change, a step steer or a J-turn at various speeds), noise seed and the
VSC estimate's error (a gain and a bias on the true sideslip, growing across the "campaign" as a firmware drifts).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rig.core.config import load_session
from sim_devices.vehicle import Drive, GroundTruth, make_scenario
from tests.calib_cli.synth import SIM_TOML, simulate_truth, write_truth_session

MANOEUVRES = (
    ("double_lane_change", {"speed_kmh": 50.0}),
    ("double_lane_change", {"speed_kmh": 70.0}),
    ("step_steer", {"speed_kmh": 60.0}),
    ("j_turn", {}),
)


def vsc_estimate(gain: float, bias_deg: float):  # type: ignore[no-untyped-def]
    """The VSC's estimate: the true CG sideslip times ``1 + gain``, plus ``bias_deg``."""

    def fn(truth: GroundTruth, t: np.ndarray) -> np.ndarray:
        return (1.0 + gain) * np.interp(t, truth.t, truth.beta_cg) + math.radians(bias_deg)

    return fn


def make_session(out: Path, i: int) -> Path:
    """Session ``i`` of the campaign (``out/run{i:02d}``)."""
    cfg = load_session(SIM_TOML)
    name, kw = MANOEUVRES[i % len(MANOEUVRES)]
    drive = Drive([make_scenario("straight", speed_kmh=50.0, duration_s=3.0), make_scenario(name, **kw)], gap_s=2.0)
    truth = simulate_truth(cfg, drive)
    return write_truth_session(out, f"run{i:02d}", cfg, truth, offset_deg=0.0, seed=100 + i,
                               vsc_beta=vsc_estimate(0.02 * i, 0.01 * (i % 5)))


def corrupt(base: Path) -> None:
    """Overwrite the MCAP magic and cut the part short: not a session any more."""
    part = base.with_name(f"{base.name}.000.mcap")
    data = bytearray(part.read_bytes())
    data[:8] = b"GARBAGE!"
    part.write_bytes(bytes(data[: len(data) // 2]))
