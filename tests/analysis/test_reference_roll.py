"""Roll correction of the GNSS reference sideslip: a roof antenna 1 m above the CG against the simulator truth.

The simulated antenna moves with the rolling body (sim_devices.gnss.antenna.TruthAntenna: its
velocity includes −p·z_r), which the reference removes with the roll model driven by the
body-fixed lateral acceleration (rig.analysis.rollover.RollModel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from rig.analysis.reference import AntennaGeometry, GnssEpochs, ImuSeries, ReferenceMethod, reference_sideslip
from rig.analysis.rollover import RollModel
from sim_devices.gnss.antenna import TruthAntenna
from sim_devices.vehicle import GroundTruth, VehicleParams
from sim_devices.vehicle.geodesy import point_enu_rolled
from tests.analysis.obs import A_XY, B_XY, BASELINE_M, ImuNoise, RtkNoise, gnss_spec_for
from tests.calibration.observe import gauss_markov

CAR = VehicleParams()
Z_M = 1.0
ROLL = RollModel.from_vehicle(CAR)
GEOM_FLAT = AntennaGeometry(A_XY, BASELINE_M)
GEOM_ROOF = AntennaGeometry(A_XY, BASELINE_M, z=Z_M)


@dataclass(frozen=True)
class RolledTrack:
    """True positions of both antennas and the velocity of A, with body roll, at the GNSS epochs."""

    idx: np.ndarray
    a_enu: tuple[np.ndarray, np.ndarray, np.ndarray]
    b_enu: tuple[np.ndarray, np.ndarray, np.ndarray]
    vel_a: np.ndarray
    """(n, 2) east, north (m/s)."""


def _track(truth: GroundTruth, rate_hz: float = 20.0) -> RolledTrack:
    idx = np.arange(0, len(truth), max(1, int(round(1.0 / (truth.dt * rate_hz)))))
    a = tuple(x[idx] for x in point_enu_rolled(truth, *A_XY, Z_M))
    b = tuple(x[idx] for x in point_enu_rolled(truth, *B_XY, Z_M))
    ant = TruthAntenna(truth, (A_XY[0], A_XY[1], Z_M))
    vel = np.array([ant.enu(float(t))[3:5] for t in truth.t[idx]])
    return RolledTrack(idx, a, b, vel)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def rolled(dlc: GroundTruth) -> RolledTrack:
    return _track(dlc)


def _imu(truth: GroundTruth, noise: ImuNoise | None, seed: int) -> ImuSeries:
    step = max(1, int(round(0.01 / truth.dt)))
    ii = np.arange(0, len(truth), step)
    if noise is None:
        return ImuSeries(truth.t[ii], truth.yaw_rate[ii], truth.ay_meas[ii])
    rng = np.random.default_rng(10_000 + seed)
    return ImuSeries(
        truth.t[ii],
        truth.yaw_rate[ii] + noise.yaw_rate_bias_rps + rng.standard_normal(ii.size) * noise.yaw_rate_sigma_rps,
        truth.ay_meas[ii] + noise.ay_bias_mps2 + rng.standard_normal(ii.size) * noise.ay_sigma_mps2,
    )


def _noisy_epochs(truth: GroundTruth, tr: RolledTrack, noise: RtkNoise, seed: int) -> GnssEpochs:
    """As tests/calibration/observe.py, on the rolled antenna track."""
    rng = np.random.default_rng(seed)
    n = tr.idx.size
    dt = float(truth.t[tr.idx[1]] - truth.t[tr.idx[0]])
    common = gauss_markov(rng, n, noise.common_sigma_m, noise.common_tau_s, dt, 3)
    pa = common + gauss_markov(rng, n, noise.relative_sigma_m, noise.relative_tau_s, dt, 3)
    pb = common + gauss_markov(rng, n, noise.relative_sigma_m, noise.relative_tau_s, dt, 3)
    ve = tr.vel_a[:, 0] + rng.standard_normal(n) * noise.velocity_sigma_mps
    vn = tr.vel_a[:, 1] + rng.standard_normal(n) * noise.velocity_sigma_mps
    a = (tr.a_enu[0] + pa[:, 0], tr.a_enu[1] + pa[:, 1], tr.a_enu[2] + pa[:, 2])
    b = (tr.b_enu[0] + pb[:, 0], tr.b_enu[1] + pb[:, 1], tr.b_enu[2] + pb[:, 2])
    return GnssEpochs.from_enu(truth.t[tr.idx], a, b, (ve, vn))


def test_roll_rate_is_the_model_state_derivative(dlc: GroundTruth) -> None:
    """The roll model's rate matches the simulator's roll rate (same physics) and the derivative of its own angle."""
    ii = np.arange(0, len(dlc), 10)
    phi, p = ROLL.roll_and_rate_from_body_ay(dlc.t[ii], dlc.ay_meas[ii])
    assert np.max(np.abs(p - dlc.roll_rate[ii])) < math.radians(0.05)  # peak ≈ 5.6 °/s
    assert np.max(np.abs(phi - dlc.roll[ii])) < math.radians(0.01)
    assert np.max(np.abs(np.gradient(phi, dlc.t[ii]) - p)) < math.radians(0.1)
    phi_old, _ = ROLL.roll_from_body_ay(dlc.t[ii], dlc.ay_meas[ii])
    np.testing.assert_allclose(phi, phi_old, atol=1e-12)


@pytest.mark.parametrize("method", [ReferenceMethod.RAW, ReferenceMethod.RTS])
def test_noise_free_roof_antenna_needs_the_roll_term(dlc: GroundTruth, rolled: RolledTrack,
                                                     method: ReferenceMethod) -> None:
    """Exact inputs: without the roll term the roof antenna's −p·z shows as sideslip error; with it, it is gone."""
    g = GnssEpochs.from_enu(dlc.t[rolled.idx], rolled.a_enu, rolled.b_enu, (rolled.vel_a[:, 0], rolled.vel_a[:, 1]))
    imu = _imu(dlc, None, 0)
    truth = dlc.beta_cg[rolled.idx]
    errs = {}
    for name, geom, model in (("flat", GEOM_FLAT, None), ("roof", GEOM_ROOF, ROLL), ("no model", GEOM_ROOF, None)):
        ref = reference_sideslip(g, imu, geom, method=method, imu_delay_s=0.0, noise_from_data=False,
                                 roll_model=model)
        e = (ref.beta - truth)[ref.valid]
        errs[name] = math.degrees(float(np.max(np.abs(e))))
        assert ref.diagnostics["roll_corrected"] == (1.0 if model is not None else 0.0)
    # −p·z at 13.9 m/s: up to 0.1 m/s → ≈ 0.4° (raw); the correction leaves the raw β exact to 0.01° and the
    # smoothed β (tuned for noisy inputs: it lags the quickest sideslip changes a little) within 0.05°
    assert errs["flat"] > 0.25
    assert errs["no model"] == errs["flat"]
    assert errs["roof"] < (0.01 if method is ReferenceMethod.RAW else 0.05)


