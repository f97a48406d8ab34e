"""``rig export``: raw GNSS streams byte-exact across parts, re-framed into exactly the logs sent; CSV tables."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.novatel import FrameKind, Framer
from rig.cli.main import app
from rig.export.csv import export_csv
from rig.export.files import ExportKind, ExportReport
from rig.export.raw_gnss import export_raw_gnss
from rig.store import find_parts, scan_part
from tests.inspect.synth import RECEIVERS, U0, Synth
from vsccore.errors import AnalysisError, SessionFileError

runner = CliRunner()


def _frames(data: bytes) -> tuple[list[tuple[FrameKind, bytes]], Framer]:
    """Frame ``data`` fed in awkward 777-byte pieces (the framer reassembles across them)."""
    fr = Framer(decode_nmea=False)
    out = []
    for i in range(0, len(data), 777):
        out += [(f.kind, f.raw) for f in fr.feed(data[i : i + 777])]
    out += [(f.kind, f.raw) for f in fr.finish()]
    return out, fr


@pytest.fixture(scope="module")
def exported(synth: Synth, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ExportReport]:
    out = tmp_path_factory.mktemp("export")
    return out, export_raw_gnss(synth.base, out)


def test_raw_streams_are_byte_exact(synth: Synth, exported: tuple[Path, ExportReport]) -> None:
    out, report = exported
    files = {f.path.name: f for f in report.files}
    assert set(files) == {"rover_a.gps", "rover_b.gps", "corrections.rtcm3"}
    assert not report.warnings
    for rx in RECEIVERS:
        data = (out / f"{rx}.gps").read_bytes()
        assert data == b"".join(synth.reads[rx])
        f = files[f"{rx}.gps"]
        assert (f.kind, f.source, f.bytes, f.records, f.sequence_breaks) == (
            ExportKind.GNSS_RAW, T.gnss_raw(rx), len(data), len(synth.reads[rx]), 0)
        assert (f.first_ns, f.last_ns) == (synth.read_times[rx][0], synth.read_times[rx][-1])
        # modification time = log time of the first bytes (RTKLIB takes the week of RTCM data from it)
        assert os.stat(out / f"{rx}.gps").st_mtime_ns == synth.read_times[rx][0]
    corr = (out / "corrections.rtcm3").read_bytes()
    assert corr == b"".join(synth.reads["relay"]) == b"".join(synth.rtcm)
    assert files["corrections.rtcm3"].kind is ExportKind.CORRECTIONS
    assert report.total_bytes == sum(len(b"".join(v)) for v in synth.reads.values())


def test_exported_streams_reframe_into_exactly_the_logs_sent(synth: Synth, exported: tuple[Path, ExportReport]) -> None:
    out, _report = exported
    for rx in RECEIVERS:
        frames, fr = _frames((out / f"{rx}.gps").read_bytes())
        assert [raw for _k, raw in frames] == synth.frames[rx]
        kinds = {k for k, _raw in frames}
        assert kinds == {FrameKind.NOVATEL_BINARY, FrameKind.NOVATEL_ASCII}
        assert fr.stats.total_skipped == 0 and fr.stats.truncated == 0 and fr.stats.crc_failures[
            FrameKind.NOVATEL_BINARY] == 0
    frames, fr = _frames((out / "corrections.rtcm3").read_bytes())
    assert [raw for _k, raw in frames] == synth.rtcm and fr.stats.total_skipped == 0


def test_no_bytes_lost_where_a_frame_straddles_a_part_boundary(synth: Synth, exported: tuple[Path, ExportReport]
                                                               ) -> None:
    """A receiver's stream is split over parts in the middle of a frame, and its export still re-frames whole."""
    straddling = []
    for rx in RECEIVERS:
        topic = T.gnss_raw(rx)
        sizes = []
        for p in find_parts(synth.base):
            tm = scan_part(p, want={topic}.__contains__).topics.get(topic)
            sizes.append(sum(map(len, tm.data)) if tm is not None else 0)
        ends = set(np.cumsum([len(f) + (2 if f.startswith(b"#") else 0) for f in synth.frames[rx]]).tolist())
        straddling += [(rx, int(b)) for b in np.cumsum(sizes)[:-1] if 0 < b < sum(sizes) and int(b) not in ends]
    assert straddling, "the test session should cut a frame at a part boundary"
    out, _report = exported
    for rx, _offset in straddling:
        frames, _fr = _frames((out / f"{rx}.gps").read_bytes())
        assert [raw for _k, raw in frames] == synth.frames[rx]


