"""Roll-corrected GNSS reference on a recorded simulated session, scored against the session's own truth.

A short drive (straight, ISO 3888-1 double lane change at 50 km/h) is recorded through the real
recording path (rig.sim.record.record_simulated: base and two rovers with the correction relay, the
VSC ECU on a virtual CAN bus) with the shipped simulated car, whose roof antennas sit 1 m above the
CG; the reference is computed as ``rig validate`` does and scored on the double lane change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from rig.analysis.reference import AntennaGeometry, ImuSpec, ReferenceSideslip, reference_sideslip
from rig.core.config import load_session
from rig.data.inputs import SessionInputs, load_inputs
from rig.evaluate.validate import _imu, roll_model, steering_model, validate_session
from rig.sim.record import record_simulated
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, make_scenario, simulate

FAST_RTK = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=1.0,
                     time_to_fix_s=3.0)


@dataclass(frozen=True)
class Session:
    inputs: SessionInputs
    dlc_span_s: tuple[float, float]
    """Truth times of the double lane change (s)."""


def _span(truth: GroundTruth, kind: str) -> tuple[float, float]:
    for key, value in truth.meta.items():
        if key.startswith("segment.") and key.endswith(".name") and value == kind:
            base = key.removesuffix(".name")
            return float(truth.meta[base + ".t_start_s"]), float(truth.meta[base + ".t_end_s"])
    raise AssertionError(f"no segment {kind!r} in the drive")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    # the baseline mounted true (the shipped car's 0.35° offset is calibration's business, not this test's)
    cfg = load_session(demo_config_path(), {"simulation.true_mount_offset_deg": 0.0})
    drive = Drive([make_scenario("straight", speed_kmh=50.0, duration_s=4.0),
                   make_scenario("double_lane_change", speed_kmh=50.0)], gap_s=2.0)
    sim = cfg.simulation
    assert sim is not None
    params = VehicleParams.from_mapping(cfg.profile.vehicle.model_dump())
    truth = simulate(drive, params, rate_hz=1000.0, origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                     initial_heading_deg=sim.initial_heading_deg, seed=sim.seed)
    out = tmp_path_factory.mktemp("recorded_roll")
    rec = record_simulated(cfg, out, name="dlc", drive=drive, truth=truth, speed=2.0, rtk=FAST_RTK,
                           config_path=demo_config_path())
    assert rec.completed and rec.summary.recording.finalized, rec.summary
    return Session(load_inputs(Path(out) / "dlc", optical=False), _span(truth, "double_lane_change"))


def _reference(inp: SessionInputs, with_roll: bool) -> ReferenceSideslip:
    prof = inp.profile
    ant = prof.antennas
    geom = AntennaGeometry(
        a_xy=ant.a.xy, baseline_length_m=ant.baseline_length_m, baseline_tolerance_m=ant.baseline_tolerance_m,
        mount_offset_rad=math.radians(prof.calibration.mount_offset_deg), z=ant.a.z_m if with_roll else 0.0,
    )
    imu, _ = _imu(inp)
    spec = ImuSpec(roll_gain_rad_per_mps2=steering_model(prof).roll_gain_rad_per_mps2)
    return reference_sideslip(inp.require_gnss().to_epochs(), imu, geom, imu_spec=spec,
                              roll_model=roll_model(prof.vehicle) if with_roll else None)


def _score(inp: SessionInputs, ref: ReferenceSideslip, span: tuple[float, float]) -> tuple[float, float, int]:
    assert inp.truth is not None
    tr = inp.truth
    truth = np.interp(ref.t, tr.t_s, tr.truth.beta_cg, left=np.nan, right=np.nan)
    e = ref.beta - truth
    m = ref.valid & np.isfinite(e) & (ref.t >= span[0]) & (ref.t <= span[1])
    rms = math.degrees(float(np.sqrt(np.mean(e[m] ** 2))))
    return rms, float(np.mean(np.abs(e[m]) <= ref.u95[m])), int(np.count_nonzero(m))


def test_recorded_dlc_roll_corrected_reference(session: Session) -> None:
    """On the recorded DLC: ≤ 0.05° RMS at the CG with ≥ 95 % coverage with the roll term, clearly worse without."""
    inp = session.inputs
    assert inp.truth is not None
    assert inp.profile.antennas.a.z_m > 0.5  # the shipped car's roof antenna
    # the DLC in simulation time → the session time base, through the truth's own time stamps
    lo, hi = np.interp(session.dlc_span_s, inp.truth.truth.t, inp.truth.t_s)
    span = (float(lo), float(hi))
    on = _score(inp, _reference(inp, True), span)
    off_ = _score(inp, _reference(inp, False), span)
    print(f"\n  recorded DLC: without roll term {off_[0]:.4f}° / {off_[1]:.3f}, with {on[0]:.4f}° / {on[1]:.3f} "
          f"(n = {on[2]})")
    assert on[2] >= 100  # ≈ 7 s at 20 Hz, mostly valid
    assert on[0] <= 0.05
    assert on[1] >= 0.95
    assert off_[0] > 2.0 * on[0]


def test_validate_session_uses_the_roll_model(session: Session) -> None:
    """``rig validate`` passes the antenna height and the roll model: its reference is the corrected one."""
    sv = validate_session(session.inputs)
    ref = sv.reference
    assert ref.diagnostics["roll_corrected"] == 1.0
    expect = _reference(session.inputs, True)
    np.testing.assert_allclose(ref.beta, expect.beta, rtol=0, atol=1e-12, equal_nan=True)
