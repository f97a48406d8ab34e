"""The recorder against mcap's own reader: contents, metadata, attachments, rollover, drops, disk faults."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

import rig.core.topics as T  # noqa: N812 - short alias used throughout the tests
from rig.core.topics import METADATA_PART_END, METADATA_RECORDER, METADATA_SESSION, Event, EventKind
from rig.store import Attachment, Recorder, find_parts, scan_part, session_metadata
from tests.recorder.helpers import T0, GatedFile, ManualClock, limited_opener, options, read_with_mcap
from tests.waiting import wait_until
from vsccore import __version__
from vsccore.errors import DiskFullError, SessionFileError


def _events(msgs: list[tuple[str, int, int, int, bytes]]) -> list[Event]:
    return [Event.from_json(T.decode_json(d)) for topic, _s, _l, _p, d in msgs if topic == T.TOPIC_EVENTS]


def test_mixed_session_reads_back_exactly_with_mcap_reader(tmp_path: Path) -> None:
    dbc = tmp_path / "car.dbc"
    dbc.write_text('VERSION ""\n')
    cfg = tmp_path / "session.toml"
    cfg.write_text("[output]\nname = 'x'\n")
    meta = session_metadata(
        session={"output": {"name": "x"}, "receivers": ["rover_a", "rover_b"]},
        vehicle={"name": "C-class", "wheelbase_m": 2.87},
        calibration={"mount_offset_deg": 0.12},
    )
    rng = np.random.default_rng(1)
    expected: list[tuple[str, int, int, bytes]] = []
    with Recorder(tmp_path, "run", meta, attachments=[Attachment.from_file(dbc), Attachment.from_file(cfg)],
                  options=options(validate_json=True)) as rec:
        gnss = rec.source("rover_a", 1000)
        can_src = rec.source("can0", 1000)
        daq = rec.source("daq", 1000)
        for i in range(50):
            t = T0 + i * 50_000_000
            raw = rng.integers(0, 256, 100, dtype=np.uint8).tobytes()
            assert gnss.put(T.gnss_raw("rover_a"), t, t + 1000, raw)
            expected.append((T.gnss_raw("rover_a"), t, t + 1000, raw))
            pos = {
                "gps_time": T.GPS_TIME.to_json(1_400_000_000_000_000_000 + i), "sol_status": "SOL_COMPUTED",
                "pos_type": "NARROW_INT",
                "lat_deg": 48.1 + i * 1e-6, "lon_deg": 9.2, "height_msl_m": 300.0, "lat_std_m": 0.01,
                "lon_std_m": 0.01, "height_std_m": 0.02,
            }
            assert gnss.put(T.gnss_bestpos("rover_a"), t, t + 2000, pos)
            expected.append((T.gnss_bestpos("rover_a"), t, t + 2000, T.encode_json(pos)))
            n = 10
            block = T.pack_can_columns(
                np.arange(n) + t, np.arange(n) + t + 5, np.full(n, 0x101 + i), np.full(n, 0x10), np.full(n, 8),
                np.full(n, 8), rng.integers(0, 256, (n, 8), dtype=np.uint8),
            )
            assert can_src.put(T.can_frames("can0"), t, t + 3000, block)
            expected.append((T.can_frames("can0"), t, t + 3000, block))
            samples = rng.normal(size=(8, 20)).astype(np.float32)
            dblock = T.pack_daq_block(T.DaqBlock(i * 20, 1000.0, tuple(f"ai{k}" for k in range(8)), samples))
            assert daq.put(T.daq_samples("dev1"), t, t + 4000, dblock)
            expected.append((T.daq_samples("dev1"), t, t + 4000, dblock))
        summary = rec.stop()
    assert summary.error is None and summary.finalized and summary.dropped == 0
    assert summary.parts == (tmp_path / "run.000.mcap",)
    msgs, mcap_summary = read_with_mcap(summary.parts[0])
    got = sorted((topic, lt, pt, d) for topic, _s, lt, pt, d in msgs if topic != T.TOPIC_EVENTS)
    assert got == sorted(expected)
    kinds = [e.kind for e in _events(msgs)]
    assert kinds[0] is EventKind.SESSION_START and kinds[-1] is EventKind.SESSION_STOP
    assert mcap_summary is not None
    assert mcap_summary.statistics.message_count == len(expected) + 2
    # each channel carries its schema from rig.core.topics
    by_topic = {c.topic: mcap_summary.schemas[c.schema_id] for c in mcap_summary.channels.values()}
    assert by_topic[T.can_frames("can0")].name == "vsc_rig.can.FrameBlock"
    assert by_topic[T.gnss_bestpos("rover_a")].encoding == T.JSON_SCHEMA_ENCODING
    # metadata and attachments
    scan = scan_part(summary.parts[0])
    md = scan.metadata_dict()
    assert md[METADATA_SESSION]["output.name"] == "x"
    assert md[METADATA_SESSION]["receivers"] == '["rover_a","rover_b"]'
    assert md[T.METADATA_VEHICLE]["wheelbase_m"] == "2.87"
    assert md[T.METADATA_CALIBRATION]["mount_offset_deg"] == "0.12"
    assert md[METADATA_RECORDER]["version"] == __version__
    assert md[METADATA_RECORDER]["host"]
    assert md[METADATA_PART_END]["reason"] == "stop"
    assert md[METADATA_PART_END]["source.rover_a.written"] == "100"
    atts = {a.name: a for a, _ref in scan.attachments}
    assert atts["car.dbc"].data == dbc.read_bytes() and atts["car.dbc"].media_type == "text/x-dbc"
    assert atts["session.toml"].data == cfg.read_bytes()


def test_rollover_loses_and_duplicates_nothing(tmp_path: Path) -> None:
    """Three producers flood while parts roll over by size: every (topic, sequence) exactly once."""
    n_per = 6000
    opts = options(chunk_size=8 * 1024, rollover_size_bytes=60_000)
    rec = Recorder(tmp_path, "roll", options=opts)
    rec.start()
    names = ("a", "b", "c")
    srcs = {n: rec.source(n, maxsize=n_per) for n in names}

    def produce(name: str) -> None:
        for i in range(n_per):
            payload = i.to_bytes(4, "little") + name.encode() * 30
            assert srcs[name].put(T.gnss_raw(name), T0 + i, T0 + i, payload)

    threads = [threading.Thread(target=produce, args=(n,)) for n in names]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    summary = rec.stop()
    assert summary.error is None and summary.finalized
    assert len(summary.parts) >= 3, summary.parts
    assert find_parts(tmp_path / "roll") == list(summary.parts)
    seqs: dict[str, list[int]] = {n: [] for n in names}
    counters: dict[str, list[int]] = {n: [] for n in names}
    for k, part in enumerate(summary.parts):
        msgs, mcap_summary = read_with_mcap(part)
        assert mcap_summary is not None  # each part finalized with its summary
        md = scan_part(part).metadata_dict()
        assert md[METADATA_RECORDER]["part_index"] == str(k)
        expected_next = summary.parts[k + 1].name if k + 1 < len(summary.parts) else ""
        assert md[METADATA_PART_END]["next_part"] == expected_next
        for topic, seq, _lt, _pt, data in msgs:
            if topic != T.TOPIC_EVENTS:
                name = topic.split("/")[2]
                seqs[name].append(seq)
                counters[name].append(int.from_bytes(data[:4], "little"))
    for n in names:
        assert sorted(seqs[n]) == list(range(n_per)), f"source {n}: sequence numbers lost or duplicated"
        assert counters[n] == list(range(n_per)), f"source {n}: payloads out of order across parts"


def test_rollover_by_duration_uses_the_injected_clock(tmp_path: Path) -> None:
    clock = ManualClock()
    rec = Recorder(tmp_path, "dur", options=options(rollover_duration_s=10.0, rollover_size_bytes=None), clock=clock)
    rec.start()
    src = rec.source("g")
    for i in range(25):
        assert src.put(T.gnss_raw("g"), T0 + i, clock.now_ns(), bytes([i]))
        assert rec.drain(10)
        clock.advance(1_000_000_000)
    summary = rec.stop()
    # 25 s of host time with 10 s parts: three parts, nothing lost
    assert len(summary.parts) == 3
    data = [d for p in summary.parts for topic, _s, _l, _p, d in read_with_mcap(p)[0] if topic == T.gnss_raw("g")]
    assert sorted(data) == [bytes([i]) for i in range(25)]
    events = [e for p in summary.parts for e in _events(read_with_mcap(p)[0])]
    assert sum(e.kind is EventKind.ROLLOVER for e in events) == 2


def test_queue_overflow_is_counted_and_recorded_as_an_event(tmp_path: Path) -> None:
    gate, entered = threading.Event(), threading.Event()

    def opener(path: Path, mode: str):
        if path.suffix == ".mcap":
            return GatedFile(path, mode, gate, entered)
        return open(path, mode)

    gate.set()
    rec = Recorder(tmp_path, "drop", options=options(), opener=opener)
    rec.start()
    src = rec.source("can0", maxsize=5)
    gate.clear()
    syncer = threading.Thread(target=rec.sync)
    syncer.start()
    assert entered.wait(10), "writer never reached flush"
    # the writer is held inside flush: the queue fills after 5 messages
    results = [src.put(T.gnss_raw("can0"), T0 + i, T0 + i, b"x") for i in range(100)]
    assert results.count(True) == 5 and results.count(False) == 95
    gate.set()
    syncer.join(10)
    summary = rec.stop()
    st = next(s for s in summary.sources if s.name == "can0")
    assert (st.accepted, st.written, st.dropped) == (5, 5, 95)
    msgs, _ = read_with_mcap(summary.parts[0])
    overflow = [e for e in _events(msgs) if e.kind is EventKind.OVERFLOW]
    assert len(overflow) == 1
    ev = overflow[0]
    assert ev.source == "can0" and ev.details["dropped"] == 95
    assert ev.details["topics"] == {T.gnss_raw("can0"): 95}
    assert (ev.start_ns, ev.end_ns) == (T0 + 5, T0 + 99)


def test_low_disk_stops_cleanly_with_disk_full_error(tmp_path: Path) -> None:
    free = [10**12]
    clock = ManualClock()
    rec = Recorder(
        tmp_path, "disk",
        options=options(min_free_bytes=100_000_000, warn_free_bytes=200_000_000, disk_check_interval_s=1.0),
        clock=clock, disk_free=lambda _d: free[0],
    )
    rec.start()
    src = rec.source("g")
    for i in range(10):
        assert src.put(T.gnss_raw("g"), T0 + i, T0 + i, bytes([i]))
    assert rec.drain(10)
    free[0] = 150_000_000  # below the warning level
    clock.advance(2_000_000_000)
    assert rec.drain(10)
    free[0] = 50_000_000  # below the minimum: the recording stops
    clock.advance(2_000_000_000)
    assert rec.failed.wait(10)
    assert not src.put(T.gnss_raw("g"), T0, T0, b"late")
    summary = rec.stop()
    assert isinstance(summary.error, DiskFullError)
    assert str(tmp_path) in str(summary.error)
    assert summary.finalized
    msgs, mcap_summary = read_with_mcap(summary.parts[0])
    assert mcap_summary is not None
    assert [d for topic, _s, _l, _p, d in msgs if topic == T.gnss_raw("g")] == [bytes([i]) for i in range(10)]
    disk_events = [e for e in _events(msgs) if e.kind is EventKind.DISK_SPACE]
    assert [e.severity.value for e in disk_events] == ["warning", "error"]
    with pytest.raises(DiskFullError):
        rec.check()


def test_refuses_to_start_below_min_free_disk(tmp_path: Path) -> None:
    rec = Recorder(tmp_path, "nofree", options=options(min_free_bytes=10**9), disk_free=lambda _d: 10**6)
    with pytest.raises(DiskFullError, match="min_free_disk_mb"):
        rec.start()
    assert not list(tmp_path.iterdir())


def test_enospc_mid_write_keeps_everything_written(tmp_path: Path) -> None:
    """The disk fills up inside a write: DiskFullError, and the part is finalized in place up to its last chunk."""
    rec = Recorder(tmp_path, "full", options=options(chunk_size=4096), opener=limited_opener(40_000))
    rec.start()
    src = rec.source("g", maxsize=100_000)
    rng = np.random.default_rng(2)
    for i in range(3000):
        payload = i.to_bytes(4, "little") + rng.integers(0, 256, 60, dtype=np.uint8).tobytes()
        if not src.put(T.gnss_raw("g"), T0 + i, T0 + i, payload):
            break
    assert rec.failed.wait(20)
    summary = rec.stop()
    assert isinstance(summary.error, DiskFullError)
    assert "finalized" in str(summary.error)
    msgs, mcap_summary = read_with_mcap(summary.parts[0])
    assert mcap_summary is not None and mcap_summary.statistics.message_count == len(msgs)
    counters = [int.from_bytes(d[:4], "little") for topic, _s, _l, _p, d in msgs if topic == T.gnss_raw("g")]
    # a gap-free prefix of what was sent, and most of the 40 kB budget was used for it
    assert counters == list(range(len(counters)))
    assert len(counters) > 300


def test_bad_names_and_existing_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="plain file name"):
        Recorder(tmp_path, "a/b")
    with pytest.raises(ValueError, match="reserved"):
        Recorder(tmp_path, "x", {METADATA_RECORDER: {"a": "b"}})
    (tmp_path / "taken.000.mcap").write_bytes(b"")
    with pytest.raises(SessionFileError, match=r"taken\.000\.mcap already exists"):
        Recorder(tmp_path, "taken", options=options()).start()
    with pytest.raises(SessionFileError, match="does not exist"):
        Recorder(tmp_path / "nope", "x", options=options()).start()
    rec = Recorder(tmp_path, "ok", options=options())
    with rec:
        src = rec.source("g")
        with pytest.raises(ValueError, match="not a vsc-rig topic"):
            src.put("/nope", 0, 0, b"")
        with pytest.raises(ValueError, match="already has a source"):
            rec.source("g")


def test_an_idle_writer_takes_messages_in_batches_not_one_wake_up_per_message(tmp_path: Path) -> None:
    """Messages that come one by one do not wake the writer one by one (the old writer did: ~3000
    wake-ups a second in a simulated drive, more CPU than the writing, most of all under a busy
    host): an idle writer looks again at its idle wait, or as soon as a source has queued a batch."""
    rec = Recorder(tmp_path, "paced", options=options(idle_wait_s=0.05, batch=64))
    rec.start()
    src = rec.source("rover_a", maxsize=10_000)
    pace = threading.Event()
    rounds0 = rec._round_id
    t0 = time.monotonic()
    for i in range(200):
        assert src.put(T.gnss_raw("rover_a"), T0 + i, T0 + i, bytes([i]))
        pace.wait(0.001)
    elapsed = time.monotonic() - t0
    rounds = rec._round_id - rounds0
    summary = rec.stop()
    # one round per idle wait and per batch at most (+ the rounds of starting and stopping)
    assert rounds <= elapsed / 0.05 + 200 / 64 + 6, f"{rounds} writer rounds for 200 messages in {elapsed:.2f} s"
    st = next(s for s in summary.sources if s.name == "rover_a")
    assert (st.accepted, st.written, st.dropped) == (200, 200, 0)
    msgs, _ = read_with_mcap(summary.parts[0])
    assert [d for topic, *_rest, d in msgs if topic == T.gnss_raw("rover_a")] == [bytes([i]) for i in range(200)]


def test_a_source_with_a_half_full_queue_wakes_the_idle_writer(tmp_path: Path) -> None:
    """A source whose queue is shorter than a batch wakes the writer when it is half full, before its
    messages would be dropped (the writer's idle wait here is far longer than the test)."""
    rec = Recorder(tmp_path, "small", options=options(idle_wait_s=30.0, batch=1000))
    rec.start()
    src = rec.source("can0", maxsize=40)
    try:
        assert wait_until(lambda: rec._hub.idle, 10.0)
        for i in range(20):
            assert src.put(T.gnss_raw("can0"), T0 + i, T0 + i, b"x")
        assert wait_until(lambda: next(s for s in rec.stats() if s.name == "can0").written == 20, 10.0)
    finally:
        summary = rec.stop()
    assert summary.error is None