def test_existing_files_are_kept_and_nothing_partial_is_left(synth: Synth, exported: tuple[Path, ExportReport]) -> None:
    out, _report = exported
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(SessionFileError, match=r"rover_a\.gps already exists"):
        export_raw_gnss(synth.base, out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # untouched, no .partial files
    again = export_raw_gnss(synth.base, out, overwrite=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and len(again.files) == 3


def test_truncated_session_exports_what_was_recorded(synth: Synth, truncated: tuple[Path, Path], tmp_path: Path
                                                    ) -> None:
    base, _original = truncated
    report = export_raw_gnss(base, tmp_path)
    assert len(report.warnings) == 1 and "exported up to its last complete record" in report.warnings[0]
    expected: dict[str, bytes] = {}
    for p in find_parts(base):
        scan = scan_part(p, want=lambda t: t.endswith("/raw"))
        for topic, tm in scan.topics.items():
            expected[topic] = expected.get(topic, b"") + b"".join(tm.data)
    got = {f.source: f.path.read_bytes() for f in report.files}
    assert got == {k: v for k, v in expected.items() if v}
    full = {T.gnss_raw(rx): b"".join(synth.reads[rx]) for rx in RECEIVERS} | {
        T.TOPIC_RELAY_RAW: b"".join(synth.reads["relay"])}
    assert all(full[k].startswith(v) for k, v in got.items())  # a prefix of what was sent
    assert any(len(v) < len(full[k]) for k, v in got.items())  # and the cut lost something
    assert all(f.sequence_breaks == 0 for f in report.files)


def test_session_without_raw_streams(tmp_path: Path) -> None:
    from rig.store import Recorder, RecorderOptions

    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0)
    with Recorder(tmp_path, "decoded_only", options=opts) as rec:
        rec.source("x").put(T.TOPIC_RELAY_STATS, U0, U0, {"bytes_in": 0, "frames_in": 0, "crc_errors": 0})
    with pytest.raises(AnalysisError, match="no raw GNSS"):
        export_raw_gnss(tmp_path / "decoded_only", tmp_path / "out")


def test_cli_export_prints_what_was_written(synth: Synth, tmp_path: Path) -> None:
    res = runner.invoke(app, ["export", str(find_parts(synth.base)[0]), "--raw-gnss", str(tmp_path / "raw")])
    assert res.exit_code == 0, res.output
    for rx in RECEIVERS:
        assert f"{rx}.gps  {len(b''.join(synth.reads[rx]))} bytes" in res.output
    assert f"corrections.rtcm3  {len(b''.join(synth.rtcm))} bytes" in res.output
    assert "convbin -r nov" in res.output
    res = runner.invoke(app, ["export", str(synth.base)])
    assert res.exit_code != 0


def test_csv_tables(synth: Synth, tmp_path: Path) -> None:
    report = export_csv(synth.base, tmp_path)
    names = {f.path.name for f in report.files}
    assert names == {"gnss_rover_a_bestpos.csv", "gnss_rover_b_bestpos.csv", "events.csv"}
    with open(tmp_path / "gnss_rover_b_bestpos.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["time_ns"]) for r in rows] == synth.bestpos_times["rover_b"]
    assert all(r["valid"] == "1" and r["sol_status"] == "SOL_COMPUTED" for r in rows)
    assert float(rows[1]["lat_deg"]) == pytest.approx(48.7 + 1e-7, abs=1e-12)
    with open(tmp_path / "events.csv", newline="") as f:
        kinds = [r["kind"] for r in csv.DictReader(f)]
    assert kinds.count("disconnect") == 1 and kinds.count("mark") == 1


def test_sequence_break_is_reported(tmp_path: Path) -> None:
    """A raw stream whose sequence numbers skip one (a read lost before the file) is exported and flagged."""
    from mcap.writer import Writer

    spec = T.spec_for_topic(T.gnss_raw("rx"))[0].schema
    with open(tmp_path / "hand.mcap", "wb") as stream:
        w = Writer(stream)
        w.start()
        sid = w.register_schema(spec.name, spec.schema_encoding, spec.data)
        cid = w.register_channel(T.gnss_raw("rx"), spec.message_encoding, sid)
        for seq, chunk in ((0, b"ab"), (1, b"cd"), (3, b"ef")):
            w.add_message(cid, U0 + seq, chunk, U0 + seq, sequence=seq)
        w.finish()
    report = export_raw_gnss(tmp_path / "hand.mcap", tmp_path / "out")
    (exp,) = report.files
    assert exp.path.read_bytes() == b"abcdef" and exp.sequence_breaks == 1
    assert report.warnings == (f"{T.gnss_raw('rx')}: sequence numbers break 1 times (reads lost or repeated)",)


def test_csv_can_roles_from_the_attached_dbc(tmp_path: Path) -> None:
    from tests.dataset.synth import utc
    from tests.dataset.synth import write_session as write_dataset_session

    ds = write_dataset_session(tmp_path, duration_s=6.0)
    export_csv(ds.base, tmp_path / "csv")
    with open(tmp_path / "csv" / "can_can0_roles.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["role"] == "yaw_rate"]
    assert len(rows) == ds.can_t_gps.size and all(r["unit"] == "rad/s" and r["ok"] == "1" for r in rows)
    t = np.asarray([int(r["time_ns"]) for r in rows])
    assert np.max(np.abs(t - utc(ds.can_t_gps))) < 1_000_000  # interface clock → host → GPS within 1 ms
    v = np.asarray([float(r["value"]) for r in rows])
    assert np.max(np.abs(v - ds.yaw_rate)) < 1e-3  # DBC resolution


def test_csv_streams_the_can_roles_and_optical_samples(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The bulk goes out batch by batch: rig.data is asked only for the GNSS logs and events (was: the whole
    session, every CAN frame and DAQ block, in memory), and small batches give the same files as one batch
    (counter checks run on across batches); the role values equal rig.data's whole-bus decode."""
    import rig.data
    from tests.dataset.synth import write_session as write_dataset_session

    ds = write_dataset_session(tmp_path, duration_s=6.0)
    asked: list[list[str] | None] = []
    real = rig.data.load_session

    def spy(path: Path | str, **kw: Any) -> rig.data.Session:
        asked.append(sorted(kw["topics"]) if kw.get("topics") is not None else None)
        return real(path, **kw)

    monkeypatch.setattr(rig.data, "load_session", spy)
    one = export_csv(ds.base, tmp_path / "one", chunk_rows=1 << 30)
    small = export_csv(ds.base, tmp_path / "small", chunk_rows=64)
    assert asked and all(a is not None and all(t.startswith("/gnss/") or t == T.TOPIC_EVENTS for t in a)
                         for a in asked)
    assert sorted(f.path.name for f in one.files) == sorted(f.path.name for f in small.files)
    for f in one.files:
        assert f.path.read_bytes() == (tmp_path / "small" / f.path.name).read_bytes(), f.path.name
    with open(tmp_path / "small" / "can_can0_roles.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    ref = real(ds.base).can_roles("can0")
    for role, s in ref.items():
        got = [r for r in rows if r["role"] == role]
        assert len(got) == len(s) and [r["ok"] == "1" for r in got] == s.ok.tolist()
        v = np.asarray([float(r["value"]) if r["value"] else np.nan for r in got])
        assert np.array_equal(v, s.values, equal_nan=True)


def test_raw_export_over_a_damaged_chunk_carries_on(synth: Synth, tmp_path: Path) -> None:
    """A bit flip in a chunk of raw reads: every intact chunk's bytes are exported, the damage is named and the
    lost reads show as a sequence break (was: SessionFileError for the whole export)."""
    import shutil

    from mcap.reader import make_reader

    parts = find_parts(synth.base)
    rx_topic = T.gnss_raw("rover_a")
    holding = []  # (part, chunk number, chunk index) of every chunk with rover A's reads, in recording order
    for p in parts:
        shutil.copy(p, tmp_path / p.name)
        with open(p, "rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None
        holding += [(p, i, ci) for i, ci in enumerate(summary.chunk_indexes)
                    if any(summary.channels[c].topic == rx_topic for c in ci.message_index_offsets)]
    part, k, ci = holding[1]  # reads before and after it (the writer thread decides how chunks fall)
    damaged = tmp_path / part.name
    raw = bytearray(damaged.read_bytes())
    raw[ci.chunk_start_offset + ci.chunk_length - 30] ^= 0x10
    damaged.write_bytes(bytes(raw))
    base = tmp_path / synth.base.name
    report = export_raw_gnss(base, tmp_path / "out")
    assert any(f"damaged chunk {k} " in w and rx_topic in w for w in report.warnings), report.warnings
    # a part whose only chunk of rover A's reads is the damaged one has none left (how chunks fall varies)
    kept = [scan_part(p, want=rx_topic.__eq__).topics.get(rx_topic) for p in find_parts(base)]
    expected = b"".join(d for tm in kept if tm is not None for d in tm.data)
    got = (tmp_path / "out" / "rover_a.gps").read_bytes()
    assert got == expected and len(got) < len(b"".join(synth.reads["rover_a"]))
    (f,) = [f for f in report.files if f.source == rx_topic]
    assert f.sequence_breaks >= 1 and any("sequence numbers break" in w for w in report.warnings)
