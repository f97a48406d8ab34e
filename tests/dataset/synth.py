"""A synthetic session of known truth, written by the real recorder (two receivers, CAN, DAQ, truth)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleMap, encode_role_frame
from drivers.optical import OpticalRole, OpticalSensorSpec, SensorKind, correvit_channels
from rig.store import Attachment, Recorder, RecorderOptions, session_metadata
from sim_devices.vehicle.truth import GroundTruth
from vsccore.gpstime import gps_ns_to_unix_ns, gps_to_ns

REPO = Path(__file__).resolve().parents[2]
DBC = REPO / "sim_devices" / "data" / "vsc_sim.dbc"
ROLES = REPO / "rig" / "examples" / "roles" / "vsc_sim.toml"
LEAP = 18
G0 = gps_to_ns(2400, 345_600.0)
H0 = 1_750_000_000_000_000_000
DRIFT = 50e-6
RATE = 1000.0
TRUE_RATE = RATE * (1 + DRIFT)
DAQ_G0 = G0 + 250_000_000  # GPS time of DAQ sample 0


def host_of_gps(g: np.ndarray) -> np.ndarray:
    return H0 + np.round((g - G0) * (1 + DRIFT)).astype(np.int64)


def utc(g: np.ndarray | int) -> np.ndarray:
    return np.asarray(g, dtype=np.int64) + (gps_ns_to_unix_ns(0, LEAP))


@dataclass
class Synth:
    base: Path
    duration_s: float
    gnss: dict[str, dict[str, np.ndarray]]
    can_t_gps: np.ndarray
    yaw_rate: np.ndarray
    lat_accel: np.ndarray
    pulses_gps: np.ndarray
    daq_n: int
    vx: np.ndarray
    vy: np.ndarray
    truth: GroundTruth
    truth_t0_utc: int
    spec: OpticalSensorSpec
    daq_true_gps: np.ndarray
    """True GPS time of every DAQ sample, in file sample-index order."""


def optical_spec() -> OpticalSensorSpec:
    return OpticalSensorSpec(
        name="s350", kind=SensorKind.BODY, mount_xyz_m=(1.0, 0.0, 0.5),
        channels=correvit_channels("s350", roles=(OpticalRole.VX, OpticalRole.VY)), min_speed_mps=0.5,
    )


BAUD = 460800
OUTPUT_LATENCY_S = 0.02
BESTPOSB_BYTES = 28 + 72 + 4
BESTVELB_BYTES = TIMEB_BYTES = 28 + 44 + 4


def tx_ns(n_bytes: int) -> int:
    """Serial transmission time of a frame at the receivers' baud rate (10 bits a byte)."""
    return round(n_bytes * 10e9 / BAUD)


def receivers_config(output_latency_s: float | None = None) -> list[dict[str, Any]]:
    logs = [{"name": "BESTPOSB", "period_s": 0.05}, {"name": "BESTVELB", "period_s": 0.05},
            {"name": "TIMEB", "period_s": 1.0}, {"name": "MARKTIMEB", "trigger": "onnew"}]
    return [{"name": r, "role": "rover", "antenna": a, "port": f"/dev/tty{a}", "baud": BAUD, "logs": logs,
             "output_latency_s": output_latency_s} for r, a in (("rover_a", "a"), ("rover_b", "b"))]


def sync_pulses(duration_s: float) -> np.ndarray:
    """GPS times of the sync switch's rising edges: 1.2 … 2.4 s apart, each 100 ms long."""
    rng = np.random.default_rng(7)
    pulses = G0 + 500_000_000 + np.cumsum(rng.uniform(1.2, 2.4, int(duration_s / 1.2)) * 1e9).astype(np.int64)
    return pulses[pulses < G0 + int((duration_s - 0.5) * 1e9)]


