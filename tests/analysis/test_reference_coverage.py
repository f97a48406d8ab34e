"""The reference sideslip's 95 % band, manoeuvre by manoeuvre (issue 16 §1).

A small version of ``benchmarks/study_reference_coverage.py``: the pieces that make the band honest
on each kind of manoeuvre, each against a known answer, and two recorded sessions (the real
recording path, the simulator's default time-correlated GNSS noise) on which the earlier reference
failed: a steady circle (seed 1: 67 % coverage, the IMU delay zeroed and the heading noise's
correlation time misread) and a sine with dwell at 80 km/h (seed 5: 78 %, the static roll gain in
transients and a heading bias beyond its stated σ).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from rig.analysis.reference import (
    AntennaGeometry,
    GnssEpochs,
    ImuSeries,
    ImuSpec,
    _acf,
    _fit_gauss_markov_acf,
    _noise_from_data,
    reference_sideslip,
)
from rig.analysis.rollover import RollModel
from rig.core.config import load_session
from rig.data.inputs import load_inputs
from rig.evaluate.validate import validate_session
from rig.sim.record import record_simulated
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, make_scenario, simulate
from tests.analysis.obs import A_XY, B_XY, BASELINE_M

CAR = VehicleParams()
FAST_RTK = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=1.0,
                     time_to_fix_s=3.0)


def _gm_plus_white(rng: np.random.Generator, n: int, period: float, tau: float, share: float,
                   sigma: float) -> np.ndarray:
    phi = math.exp(-period / tau)
    drive = rng.standard_normal(n) * math.sqrt(1.0 - phi * phi)
    drive[0] = rng.standard_normal()
    gm = np.asarray(lfilter([1.0], [1.0, -phi], drive))
    return sigma * (math.sqrt(share) * gm + math.sqrt(1.0 - share) * rng.standard_normal(n))


def _length_only_epochs(t: np.ndarray, length_error: np.ndarray) -> GnssEpochs:
    n = t.size
    return GnssEpochs(t=t, baseline_azimuth=np.zeros(n), baseline_length=BASELINE_M + length_error,
                      velocity_east=np.full(n, 10.0), velocity_north=np.zeros(n), fixed_a=np.ones(n, dtype=bool),
                      fixed_b=np.ones(n, dtype=bool))


def test_gauss_markov_split_from_every_lag() -> None:
    """A 30 min record of 0.7 Gauss–Markov (τ = 1 s) + 0.3 white at 20 Hz: the fit over all lags finds both."""
    period = 0.05
    n = 36_000
    e = _gm_plus_white(np.random.default_rng(3), n, period, 1.0, 0.7, 0.003)
    t = np.arange(n) * period
    lags = np.arange(1, 81)
    share, phi, v = _fit_gauss_markov_acf(lags, [(_acf(e - e.mean(), t, period, lags), n, 1)], period)
    tau = -period / math.log(phi)
    assert share == pytest.approx(0.7, abs=0.06)
    assert tau == pytest.approx(1.0, rel=0.15)
    assert 0.0 < v < 1e-3
    # through the session-level estimate: σ_ψ = σ(length)/L, the fit used (record ≥ 2 min)
    est = _noise_from_data(_length_only_epochs(t, e), np.ones(n, dtype=bool), BASELINE_M, prior_tau_s=5.0)
    assert est is not None
    assert est.heading_sigma_rad == pytest.approx(0.003 / BASELINE_M, rel=0.05)
    assert est.tau_s == pytest.approx(1.0, rel=0.15)


def test_short_record_takes_the_specified_correlation() -> None:
    """20 s cannot tell the split: all Gauss–Markov with the specified τ, the scatter corrected for the record mean."""
    period = 0.05
    n = 400
    t = np.arange(n) * period
    sig_hat = []
    for seed in range(40):
        e = _gm_plus_white(np.random.default_rng(100 + seed), n, period, 1.0, 1.0, 0.003)
        est = _noise_from_data(_length_only_epochs(t, e), np.ones(n, dtype=bool), BASELINE_M, prior_tau_s=1.0)
        assert est is not None
        assert est.gm_share == 1.0
        assert est.tau_s == pytest.approx(1.0, rel=1e-9)
        sig_hat.append(est.heading_sigma_rad * BASELINE_M)
    # the scatter about a 20 s mean misses ≈ 2τ/T = 10 % of the variance; corrected, the σ is unbiased
    assert float(np.sqrt(np.mean(np.square(sig_hat)))) == pytest.approx(0.003, rel=0.08)


def test_dynamic_roll_takes_gravity_out_of_ay_in_transients() -> None:
    """Noise-free sine with dwell at 80 km/h: the roll model's φ(t) instead of the static gain k_φ·a_y.

    Body roll lags a_y at 0.7 Hz, so g·sin φ from the static gain is wrong by ≈ 0.1 m/s² through each
    lobe; the course channel integrated that into 0.08° of sideslip error.
    """
    truth = simulate(Drive([make_scenario("straight", speed_kmh=80.0, duration_s=4.0),
                            make_scenario("sine_with_dwell", speed_kmh=80.0)], gap_s=2.0), rate_hz=1000.0)
    idx = np.arange(0, len(truth), 50)
    ea, na, ua = truth.point_enu(*A_XY, 0.0)
    eb, nb, ub = truth.point_enu(*B_XY, 0.0)
    ve, vn = truth.point_velocity_enu(*A_XY)
    g = GnssEpochs.from_enu(truth.t[idx], (ea[idx], na[idx], ua[idx]), (eb[idx], nb[idx], ub[idx]),
                            (ve[idx], vn[idx]))
    imu = ImuSeries(truth.t[::10], truth.yaw_rate[::10], truth.ay_meas[::10])
    model = RollModel.from_vehicle(CAR)
    spec = ImuSpec(roll_gain_rad_per_mps2=model.roll_gain_rad_per_mps2)
    err = {}
    for name, m in (("static", None), ("dynamic", model)):
        ref = reference_sideslip(g, imu, AntennaGeometry(A_XY, BASELINE_M), imu_spec=spec, imu_delay_s=0.0,
                                 noise_from_data=False, roll_model=m)
        e = (ref.beta - truth.beta_cg[idx])[ref.valid]
        err[name] = math.degrees(float(np.max(np.abs(e))))
    print(f"\n  noise-free sine with dwell, max |error|: static roll gain {err['static']:.3f}°, "
          f"roll model {err['dynamic']:.3f}°")
    assert err["static"] > 0.05
    assert err["dynamic"] < 0.03


# --- recorded sessions ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Recorded:
    path: Path
    span_truth_s: tuple[float, float]


def _span(truth: GroundTruth, name: str) -> tuple[float, float]:
    for key, value in truth.meta.items():
        if key.startswith("segment.") and key.endswith(".name") and value == name:
            base = key.removesuffix(".name")
            return float(truth.meta[base + ".t_start_s"]), float(truth.meta[base + ".t_end_s"])
    raise AssertionError(f"no segment {name!r} in the drive")


CASES = {
    "circle": (1, "steady_state_circle", lambda: Drive(
        [make_scenario("straight", speed_kmh=45.0, duration_s=6.0),
         make_scenario("steady_state_circle", radius_m=40.0, speed_start_kmh=45.0, speed_end_kmh=45.0,
                       settle_s=4.0, hold_s=6.0)], gap_s=2.0)),
    "sine80": (5, "sine_with_dwell", lambda: Drive(
        [make_scenario("straight", speed_kmh=80.0, duration_s=6.0),
         make_scenario("sine_with_dwell", speed_kmh=80.0)], gap_s=2.0)),
}
"""Kind → (seed, scored segment, drive), as in benchmarks/study_reference_coverage.py."""


@pytest.fixture(scope="module", params=sorted(CASES))
def recorded(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    seed, segment, make_drive = CASES[request.param]
    cfg = load_session(demo_config_path(), {"simulation.true_mount_offset_deg": 0.0, "simulation.seed": seed})
    sim = cfg.simulation
    assert sim is not None
    drive = make_drive()
    params = VehicleParams.from_mapping(cfg.profile.vehicle.model_dump())
    truth = simulate(drive, params, rate_hz=1000.0, origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                     initial_heading_deg=sim.initial_heading_deg, seed=seed)
    out = tmp_path_factory.mktemp(f"coverage_{request.param}")
    # 2× real time: faster, and the host's scheduling delays (scaled by the clock speed) blur the CAN stamps
    rec = record_simulated(cfg, out, name="rec", drive=drive, truth=truth, speed=2.0, rtk=FAST_RTK,
                           config_path=demo_config_path())
    assert rec.completed and rec.summary.recording.finalized, rec.summary
    (out / "span.json").write_text(json.dumps(_span(truth, segment)))
    return Recorded(out / "rec", _span(truth, segment))


def test_recorded_band_covers_the_manoeuvre(recorded: Recorded) -> None:
    """``rig validate``'s reference on a recorded session: the stated U95 covers ≥ 85 % of the manoeuvre's
    epochs (the per-session floor of issue 16; ≥ 95 % pooled is the benchmark's), with a band that stays
    narrow (mean half-width ≤ 0.15°) and no more than 0.12° RMS error.

    One recording is one draw, and the seed does not fix it: the recording starts at a different phase of the
    simulated GPS second from run to run (TIME and MARK at +0.40 or +0.91 s), and the sine at seed 5 (the
    study's worst session) gave two outcomes in 2026-12-03's suite runs: coverage 93.5 % / RMS 0.068° / U95
    0.134° and coverage 86.3 % / RMS 0.106° / U95 0.121°, idle and under load alike."""
    inp = load_inputs(recorded.path, optical=False)
    assert inp.truth is not None
    tr = inp.truth
    lo, hi = np.interp(recorded.span_truth_s, tr.truth.t, tr.t_s)
    ref = validate_session(inp).reference
    truth = np.interp(ref.t, tr.t_s, tr.truth.beta_cg, left=np.nan, right=np.nan)
    e = ref.beta - truth
    m = ref.valid & np.isfinite(e) & (ref.t >= lo) & (ref.t <= hi)
    cov = float(np.mean(np.abs(e[m]) <= ref.u95[m]))
    rms = math.degrees(float(np.sqrt(np.mean(e[m] ** 2))))
    half = math.degrees(float(np.mean(ref.u95[m])))
    print(f"\n  {recorded.path.parent.name}: n {int(m.sum())}, coverage {100 * cov:.1f} %, RMS {rms:.4f}°, "
          f"mean U95 {half:.4f}°, IMU delay {1e3 * ref.diagnostics['imu_delay_s']:.1f} ms")
    assert int(m.sum()) >= 100
    assert cov >= 0.85
    assert half <= 0.15
    assert rms <= 0.12
