"""The recorder keeps log_time monotonic per channel (clamps counted and reported) and records stalls as gaps."""

from __future__ import annotations

import json
from pathlib import Path

import rig.core.topics as T  # noqa: N812 - short alias
from rig.core.topics import Event, EventKind
from rig.store import Recorder, find_parts, scan_part
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


def test_events_keep_the_time_they_are_about(tmp_path: Path) -> None:
    """/rig/events is exempt from the clamp: a mark's log_time is its key press, even after later events."""
    clock = ManualClock()
    with Recorder(tmp_path, "run", {}, options=options(), clock=clock) as rec:
        src = rec.source("rover_a")
        for k in range(10):
            src.put(POS, T0 + k * 50 * MS, T0 + k, _pos(k))
        rec.event(EventKind.INFO, "later", log_time_ns=T0 + 2 * NS)
        rec.event(EventKind.MARK, "pressed earlier", log_time_ns=T0 + NS)
        timings = {c.topic: c for c in rec.channel_timings()}
    _times, events = _read(tmp_path / "run")
    (mark,) = [(t, e) for t, e in events if e.kind is EventKind.MARK]
    assert mark[0] == T0 + NS
    assert timings[T.TOPIC_EVENTS].clamped == 0


def test_a_stall_longer_than_k_periods_is_kept_with_its_span(tmp_path: Path) -> None:
    clock = ManualClock()
    with Recorder(tmp_path, "run", {}, options=options(), clock=clock) as rec:
        src = rec.source("rover_a")
        t = [T0 + k * 50 * MS for k in range(100)]                # 20 Hz for 5 s: the period is learnt
        t += [t[-1] + 2 * NS + k * 50 * MS for k in range(20)]    # then 2 s of silence, then on
        for k, tk in enumerate(t):
            src.put(POS, tk, T0 + k, _pos(k))
        src.gap(T0 - 10 * NS, T0 - 9 * NS, "port lost")           # what the device reported itself
        (timing,) = [c for c in rec.channel_timings() if c.topic == POS]
        assert timing.period_ns == 50 * MS
        # while silent, the channel is late; a live dashboard asks this
        assert timing.late_ns(t[-1] + NS) == NS
        assert timing.late_ns(t[-1] + 100 * MS) is None
    assert (timing.stalls, timing.stalled_ns) == (1, t[100] - t[99])
    assert timing.stall_spans == ((t[99], t[100]),)  # old code: nothing
    assert timing.source == "rover_a" and timing.source_gaps == ((T0 - 10 * NS, T0 - 9 * NS),)
