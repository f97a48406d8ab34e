"""How far the time-base quality gate's figures are from the truth, on recorded simulated sessions.

Issue 15's gate (:mod:`rig.core.quality`) rates each stream by an upper bound of its timing error. This
script records three simulated sessions through the real ``rig record`` path and sets every gate
figure beside the simulator's truth (the simulated host clock is true UTC, the simulated ECU stamps
each CAN frame with its true transmit time, the simulated DAQ's sample clock is in the ``sim`` event):

- ``governed``: the governed simulated clock (a busy host makes the recording slower, not late);
- ``free``: the free-running clock (the host's real scheduling latency);
- ``starved``: free-running, with a CAN reader slower than the ECU sends
  (``tests/quality/test_starved_recording.py``'s :class:`StarvedBus`);
- ``late``: governed, with the reference receiver's output latency configured ``--late-ms`` short of the
  simulator's (a known constant offset of the host map, as ``tests/quality/test_map_error.py`` records).

For every session and stream it prints:

- ``old``: the figure of the previous statistic (:meth:`ClockEstimator.envelope_error_ns`: the 95th
  percentile, per second, of the lowest pair's height above the map);
- ``floor``: the figure of H21 (:meth:`ClockEstimator.map_error_ns`: the highest the latency floor held
  above the map for 5 s on end, plus :data:`rig.core.quality.FLOOR_ALLOWANCE_MS`);
- ``new``: the figure the gate now uses: ``floor`` plus the DAQ's causality bound of the host map
  (:func:`rig.data.verdicts.daq_causality_ns`: how much earlier than their sync-timed last samples the map puts
  the DAQ blocks' arrivals, held in three half-seconds of 10 s), printed on its own line beside the host
  map's true error (its median: the constant offset it is meant to see);
- ``truth``: max and 95th percentile of |time on the common base − true time| over the frames
  (CAN), over the host instants of the GNSS logs (host map: the mapped GPS time of a host instant
  against the true one), over the samples (DAQ);
- the ratio figure / truth (max).

Run: ``.venv/bin/python benchmarks/study_timebase_gate.py [--out DIR] [--reuse] [--duration S] [--kinds K,…]``
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from rig.core.config import SessionConfig
from rig.core.config import load_session as load_config
from rig.core.quality import FLOOR_ALLOWANCE_MS
from rig.core.timebase import ClockEstimator
from rig.data import Session, load_session
from rig.data.verdicts import daq_causality_ns, session_verdicts
from rig.record.recording import Recording
from rig.sim.record import record_simulated
from rig.sim.truth import timing_vs_truth
from rig.sim.world import SimWorld
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle.scenarios import make_scenario

MS = 1e6
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the starved reader of the tests


LATE_MS = 2.0


def _config(kind: str, speed: float = 1.0) -> SessionConfig:
    over: dict[str, object] = {"simulation.speed": speed, "simulation.governed": kind in ("governed", "late")}
    if kind == "late":
        base = load_config(demo_config_path())
        assert base.simulation is not None
        i = next(k for k, r in enumerate(base.receivers) if r.name == "rover_a")
        over[f"receivers.{i}.output_latency_s"] = base.simulation.gnss.output_latency_s - LATE_MS / 1e3
    return load_config(demo_config_path(), over)


def record(out: Path, kind: str, duration_s: float, speed: float) -> Path:
    drive = make_scenario("straight", speed_kmh=50.0, duration_s=duration_s)
    rtk = RtkParams(time_to_float_s=0.5, time_to_fix_s=1.0)
    if kind in ("governed", "free", "late"):
        cfg = _config(kind, speed)
        rec = record_simulated(cfg, out, name=kind, drive=drive, lead_s=2.0, rtk=rtk)
        if rec.summary.recording.error is not None:
            raise SystemExit(f"{kind}: recording failed: {rec.summary.recording.error}")
        return out / kind
    from tests.quality.test_starved_recording import READ_DELAY_S, StarvedBus

    cfg = _config("starved")
    world = SimWorld(cfg, drive=drive, lead_s=2.0, rtk=rtk, governed=False)
    world.start()
    try:
        assert world.clock is not None
        session = Recording(
            cfg, out_dir=out, name=kind, clock=world.clock, ports=world, daq_factory=world.daq_session,
            can_factory=lambda c: StarvedBus(world.can_bus(c), READ_DELAY_S), plugins=[world],
        )
        session.start()
        try:
            wait = threading.Event()
            while world.clock.now_ns() < world.end_ns and not session.failed.is_set():
                wait.wait(0.1)
        finally:
            session.stop()
    finally:
        world.stop()
    return out / kind


def _ms(ns: float | None) -> float:
    return math.nan if ns is None else ns / MS


def _est(name: str, dev: np.ndarray, host: np.ndarray) -> ClockEstimator:
    order = np.argsort(dev, kind="stable")
    est = ClockEstimator(name)
    est.add_many(dev[order], host[order])
    return est


def _row(stream: str, old_ms: float, floor_ms: float, new_ms: float, err_ns: np.ndarray, verdict: str) -> str:
    e = np.asarray(err_ns, dtype=np.float64)
    a = np.abs(e)
    mx = float(a.max()) / MS if a.size else math.nan
    p95 = float(np.percentile(a, 95)) / MS if a.size else math.nan
    const = float(np.median(e)) / MS if a.size else math.nan
    dev = float(np.abs(e - np.median(e)).max()) / MS if a.size else math.nan
    r_old = old_ms / mx if mx > 0 else math.inf
    r_new = new_ms / mx if mx > 0 else math.inf
    return (f"  {stream:<18} old {old_ms:9.3f}  floor {floor_ms:7.3f}  new {new_ms:7.3f}"
            f"  truth max {mx:8.3f} p95 {p95:8.3f}"
            f" (median {const:+7.3f}, max |err - median| {dev:7.3f})"
            f"  old/truth {r_old:7.2f}  new/truth {r_new:5.2f}  {verdict}")


def study(path: Path, cfg: SessionConfig) -> list[str]:
    ds: Session = load_session(path, gnss_min_latency_s=None)
    v = session_verdicts(ds)
    lines = [f"{path.name}: figures and truth in ms"]
    host = ds.host_clock
    assert host is not None and ds.leap_seconds is not None
    h_old = _ms(host.envelope_error_ns())
    h_floor = _ms(host.map_error_ns())
    causal = 0.0
    for dev_name in ds.daq_devices():
        b, why = daq_causality_ns(ds, dev_name)
        causal = max(causal, _ms(b) if b is not None else 0.0)
        lines.append(f"  daq:{dev_name} causality bound of the host map {_ms(b):.3f} ms {why}")
    h_new = h_floor + causal
    # host map truth: the mapped common time of every GNSS log's host instant against the host instant
    # itself (the simulated host clock is true UTC)
    rx = host.name.removeprefix("gnss:")
    hs = np.asarray(ds.gnss(rx).bestpos.host_ns, dtype=np.int64)
    lines.append(_row(f"gnss:{rx} (map)", h_old, h_floor + FLOOR_ALLOWANCE_MS, h_new + FLOOR_ALLOWANCE_MS,
                      ds.host_to_utc(hs)[0] - hs, v[f"gnss:{rx}"].verdict.value))
    for bus in ds.can_buses():
        fr = ds.can_frames(bus)
        dev = fr.records["device_ts_ns"].astype(np.int64)
        hst = fr.records["host_ts_ns"].astype(np.int64)
        est = _est(f"can:{bus}", dev, hst)
        c_old = _ms(est.envelope_error_ns())
        c_new = _ms(est.map_error_ns())
        verdict = v[f"can:{bus}"].verdict.value
        lines.append(_row(f"can:{bus} (map)", c_old, c_new, c_new, est.mapping()(dev) - dev, "(no allowance)"))
        lines.append(_row(f"can:{bus}", c_old + h_old, c_new + h_floor + FLOOR_ALLOWANCE_MS,
                          c_new + h_new + FLOOR_ALLOWANCE_MS, fr.time_ns - dev, verdict))
        lag = hst - est.mapping()(dev)
        lines.append(f"  {'':<16} arrival lag above the map: p50 {np.percentile(lag, 50) / MS:.3f} ms, "
                     f"p95 {np.percentile(lag, 95) / MS:.3f} ms, max {lag.max() / MS:.3f} ms (latency, not error)")
    for st in timing_vs_truth(ds, cfg):
        if st.stream.startswith("daq:"):
            name = st.stream.split()[0]
            fig = next((f.value for f in v[name].figures if f.name == "timing_error_ms"), math.nan) if name in v \
                else math.nan
            lines.append(f"  {name:<16} sync rms {fig:9.3f} ms  truth max {st.max_abs_ns / MS:9.3f} ms "
                         f"rms {st.rms_ns / MS:9.3f} ms  verdict {v[name].verdict.value if name in v else '-'}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the recordings here (default: a temporary dir)")
    ap.add_argument("--reuse", action="store_true", help="analyse recordings already in --out")
    ap.add_argument("--duration", type=float, default=6.0, help="drive duration (s) of each recording")
    ap.add_argument("--kinds", default="governed,free,starved,late")
    ap.add_argument("--speed", type=float, default=1.0, help="clock speed of the governed and free recordings")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        for kind in args.kinds.split(","):
            path = out / kind
            if not (args.reuse and any(out.glob(f"{kind}.*.mcap"))):
                t0 = time.monotonic()
                record(out, kind, args.duration, args.speed if kind != "starved" else 1.0)
                print(f"recorded {kind} in {time.monotonic() - t0:.1f} s", flush=True)
            for line in study(path, _config(kind, args.speed)):
                print(line, flush=True)


if __name__ == "__main__":
    main()
