"""Acceptance: a recorded session replayed onto a live bus and recorded again by the rig's reader and recorder
gives every frame back byte-exact, in order, with its recorded spacing; a fault changes exactly its signal.

Over socketcand (python-can's client to the simulated server on 127.0.0.1) and a python-can virtual bus. The
default suite replays at 4x and checks bytes and order. The 1x timing acceptance (spacing error <= 1 ms at
every frame) is measured on the host's real clock with the receiving side (server and recorder) in another
process (:class:`~tests.replay.receiver.ReceivingSide`), behind the ``idle_host`` marker: on a shared 2-core
machine the host's scheduling, not the player, decides it (figures: ``benchmarks/bench_replay.py``). The
spacing is measured on the stamps the receiving recorder records (``device_ts_ns``: the socketcand server's
kernel arrival stamp of each ``< send >``), not its own receive times. Where the process may, the player runs
on SCHED_FIFO (``rig replay --rt-priority``) and so does the receiving process (which stands in for an
interface stamping in hardware). Measured 2026-12-03 on the rig's 2-core VM, 10 idle runs of the two
cross-process tests: 6 of 10 with every frame within 1 ms, the others 2-8 frames over (at most 2.6 ms), each
where the player itself sent late (1.1-2.2 ms) though on SCHED_FIFO: the hypervisor took the virtual CPU
(/proc/stat counts steal time on this VM even when idle). Ordinary scheduling before: 7 of 10 idle; under 6
busy processes 0 of 5 (4661-5324 frames over 1 ms), with SCHED_FIFO on both sides 1 of 4 (20 frames in all).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.can.bus import CanBusConfig
from drivers.can.checks import FrameFlag
from drivers.can.vector_decode import VectorRoleDecoder
from rig.data import Session
from rig.replay.faults import parse_fault
from rig.replay.plan import ReplayPlan, build_plan
from rig.replay.player import ReplayStats, parse_bus_spec, replay_session
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from tests.replay.conftest import fifo_allowed
from tests.replay.receiver import ReceivingRecorder, ReceivingSide

MS = 1_000_000
RT_PRIORITY = 50 if fifo_allowed() else None
"""The player on SCHED_FIFO where this process may (``rig replay --rt-priority``), as on a bench PC set up for it."""
RX_PRIORITY = 40 if RT_PRIORITY else None
"""The receiving side too (it stands in for an interface that stamps in hardware; see ``tests/replay/receiver``)."""


def _replay_into(tmp: Path, recorded: Session, rx_config: CanBusConfig, tx_spec: str, *, speed: float,
                 faults: tuple[str, ...] = ()) -> tuple[ReplayPlan, ReplayStats, Session]:
    plans: list[ReplayPlan] = []
    with ReceivingRecorder(rx_config) as rx:
        stats = replay_session(recorded.path, parse_bus_spec(tx_spec), speed=speed,
                               faults=[parse_fault(f) for f in faults], on_plan=plans.append)
        assert rx.wait_for(len(plans[0]), 10.0), f"received {len(rx.frames)} of {len(plans[0])} frames"
    again = rx.write(tmp, "again", recorded)
    return plans[0], stats, again


def _assert_same_frames(plan: ReplayPlan, again: Session, payloads: np.ndarray) -> None:
    got = again.can_frames("vsc").records
    assert got.shape[0] == len(plan)
    assert np.array_equal(got["can_id"], plan.can_id)
    assert np.array_equal(got["len"].astype(np.int64), plan.length)
    assert np.array_equal(got["flags"] & int(T.CanFlag.EXTENDED), plan.flags & int(T.CanFlag.EXTENDED))
    w = payloads.shape[1]
    assert np.array_equal(got["data"][:, :w], payloads), "payload bytes differ"


def _spacing_error_ns(plan: ReplayPlan, again: Session, speed: float) -> np.ndarray:
    """Per frame: received spacing (interface stamps) minus the recorded spacing / speed."""
    dev = again.can_frames("vsc").records["device_ts_ns"].astype(np.int64)
    return np.diff(dev) - np.diff(plan.t_ns) / speed


@pytest.fixture
def socketcand(channel: str):
    with SocketcandServer(virtual_channel_opener({"vsc0": channel}), rawmode_settle_s=0.0) as server:
        yield server


def _socketcand_configs(server: SocketcandServer) -> tuple[CanBusConfig, str]:
    host, port = server.address
    rx = CanBusConfig(interface="socketcand", channel="vsc0", options={"host": host, "port": port}, name="rx")
    return rx, f"socketcand:vsc0,host={host},port={port}"


def test_socketcand_replay_is_byte_exact_and_in_order(recorded: Session, socketcand: SocketcandServer,
                                                      tmp_path: Path) -> None:
    rx, tx = _socketcand_configs(socketcand)
    plan, stats, again = _replay_into(tmp_path, recorded, rx, tx, speed=4.0)
    assert stats.frames_sent == len(plan) == len(recorded.can_frames("vsc"))
    assert not plan.rewritten.any()
    _assert_same_frames(plan, again, plan.recorded)
    # the whole recording went out: every recorded frame's bytes, counters and checksums as they were
    src = recorded.can_frames("vsc").records
    assert np.array_equal(again.can_frames("vsc").records["data"], src["data"])


def test_virtual_replay_is_byte_exact_and_keeps_the_spacing(recorded: Session, channel: str, tmp_path: Path) -> None:
    rx = CanBusConfig(interface="virtual", channel=channel, name="rx")
    plan, _stats, again = _replay_into(tmp_path, recorded, rx, f"virtual:{channel}", speed=4.0)
    _assert_same_frames(plan, again, plan.recorded)
    # a loose bound at 4x on a shared machine; the 1 ms figure at 1x is the realtime test below
    err = np.abs(_spacing_error_ns(plan, again, 4.0))
    assert np.median(err) < 1 * MS, np.percentile(err, [50, 99, 100])


def test_fault_injection_changes_exactly_the_chosen_signal(recorded: Session, socketcand: SocketcandServer,
                                                           tmp_path: Path) -> None:
    rx, tx = _socketcand_configs(socketcand)
    plan, _stats, again = _replay_into(tmp_path, recorded, rx, tx, speed=4.0,
                                       faults=("yaw_rate:offset=0.05@1.0..2.0",))
    _assert_same_frames(plan, again, plan.data)
    db = recorded.dbc()
    msg = db.get_message_by_name("ESC_SensorCluster")
    src = recorded.can_frames("vsc")
    rec = again.can_frames("vsc").records
    rows = np.flatnonzero(rec["can_id"] == msg.frame_id)
    t_rel = plan.t_ns[rows] / 1e9
    in_window = (t_rel >= 1.0) & (t_rel < 2.0)
    assert in_window.sum() >= 90  # 100 Hz for 1 s
    for k, r in enumerate(rows):
        before = msg.decode(bytes(src.records["data"][r][:8]), decode_choices=False)
        after = msg.decode(bytes(rec["data"][r][:8]), decode_choices=False)
        changed = {n for n in before if before[n] != after[n]}
        if in_window[k]:
            assert changed <= {"ESC_YawRate", "CHECKSUM"} and "ESC_YawRate" in changed
            assert after["ESC_YawRate"] - before["ESC_YawRate"] == pytest.approx(np.degrees(0.05), abs=0.0051)
            assert after["COUNTER"] == before["COUNTER"]
        else:
            assert not changed and bytes(rec["data"][r]) == bytes(src.records["data"][r])
    # other messages untouched; every checksum and counter of the second recording verifies
    others = np.flatnonzero(rec["can_id"] != msg.frame_id)
    assert np.array_equal(rec["data"][others], src.records["data"][others])
    decoded = VectorRoleDecoder(db, recorded.rolemap(db, "vsc")).decode(again.can_frames("vsc").batch())
    for name, series in decoded.roles.items():
        bad = series.flags & int(FrameFlag.frame_level())
        assert not bad.any(), (name, FrameFlag(int(bad[bad != 0][0])).names())


@pytest.mark.idle_host
def test_spacing_within_1ms_at_1x_on_a_virtual_bus(recorded: Session, channel: str, tmp_path: Path) -> None:
    """At 1x every frame's spacing from its predecessor, as the virtual bus stamps it at send, is within 1 ms
    of the recorded spacing. The receiving reader runs in the player's process here, so the interpreter's
    thread switch interval is shortened (from 5 ms) for the test: the reader's work must not hold the
    player's wake-up (``rig replay`` itself runs alone in its process)."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(0.0002)
    try:
        rx = CanBusConfig(interface="virtual", channel=channel, name="rx")
        plan, stats, again = _replay_into(tmp_path, recorded, rx, f"virtual:{channel}", speed=1.0)
    finally:
        sys.setswitchinterval(interval)
    _assert_same_frames(plan, again, plan.recorded)
    err = np.abs(_spacing_error_ns(plan, again, 1.0))
    assert err.max() <= 1 * MS, f"spacing error µs p50/p99/max {np.percentile(err, [50, 99, 100]) / 1e3}"
    assert stats.late_frames == 0, stats.summary()


