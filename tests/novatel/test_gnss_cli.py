"""``rig gnss decode``: one JSON object per message plus a summary, from a file or stdin."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from drivers.novatel import FrameKind
from rig.cli.main import app, main
from tests.novatel.gen import mixed_stream

runner = CliRunner()
MIXED = mixed_stream()
GARBAGE = b"\x01\x02noise"
CAPTURE = GARBAGE + b"".join(wire for _, wire, _ in MIXED)


def _lines(output: str) -> list[dict[str, Any]]:
    return [json.loads(line) for line in output.splitlines() if line.strip()]


def _check(objects: list[dict[str, Any]]) -> None:
    *frames, summary = objects
    assert [o["kind"] for o in frames] == [kind.value for kind, _, _ in MIXED]
    assert summary["kind"] == "summary"
    assert summary["total_frames"] == len(MIXED)
    assert summary["bytes_skipped"] == {"garbage": len(GARBAGE)}
    assert summary["frames"]["response"] == 2
    assert summary["bytes_in"] == len(CAPTURE)
    binary = frames[[k for k, _, _ in MIXED].index(FrameKind.NOVATEL_BINARY)]
    assert binary["type"] == "BESTPOS"
    assert binary["header"]["week"] == 2300
    assert binary["header"]["gps_ns"] == (2300 * 604_800 + 345_600) * 10**9 + 50_000_000
    assert binary["body"]["pos_type"] == "NARROW_INT"
    assert binary["body"]["lat_deg"] == pytest.approx(48.1173, abs=1e-12)
    rtcm = frames[[k for k, _, _ in MIXED].index(FrameKind.RTCM3)]
    assert rtcm["message_number"] == 1005
    assert rtcm["fields"]["DF003"] == 2003
    nmea = frames[[k for k, _, _ in MIXED].index(FrameKind.NMEA)]
    assert nmea["type"] == "GGA" and nmea["fields"]["num_sats"] == "12"
    error = [o for o in frames if o["kind"] == "response" and not o["ok"]]
    assert error == [{"kind": "response", "ok": False, "text": "Invalid Message ID"}]


def test_decode_file(tmp_path: Path) -> None:
    capture = tmp_path / "rover_a.raw"
    capture.write_bytes(CAPTURE)
    result = runner.invoke(app, ["gnss", "decode", str(capture)])
    assert result.exit_code == 0, result.output
    _check(_lines(result.stdout))


def test_decode_stdin() -> None:
    result = runner.invoke(app, ["gnss", "decode", "-"], input=CAPTURE)
    assert result.exit_code == 0, result.output
    _check(_lines(result.stdout))


def test_summary_only_counts_crc_failures(tmp_path: Path) -> None:
    kind, wire, raw = next(m for m in MIXED if m[0] is FrameKind.NOVATEL_BINARY)
    bad = bytearray(raw)
    bad[40] ^= 0x10
    capture = tmp_path / "bad.raw"
    capture.write_bytes(bytes(bad) + wire)
    result = runner.invoke(app, ["gnss", "decode", "--summary-only", str(capture)])
    assert result.exit_code == 0, result.output
    (summary,) = _lines(result.stdout)
    assert summary["frames"] == {kind.value: 1}
    assert summary["crc_failures"] == {kind.value: 1}
    assert summary["bytes_skipped"] == {"crc_failure": len(raw)}


def test_vectors_decode_through_the_cli(shared_dir: Path) -> None:
    result = runner.invoke(app, ["gnss", "decode", str(shared_dir / "vectors/novatel/ascii_logs.txt")])
    assert result.exit_code == 0, result.output
    *frames, summary = _lines(result.stdout)
    assert {f["type"] for f in frames} == {"BESTPOS", "BESTVEL", "HEADING2", "TIME"}
    times = [f for f in frames if f["type"] == "TIME"]
    assert [t["body"]["leap_seconds"] for t in times] == [16, 18]
    assert summary["crc_failures"] == {}


def test_missing_file_is_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nope.raw"
    with pytest.raises(SystemExit) as excinfo:
        main(["gnss", "decode", str(missing)])
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("rig: error: ") and str(missing) in err
