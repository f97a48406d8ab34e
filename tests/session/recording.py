"""One recorded simulated session shared by the session tests, and the truth models to score it.

The recording runs the shipped simulated car (``rig/examples/sim.toml``) through a J-turn in real
time with every device: base + two rovers on pseudo-terminals with the correction relay, the
VSC ECU on a virtual CAN bus, the simulated DAQ with the optical sensor and the sync switch.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from rig.core.config import SessionConfig, load_session
from rig.data import Session, align
from rig.data import load_session as load_recording
from rig.sim.record import SimRecording, record_simulated
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle.truth import GroundTruth
from vsccore.gpstime import gps_ns_to_unix_ns

FloatArray = npt.NDArray[np.float64]

FAST_RTK = RtkParams(max_correction_age_s=5.0, float_hold_s=10.0, psrdiff_timeout_s=30.0, time_to_float_s=0.5,
                     time_to_fix_s=2.0)
"""A quicker RTK engine than a real receiver's, so a short test drive spends most of its time fixed."""



def config(drive: str, speed: float, **overrides: object) -> SessionConfig:
    return load_session(demo_config_path(), {"simulation.drive": drive, "simulation.speed": speed, **overrides})


@dataclass(frozen=True)
class Recorded:
    cfg: SessionConfig
    rec: SimRecording
    ds: Session
    truth: GroundTruth
    """The ground truth read back from the file, with the CG height (not in /sim/truth) restored."""
    truth_ns: npt.NDArray[np.int64]


def record(tmp: Path, drive: str = "j_turn", speed: float = 1.0, lead_s: float = 5.0, **overrides: object) -> Recorded:
    """Record at real time by default: the host's scheduling latency, which the CAN → host → GPS
    mapping cannot remove, is then what it is in a car, not multiplied by the clock speed."""
    cfg = config(drive, speed, **overrides)
    rec = record_simulated(cfg, tmp, name="rec", rtk=FAST_RTK, lead_s=lead_s, config_path=demo_config_path())
    ds = load_recording(tmp / "rec")  # the receivers' output latency measured, as in a car, never told
    t = ds.truth()
    truth = dataclasses.replace(t.truth, meta={"cg_height_m": cfg.profile.vehicle.cg_height_m})
    return Recorded(cfg, rec, ds, truth, t.time_ns)


def first_order(x: FloatArray, dt: float, bandwidth_hz: float) -> FloatArray:
    """First-order low-pass (exact discretisation) started at the first value: a MEMS sensing bandwidth."""
    a = math.exp(-2.0 * math.pi * bandwidth_hz * dt)
    return np.asarray(lfilter([1.0 - a], [1.0, -a], x - x[0]) + x[0], dtype=np.float64)


def sensor_view(truth: GroundTruth, truth_ns: npt.NDArray[np.int64], x: FloatArray, t_ns: npt.ArrayLike,
                bandwidth_hz: float, latency_s: float, bias: float) -> FloatArray:
    """What an inertial sensor with this bandwidth, output latency and bias reads of ``x`` at times ``t_ns``."""
    filtered = first_order(np.asarray(x, dtype=np.float64), truth.dt, bandwidth_hz)
    return align(np.asarray(t_ns, dtype=np.int64) - round(latency_s * 1e9), truth_ns, filtered) + bias


def daq_true_utc(ds: Session, sample_index: npt.ArrayLike) -> FloatArray:
    """True time (UTC ns, float) of DAQ samples, from the simulator's record of the DAQ's sample clock."""
    ev = [e for _t, e in ds.events if e.source == "sim" and "sample0_gps_ns" in e.details]
    assert len(ev) == 1, f"expected one simulated DAQ acquisition, got {len(ev)}"
    d = ev[0].details
    assert ds.leap_seconds is not None
    g0 = gps_ns_to_unix_ns(int(d["sample0_gps_ns"]), ds.leap_seconds)
    return g0 + np.asarray(sample_index, dtype=np.float64) * (1e9 / float(d["true_rate_hz"]))
