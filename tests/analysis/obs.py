"""GNSS epochs and IMU series for the analysis code, observed from a simulated drive (test helper).

Builds on :mod:`tests.calibration.observe` (RTK-level dual-antenna noise); the IMU is a vehicle
sensor cluster at the CG with a constant bias and white noise on the yaw rate and the body-fixed
lateral acceleration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.analysis.reference import GnssEpochs, GnssSpec, ImuSeries
from sim_devices.vehicle.truth import GroundTruth
from tests.calibration.observe import A_XY, B_XY, BASELINE_M, RtkNoise, observe

__all__ = ["A_XY", "BASELINE_M", "B_XY", "ImuNoise", "RtkNoise", "gnss_spec_for", "observe_reference_inputs"]


@dataclass(frozen=True)
class ImuNoise:
    rate_hz: float = 100.0
    yaw_rate_bias_rps: float = math.radians(0.25)
    yaw_rate_sigma_rps: float = math.radians(0.08)
    ay_bias_mps2: float = 0.05
    ay_sigma_mps2: float = 0.03


def gnss_spec_for(noise: RtkNoise) -> GnssSpec:
    """The error model a user would configure for ``noise`` (from the receiver's specification)."""
    return GnssSpec(
        position_sigma_m=math.hypot(noise.common_sigma_m, noise.relative_sigma_m),
        relative_sigma_m=noise.relative_sigma_m,
        relative_tau_s=max(noise.relative_tau_s, 1.0 / noise.rate_hz),
        velocity_sigma_mps=noise.velocity_sigma_mps,
    )


def observe_reference_inputs(
    truth: GroundTruth,
    *,
    noise: RtkNoise | None = None,
    imu_noise: ImuNoise | None = None,
    mount_offset_rad: float = 0.0,
    seed: int = 0,
) -> tuple[GnssEpochs, ImuSeries, np.ndarray]:
    """GNSS epochs, IMU series and the truth indices of the GNSS epochs."""
    obs = observe(truth, noise=noise, mount_offset_rad=mount_offset_rad, seed=seed)
    gnss = GnssEpochs.from_enu(obs.t, obs.a_enu, obs.b_enu, obs.vel_a_en)
    im = imu_noise or ImuNoise()
    rng = np.random.default_rng(10_000 + seed)
    step = max(1, int(round(1.0 / (truth.dt * im.rate_hz))))
    ii = np.arange(0, len(truth), step)
    imu = ImuSeries(
        truth.t[ii],
        truth.yaw_rate[ii] + im.yaw_rate_bias_rps + rng.standard_normal(ii.size) * im.yaw_rate_sigma_rps,
        truth.ay_meas[ii] + im.ay_bias_mps2 + rng.standard_normal(ii.size) * im.ay_sigma_mps2,
    )
    return gnss, imu, obs.idx