def _assert_spacing_within_1ms(plan: ReplayPlan, again: Session, note: str) -> None:
    err = np.abs(_spacing_error_ns(plan, again, 1.0))
    assert err.max() <= 1 * MS, (f"spacing error µs p50/p99/max {np.percentile(err, [50, 99, 100]) / 1e3}, "
                                 f"{np.count_nonzero(err > MS)} of {err.size} > 1 ms; {note}")


@pytest.mark.idle_host
def test_spacing_within_1ms_at_1x_received_in_another_process(recorded: Session, channel: str,
                                                               tmp_path: Path) -> None:
    """The acceptance measurement: the player (here, :func:`replay_session`) sends over TCP to a socketcand
    server in another process, whose bus stamps each frame as its ``< send >`` arrives, and the rig's recorder
    there records them (:class:`ReceivingSide`): every frame's received spacing within 1 ms of the recorded."""
    plan = build_plan(recorded)
    with ReceivingSide(channel, recorded, tmp_path, len(plan), rt_priority=RX_PRIORITY) as side:
        stats = replay_session(recorded.path, parse_bus_spec(side.bus_spec), speed=1.0, rt_priority=RT_PRIORITY)
        again = side.result(30.0)
    _assert_same_frames(plan, again, plan.recorded)
    _assert_spacing_within_1ms(plan, again, f"player: {stats.summary()}")


@pytest.mark.idle_host
def test_spacing_within_1ms_at_1x_from_rig_replay_over_socketcand(recorded: Session, channel: str,
                                                                  tmp_path: Path) -> None:
    """``rig replay`` in a process of its own sends to the receiving side in a third process (as above)."""
    plan = build_plan(recorded)
    with ReceivingSide(channel, recorded, tmp_path, len(plan), rt_priority=RX_PRIORITY) as side:
        rt = ["--rt-priority", str(RT_PRIORITY)] if RT_PRIORITY else []
        done = subprocess.run([sys.executable, "-m", "rig", "replay", str(recorded.path), "--bus", side.bus_spec, *rt],
                              capture_output=True, text=True, timeout=60, check=False)
        assert done.returncode == 0, done.stderr
        again = side.result(30.0)
    _assert_same_frames(plan, again, plan.recorded)
    _assert_spacing_within_1ms(plan, again, f"rig replay: {done.stdout.strip().splitlines()[-1]}")
    assert done.stdout.strip().endswith(" 0 frames > 1 ms late"), done.stdout
