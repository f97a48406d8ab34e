"""Read and validate a one-hour session on one core (issue 9's target: under 30 s).

The session is built once, synthetically, with the real Recorder and cached (default
``$TMPDIR/vsc_rig_bench_validate``): the vehicle simulator drives every manoeuvre kind for an hour;

- GNSS: three receivers at 20 Hz (base, rovers A and B): BESTPOS, BESTVEL, LocationFix, the raw
  binary bytes (BESTPOSB + BESTVELB sized) and TIME at 1 Hz; the rovers' antennas at their lever
  arms with RTK-level noise (1 cm, half white, half correlated over 1 s);
- CAN: a 500 kbit/s bus at 50 % load (≈ 2000 frames/s of 8 bytes ≈ 125 bits each): the simulated
  VSC ECU's own frames (:func:`sim_devices.vsc_ecu.frames`, ≈ 360 frames/s, with its sideslip
  estimate) plus other ECUs' traffic on identifiers outside the DBC;
- DAQ: eight channels at 1 kHz (int16 counts, blocks of 100 samples): the optical sensor's four
  outputs, brake pressure, the sync switch and two spare channels; ``/optical/body`` at 100 Hz;
- the session configuration, vehicle profile, DBC and role map as metadata and attachments.

Timed (``time.perf_counter`` and process CPU time, BLAS limited to one thread, the process pinned
to one CPU when possible): reading the session into arrays (:func:`rig.data.inputs.load_inputs`),
validating (:func:`rig.evaluate.validate.validate_session`, RTS reference), and writing the HTML report.

Run: ``/work/venv/bin/python benchmarks/bench_validate.py [--minutes 60] [--cache DIR] [--rebuild]``
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402 - the thread limits must precede numpy
import contextlib  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pymap3d  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

import rig.core.topics as T  # noqa: E402, N812
from rig.core.config import load_session as load_config  # noqa: E402
from rig.store import Attachment, Recorder, RecorderOptions, session_metadata  # noqa: E402
from rig.workflows.demo import demo_config_path  # noqa: E402
from sim_devices.vehicle import Drive, GroundTruth, VehicleParams, make_scenario, simulate  # noqa: E402
from sim_devices.vsc_ecu import frames, vsc_sim_dbc_path  # noqa: E402
from vsccore.gpstime import gps_ns_to_unix_ns, gps_to_ns  # noqa: E402

LEAP = 18
G0 = gps_to_ns(2400, 345_600.0)
H0 = 1_750_000_000_000_000_000
NAME = "hour"
SCENARIOS: list[tuple[str, dict[str, float | str]]] = [
    ("straight", {"speed_kmh": 60.0, "duration_s": 8.0, "heading_deg": 0.0}),
    ("double_lane_change", {"speed_kmh": 60.0}),
    ("step_steer", {"speed_kmh": 80.0}),
    ("j_turn", {}),
    ("fishhook", {}),
    ("steady_state_circle", {"radius_m": 40.0, "speed_start_kmh": 30.0, "speed_end_kmh": 50.0, "ay_rate_mps3": 0.5}),
    ("sine_with_dwell", {}),
    ("straight", {"speed_kmh": 60.0, "duration_s": 8.0, "heading_deg": 180.0}),
]
CAN_FRAMES_PER_S = 2000
DAQ_CHANNELS = ("s350_vx", "s350_vy", "s350_angle", "s350_valid", "p_mc", "sync", "spare_1", "spare_2")


def _utc(g: np.ndarray | int) -> np.ndarray:
    return np.asarray(g, dtype=np.int64) + gps_ns_to_unix_ns(0, LEAP)


def _ar1(rng: np.random.Generator, n: int, sigma: float, phi: float) -> np.ndarray:
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - phi * phi)
    return np.asarray(lfilter([1.0], [1.0, -phi], e), dtype=float)


def _drive(minutes: float, params: VehicleParams) -> GroundTruth:
    one = [make_scenario(name, **kw) for name, kw in SCENARIOS]
    probe = simulate(Drive(one, gap_s=4.0), params, rate_hz=100.0)
    if minutes * 60.0 <= 1.5 * probe.t[-1]:
        return probe
    per_rep = simulate(Drive(one * 2, gap_s=4.0), params, rate_hz=100.0).t[-1] - probe.t[-1]  # with the join
    reps = 1 + max(0, round((minutes * 60.0 - probe.t[-1]) / per_rep))
    return simulate(Drive(one * reps, gap_s=4.0), params, rate_hz=100.0)


def build(out: Path, minutes: float) -> Path:
    """Write the synthetic session into ``out``; returns its base path."""
    t_start = time.perf_counter()
    cfg = load_config(demo_config_path())
    prof = cfg.profile
    params = VehicleParams.from_mapping(prof.vehicle.model_dump(), section="vehicle")
    truth = _drive(minutes, params)
    print(f"  simulated {truth.t[-1] / 60:.1f} min of driving in {time.perf_counter() - t_start:.1f} s")
    rng = np.random.default_rng(9)
    meta = session_metadata(
        session=cfg.model_dump(mode="json"),
        vehicle={"vehicle": prof.vehicle.model_dump(mode="json"), "antennas": prof.antennas.model_dump(mode="json"),
                 "optical": [o.model_dump(mode="json") for o in prof.optical]},
        calibration=prof.calibration.model_dump(mode="json"),
    )
    roles = Path(str(demo_config_path())).parent / "roles" / "vsc_sim.toml"
    atts = [Attachment.from_file(vsc_sim_dbc_path()),
            Attachment("vsc.roles.toml", "application/toml", roles.read_bytes())]
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0)
    t_end = float(truth.t[-1])
    k = np.arange(int(t_end * 20) + 1)
    g = G0 + k * 50_000_000
    ts = k * 0.05
    lat0, lon0, h0 = truth.lat0_deg, truth.lon0_deg, truth.h0_m
    out.mkdir(parents=True, exist_ok=True)
    ant = prof.antennas
    chunk_s = 30.0
    with Recorder(out, NAME, meta, attachments=atts, options=opts) as rec:
        # ---- GNSS -----------------------------------------------------------------------
        gnss_rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for rx, arm in (("base", None), ("rover_a", ant.a), ("rover_b", ant.b)):
            if arm is None:
                e = np.full(ts.size, -50.0)
                n = np.full(ts.size, -50.0)
                ve = vn = np.zeros(ts.size)
                z = 1.5
            else:
                ee, nn, _u = truth.point_enu(arm.x_m, arm.y_m)
                vve, vvn = truth.point_velocity_enu(arm.x_m, arm.y_m)
                e, n = np.interp(ts, truth.t, ee), np.interp(ts, truth.t, nn)
                ve, vn = np.interp(ts, truth.t, vve), np.interp(ts, truth.t, vvn)
                z = arm.z_m + prof.vehicle.cg_height_m
            e = e + rng.normal(0.0, 0.007, ts.size) + _ar1(rng, ts.size, 0.007, math.exp(-0.05))
            n = n + rng.normal(0.0, 0.007, ts.size) + _ar1(rng, ts.size, 0.007, math.exp(-0.05))
            ve = ve + rng.normal(0.0, 0.02, ts.size)
            vn = vn + rng.normal(0.0, 0.02, ts.size)
            lat, lon, h = pymap3d.enu2geodetic(e, n, np.full(ts.size, z), lat0, lon0, h0)
            gnss_rows.append((rx, np.asarray(lat), np.asarray(lon), np.asarray(h), ve, vn))
        srcs = {rx: rec.source(rx, maxsize=200_000) for rx, *_ in gnss_rows}
        host_g = H0 + (g - G0) + 20_000_000 + rng.exponential(2e6, g.size).astype(np.int64)
        per_chunk = int(chunk_s * 20)
        for c0 in range(0, g.size, per_chunk):
            for rx, lat, lon, h, ve, vn in gnss_rows:
                src = srcs[rx]
                for i in range(c0, min(c0 + per_chunk, g.size)):
                    gi, ui, hi = int(g[i]), int(_utc(g[i])), int(host_g[i])
                    src.put(T.gnss_raw(rx), ui, hi, rng.bytes(180))
                    src.put(T.gnss_bestpos(rx), ui, hi, {
                        "gps_time_ns": gi, "time_status": "FINESTEERING", "sol_status": "SOL_COMPUTED",
                        "pos_type": "NARROW_INT", "lat_deg": float(lat[i]), "lon_deg": float(lon[i]),
                        "height_msl_m": float(h[i]), "undulation_m": 0.0, "lat_std_m": 0.01, "lon_std_m": 0.01,
                        "height_std_m": 0.02, "diff_age_s": 1.0, "num_svs": 24, "num_sol_svs": 20})
                    src.put(T.gnss_bestvel(rx), ui, hi + 1000, {
                        "gps_time_ns": gi, "sol_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY",
                        "latency_s": 0.0, "hor_speed_mps": float(math.hypot(ve[i], vn[i])),
                        "track_over_ground_deg": float(math.degrees(math.atan2(ve[i], vn[i])) % 360.0),
                        "vert_speed_mps": 0.0})
                    if rx != "base":
                        src.put(T.gnss_fix(rx), ui, hi + 2000,
                                T.location_fix(ui, rx, lat[i], lon[i], h[i], 0.01, 0.01, 0.02))
                    if i % 20 == 0:
                        src.put(T.gnss_time(rx), ui, hi + 3000, {
                            "gps_time_ns": gi, "clock_status": "VALID", "utc_offset_s": -float(LEAP),
                            "leap_seconds": LEAP, "utc_status": "VALID"})
            rec.drain(timeout_s=120.0)
        print(f"  GNSS written ({time.perf_counter() - t_start:.1f} s)")

        # ---- CAN: the ECU's frames plus other traffic up to 50 % load --------------------
        t_ecu = time.perf_counter()
        ecu_t: list[float] = []
        ecu_id: list[int] = []
        ecu_data: list[bytes] = []
        for t, msg in frames(truth):
            ecu_t.append(t)
            ecu_id.append(msg.arbitration_id)
            ecu_data.append(bytes(msg.data))
        n_ecu = len(ecu_t)
        n_other = max(0, int(CAN_FRAMES_PER_S * t_end) - n_ecu)
        other_t = np.sort(rng.uniform(0.0, t_end, n_other))
        other_id = rng.integers(0x500, 0x7F0, n_other).astype(np.uint32)
        all_t = np.concatenate([np.asarray(ecu_t), other_t])
        all_id = np.concatenate([np.asarray(ecu_id, dtype=np.uint32), other_id])
        data = np.zeros((all_t.size, 8), dtype=np.uint8)
        ecu_bytes = np.frombuffer(b"".join(d.ljust(8, b"\0")[:8] for d in ecu_data), dtype=np.uint8)
        data[:n_ecu] = ecu_bytes.reshape(n_ecu, 8)
        data[n_ecu:] = rng.integers(0, 256, (n_other, 8), dtype=np.uint8)
        order = np.argsort(all_t, kind="stable")
        all_t, all_id, data = all_t[order], all_id[order], data[order]
        host_c = H0 + np.round(all_t * 1e9).astype(np.int64) + 300_000
        print(f"  CAN: {n_ecu} ECU frames + {n_other} other frames ({all_t.size / t_end:.0f} frames/s; "
              f"ECU frames encoded in {time.perf_counter() - t_ecu:.1f} s)")
        can_src = rec.source("vsc", maxsize=100_000)
        block = 200  # ≈ 0.1 s of traffic per block, as the live session batches
        flags = int(T.CanFlag.RX)
        for b in range(0, all_t.size, block):
            sl = slice(b, min(b + block, all_t.size))
            m = sl.stop - sl.start
            packed = T.pack_can_columns(np.full(m, T.NO_TIME_NS), host_c[sl], all_id[sl], np.full(m, flags),
                                        np.full(m, 8), np.full(m, 8), data[sl])
            can_src.put(T.can_frames("vsc"), int(_utc(G0 + int(all_t[sl.start] * 1e9))), int(host_c[sl.stop - 1]),
                        packed)
            if (b // block) % 500 == 0:
                rec.drain(timeout_s=120.0)
        rec.drain(timeout_s=120.0)
        print(f"  CAN written ({time.perf_counter() - t_start:.1f} s)")

        # ---- DAQ 8 × 1 kHz and the decimated optical topic ------------------------------
        daq_src = rec.source("daq.SimDAQ", maxsize=100_000)
        mount = prof.optical[0].mount
        vx_s, vy_s = truth.point_velocity(mount.x_m, mount.y_m)
        n_daq = int(t_end * 1000)
        scale = 10.0 / 32767.0
        per_block = 100
        t_blocks = 600.0  # build the channels ten minutes at a time
        for s0 in range(0, n_daq, int(t_blocks * 1000)):
            idx = np.arange(s0, min(s0 + int(t_blocks * 1000), n_daq))
            tt = idx / 1000.0
            vx = np.interp(tt, truth.t, vx_s)
            vy = np.interp(tt, truth.t, vy_s)
            volts = np.vstack([
                vx * 3.6 / 25.0, vy * 3.6 / 25.0, np.degrees(np.arctan2(vy, vx)) / 4.0, np.full(idx.size, 5.0),
                np.interp(tt, truth.t, np.zeros_like(truth.t)) + 0.2, np.where((idx % 1000) < 10, 5.0, 0.0),
                rng.normal(0.0, 0.01, idx.size), rng.normal(0.0, 0.01, idx.size),
            ])
            counts = np.clip(np.round(volts / scale), -32768, 32767).astype(np.int16)
            for j in range(0, idx.size, per_block):
                first = int(idx[j])
                blk = T.DaqBlock(first, 1000.0, DAQ_CHANNELS, counts[:, j : j + per_block],
                                 scale=(scale,) * len(DAQ_CHANNELS), offset=(0.0,) * len(DAQ_CHANNELS))
                ti = int(_utc(G0 + first * 1_000_000))
                daq_src.put(T.daq_samples("SimDAQ"), ti, H0 + first * 1_000_000 + 5_000_000, T.pack_daq_block(blk))
                for i in range(j, min(j + per_block, idx.size), 10):  # /optical/body at 100 Hz
                    daq_src.put(T.optical("body"), int(_utc(G0 + int(idx[i]) * 1_000_000)),
                                H0 + first * 1_000_000 + 5_000_000, {
                                    "sample_index": int(idx[i]), "vx_mps": float(vx[i]), "vy_mps": float(vy[i]),
                                    "speed_mps": float(math.hypot(vx[i], vy[i])),
                                    "slip_angle_rad": float(math.atan2(vy[i], vx[i])), "valid": True})
                if (j // per_block) % 200 == 0:
                    rec.drain(timeout_s=120.0)
        rec.drain(timeout_s=120.0)
        for minute in range(1, int(t_end // 60)):
            rec.event(T.EventKind.MARK, f"lap {minute}", log_time_ns=int(_utc(G0 + minute * 60 * 10**9)))
        stats = rec.stats()
    dropped = sum(s.dropped for s in stats)
    size = sum(p.stat().st_size for p in out.glob(f"{NAME}.*.mcap"))
    print(f"  session written in {time.perf_counter() - t_start:.1f} s: {size / 1e6:.0f} MB, dropped {dropped}")
    if dropped:
        raise SystemExit(f"the synthetic session lost {dropped} messages; rebuild with a larger source queue")
    return out / NAME


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vsc_rig_bench_validate")
    ap.add_argument("--rebuild", action="store_true")
    ap.add_argument("--report", action="store_true", help="Also write (and time) the HTML report.")
    args = ap.parse_args()
    cache: Path = args.cache / f"{args.minutes:g}min"
    if args.rebuild and cache.exists():
        shutil.rmtree(cache)
    if not list(cache.glob(f"{NAME}.*.mcap")):
        print(f"building the synthetic session in {cache} (once) ...")
        build(cache, args.minutes)
    path = cache / NAME
    if hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

    from rig.data.inputs import load_inputs
    from rig.evaluate.validate import validate_session

    def timed(label: str, fn):  # type: ignore[no-untyped-def]
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        w, c = time.perf_counter() - w0, time.process_time() - c0
        print(f"{label:<34} {w:7.2f} s wall  {c:7.2f} s CPU")
        return out, w

    print(f"session {path} ({sum(p.stat().st_size for p in cache.glob('*.mcap')) / 1e6:.0f} MB)")
    inp, t_read = timed("read (load_inputs)", lambda: load_inputs(path))
    steps: list[tuple[str, float]] = []
    last_t, last_step = [time.perf_counter()], [""]

    def progress(step: str) -> None:
        now = time.perf_counter()
        if last_step[0]:
            steps.append((last_step[0], now - last_t[0]))
        last_t[0], last_step[0] = now, step

    sv, t_val = timed("validate (RTS reference, scoring)", lambda: validate_session(inp, progress=progress))
    steps.append((last_step[0], time.perf_counter() - last_t[0]))
    for name, dt in steps:
        print(f"    {name:<30} {dt:7.2f} s")
    total = t_read + t_val
    if args.report:
        from rig.evaluate.report import write_validation_report

        _files, t_rep = timed("report (HTML + plots)", lambda: write_validation_report(sv, cache / "report"))
        total += t_rep
    n_can = sum(len(s) for s in inp.can.values())
    print(f"\n{sv.t_s.size} GNSS epochs ({(sv.t_s[-1] - sv.t_s[0]) / 60:.1f} min), {len(inp.can)} CAN roles "
          f"({n_can} role samples), {len(inp.session.can_frames('vsc'))} CAN frames, "
          f"{sum(inp.session.topic_counts.get(T.daq_samples(d), 0) for d in inp.session.daq_devices())} DAQ blocks")
    m = sv.result.overall.metrics
    if m is not None:
        print(f"validation: reference valid {100 * sv.result.reference_valid_fraction:.1f} %, "
              f"{len(sv.result.manoeuvres)} manoeuvres, overall RMSE {math.degrees(m.rmse_rad):.3f}°")
    print(f"read + validate{' + report' if args.report else ''}: {total:.1f} s (target < 30 s)")


if __name__ == "__main__":
    main()
