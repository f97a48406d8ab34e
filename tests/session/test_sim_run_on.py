"""The simulated car's CAN bus runs until the session stops (issue 15 §2, the CAN stream's early end).

The ECU stopped with the drive while the other simulated devices (DAQ, optical, GNSS) went on while
the session stopped, so a governed demo recording's CAN stream ended ~0.6 s before its last stream:
the simulator, not the recorder, ending the bus. A real car's bus runs until the recorder stops; so
does the simulated ECU now, the car running on in its last state."""

from __future__ import annotations

from pathlib import Path

from rig.core.quality import backward_steps
from rig.data import load_session as load_recording
from rig.sim.record import record_simulated
from tests.session.recording import FAST_RTK, config

END_BOUND_S = 0.2
"""Most a CAN stream (10-100 ms messages) may end before the session's last stream (the old CAN
stream: 0.5-0.6 s before; the DAQ delivers a block every 0.1 s)."""


def test_the_can_streams_of_a_governed_recording_end_within_0_2_s_of_the_last_stream(tmp_path: Path) -> None:
    cfg = config("straight:duration_s=2,speed_kmh=40", 3.0)
    rec = record_simulated(cfg, tmp_path, name="runon", rtk=FAST_RTK, lead_s=1.0, governed=True)
    assert rec.completed and rec.summary.recording.error is None
    ds = load_recording(tmp_path / "runon")
    last: dict[str, int] = {}
    for topic in ds.topic_counts:
        if topic.startswith(("/can/", "/gnss/", "/daq/", "/optical/")):
            times = ds.message_times(topic)[0]
            if len(times):
                last[topic] = int(times.max())
                assert backward_steps(times)[0] == 0, topic
    # CAN: each frame's own time (the frames topic carries blocks of frames under the first one's time)
    can = {f"can:{bus}": int(ds.can_frames(bus).time_ns.max()) for bus in ds.can_buses()}
    assert can, f"no CAN bus recorded: {sorted(ds.topic_counts)}"
    # the bus ran on past the drive, up to the session's stop (the loop stops at world.end_ns, 0.12 s
    # past the drive on the governed clock; the old ECU's last frame was at the drive's end)
    drive_end_utc_ns = rec.world.truth_t0_utc_ns + round(rec.world.duration_s * 1e9)
    past = {bus: (t - drive_end_utc_ns) / 1e9 for bus, t in can.items()}
    assert min(past.values()) >= 0.1, f"CAN frames end this long (s) after the drive: {past}"
    end = max(last.values())
    before = {bus: (end - t) / 1e9 for bus, t in can.items()}
    assert max(before.values()) <= END_BOUND_S, f"CAN frames end this long (s) before the last stream: {before}"
    # the frames after the drive are the car running on, sent as in the drive (no frame skipped)
    health = rec.world.health()
    ecu = {k: v for k, v in health.items() if k.startswith("ecu:")}
    assert ecu and all(v["frames_skipped"] == 0 for v in ecu.values()), ecu
