"""``rig info``: the session summary against the synthetic session's known content and an independent count."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

import rig.core.topics as T  # noqa: N812 - short alias
import rig.data.info as inspect_mod
import rig.store.parts as parts_mod
from rig.cli.main import app, main
from rig.data.info import INFO_JSON_KEYS, ReadVia, format_info, info_to_json, read_session_info
from rig.store import ProblemKind, Recorder, RecorderOptions, find_parts, recover, scan_part
from tests.inspect.synth import CALIBRATION, CLOCKS, DT, GAP_EPOCHS, U0, Synth
from vsccore.errors import SessionFileError

runner = CliRunner()


def _independent_counts(base: Path) -> dict[str, int]:
    """Messages per topic counted by the recorder's own scanner (every chunk decompressed)."""
    counts: dict[str, int] = {}
    for p in find_parts(base):
        s = scan_part(p, collect=False)
        for cid, n in s.channel_counts.items():
            counts[s.channels[cid].topic] = counts.get(s.channels[cid].topic, 0) + n
    return counts


def test_counts_rates_and_span(synth: Synth) -> None:
    info = read_session_info(synth.base)
    parts = find_parts(synth.base)
    assert len(info.parts) == len(parts) >= 3
    assert all(p.finalized and p.read_via is ReadVia.SUMMARY and p.problem is None for p in info.parts)
    assert [p.end_reason for p in info.parts] == ["rollover (size)"] * (len(parts) - 1) + ["stop"]
    assert not info.truncated and not info.warnings
    counts = _independent_counts(synth.base)
    assert {t.topic: t.messages for t in info.topics} == counts
    assert info.messages == sum(counts.values()) == sum(p.messages for p in info.parts)
    # known content
    n = synth.epochs
    assert info.topic(T.gnss_bestpos("rover_a")).messages == n
    assert info.topic(T.gnss_bestpos("rover_b")).messages == n - (GAP_EPOCHS[1] - GAP_EPOCHS[0])
    assert info.topic(T.gnss_raw("rover_a")).messages == len(synth.reads["rover_a"])
    assert info.topic(T.TOPIC_RELAY_RAW).messages == len(synth.reads["relay"])
    assert info.topic(T.TOPIC_TIMEBASE).messages == synth.timebase_count
    # time span: the first and last synthetic messages (the recorder's own events lie inside)
    assert info.start_ns == U0 == min(synth.all_times)
    assert info.end_ns == max(synth.all_times)
    assert info.duration_s == pytest.approx((max(synth.all_times) - U0) / 1e9, abs=1e-9)
    # 20 Hz exactly: (n − 1) intervals of 50 ms
    bp = info.topic(T.gnss_bestpos("rover_a"))
    assert bp.first_ns == U0 and bp.last_ns == U0 + (n - 1) * DT
    assert bp.rate_hz == pytest.approx(20.0, rel=1e-12)
    assert bp.typical_interval_s == pytest.approx(0.05, abs=1e-12)
    assert info.topic(T.TOPIC_RELAY_STATS).rate_hz == pytest.approx(1.0, rel=1e-12)


