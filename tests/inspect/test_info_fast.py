"""``rig info`` stays fast on a long session: what its default path reads, and what it must not.

Not timed (benchmarks/bench_startup.py times it): the default path decompresses only the chunks that
hold ``/rig/events`` or ``/rig/timebase`` messages, never loads the dataset, takes the time-base
verdicts the recorder wrote at the end of the recording, reads the summary with its own parser (equal
to mcap's reader), and imports none of the heavy libraries. ``--verify`` stays the thorough path.
"""

from __future__ import annotations

import json
import mmap
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

import rig.core.topics as T  # noqa: N812 - short alias used throughout the tests
import rig.store.parts as parts_mod
import rig.store.records as records_mod
from rig.cli.main import main
from rig.core.quality import Gap, StreamQuality, judge, verdict_lines
from rig.data.info import VerdictSource, format_info, info_to_json, read_session_info
from rig.store import Recorder, find_parts
from tests.inspect.synth import U0, Synth
from tests.recorder.helpers import options

PAYLOAD = {T.TOPIC_EVENTS, T.TOPIC_TIMEBASE}


def _summary(part: Path) -> Any:
    with open(part, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        return records_mod.read_summary(mm)


def test_summary_parser_equals_mcaps_reader(synth: Synth) -> None:
    for part in find_parts(synth.base):
        ours = _summary(part)
        with open(part, "rb") as f:
            theirs = make_reader(f).get_summary()
        assert theirs is not None and ours is not None
        assert ours.statistics == theirs.statistics
        assert ours.schemas == theirs.schemas and ours.channels == theirs.channels
        assert ours.chunk_indexes == theirs.chunk_indexes
        assert ours.attachment_indexes == theirs.attachment_indexes
        assert ours.metadata_indexes == theirs.metadata_indexes


def test_default_info_decompresses_only_event_and_timebase_chunks_and_never_loads_the_dataset(
    synth: Synth, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:
    expected: set[tuple[str, int]] = set()
    total = 0
    for part in find_parts(synth.base):
        s = _summary(part)
        wanted = {cid for cid, ch in s.channels.items() if ch.topic in PAYLOAD}
        total += len(s.chunk_indexes)
        expected |= {(part.name, ci.chunk_start_offset) for ci in s.chunk_indexes
                     if wanted & set(ci.message_index_offsets)}
    assert 0 < len(expected) < total / 2  # most chunks hold raw bytes and decoded logs only

    seen: list[str] = []
    real = records_mod.decompress_chunk

    def counting(compression: str, raw: bytes, usize: int, where: str) -> bytes:
        seen.append(where)
        return real(compression, raw, usize, where)

    def forbidden(*_a: Any, **_k: Any) -> Any:
        raise AssertionError("rig info read every message (scan or dataset) on its default path")

    monkeypatch.setattr(records_mod, "decompress_chunk", counting)
    monkeypatch.setattr(parts_mod, "scan_part", forbidden)
    monkeypatch.setattr("rig.data.load_session", forbidden)
    main(["info", str(synth.base)])  # returns: exit status 0
    assert "time-base verdicts" in capsys.readouterr().out
    parts = {p.name: p for p in find_parts(synth.base)}
    # the offsets named by the reader: one decompression per chunk holding events or time-base records
    got = set()
    for where in seen:
        offset = int(where.rsplit("offset ", 1)[1].split()[0].rstrip(":"))
        got |= {(name, offset) for name in parts if (name, offset) in expected}
    assert len(seen) == len(expected) and got == expected


def _session_with_recorded_verdicts(tmp_path: Path) -> tuple[Path, dict[str, StreamQuality]]:
    fix = "record at --speed 2"
    verdicts = {
        "can:vsc": StreamQuality("can:vsc", (judge("timing_error_ms", 7.5, fix), judge("missing_percent", 0.4, fix)),
                                 (Gap("can:vsc", "/can/vsc/frames", "stall", U0 + 10**9, U0 + 3 * 10**9),), "live"),
        "gnss:rover_a": StreamQuality("gnss:rover_a", (judge("host_map_error_ms", 0.2, fix),), (), "live"),
    }
    with Recorder(tmp_path, "rv", {}, options=options()) as rec:
        src = rec.source("rover_a")
        for k in range(100):
            t = U0 + k * 50_000_000
            src.put(T.gnss_bestpos("rover_a"), t, t, b'{"gps_time_ns": 0}')
        # as rig.record.recording writes it at the end of a recording
        rec.event(T.EventKind.TIMEBASE, "time-base verdicts at the end of the recording: can:vsc unusable",
                  log_time_ns=U0 + 5 * 10**9, verdicts={k: q.to_json() for k, q in verdicts.items()})
    return tmp_path / "rv", verdicts


def test_recorded_verdicts_by_default_recomputed_with_verify(tmp_path: Path) -> None:
    base, verdicts = _session_with_recorded_verdicts(tmp_path)
    info = read_session_info(base, verdicts=VerdictSource.RECORDED)
    text = format_info(info)
    block = text[text.index("time-base verdicts"):]
    assert "as the recorder judged at the end of the recording" in block.splitlines()[0]
    for line in verdict_lines(verdicts):
        assert f"  {line}\n" in block, line
    assert "can:vsc          UNUSABLE" in block and "gap: can:vsc stalled: no /can/vsc/frames for 2.000 s" in block
    doc = info_to_json(info)["timebase"]["verdicts"]
    assert doc == {"problem": None, "source": "recorded",
                   "streams": json.loads(json.dumps({k: q.to_json() for k, q in sorted(verdicts.items())}))}

    runner = CliRunner()
    from rig.cli.main import app

    plain = json.loads(runner.invoke(app, ["info", "--json", str(base)]).output)
    assert plain["timebase"]["verdicts"]["source"] == "recorded"
    assert plain["timebase"]["verdicts"]["streams"]["can:vsc"]["verdict"] == "unusable"
    verified = json.loads(runner.invoke(app, ["info", "--verify", "--json", str(base)]).output)
    assert verified["timebase"]["verdicts"]["source"] == "data"  # computed from the streams again
    assert "can:vsc" not in verified["timebase"]["verdicts"]["streams"]  # this file has no CAN data


def test_a_session_without_recorded_verdicts_says_so(synth: Synth) -> None:
    info = read_session_info(synth.base, verdicts=VerdictSource.RECORDED)
    assert info.verdicts is not None and info.verdicts.streams == {}
    assert "rig info --verify computes them from the data" in format_info(info)
    assert info_to_json(info)["timebase"]["verdicts"]["problem"].startswith("none recorded")
    computed = read_session_info(synth.base)  # the library's default: from the data, as before
    assert computed.verdicts is not None and computed.verdicts.source is VerdictSource.DATA
    assert set(computed.verdicts.streams) == {"gnss:rover_a", "gnss:rover_b"}


def test_rig_info_imports_no_heavy_library(synth: Synth) -> None:
    code = ("import json, sys\n"
            "from rig.data.info import VerdictSource, format_info, read_session_info\n"
            f"format_info(read_session_info({str(synth.base)!r}, verdicts=VerdictSource.RECORDED))\n"
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    env = {**os.environ, "NO_COLOR": "1"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env,
                       check=False)
    assert r.returncode == 0, r.stderr
    loaded = set(json.loads(r.stdout.splitlines()[-1]))
    assert "mcap" in loaded and "numpy" in loaded  # the check sees what was imported
    heavy = {"can", "cantools", "asammdf", "pandas", "scipy", "matplotlib", "pydantic", "typer", "rich", "drivers",
             "sim_devices", "calibration", "pymap3d"}
    assert not loaded & heavy, sorted(loaded & heavy)
