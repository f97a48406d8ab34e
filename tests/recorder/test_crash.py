"""A recorder killed with SIGKILL leaves a part readable up to its last complete chunk; recovery finalizes it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

import rig.core.topics as T  # noqa: N812 - short alias used throughout the tests
from rig.store import ProblemKind, recover, scan_part
from tests.recorder.helpers import read_with_mcap

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL")
def test_sigkill_mid_recording_then_recover(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.recorder.crash_child", str(tmp_path)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True,
    )
    try:
        assert proc.stdout is not None
        synced = 0
        for _ in range(5):  # let it sync a few times, then kill it while it writes on
            line = proc.stdout.readline()
            assert line.startswith("synced "), (line, proc.stderr.read() if proc.stderr else "")
            synced = int(line.split()[1])
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    part = tmp_path / "crash.000.mcap"

    # 1. the reader tolerates the crashed part: a truncation, not corruption, and a gap-free prefix
    scan = scan_part(part)
    assert scan.problem_kind is ProblemKind.TRUNCATED and not scan.finalized
    counters = [int.from_bytes(d[:8], "little") for d in scan.topics[T.gnss_raw("g")].data]
    assert counters == list(range(len(counters)))
    assert len(counters) >= synced, f"only {len(counters)} of {synced} synced messages readable"

    # 2. mcap's own reader cannot use the summary of the crashed part (there is none)
    with open(part, "rb") as f, pytest.raises(Exception):  # noqa: B017 - mcap raises its own errors here
        make_reader(f).get_summary()

    # 3. recover writes a finalized, indexed copy that mcap's seeking reader opens
    report = recover(part)
    assert report.finalized and report.problem_kind is ProblemKind.TRUNCATED
    assert report.path == tmp_path / "crash.000.recovered.mcap"
    msgs, summary = read_with_mcap(report.path)
    assert summary is not None and summary.statistics.message_count == report.messages == len(msgs)
    got = [int.from_bytes(d[:8], "little") for topic, _s, _l, _p, d in msgs if topic == T.gnss_raw("g")]
    assert got == counters
    assert scan_part(report.path).finalized


def test_rig_recover_command(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from rig.cli.main import app
    from rig.store import Recorder
    from tests.recorder.helpers import T0, options

    with Recorder(tmp_path, "r", options=options(chunk_size=2000)) as rec:
        src = rec.source("g")
        for i in range(500):
            src.put(T.gnss_raw("g"), T0 + i, T0 + i, i.to_bytes(8, "little") * 4)
    part = tmp_path / "r.000.mcap"
    data = part.read_bytes()
    part.write_bytes(data[: len(data) // 2])
    result = CliRunner().invoke(app, ["recover", str(part), "--out", str(tmp_path / "fixed.mcap")])
    assert result.exit_code == 0, result.output
    assert "recovered" in result.output
    msgs, summary = read_with_mcap(tmp_path / "fixed.mcap")
    assert summary is not None and 0 < len(msgs) < 502