def test_gaps_found_only_where_data_stopped(synth: Synth) -> None:
    info = read_session_info(synth.base)
    gappy = {t.topic: t for t in info.topics if t.gap_count}
    assert set(gappy) == {T.gnss_bestpos("rover_b"), T.gnss_raw("rover_b")}
    bp = gappy[T.gnss_bestpos("rover_b")]
    assert bp.gap_count == 1 and bp.gaps[0].start_ns == synth.gap_start_ns and bp.gaps[0].end_ns == synth.gap_end_ns
    assert bp.gap_total_s == pytest.approx((GAP_EPOCHS[1] - GAP_EPOCHS[0] + 1) * 0.05, abs=1e-9)
    raw = gappy[T.gnss_raw("rover_b")]
    times = synth.read_times["rover_b"]
    before = max(t for t in times if t < synth.gap_end_ns)
    after = min(t for t in times if t >= synth.gap_end_ns)
    assert raw.gaps[0].start_ns == before and raw.gaps[0].end_ns == after
    # the bursty correction stream (a few reads once a second) is not taken for gappy
    relay = info.topic(T.TOPIC_RELAY_RAW)
    assert relay.typical_interval_s == pytest.approx(1.0, abs=0.05) and relay.gap_count == 0
    # event-like topics are not checked
    assert info.topic(T.TOPIC_EVENTS).gap_threshold_s is None
    # the device's own disconnect/connect events give a device gap
    (dg,) = info.device_gaps
    assert (dg.device, dg.kind.value, dg.start_ns, dg.end_ns, dg.open) == (
        "rover_b", "disconnect", *synth.disconnect, False)
    # a minimum gap above 2.05 s hides rover_b's
    assert read_session_info(synth.base, min_gap_s=3.0).topic(T.gnss_bestpos("rover_b")).gap_count == 0


def test_devices_timebase_calibration_events(synth: Synth) -> None:
    info = read_session_info(synth.base)
    devices = {d.name: d for d in info.devices}
    assert set(devices) == {"rover_a", "rover_b", "relay", "timebase"}
    a, b = devices["rover_a"], devices["rover_b"]
    assert (a.kind, a.topics) == ("gnss", (T.gnss_bestpos("rover_a"), T.gnss_raw("rover_a")))
    assert a.messages == a.written == synth.epochs + len(synth.reads["rover_a"])
    assert (a.errors, a.dropped, b.disconnects, b.connects, b.warnings) == (1, 0, 1, 1, 1)
    assert devices["relay"].kind == "relay" and devices["timebase"].written == synth.timebase_count
    # time base: the last record of every clock
    assert info.timebase_records == synth.timebase_count
    assert [c.clock for c in info.clocks] == list(CLOCKS)
    for c in info.clocks:
        last = synth.timebase_last[c.clock]
        assert (c.method, c.status, c.n, c.drift_ppm, c.jitter_ns, c.latency_p95_ns, c.rms_ns, c.leap_seconds) == (
            last["method"], last["status"], last["n"], last["drift_ppm"], last["jitter_ns"], last["latency_p95_ns"],
            last["rms_ns"], last["leap_seconds"])
        assert c.records == synth.timebase_count // len(CLOCKS)
    assert dict(info.calibration) == T.flatten_metadata(CALIBRATION)
    # events: the synthetic ones plus the recorder's start, stop and one rollover per new part
    expected = dict(synth.events, session_start=1, session_stop=1, rollover=len(info.parts) - 1)
    assert dict(info.events.by_kind) == dict(sorted(expected.items()))
    assert info.events.total == sum(expected.values()) == info.topic(T.TOPIC_EVENTS).messages
    assert [(e.kind, e.source) for e in info.events.problems] == [("error", "rover_a"), ("disconnect", "rover_b")]
    assert [e.text for e in info.events.marks] == ["operator mark: start of circle"]
    assert [(x.name, x.size_bytes) for x in info.attachments] == [("session.toml", 22)]
    assert info.recorder["software"] == "vsc-rig" and "part_index" not in info.recorder


def test_fast_path_agrees_with_full_scan(synth: Synth, monkeypatch: pytest.MonkeyPatch) -> None:
    fast = info_to_json(read_session_info(synth.base))

    def no_index(path: Path) -> None:
        raise parts_mod.NoIndexError("forced scan")

    monkeypatch.setattr(parts_mod, "_read_indexed", no_index)
    slow = info_to_json(read_session_info(synth.base))
    assert {p["read_via"] for p in slow["parts"]} == {"scan"}
    # only the scan checks chunk CRCs; --verify asks for it
    assert (fast["verified"], slow["verified"]) == (False, True)
    monkeypatch.undo()
    verified = info_to_json(read_session_info(synth.base, verify=True))
    for doc in (fast, slow, verified):
        doc.pop("verified")
        for p in doc["parts"]:
            p.pop("read_via")
    assert fast == slow == verified
    assert verified["damaged_chunks"] == 0


