"""Simulated sessions for the calibration commands, recorded through the real recording path.

:func:`record_sim` runs :func:`rig.sim.record.record_simulated` (simulated receivers on
pseudo-terminals, the VSC ECU on a virtual CAN bus, the simulated DAQ, the real recorder) with the
example configuration ``rig/examples/sim.toml`` and ``--set``-style overrides, on a short drive.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
from scipy.signal import lfilter

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleMap, encode_role_frame
from rig.core.config import SessionConfig, load_session
from rig.sim.record import record_simulated
from rig.sim.world import true_antenna_lever_arms
from rig.store import Attachment, Recorder, RecorderOptions, session_metadata
from sim_devices.gnss import RtkParams
from sim_devices.vehicle import Drive, GroundTruth, Scenario, VehicleParams, make_scenario, simulate
from vsccore.gpstime import gps_ns_to_unix_ns, gps_to_ns

REPO = Path(__file__).resolve().parents[2]
SIM_TOML = REPO / "rig" / "examples" / "sim.toml"
DBC = REPO / "sim_devices" / "data" / "vsc_sim.dbc"
ROLES = REPO / "rig" / "examples" / "roles" / "vsc_sim.toml"
FAST_RTK = RtkParams(time_to_float_s=0.5, time_to_fix_s=1.0)
"""A quick RTK fix so the lead before the drive stays short (the tests are about the drive)."""


def straights(speed_kmh: float = 40.0, duration_s: float = 7.0, heading_deg: float = 0.0) -> Drive:
    """Two straight runs in opposite directions (the transition between them is the simulator's)."""
    back = heading_deg + 180.0 if heading_deg < 180.0 else heading_deg - 180.0
    return Drive([make_scenario("straight", speed_kmh=speed_kmh, duration_s=duration_s, heading_deg=heading_deg),
                  make_scenario("straight", speed_kmh=speed_kmh, duration_s=duration_s, heading_deg=back)],
                 gap_s=3.0)


def circles(swa_max_deg: float = 520.0, swa_step_deg: float = 130.0, hold_s: float = 3.0) -> Scenario:
    """Constant-SWA circles at 5 km/h, forward then reverse."""
    return make_scenario("swa_circles", speed_kmh=5.0, swa_max_deg=swa_max_deg, swa_step_deg=swa_step_deg,
                         direction="both", swa_rate_dps=360.0, settle_s=1.5, hold_s=hold_s)


def record_sim(
    out: Path,
    name: str,
    drive: Drive | Scenario,
    overrides: Mapping[str, Any] | None = None,
    *,
    speed: float = 20.0,
    lead_s: float = 3.0,
) -> Path:
    """Record a simulated session; returns its base path (``out/name``)."""
    cfg = load_session(SIM_TOML, overrides=dict(overrides or {}))
    rec = record_simulated(cfg, out, name=name, drive=drive, speed=speed, lead_s=lead_s, rtk=FAST_RTK)
    if not rec.completed:
        raise RuntimeError(f"simulated session {name} did not complete")
    return out / name


def overrides_low_noise(offset_deg: float, extra: Sequence[tuple[str, Any]] = ()) -> dict[str, Any]:
    """RTK-level relative noise of a dual-antenna set-up.

    1 mm 2-D RMS per rover (independent between A and B), correlation time 0.2 s: the baseline
    heading then scatters by about 0.04° per epoch at 1.58 m, in line with what dual-antenna
    systems quote (0.1° at 1 m separation ≈ 1.7 mm relative); velocity 1 cm/s per axis.
    """
    d: dict[str, Any] = {
        "simulation.true_mount_offset_deg": offset_deg,
        "simulation.gnss.position_noise_m": 0.001,
        "simulation.gnss.velocity_noise_mps": 0.01,
        "simulation.gnss.correlation_time_s": 0.2,
    }
    d.update(dict(extra))
    return d


# ---------------------------------------------------------------------------------------------
# Fast sessions straight from simulator truth (no devices): the real Recorder, decoded GNSS topics
# computed from the truth antenna tracks plus white noise, CAN role frames, the truth itself.
# ---------------------------------------------------------------------------------------------

LEAP = 18
G0 = gps_to_ns(2400, 345_600.0)
H0 = 1_750_000_000_000_000_000


def _utc(g: np.ndarray | int) -> np.ndarray:
    return np.asarray(g, dtype=np.int64) + gps_ns_to_unix_ns(0, LEAP)


def _gm_noise(rng: np.random.Generator, n: int, sigma: float, tau_s: float, dt: float = 0.05,
              correlated_fraction: float = 0.7) -> np.ndarray:
    phi = math.exp(-dt / tau_s)
    w = rng.normal(0.0, math.sqrt(1.0 - phi * phi), n)
    w[0] = rng.normal()
    gm = lfilter([1.0], [1.0, -phi], w)
    return np.asarray(sigma * (math.sqrt(correlated_fraction) * gm
                               + math.sqrt(1.0 - correlated_fraction) * rng.normal(size=n)))


def simulate_truth(cfg: SessionConfig, drive: Drive | Scenario, rate_hz: float = 100.0) -> GroundTruth:
    params = VehicleParams.from_mapping(cfg.profile.vehicle.model_dump(), section="vehicle")
    sim = cfg.simulation
    assert sim is not None
    return simulate(drive, params, rate_hz=rate_hz, origin=(sim.origin_lat_deg, sim.origin_lon_deg, sim.origin_h_m),
                    seed=sim.seed)


def write_truth_session(
    out: Path,
    name: str,
    cfg: SessionConfig,
    truth: GroundTruth,
    *,
    offset_deg: float,
    noise_m: float = 0.002,
    correlation_s: float = 0.2,
    vel_noise_mps: float = 0.01,
    receivers: Sequence[str] = ("rover_a", "rover_b"),
    can_roles: bool = True,
    seed: int = 7,
    swa_offset_deg: float = 0.0,
    vsc_beta: Callable[[GroundTruth, np.ndarray], np.ndarray] | None = None,
) -> Path:
    """Record a session of ``truth`` (t = 0 at GPS time G0) with the real Recorder; returns its base path.

    GNSS at 20 Hz: BESTPOS (antenna at its true lever arm + noise of σ ``noise_m`` per axis and rover: 70 %
    of the variance a first-order Gauss–Markov process with time constant ``correlation_s``, as in the
    simulated receivers, 30 % white),
    BESTVEL, TIME; CAN at 50 Hz: ESC_SensorCluster (yaw_rate, lat_accel) and SAS_Steering (swa)
    from the truth (SAS zero error ``swa_offset_deg`` added); ``/sim/truth``. The receivers' antennas follow
    ``cfg.receivers``. ``vsc_beta(truth, t_s)``: the VSC's sideslip estimate (rad) at the CAN times, sent as
    VSC_Status (role ``vsc_beta_estimate``) beside the sensor cluster.
    """
    rng = np.random.default_rng(seed)
    db = load_dbc(DBC)
    rolemap = RoleMap.from_toml(ROLES, db)
    profile = cfg.profile
    # the receivers' logs below leave 20 ms after their epoch, stated per receiver (the file has no DAQ sync
    # to measure it from)
    cfg = cfg.model_copy(update={"receivers": tuple(r.model_copy(update={"output_latency_s": 0.02})
                                                    for r in cfg.receivers)})
    meta = session_metadata(
        session=cfg.model_dump(mode="json"),
        vehicle={"vehicle": profile.vehicle.model_dump(mode="json"),
                 "antennas": profile.antennas.model_dump(mode="json"),
                 "optical": [o.model_dump(mode="json") for o in profile.optical]},
        calibration=profile.calibration.model_dump(mode="json"),
    )
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0)
    atts = [Attachment.from_file(DBC), Attachment("vsc.roles.toml", "application/toml", ROLES.read_bytes())]
    arms = true_antenna_lever_arms(cfg.profile.antennas, offset_deg)
    antenna_of = {r.name: r.antenna for r in cfg.receivers if r.role == "rover"}
    t_end = float(truth.t[-1])
    k = np.arange(int(t_end * 20) + 1)
    g = G0 + k * 50_000_000
    ts = k * 0.05
    lat0, lon0, h0 = truth.lat0_deg, truth.lon0_deg, truth.h0_m
    out.mkdir(parents=True, exist_ok=True)
    with Recorder(out, name, meta, attachments=atts, options=opts) as rec:
        for rx in receivers:
            src = rec.source(rx, maxsize=100_000)
            ant = antenna_of.get(rx) or rx[-1]
            x, y, z = arms[ant]
            e, n, _u = truth.point_enu(x, y)
            ve, vn = truth.point_velocity_enu(x, y)
            e = np.interp(ts, truth.t, e) + _gm_noise(rng, ts.size, noise_m, correlation_s)
            n = np.interp(ts, truth.t, n) + _gm_noise(rng, ts.size, noise_m, correlation_s)
            u = (np.full(ts.size, float(truth.meta.get("cg_height_m", 0.5)) + z)
                 + _gm_noise(rng, ts.size, noise_m, correlation_s))
            ve = np.interp(ts, truth.t, ve) + rng.normal(0.0, vel_noise_mps, ts.size)
            vn = np.interp(ts, truth.t, vn) + rng.normal(0.0, vel_noise_mps, ts.size)
            lat, lon, h = pymap3d.enu2geodetic(e, n, u, lat0, lon0, h0)
            # a BESTPOSB frame is 28 header + 72 body + 4 CRC bytes (OEM7 manual); the host stamps its last byte
            baud = next((r.baud for r in cfg.receivers if r.name == rx), 115200)
            tx_ns = round(104 * 10 * 1e9 / baud)
            host = H0 + (g - G0) + 20_000_000 + tx_ns + rng.exponential(2e6, g.size).astype(np.int64)
            spd = np.hypot(ve, vn)
            trk = np.degrees(np.arctan2(ve, vn)) % 360.0
            for i in range(g.size):
                gi, ui, hi = int(g[i]), int(_utc(g[i])), int(host[i])
                src.put(T.gnss_bestpos(rx), ui, hi, {
                    "gps_time_ns": gi, "time_status": "FINESTEERING", "sol_status": "SOL_COMPUTED",
                    "pos_type": "NARROW_INT", "lat_deg": float(lat[i]), "lon_deg": float(lon[i]),
                    "height_msl_m": float(h[i]), "undulation_m": 0.0, "lat_std_m": noise_m, "lon_std_m": noise_m,
                    "height_std_m": noise_m, "diff_age_s": 1.0})
                src.put(T.gnss_bestvel(rx), ui, hi + 1000, {
                    "gps_time_ns": gi, "sol_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY", "latency_s": 0.0,
                    "hor_speed_mps": float(spd[i]), "track_over_ground_deg": float(trk[i]), "vert_speed_mps": 0.0})
                if i % 20 == 0:
                    src.put(T.gnss_time(rx), ui, hi + 2000, {
                        "gps_time_ns": gi, "clock_status": "VALID", "utc_offset_s": -float(LEAP),
                        "leap_seconds": LEAP, "utc_status": "VALID"})
        if can_roles:
            can_src = rec.source("vsc", maxsize=100_000)
            kc = np.arange(int(t_end * 50))
            tc = kc * 0.02
            gc = G0 + kc * 20_000_000
            hc = H0 + (gc - G0) + 300_000
            r = np.interp(tc, truth.t, truth.yaw_rate)
            ay = np.interp(tc, truth.t, truth.ay_meas)
            swa = np.interp(tc, truth.t, truth.swa) + math.radians(swa_offset_deg)
            ids = {m: db.get_message_by_name(m).frame_id for m in ("ESC_SensorCluster", "SAS_Steering", "VSC_Status")}
            beta_est = None if vsc_beta is None else np.asarray(vsc_beta(truth, tc), dtype=float)
            rows: list[tuple[int, int, int, bytes]] = []
            for i in range(kc.size):
                rows.append((int(gc[i]), int(hc[i]), ids["ESC_SensorCluster"], encode_role_frame(
                    db, rolemap, "ESC_SensorCluster", {"yaw_rate": float(r[i]), "lat_accel": float(ay[i])},
                    counter=i)))
                rows.append((int(gc[i]), int(hc[i]) + 1000, ids["SAS_Steering"], encode_role_frame(
                    db, rolemap, "SAS_Steering", {"swa": float(swa[i])}, counter=i)))
                if beta_est is not None:
                    rows.append((int(gc[i]), int(hc[i]) + 2000, ids["VSC_Status"], encode_role_frame(
                        db, rolemap, "VSC_Status", {"vsc_beta_estimate": float(beta_est[i])}, counter=i)))
            for b in range(0, len(rows), 100):
                blk = rows[b: b + 100]
                m = len(blk)
                payload = np.zeros((m, 8), dtype=np.uint8)
                for j, row in enumerate(blk):
                    payload[j, : len(row[3])] = np.frombuffer(row[3], dtype=np.uint8)
                packed = T.pack_can_columns(
                    np.full(m, T.NO_TIME_NS), [x[1] for x in blk], [x[2] for x in blk], np.full(m, int(T.CanFlag.RX)),
                    np.full(m, 8), np.full(m, 8), payload)
                can_src.put(T.can_frames("vsc"), int(_utc(blk[0][0])), int(blk[-1][1]), packed)
        truth_src = rec.source("sim", maxsize=10_000)
        t0 = int(_utc(G0))
        for b in range(0, len(truth.t), 500):
            truth_src.put(T.TOPIC_SIM_TRUTH, t0 + int(truth.t[b] * 1e9), H0, T.pack_truth_block(
                truth, b, min(b + 500, len(truth.t)), t0))
        rec.event(T.EventKind.MARK, "operator mark: circles", log_time_ns=int(_utc(G0 + 2 * 10**9)))
    return out / name


def run_cli(args: Sequence[str]) -> int:
    """Run ``rig ARGS`` in-process; the exit status (0 when the command returns normally)."""
    from rig.cli.main import main

    try:
        main(list(args))
    except SystemExit as exc:
        return int(exc.code or 0) if not isinstance(exc.code, str) else 1
    return 0