def test_dlc_roof_antenna_meets_005_deg_with_coverage(dlc: GroundTruth, rolled: RolledTrack) -> None:
    """Issue 9 with the antennas 1 m above the CG: DLC at 50 km/h, RTK-level noise, default noise model.

    With the roll correction the RTS reference at the CG is within 0.05° RMS of the truth and its
    95 % band covers it at ≥ 95 % of the epochs (6 noise realisations); without it, neither holds.
    """
    noise = RtkNoise()
    spec = gnss_spec_for(noise)
    truth = dlc.beta_cg[rolled.idx]
    out: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {"off": ([], []), "on": ([], [])}
    for seed in range(6):
        g = _noisy_epochs(dlc, rolled, noise, seed)
        imu = _imu(dlc, ImuNoise(), seed)
        for name, geom, model in (("off", GEOM_FLAT, None), ("on", GEOM_ROOF, ROLL)):
            ref = reference_sideslip(g, imu, geom, gnss_spec=spec, roll_model=model)
            e = (ref.beta - truth)[ref.valid]
            out[name][0].append(e)
            out[name][1].append(np.abs(e) <= ref.u95[ref.valid])
    figs = {}
    for name, (es, cs) in out.items():
        e = np.concatenate(es)
        figs[name] = (math.degrees(float(np.sqrt(np.mean(e * e)))), float(np.mean(np.concatenate(cs))))
    print(f"\n  DLC roof antenna: without roll term {figs['off'][0]:.4f}° / {figs['off'][1]:.3f}, "
          f"with {figs['on'][0]:.4f}° / {figs['on'][1]:.3f}")
    assert figs["on"][0] <= 0.05
    assert figs["on"][1] >= 0.95
    assert figs["off"][0] > 2.0 * figs["on"][0]
    assert figs["off"][1] < 0.9