def test_recovered_copy_without_message_index_is_scanned(synth: Synth, tmp_path: Path) -> None:
    first = find_parts(synth.base)[0]
    copy = recover(first, tmp_path / "copy.mcap")
    assert copy.was_finalized
    info = read_session_info(copy.path)
    assert info.parts[0].read_via is ReadVia.SCAN  # the recovered summary has no message index offsets
    assert info.messages == scan_part(first, collect=False).message_count


def test_truncated_last_part(truncated: tuple[Path, Path]) -> None:
    base, original = truncated
    info = read_session_info(base)
    last = info.parts[-1]
    assert last.problem_kind is ProblemKind.TRUNCATED and not last.finalized and last.read_via is ReadVia.SCAN
    assert all(p.read_via is ReadVia.SUMMARY and p.finalized for p in info.parts[:-1])
    assert info.truncated and len(info.warnings) == 1 and "truncated" in info.warnings[0]
    assert last.path.name in info.warnings[0]
    assert {t.topic: t.messages for t in info.topics if t.messages} == {
        k: v for k, v in _independent_counts(base).items() if v}
    assert 0 < last.messages < scan_part(original, collect=False).message_count
    text = format_info(info)
    assert "TRUNCATED" in text and "warnings" in text


def test_json_keys_stable_and_documented(synth: Synth) -> None:
    doc = info_to_json(read_session_info(synth.base))
    assert tuple(doc) == INFO_JSON_KEYS
    documented = set(re.findall(r"``(\w+)``", inspect_mod.__doc__ or ""))
    gappy = next(t for t in doc["topics"] if t["gaps"])
    nested = {
        *doc, *doc["parts"][0], *doc["topics"][0], *gappy["gaps"][0], *doc["devices"][0],
        *doc["device_gaps"][0], *doc["timebase"], *doc["timebase"]["clocks"][0], *doc["events"],
        *doc["events"]["problems"][0], *doc["attachments"][0],
    }
    assert nested - documented == set()
    json.dumps(doc, allow_nan=False)  # strict JSON: no NaN


def test_text_report(synth: Synth) -> None:
    text = format_info(read_session_info(synth.base))
    for needle in ("session    run", "20.00 Hz", "/gnss/rover_b/bestpos", "1 (2.05 s)", "rover_b disconnect",
                   "gnss:rover_a", "lower_envelope", "gnss.mount_offset_deg   = 0.12", "operator mark",
                   "checksum burst", "session.toml"):
        assert needle in text, needle


