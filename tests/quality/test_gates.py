"""Every result that uses a stream checks its time-base verdict: degraded → a headline warning, unusable →
exit status 2 naming the stream, the figure and the fix."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rig.core.quality import Figure, StreamQuality, TimingQualityError, Verdict, gate, judge
from rig.data.info import format_info, info_to_json, read_session_info
from tests.calib_cli.synth import run_cli


def _q(stream: str, value_ms: float) -> StreamQuality:
    return StreamQuality(stream, (judge("timing_error_ms", value_ms, "record at --speed 2"),))


def test_gate_refuses_unusable_warns_degraded_and_skips_unknown_streams() -> None:
    v = {"can:vsc": _q("can:vsc", 240.0), "gnss:rover_a": _q("gnss:rover_a", 2.0), "can:body": _q("can:body", 0.1)}
    with pytest.raises(TimingQualityError) as ei:
        gate(v, ["gnss:rover_a", "can:vsc"], what="rig validate s1")
    msg = str(ei.value)
    assert "rig validate s1" in msg and "can:vsc unusable" in msg and "timing error 240 ms" in msg
    assert "unusable > 5 ms" in msg and "fix: record at --speed 2" in msg
    assert isinstance(ei.value, ValueError)  # an AnalysisError: the CLI's exit status 2
    warnings = gate(v, ["gnss:rover_a", "can:body", "daq:none"], what="x")
    expected = ("TIMING DEGRADED — gnss:rover_a degraded: timing error 2 ms (degraded > 1, unusable > 5 ms); "
                "fix: record at --speed 2")
    assert warnings == (expected,)
    assert gate(v, ["can:body"], what="x") == ()
    assert isinstance(v["can:body"].figures[0], Figure) and v["can:body"].verdict is Verdict.GOOD


@pytest.mark.parametrize("command", [
    ["validate", "--no-progress"],
    ["rollover"],
    ["steering", "reconstruct"],
    ["calibrate-baseline", "--no-record"],
    ["calibrate-steering-ratio", "--no-record"],
])
def test_every_command_exits_2_on_a_starved_can_stream_naming_it(
    sessions: dict[str, Path], command: list[str], capsys: pytest.CaptureFixture[str],
) -> None:
    assert run_cli([*command, str(sessions["starved_interface"])]) == 2
    err = capsys.readouterr().err
    assert "refused, time base unusable" in err and "can:vsc unusable" in err, err
    assert "timing error" in err and "--speed 2" in err


def test_a_degraded_stream_heads_the_calibration_output_and_its_json(
    sessions: dict[str, Path], capsys: pytest.CaptureFixture[str],
) -> None:
    assert run_cli(["calibrate-baseline", "--no-record", str(sessions["jittery"])]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith("TIMING DEGRADED — can:vsc degraded: timing error")
    assert run_cli(["calibrate-baseline", "--no-record", "--json", str(sessions["jittery"])]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["warnings"][0].startswith("TIMING DEGRADED — can:vsc degraded")


def test_a_clean_session_passes_the_gate_without_a_warning(
    sessions: dict[str, Path], capsys: pytest.CaptureFixture[str],
) -> None:
    assert run_cli(["calibrate-baseline", "--no-record", str(sessions["clean"])]) == 0
    assert "TIMING" not in capsys.readouterr().out


def test_rig_info_shows_the_verdicts(sessions: dict[str, Path]) -> None:
    info = read_session_info(sessions["starved_interface"])
    text = format_info(info)
    block = text[text.index("time-base verdicts"):]
    assert "can:vsc" in block and "UNUSABLE" in block and "ended early" in block
    assert "gnss:rover_a     GOOD" in block
    doc = info_to_json(info)["timebase"]["verdicts"]
    assert doc["problem"] is None
    assert doc["streams"]["can:vsc"]["verdict"] == "unusable"
    assert doc["streams"]["can:vsc"]["figures"]["timing_error_ms"]["unusable_above"] == 5.0


def test_a_degraded_stream_is_in_the_validation_headline_report_and_json(
    sessions: dict[str, Path], tmp_path: Path,
) -> None:
    from rig.evaluate.report import write_validation_report
    from rig.evaluate.validate import validate_session, validation_lines

    sv = validate_session(sessions["jittery"], estimator="tests.quality.estimators:zero")
    (w,) = sv.timing_warnings
    assert w.startswith("TIMING DEGRADED — can:vsc degraded: timing error")
    assert validation_lines(sv)[1] == w  # right under the session line, before any figure
    doc = sv.to_dict()
    assert doc["timing_warnings"] == [w]
    assert doc["time_base"]["can:vsc"]["verdict"] == "degraded"
    html = write_validation_report(sv, tmp_path / "report").html.read_text(encoding="utf-8")
    head = html[html.index("class='verdict"): html.index("<ul>")]
    assert "class='timing'" in head and "can:vsc degraded" in head
    assert "Time base of the streams used" in html
