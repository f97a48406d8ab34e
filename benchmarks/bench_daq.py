"""DAQ chain figures: simulated-DAQ rendering, the reader session, optical conversion, sync edges, Correvit CAN.

Prints, for eight channels at 1 kHz (a Correvit's five outputs, a brake-pressure transducer, the
sync line and a spare input):

- the simulated DAQ's rendering rate (offline ``generate``) and the end-to-end rate of a
  :class:`DaqLink` on the ``sim`` backend (backend chosen by name, health checks and sync
  detection on, a consumer that converts every block to optical samples), as multiples of real time;
- optical ``convert_block`` and streaming ``SyncEdgeDetector`` throughput (samples/s);
- sync-edge accuracy against the simulator's true pulse times (µs), for the cubic interpolation
  and for a plain chord between the two bracketing samples;
- Correvit-over-CAN decoding: frames/s through ``VectorRoleDecoder`` + ``from_role_series`` and
  through the live ``RoleDecoder`` + ``OpticalCanAssembler``.

Run: ``/work/venv/bin/python benchmarks/bench_daq.py [--seconds S]``
"""

from __future__ import annotations

import argparse
import threading
import time
from typing import Any

import numpy as np

from drivers.analog import brake_pressure_spec
from drivers.can import FrameBatch, RoleDecoder, RoleMap, VectorRoleDecoder, load_dbc
from drivers.daq import DaqBlock, DaqChannelConfig, DaqEvent, DaqEventKind, DaqLink, SyncEdgeDetector, find_edges
from drivers.optical import (
    OpticalCanAssembler,
    OpticalChannel,
    OpticalRole,
    OpticalSensorSpec,
    SensorKind,
    convert_block,
    correvit_channels,
    from_role_series,
)
from sim_devices.daq import (
    BrakePressureOutput,
    SimDaqBackend,
    SimOpticalSensor,
    SyncPulseOutput,
    correvit_can_frames,
    correvit_dbc_path,
    correvit_role_table,
    wire_optical,
)
from sim_devices.vehicle.truth import GroundTruth

RATE = 1000.0
T0_NS = 1_700_000_000 * 10**9


class _JumpClock:
    """A clock that jumps to whatever time a reader waits for (as fast as the machine goes)."""

    def __init__(self, t_ns: int) -> None:
        self._t = t_ns
        self._lock = threading.Lock()

    def now_ns(self) -> int:
        with self._lock:
            return self._t

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        if stop is not None and stop.is_set():
            return False
        with self._lock:
            self._t = max(self._t, t_ns)
        return True


def _truth(seconds: float) -> GroundTruth:
    t = np.arange(0.0, seconds, 1e-3)
    n = t.size
    w = 2 * np.pi * 0.5
    vx, vy, r = np.full(n, 22.0), 0.6 * np.sin(w * t - 0.4), 0.25 * np.sin(w * t)
    yaw = np.cumsum(r) * 1e-3
    z = np.zeros(n)
    return GroundTruth(
        t=t, east=z, north=z, yaw=yaw, vx=vx, vy=vy, yaw_rate=r, ax=-r * vy, ay=r * vx, ax_meas=-r * vy,
        ay_meas=r * vx, roll=z, roll_rate=z, road_wheel_angle=0.05 * np.sin(w * t), swa=z,
        wheel_speed=np.repeat(vx[:, None], 4, axis=1), wheel_load=np.full((n, 4), 4000.0), ltr=z,
    )


Setup = tuple[GroundTruth, OpticalSensorSpec, list[DaqChannelConfig], dict[str, Any], list[float]]


