"""The recorder keeps log_time monotonic per channel (clamps counted and reported) and records stalls as gaps."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import rig.topics as T  # noqa: N812 - short alias
from rig.recorder import Recorder, find_parts, scan_part
from rig.topics import Event, EventKind
from tests.recorder.helpers import T0, ManualClock, options

MS = 1_000_000
NS = 1_000_000_000
POS = T.gnss_bestpos("rover_a")


def _pos(k: int) -> dict[str, object]:
    return {"gps_time_ns": k, "time_status": "FINESTEERING", "sol_status": "SOL_COMPUTED", "pos_type": "NARROW_INT",
            "lat_deg": 48.0, "lon_deg": 9.0, "height_msl_m": 300.0, "lat_std_m": 0.01, "lon_std_m": 0.01,
            "height_std_m": 0.02, "diff_age_s": None}


def _read(base: Path) -> tuple[dict[str, list[int]], list[tuple[int, Event]]]:
    times: dict[str, list[int]] = {}
    events: list[tuple[int, Event]] = []
    for p in find_parts(base):
        scan = scan_part(p)
        for topic, tm in scan.topics.items():
            times.setdefault(topic, []).extend(tm.log_time)
            if topic == T.TOPIC_EVENTS:
                events += [(t, Event.from_json(json.loads(d))) for t, d in zip(tm.log_time, tm.data, strict=True)]
    return times, events


def test_a_message_whose_log_time_runs_back_is_clamped_counted_and_reported(tmp_path: Path) -> None:
    clock = ManualClock()
    with Recorder(tmp_path, "run", {}, options=options(), clock=clock) as rec:
        src = rec.source("rover_a")
        t = [T0 + k * 50 * MS for k in range(10)]
        t[6] = t[5] - 408 * MS  # the first TIME replaced a host estimate: 408 ms back (issue 15)
        for k, tk in enumerate(t):
            assert src.put(POS, tk, T0 + k, _pos(k))
        (timing,) = [c for c in rec.channel_timings() if c.topic == POS]
    times, events = _read(tmp_path / "run")
    got = times[POS]
    assert all(b >= a for a, b in zip(got, got[1:], strict=False)), got  # old code: 408 ms back in the file
    assert got[6] == t[5] and len(got) == 10  # nothing lost: written at the channel's last log_time
    assert (timing.clamped, timing.clamp_max_ns) == (1, 408 * MS)
    (ev,) = [e for _t, e in events if e.kind is EventKind.TIMEBASE and e.details.get("topic") == POS]
    assert ev.details["clamped"] == 1 and ev.details["step_back_ns"] == 408 * MS and ev.source == "rover_a"


def test_events_from_several_threads_and_the_writer_stay_monotonic(tmp_path: Path) -> None:
    clock = ManualClock()
    with Recorder(tmp_path, "run", {}, options=options(), clock=clock) as rec:
        barrier = threading.Barrier(4)

        def emit(i: int) -> None:
            barrier.wait(5.0)
            for k in range(200):
                # late events carry an older log time than ones already queued (a gap reported at its start)
                rec.event(EventKind.INFO, f"{i}:{k}", log_time_ns=T0 + (k * 7 + i * 13) % 1000 * MS)

        threads = [threading.Thread(target=emit, args=(i,)) for i in range(4)]
        for th in threads:
            th.start()
        for th in threads:
            th.join(10.0)
    times, _events = _read(tmp_path / "run")
    ev = times[T.TOPIC_EVENTS]
    assert len(ev) >= 800
    assert all(b >= a for a, b in zip(ev, ev[1:], strict=False))


def test_a_stall_longer_than_k_periods_is_a_gap_event_with_its_span(tmp_path: Path) -> None:
    clock = ManualClock()
    with Recorder(tmp_path, "run", {}, options=options(), clock=clock) as rec:
        src = rec.source("rover_a")
        t = [T0 + k * 50 * MS for k in range(100)]                # 20 Hz for 5 s: the period is learnt
        t += [t[-1] + 2 * NS + k * 50 * MS for k in range(20)]    # then 2 s of silence, then on
        for k, tk in enumerate(t):
            src.put(POS, tk, T0 + k, _pos(k))
        (timing,) = [c for c in rec.channel_timings() if c.topic == POS]
        assert timing.period_ns == 50 * MS
        # while silent, the channel is late; a live dashboard asks this
        assert timing.late_ns(t[-1] + NS) == NS
        assert timing.late_ns(t[-1] + 100 * MS) is None
    _times, events = _read(tmp_path / "run")
    (gap,) = [e for _t, e in events if e.kind is EventKind.GAP]
    assert (gap.start_ns, gap.end_ns) == (t[99], t[100])  # old code: no event
    assert gap.details["topic"] == POS and gap.details["gap"] == "stall" and gap.source == "rover_a"
    assert (timing.stalls, timing.stalled_ns) == (1, t[100] - t[99])