def test_cli_info_text_json_and_errors(synth: Synth, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    part = find_parts(synth.base)[1]
    res = runner.invoke(app, ["info", str(part), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["format"] == "vsc-rig.info" and doc["version"] == 1 and len(doc["parts"]) == len(find_parts(synth.base))
    res = runner.invoke(app, ["info", str(synth.base)])
    assert res.exit_code == 0 and "time base" in res.output
    with pytest.raises(SystemExit) as exc:
        main(["info", str(tmp_path / "nothing")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("rig: error: ") and "nothing" in err
    bad = tmp_path / "bad.000.mcap"
    bad.write_bytes(b"not mcap at all")
    with pytest.raises(SessionFileError, match="not an MCAP"):
        read_session_info(bad)


def test_events_on_another_clock_do_not_stretch_the_span(tmp_path: Path) -> None:
    """Without a host → common time mapping the recorder's own events carry wall-clock times far from the data."""
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0)
    with Recorder(tmp_path, "s", options=opts) as rec:
        src = rec.source("relay")
        for k in range(10):
            src.put(T.TOPIC_RELAY_STATS, U0 + k * 10**9, U0, {"bytes_in": k, "frames_in": k, "crc_errors": 0})
    info = read_session_info(tmp_path / "s")
    assert (info.start_ns, info.end_ns, info.duration_s) == (U0, U0 + 9 * 10**9, 9.0)
    assert info.events.by_kind == {"session_start": 1, "session_stop": 1}
    (warning,) = info.warnings
    assert "2 events lie outside the recorded data" in warning


def test_damaged_message_index_falls_back_to_the_scan(synth: Synth, tmp_path: Path) -> None:
    from mcap.reader import make_reader

    src = find_parts(synth.base)[0]
    data = bytearray(src.read_bytes())
    with open(src, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    offset = next(off for ci in summary.chunk_indexes for off in ci.message_index_offsets.values())
    data[offset + 9] ^= 0xFF  # the channel id of a message index record (the scanner skips these records)
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    info = read_session_info(damaged)
    assert info.parts[0].read_via is ReadVia.SCAN
    assert info.messages == scan_part(src, collect=False).message_count
    # no record CRC covers a message index; the data section's CRC (DataEnd) does: damaged, nothing lost
    assert info.parts[0].problem is not None and "no message lost" in info.parts[0].problem


def test_calibration_results_file_in_text_and_json(synth: Synth, tmp_path: Path) -> None:
    """``rig calibrate-baseline`` writes ``<base>.calibration.json``; ``rig info`` shows what it holds."""
    from rig.data.sidefiles import calibration_file_path, update_calibration_file

    for p in find_parts(synth.base):
        shutil.copy(p, tmp_path / p.name)
    base = tmp_path / synth.base.name
    info = read_session_info(base)
    assert info.calibration_file is None and info_to_json(info)["calibration_file"] is None
    assert "(no calibration file" in format_info(info)
    mount = {"offset_deg": 0.352, "u95_deg": 0.041, "date": "2025-06-01", "session": base.name, "ci_low_deg": 0.311,
             "ci_high_deg": 0.393, "segments": [{"t_start_s": 12.0, "offset_deg": 0.35}], "warnings": []}
    update_calibration_file(base, "mount_offset", mount)
    path = update_calibration_file(base, "optical_zero", {"body": {"zero_deg": 0.25, "u95_deg": 0.02}})
    assert path == calibration_file_path(base) == tmp_path / f"{base.name}.calibration.json"

    info = read_session_info(find_parts(base)[1])  # any part finds it
    cf = info.calibration_file
    assert cf is not None and cf.path == path and cf.problem is None and not info.warnings
    assert cf.results["mount_offset"]["offset_deg"] == 0.352 and cf.results["optical_zero"]["body"]["zero_deg"] == 0.25
    doc = info_to_json(info)
    assert tuple(doc) == INFO_JSON_KEYS
    assert set(doc["calibration_file"]) <= set(re.findall(r"``(\w+)``", inspect_mod.__doc__ or ""))
    assert doc["calibration_file"]["path"] == str(path)
    assert doc["calibration_file"]["results"]["mount_offset"]["segments"] == mount["segments"]
    json.dumps(doc, allow_nan=False)
    text = format_info(info)
    assert f"calibration results ({path.name})" in text
    for needle in ("offset_deg = 0.352", "u95_deg = 0.041", "date = 2025-06-01", "warnings = []",
                   "body: zero_deg = 0.25, u95_deg = 0.02", "1 more field (see --json)"):  # the segments table
        assert needle in text, needle
    res = runner.invoke(app, ["info", str(base), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["calibration_file"]["results"]["mount_offset"]["u95_deg"] == 0.041
    res = runner.invoke(app, ["info", str(base)])
    assert res.exit_code == 0 and "offset_deg = 0.352" in res.output

    # a damaged file is reported, not raised
    path.write_text("{ not json", encoding="utf-8")
    info = read_session_info(base)
    assert info.calibration_file is not None and info.calibration_file.problem is not None
    assert any(path.name in w for w in info.warnings)
    assert "not a JSON calibration file" in format_info(info)