def _setup(seconds: float) -> Setup:
    truth = _truth(seconds + 1.0)
    spec = OpticalSensorSpec("body", SensorKind.BODY, (1.6, 0.5, 0.4), correvit_channels("body"))
    chans = [DaqChannelConfig(c.channel or "", f"sim/ai{i}") for i, c in enumerate(spec.channels)]
    chans += [
        DaqChannelConfig("p_mc", "sim/ai5", 0.0, 5.0),
        DaqChannelConfig("sync", "sim/ai6", 0.0, 10.0),
        DaqChannelConfig("spare", "sim/ai7"),
    ]
    rng = np.random.default_rng(1)
    edges = list(0.5 + np.cumsum(rng.uniform(0.8, 1.2, int(seconds) - 1)))
    sources = wire_optical(SimOpticalSensor(spec, velocity_noise_mps=0.02), chans) | {
        "sim/ai5": BrakePressureOutput("master", brake_pressure_spec("p_mc", "p_mc").scaling),
        "sim/ai6": SyncPulseOutput(tuple(edges), width_s=0.2, noise_v=0.002),
    }
    return truth, spec, chans, sources, edges


def bench_render(seconds: float) -> None:
    truth, _, chans, sources, _ = _setup(seconds)
    b = SimDaqBackend(truth=truth, sources=sources, truth_start_ns=0)
    b.configure(chans)
    t0 = time.perf_counter()
    v = b.generate(t1_s=seconds)
    dt = time.perf_counter() - t0
    print(f"sim DAQ render (generate): {v.shape[1] / dt:,.0f} samples/s per channel x {v.shape[0]} channels "
          f"= {v.shape[1] / dt / RATE:,.0f}x real time at 1 kHz")


def bench_session(seconds: float) -> None:
    truth, spec, chans, sources, edges = _setup(seconds)
    clock = _JumpClock(T0_NS)
    n_target = int(seconds * RATE) - 100
    done = threading.Event()
    edge_events: list[DaqEvent] = []
    blocks = [0]

    def on_block(block: DaqBlock) -> None:
        convert_block(spec, block)
        blocks[0] += 1
        if block.next_sample_index >= n_target:
            done.set()

    def on_event(ev: DaqEvent) -> None:
        if ev.kind is DaqEventKind.SYNC_EDGE:
            edge_events.append(ev)

    cfg = {
        "backend": "sim", "device": "bench", "rate_hz": RATE, "block_size": 100, "buffer_samples": 10_000,
        "channels": [{"name": c.name, "physical": c.physical_channel, "range_v": (c.min_v, c.max_v)} for c in chans],
        "sync_channel": "sync", "sync_threshold_v": 2.5,
    }
    options: dict[str, Any] = {"truth": truth, "sources": sources, "truth_start_ns": T0_NS, "clock_ppm": 30.0}
    session = DaqLink.from_config(cfg, on_block=on_block, on_event=on_event, clock=clock, backend_options=options)
    t0 = time.perf_counter()
    with session:
        done.wait(600.0)
    dt = time.perf_counter() - t0
    ref = SimDaqBackend(**options)
    t_edge = np.asarray(ref.sample_time_s(np.array([e.edge_index for e in edge_events]), 0.0, RATE))
    true = np.asarray(edges[: len(edge_events)])
    err_us = (t_edge - true) * 1e6
    print(f"DaqLink sim->blocks->health->sync->optical: {blocks[0]} blocks of 100 in {dt:.2f} s = "
          f"{seconds / dt:,.0f}x real time ({8 * n_target / dt:,.0f} channel-samples/s)")
    print(f"  live sync edges ({len(edge_events)}, 30 ppm clock, 2 mV noise): error vs true pulse time "
          f"max {np.max(np.abs(err_us)):.2f} µs, rms {np.sqrt(np.mean(err_us**2)):.2f} µs")


def bench_convert_and_edges(seconds: float) -> None:
    truth, spec, chans, sources, _ = _setup(seconds)
    b = SimDaqBackend(truth=truth, sources=sources, truth_start_ns=0)
    b.configure(chans)
    v = b.generate(t1_s=seconds)
    blk = DaqBlock(0, RATE, v, 0, tuple(c.name for c in chans))
    t0 = time.perf_counter()
    convert_block(spec, blk)
    dt = time.perf_counter() - t0
    print(f"optical convert_block: {v.shape[1] / dt:,.0f} samples/s")
    det = SyncEdgeDetector(low=1.5, high=3.5)
    sync = blk.channel("sync")
    t0 = time.perf_counter()
    for k in range(0, sync.size, 100):
        det.process(sync[k : k + 100], k)
    dt = time.perf_counter() - t0
    print(f"SyncEdgeDetector, blocks of 100: {sync.size / dt:,.0f} samples/s")


