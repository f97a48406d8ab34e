"""The simulated VSC ECU in another process (``rig can sim-ecu``), read through socketcand by a bus session.

The ECU process and this test build the same ground truth from the same scenario, so the frames that
cross the process boundary are compared byte for byte with the offline :func:`frames` of that truth.
"""

from __future__ import annotations

import queue
import re
import selectors
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.can.bus import BusEvent, BusOpened, CanBusConfig, CanBusLink, CanFrame, TimestampSource
from drivers.can.checks import FrameFlag
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap
from sim_devices.vehicle import make_scenario, simulate
from sim_devices.vsc_ecu import VscEcuConfig, frames, vsc_sim_dbc_path
from vsccore.clock import SystemClock

REPO = Path(__file__).resolve().parents[2]
SCENARIO = ["--scenario", "step_steer", "--param", "lead_s=0.5", "--param", "hold_s=2.5", "--param", "speed_kmh=60"]
SEED = 3


def _ready_line(proc: subprocess.Popen[str], timeout_s: float) -> str:
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            raise AssertionError(f"rig can sim-ecu printed nothing within {timeout_s} s")
    return proc.stdout.readline()


@pytest.mark.realtime  # the ECU process runs on the wall clock: a starved host makes it skip frames
def test_ecu_process_frames_match_the_offline_frames_and_decode() -> None:
    cmd = [sys.executable, "-m", "rig", "can", "sim-ecu", *SCENARIO, "--port", "0", "--speed", "2"]
    cmd += ["--delay", "1.0", "--seed", str(SEED)]
    received: queue.Queue[CanFrame] = queue.Queue()
    events: queue.Queue[BusEvent] = queue.Queue()
    with subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as proc:
        try:
            line = _ready_line(proc, 60.0)
            match = re.search(r"on 127\.0\.0\.1:(\d+) bus 'vsc0', t0_ns=(\d+)", line)
            assert match is not None, line
            port, t0_ns = int(match[1]), int(match[2])
            config = CanBusConfig.from_mapping(
                {"name": "vsc", "interface": "socketcand", "channel": "vsc0", "host": "127.0.0.1", "port": port}
            )
            session = CanBusLink(config, received.put, events.put, clock=SystemClock(), backoff_initial_s=0.05)
            session.start()
            try:
                assert proc.wait(timeout=60.0) == 0
            finally:
                session.stop()
            assert proc.stdout is not None
            summary = proc.stdout.read()
        finally:
            if proc.poll() is None:
                proc.kill()
    assert "drive finished" in summary and "0 skipped" in summary, summary
    opened = [e for e in _drain(events) if isinstance(e, BusOpened)]
    assert opened[0].timestamp_source is TimestampSource.KERNEL  # socketcand forwards the remote stamp
    got = _drain(received)
    assert len(got) > 500

    # The same drive, offline: the frames that crossed the process boundary are a contiguous tail of it.
    truth = simulate(make_scenario("step_steer", lead_s=0.5, hold_s=2.5, speed_kmh=60))
    offline = list(frames(truth, VscEcuConfig(seed=SEED)))
    head = [(f.arbitration_id, f.data) for f in got[:5]]
    first = next(
        i for i in range(len(offline)) if [(m.arbitration_id, bytes(m.data)) for _, m in offline[i : i + 5]] == head
    )
    tail = offline[first:]
    assert len(got) == len(tail)
    for frame, (t, msg) in zip(got, tail, strict=True):
        assert (frame.arbitration_id, frame.data) == (msg.arbitration_id, bytes(msg.data))
        # the server forwards the ECU's transmit time with microsecond resolution
        assert frame.device_ts_ns == pytest.approx(t0_ns + t * 1e9, abs=1_500)

    # And they decode, with every counter and checksum in order, to the truth's speed.
    db = load_dbc(vsc_sim_dbc_path())
    rolemap = RoleMap.from_toml(REPO / "examples" / "roles" / "vsc_sim.toml", db)
    decoder = RoleDecoder(db, rolemap)
    speeds = []
    for frame in got:
        decoded = decoder.decode(frame.arbitration_id, frame.data, frame.device_ts_ns or 0)
        assert decoded.flags == FrameFlag.OK, decoded
        t = ((frame.device_ts_ns or 0) - t0_ns) / 1e9
        speeds += [(t, s.value) for s in decoded.samples if s.role == "wheel_speed_rl"]
    t_ws, v_ws = np.array(speeds).T
    true_rl = np.interp(t_ws, truth.t, truth.wheel_speed[:, 2])
    # the ECU assumes a nominal rolling radius 0.15 % off the rear-left tyre's; tooth timing adds noise
    ratio = v_ws / true_rl * (1 + VscEcuConfig().tyre_radius_error[2])
    assert np.median(ratio) == pytest.approx(1.0, abs=2e-3)


def _drain(q: queue.Queue) -> list:  # type: ignore[type-arg]
    out = []
    while True:
        try:
            out.append(q.get_nowait())
        except queue.Empty:
            return out