def write_session(out: Path, name: str = "synth", duration_s: float = 20.0, rollover_bytes: int | None = 150_000,
                  *, daq_segments: list[tuple[float, float]] | None = None, simulated: bool = True) -> Synth:
    """A session of known truth. The receivers' logs reach the host ``OUTPUT_LATENCY_S`` plus their serial
    transmission time (plus jitter) after their GPS time, stated in each receiver's ``output_latency_s`` (the
    file has no DAQ sync to measure it from); ``simulated`` adds a simulation section.
    ``daq_segments``: DAQ acquisitions as (start, end) seconds after :data:`DAQ_G0` (default: one from 0),
    numbered in the file the way the recording session does (next index + the gap the host time shows)."""
    rng = np.random.default_rng(42)
    db = load_dbc(DBC)
    rolemap = RoleMap.from_toml(ROLES, db)
    session: dict[str, Any] = {"output": {"name": name}, "can": [{"name": "can0"}],
                               "receivers": receivers_config(OUTPUT_LATENCY_S)}
    if simulated:
        session["simulation"] = {"gnss": {"output_latency_s": OUTPUT_LATENCY_S}}
    meta = session_metadata(session=session, vehicle={"wheelbase_m": 2.87}, calibration={"mount_offset_deg": 0.1})
    # batch=1: the recorder checks the rollover size once per round, and a round takes up to ``batch``
    # messages of each source; with the default 256 one round could write the whole 240 kB truth stream,
    # so how many parts the session got (2 or 3) depended on how far the writer thread lagged behind.
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0, chunk_size=32 * 1024,
                           rollover_size_bytes=rollover_bytes, batch=1)
    atts = [Attachment.from_file(DBC), Attachment("can0.roles.toml", "application/toml", ROLES.read_bytes())]
    gnss: dict[str, dict[str, np.ndarray]] = {}
    vx_all: list[np.ndarray] = []
    vy_all: list[np.ndarray] = []
    next_index = 0
    with Recorder(out, name, meta, attachments=atts, options=opts) as rec:
        # --- GNSS, 20 Hz, two receivers; TIME at 1 Hz; MARKTIME of the sync pulses on rover_a
        pulses = sync_pulses(duration_s)
        for r_i, recv in enumerate(("rover_a", "rover_b")):
            src = rec.source(recv)
            g = G0 + np.arange(int(duration_s * 20)) * 50_000_000
            lat = 48.7 + np.cumsum(rng.normal(0, 1e-6, g.size))
            status = np.where(rng.random(g.size) < 0.05, "INSUFFICIENT_OBS", "SOL_COMPUTED")
            host = host_of_gps(g) + rng.exponential(3e6, g.size).astype(np.int64) + round(OUTPUT_LATENCY_S * 1e9)
            # each log is read once its last byte is in; BESTVEL follows BESTPOS on the port
            host_pos = host + tx_ns(BESTPOSB_BYTES)
            host_vel = host_pos + tx_ns(BESTVELB_BYTES)
            host_time = host_vel + tx_ns(TIMEB_BYTES)
            for k in range(g.size):
                gt = T.GPS_TIME.to_json(int(g[k]))  # {week, tow_ns}, as the recorder writes it
                pos = {"gps_time": gt, "time_status": "FINESTEERING", "sol_status": str(status[k]),
                       "pos_type": "NARROW_INT", "lat_deg": float(lat[k]), "lon_deg": 9.18 + r_i * 1e-5,
                       "height_msl_m": 300.0, "lat_std_m": 0.01, "lon_std_m": 0.01, "height_std_m": 0.02,
                       "diff_age_s": None}
                src.put(T.gnss_bestpos(recv), int(utc(g[k])), int(host_pos[k]), pos)
                vel = {"gps_time": gt, "sol_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY",
                       "latency_s": 0.0, "hor_speed_mps": 20.0, "track_over_ground_deg": 90.0, "vert_speed_mps": 0.0}
                src.put(T.gnss_bestvel(recv), int(utc(g[k])), int(host_vel[k]), vel)
                if k % 20 == 0:
                    tm = {"gps_time": gt, "clock_status": "VALID", "utc_offset_s": -float(LEAP),
                          "leap_seconds": LEAP, "utc_status": "VALID"}
                    src.put(T.gnss_time(recv), int(utc(g[k])), int(host_time[k]), tm)
            if recv == "rover_a":
                for p in pulses.tolist():
                    src.put(T.gnss_marktime("rover_a"), int(utc(p)), int(host_of_gps(np.asarray([p]))[0]) + 30_000_000,
                            {"gps_time": T.GPS_TIME.to_json(p), "clock_status": "VALID", "event_input": "MARK1"})
            gnss[recv] = {"gps": g, "lat": lat, "valid": status == "SOL_COMPUTED"}
        # --- CAN at 100 Hz, interface clock −30 ppm vs host, in blocks of 50
        can_src = rec.source("can0")
        t_can = G0 + 5_000_000 + np.arange(int(duration_s * 100)) * 10_000_000
        yaw = 0.2 * np.sin(np.arange(t_can.size) / 50.0)  # rad/s
        ay = 3.0 * np.cos(np.arange(t_can.size) / 70.0)  # m/s^2
        payloads = np.zeros((t_can.size, 8), dtype=np.uint8)
        for k in range(t_can.size):
            p = encode_role_frame(db, rolemap, "ESC_SensorCluster", {"yaw_rate": yaw[k], "lat_accel": ay[k]}, counter=k)
            payloads[k] = np.frombuffer(p, dtype=np.uint8)
        h_ev = host_of_gps(t_can)
        iface = 9_000_000_000 + np.round((h_ev - H0) * (1 - 30e-6)).astype(np.int64)
        recv_host = h_ev + rng.exponential(0.3e6, t_can.size).astype(np.int64)
        for b in range(0, t_can.size, 50):
            sl = slice(b, b + 50)
            n = t_can[sl].size
            block = T.pack_can_columns(iface[sl], recv_host[sl], np.full(n, 257), np.full(n, int(T.CanFlag.RX)),
                                       np.full(n, 8), np.full(n, 8), payloads[sl])
            can_src.put(T.can_frames("can0"), int(utc(t_can[b])), int(recv_host[sl][-1]), block)
        # --- DAQ: sync channel + optical vx/vy/valid, 1 kHz nominal (50 ppm fast), blocks of 100 samples
        daq_src = rec.source("daq1")
        names = ("sync", "s350_vx", "s350_vy", "s350_valid")
        segments = daq_segments or [(0.0, (int(duration_s * RATE) - 400) / RATE)]
        base = 0
        last_host: int | None = None
        true_gps: list[np.ndarray] = []
        done = 0  # samples written so far (the optical signals run on over all acquisitions)
        for s0, s1 in segments:
            n_seg = round((s1 - s0) * RATE)
            kk = np.arange(n_seg)
            g_k = DAQ_G0 + round(s0 * 1e9) + np.round(kk / TRUE_RATE * 1e9).astype(np.int64)
            true_gps.append(g_k)
            k_all = done + kk
            vx_s = 20.0 + 2.0 * np.sin(k_all / 3000.0)
            vy_s = 0.5 * np.sin(k_all / 1000.0)
            sync = np.zeros(n_seg)
            for e in (pulses - int(g_k[0])) / 1e9 * TRUE_RATE:
                rise = np.clip((kk - e) / 4.0 + 0.5, 0.0, 1.0)
                fall = np.clip((kk - e - 100) / 4.0 + 0.5, 0.0, 1.0)
                sync += 5.0 * (0.5 - 0.5 * np.cos(np.pi * rise)) - 5.0 * (0.5 - 0.5 * np.cos(np.pi * fall))
            volts = np.vstack([sync, vx_s * 3.6 * 0.04, vy_s * 3.6 * 0.04, np.full(n_seg, 5.0)]).astype(np.float32)
            for b in range(0, n_seg, 100):
                last = min(b + 99, n_seg - 1)
                host_b = int(host_of_gps(g_k[last : last + 1])[0]) + 4_000_000
                if b == 0 and last_host is not None:  # rig.record.daq.DaqDevice._index_base
                    base = next_index + max(0, round((host_b - last_host) / (1e9 / RATE)))
                first = base + b
                blk = T.DaqBlock(first, RATE, names, np.ascontiguousarray(volts[:, b : b + 100]))
                # the live session's log time: its sync fit, made on the first acquisition
                log_t = int(utc(DAQ_G0 + round(first / TRUE_RATE * 1e9)))
                daq_src.put(T.daq_samples("daq1"), log_t, host_b, T.pack_daq_block(blk))
                last_host = host_b
                next_index = base + last + 1
            done += n_seg
            vx_all.append(vx_s)
            vy_all.append(vy_s)
        vx, vy = np.concatenate(vx_all), np.concatenate(vy_all)
        n_daq = done
        # --- simulator truth at 100 Hz
        m = int(duration_s * 100)
        t = np.arange(m) / 100.0
        names_t = ("east", "north", "yaw", "vx", "vy", "yaw_rate", "ax", "ay", "ax_meas", "ay_meas", "roll",
                   "roll_rate", "road_wheel_angle", "swa", "ltr")
        fields: dict[str, Any] = {f: rng.normal(size=m) for f in names_t}
        truth = GroundTruth(t=t, wheel_speed=rng.normal(size=(m, 4)), wheel_load=rng.normal(size=(m, 4)),
                            lat0_deg=48.7, lon0_deg=9.18, h0_m=300.0, **fields)
        truth_src = rec.source("sim")
        t0 = int(utc(G0))
        for b in range(0, m, 250):
            block = T.pack_truth_block(truth, b, min(b + 250, m), t0)
            truth_src.put(T.TOPIC_SIM_TRUTH, t0 + int(t[b] * 1e9), H0, block)
        rec.event(T.EventKind.MARK, "operator mark: start of circle", log_time_ns=int(utc(G0 + 3 * 10**9)))
    return Synth(out / name, duration_s, gnss, t_can, yaw, ay, pulses, n_daq, vx, vy, truth, t0, optical_spec(),
                 np.concatenate(true_gps))