def bench_edge_accuracy() -> None:
    rng = np.random.default_rng(7)
    edges = tuple(1.0 + np.cumsum(rng.uniform(0.7, 1.3, 200)))
    chans = [DaqChannelConfig("sync", "sim/ai0", 0.0, 10.0)]
    for noise in (0.0, 0.002, 0.02):
        b = SimDaqBackend(sources={"sim/ai0": SyncPulseOutput(edges, width_s=0.2, rise_time_s=0.004)},
                          truth_start_ns=0, adc_noise_v=noise, clock_ppm=30.0, seed=3)
        b.configure(chans)
        x = b.generate(t1_s=edges[-1] + 0.5)[0]
        found = find_edges(x, low=1.5, high=3.5)
        true_idx = (np.asarray(edges) * RATE) * (1 + 30e-6)
        err_us = (found - true_idx) / RATE * 1e6
        chord = []
        for r in true_idx:
            j = int(np.floor(r)) - 2
            seg = x[j : j + 6]
            i = int(np.flatnonzero((seg[:-1] < 2.5) & (seg[1:] >= 2.5))[-1])
            a, c = seg[i], seg[i + 1]
            chord.append(((j + i + (2.5 - a) / (c - a)) - r) / RATE * 1e6)
        ch = np.asarray(chord)
        print(f"sync edges, 4 ms rise, {noise * 1e3:.0f} mV noise, 200 edges at random phases: cubic max "
              f"{np.max(np.abs(err_us)):.2f} µs rms {np.sqrt(np.mean(err_us**2)):.2f} µs; chord max "
              f"{np.max(np.abs(ch)):.2f} µs rms {np.sqrt(np.mean(ch**2)):.2f} µs")


def bench_can(seconds: float) -> None:
    db = load_dbc(correvit_dbc_path())
    rolemap = RoleMap.from_mapping(correvit_role_table(), db)
    roles = (OpticalRole.VX, OpticalRole.VY, OpticalRole.SLIP_ANGLE, OpticalRole.SPEED)
    spec = OpticalSensorSpec(
        "c", SensorKind.BODY, (1.6, 0.5, 0.4), tuple(OpticalChannel(r, can_role=f"correvit_{r.value}") for r in roles)
    )
    truth = _truth(seconds + 1.0)
    frames = correvit_can_frames(SimOpticalSensor(spec), truth, db, rolemap, t1_s=seconds)
    t0 = time.perf_counter()
    batch = VectorRoleDecoder(db, rolemap).decode(FrameBatch.from_frames(frames))
    s = from_role_series(spec, batch.roles)
    dt = time.perf_counter() - t0
    print(f"Correvit CAN offline (VectorRoleDecoder + from_role_series): {len(frames) / dt:,.0f} frames/s "
          f"({len(s)} samples)")
    dec, asm = RoleDecoder(db, rolemap), OpticalCanAssembler(spec, rolemap)
    t0 = time.perf_counter()
    n = 0
    for ts, fid, data in frames:
        out = asm.add(dec.decode(fid, data, ts))
        n += 0 if out is None else len(out)
    dt = time.perf_counter() - t0
    print(f"Correvit CAN live (RoleDecoder + OpticalCanAssembler): {len(frames) / dt:,.0f} frames/s ({n} samples)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per figure (default 60)")
    args = ap.parse_args()
    bench_render(args.seconds)
    bench_session(args.seconds)
    bench_convert_and_edges(args.seconds)
    bench_edge_accuracy()
    bench_can(args.seconds)


if __name__ == "__main__":
    main()
