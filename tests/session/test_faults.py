"""Faults during a simulated session: a rover's cable pulled and plugged back, the DAQ unplugged and
replugged, all while the file rolls over into new parts. Each fault is an event in the file, the
other devices record on, and the recording finishes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.data import load_session
from rig.record.recording import Recording
from rig.sim.record import record_simulated
from rig.sim.world import SimWorld
from tests.session.recording import FAST_RTK, config

MS = 1_000_000


def _unplug_rover(world: SimWorld, _s: Recording) -> None:
    world.receivers["rover_b"].unplug()


def _replug_rover(world: SimWorld, _s: Recording) -> None:
    world.receivers["rover_b"].replug()


def _unplug_daq(world: SimWorld, _s: Recording) -> None:
    world.daq_link.unplug()


def _replug_daq(world: SimWorld, _s: Recording) -> None:
    world.daq_link.replug()


def _unplug_can(world: SimWorld, _s: Recording) -> None:
    world.can_link.unplug()


def _replug_can(world: SimWorld, _s: Recording) -> None:
    world.can_link.replug()


def test_unplugged_devices_come_back_and_the_recording_goes_on(tmp_path: Path) -> None:
    # parts of two seconds (session clock): the faults and their recovery span several parts
    cfg = config("straight:duration_s=8,speed_kmh=50", 3.0, **{"output.rollover_duration_s": 2.0})
    rec = record_simulated(
        cfg, tmp_path, name="faults", rtk=FAST_RTK,
        actions=[(1.0, _unplug_rover), (2.5, _replug_rover), (3.5, _unplug_daq), (4.5, _replug_daq),
                 (5.5, _unplug_can), (6.5, _replug_can)],
    )
    assert rec.completed
    print(f"recorded in {rec.wall_s:.1f} s")
    summary = rec.summary
    assert summary.recording.finalized and summary.recording.dropped == 0
    assert len(summary.parts) >= 5
    ds = load_session(tmp_path / "faults", allow_truncated=False)
    assert len(ds.parts) == len(summary.parts)
    t0 = rec.world.truth_t0_utc_ns
    events = [(t, e) for t, e in ds.events]
    kinds_b = [e.kind for _t, e in events if e.source == "rover_b"]
    assert T.EventKind.DISCONNECT in kinds_b
    assert kinds_b.count(T.EventKind.CONNECT) >= 2
    gaps = [e for _t, e in events if e.source == "rover_b" and e.kind is T.EventKind.GAP]
    # a stream that ends over a second before the session is an 'ended_early' gap of its own (the
    # recorder's closing check, which a loaded host can trigger); the unplug is the one other gap
    ended_early = [e for e in gaps if e.details.get("gap") == "ended_early"]
    assert all(e.start_ns is not None and e.start_ns > t0 + 6000 * MS for e in ended_early), ended_early
    gaps = [e for e in gaps if e not in ended_early]
    assert len(gaps) == 1
    gap = gaps[0]
    assert gap.start_ns is not None and gap.end_ns is not None
    assert t0 + 900 * MS < gap.start_ns < t0 + 2000 * MS
    assert t0 + 2400 * MS < gap.end_ns < t0 + 6000 * MS
    # rover_b's logs stop while its cable is out (1.0 … 2.5 s) and resume after it; rover_a never stops.
    # (The gap event is the host's: from noticing the loss to reopening the port, a little later.)
    tb = ds.gnss("rover_b").bestpos.time_ns
    assert not np.any((tb > t0 + 1100 * MS) & (tb < t0 + 2400 * MS))
    assert np.count_nonzero(tb > gap.end_ns + 1000 * MS) > 20
    ta = ds.gnss("rover_a").bestpos.time_ns
    ta = ta[(ta > t0) & (ta < t0 + 8000 * MS)]
    assert np.diff(ta).max() <= 60 * MS
    # the DAQ: a disconnect, a reconnect, two acquisitions with unique sample indices
    daq_kinds = [e.kind for _t, e in events if e.source == "daq.SimDAQ"]
    assert T.EventKind.DISCONNECT in daq_kinds and daq_kinds.count(T.EventKind.CONNECT) == 2
    d = ds.daq("SimDAQ")
    assert np.all(np.diff(d.sample_index) > 0)
    assert d.lost > 0  # the unplugged time is a gap in the index, not samples renumbered
    steps = np.flatnonzero(np.diff(d.sample_index) > 1)
    assert steps.size == 1
    assert len(rec.world.daq_timing()) == 2
    # CAN: the adapter vanished for a second; the frames stop and resume, the gap is an event
    can_events = [e for _t, e in events if e.source == "can.vsc"]
    assert [e.kind for e in can_events].count(T.EventKind.CONNECT) >= 2
    can_gaps = [e for e in can_events if e.kind is T.EventKind.GAP]
    assert len(can_gaps) == 1 and can_gaps[0].details["recovered"] is True
    frames = ds.can_frames("vsc")
    dev = np.sort(frames.records["device_ts_ns"])
    dev = dev[dev > t0]
    step = np.diff(dev)
    big = np.flatnonzero(step > 20 * MS)
    assert big.size == 1  # one hole, where the cable was out
    assert t0 + 5400 * MS < dev[big[0]] < t0 + 6000 * MS
    # back within the reconnect back-off (2 s real at most, 6 s of simulated time). Device times are the
    # ECU's send times: on a loaded machine the ECU thread runs behind the scaled clock and sends a late
    # burst after the replug, so the hole in device time can be shorter than the 1 s the cable was out.
    assert dev[big[0] + 1] - dev[big[0]] > 300 * MS
    assert dev[big[0] + 1] < t0 + 12_500 * MS
    # the rover's and the DAQ's troubles are theirs alone
    assert summary.device_errors.get("rover_a", 0) == 0
