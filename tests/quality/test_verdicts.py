"""Per-stream time-base verdicts computed from what a session file holds (rig.data.verdicts.session_verdicts)."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.core.quality import (
    MIN_STALL_S,
    STALL_FACTOR,
    THRESHOLDS,
    StreamQuality,
    Verdict,
    backward_steps,
    find_gaps,
    judge,
)
from rig.data import load_session
from rig.data.verdicts import session_verdicts

MS = 1_000_000
NS = 1_000_000_000


def verdicts(path: Path) -> dict[str, StreamQuality]:
    return session_verdicts(load_session(path))


def figure(q: StreamQuality, name: str) -> float:
    return next(f.value for f in q.figures if f.name == name)


def test_a_clean_session_is_good_on_every_stream(sessions: dict[str, Path]) -> None:
    v = verdicts(sessions["clean"])
    assert set(v) == {"gnss:rover_a", "gnss:rover_b", "can:vsc"}
    assert {q.verdict for q in v.values()} == {Verdict.GOOD}, [q.message() for q in v.values()]
    assert figure(v["can:vsc"], "timing_error_ms") < 1.0
    assert figure(v["gnss:rover_a"], "host_map_error_ms") < 1.0
    assert all(not q.gaps for q in v.values())


def test_a_starved_interface_stamped_reader_is_unusable_with_its_figures_and_its_early_end(
    sessions: dict[str, Path],
) -> None:
    v = verdicts(sessions["starved_interface"])
    can = v["can:vsc"]
    assert can.verdict is Verdict.UNUSABLE
    # the backlog reached seconds: the bins' lowest frames sit that far above the envelope
    assert figure(can, "timing_error_ms") > 1000.0
    early = [g for g in can.gaps if g.kind == "ended_early"]
    assert len(early) == 1 and early[0].duration_s > 5.0
    assert figure(can, "missing_percent") > 10.0
    assert "timing error" in can.message() and "--speed 2" in can.message()
    # GNSS (on GPS time) sets the session's end; it is not judged by the late CAN stream
    assert v["gnss:rover_a"].verdict is Verdict.GOOD


def test_a_starved_host_stamped_reader_is_unusable_and_the_fix_is_hardware_stamps(sessions: dict[str, Path]) -> None:
    can = verdicts(sessions["starved_host"])["can:vsc"]
    assert can.verdict is Verdict.UNUSABLE
    assert figure(can, "timing_error_ms") > 100.0
    assert "a CAN interface with hardware stamps" in can.message()
    assert "host stamps only" in can.note


def test_a_stall_is_a_gap_with_its_span_and_degrades_the_stream(sessions: dict[str, Path]) -> None:
    can = verdicts(sessions["stalled"])["can:vsc"]
    assert can.verdict is Verdict.DEGRADED
    (gap,) = can.gaps
    assert gap.kind == "stall" and gap.topic == "/can/vsc/frames"
    assert gap.duration_s == pytest.approx(0.52, abs=0.03)  # 3.0 … 3.5 s without the frames at its ends
    assert 0.0 < figure(can, "missing_percent") < 5.0
    assert figure(can, "timing_error_ms") < 1.0  # frames lost are not frames late


def test_ms_of_host_jitter_degrade_but_do_not_refuse(sessions: dict[str, Path]) -> None:
    can = verdicts(sessions["jittery"])["can:vsc"]
    assert can.verdict is Verdict.DEGRADED
    assert 1.0 < figure(can, "timing_error_ms") < 5.0


def test_backward_steps_in_file_order() -> None:
    assert backward_steps([0, 10 * MS, 5 * MS, 20 * MS, 2 * MS]) == (2, 18.0)
    assert backward_steps([1, 1, 2]) == (0, 0.0)


def test_gaps_stall_threshold_and_early_end() -> None:
    t = list(range(0, 10 * NS, 50 * MS))  # 20 Hz for 10 s …
    t = [x for x in t if not 4 * NS < x < 4 * NS + 550 * MS]  # … silent for 0.55 s: > 10 periods and > 0.25 s
    gaps = find_gaps("gnss:x", "/gnss/x/bestpos", t, session_end_ns=12 * NS)
    assert [(g.kind, g.start_ns, g.end_ns) for g in gaps] == [
        ("stall", 4 * NS, 4 * NS + 550 * MS), ("ended_early", t[-1], 12 * NS)]
    # a silence under the threshold is not a stall; an end within END_TOLERANCE_S is not early
    short = [x for x in range(0, 10 * NS, 50 * MS) if not 4 * NS < x < 4 * NS + 450 * MS]  # 0.45 s < 10 periods
    assert find_gaps("gnss:x", "/gnss/x/bestpos", short, session_end_ns=short[-1] + NS // 2) == []
    assert STALL_FACTOR * 50 * MS / NS >= MIN_STALL_S  # at 20 Hz the period rule decides


def test_thresholds_are_in_one_table_with_their_rationale() -> None:
    for name, th in THRESHOLDS.items():
        assert th.figure == name and th.why
        assert th.unusable_above is None or th.unusable_above > th.degraded_above
    t = THRESHOLDS["timing_error_ms"]
    assert judge("timing_error_ms", t.degraded_above, "").verdict is Verdict.GOOD
    assert judge("timing_error_ms", t.degraded_above * 1.01, "").verdict is Verdict.DEGRADED
    assert t.unusable_above is not None
    assert judge("timing_error_ms", t.unusable_above * 1.01, "").verdict is Verdict.UNUSABLE
