"""The recording commands end to end: ``rig sim record`` in a process stopped by SIGTERM leaves a
finalized file; ``rig record`` records simulated devices reached through their real ports."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import tomli_w
from typer.testing import CliRunner

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.cli.main import app
from rig.data import load_session
from rig.sim.world import SimWorld
from rig.store import find_parts
from rig.workflows.demo import demo_config_path
from tests.session.recording import FAST_RTK, config

REPO = Path(__file__).resolve().parents[2]


def _wait_for_line(proc: subprocess.Popen[str], needle: str, timeout_s: float) -> list[str]:
    """Read the process's stderr until a line holds ``needle`` (fails on exit or timeout)."""
    assert proc.stderr is not None
    seen: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise AssertionError(f"process ended before {needle!r}: {''.join(seen)}")
        seen.append(line)
        if needle in line:
            return seen
    raise AssertionError(f"no {needle!r} within {timeout_s} s: {''.join(seen)}")


def test_sigterm_ends_sim_record_with_a_finalized_file(tmp_path: Path) -> None:
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "rig", "sim", "record", str(demo_config_path()), "--out", str(out),
           "--name", "term", "--drive", "straight:duration_s=60", "--speed", "5", "--no-dashboard"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env, cwd=REPO)
    try:
        _wait_for_line(proc, "recording term", timeout_s=60)
        part = out / "term.000.mcap"
        deadline = time.monotonic() + 30
        # recording: wait (on the process, so an early exit shows) until data has reached the disk
        while part.stat().st_size < 200_000:
            assert time.monotonic() < deadline, "the recording did not grow"
            try:
                proc.wait(timeout=0.2)
                raise AssertionError("rig sim record exited early")
            except subprocess.TimeoutExpired:
                pass
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
        rest = proc.stderr.read() if proc.stderr is not None else ""
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()
    assert code == 0, rest
    assert "stopped by SIGTERM" in rest
    assert "stopped early" in rest
    assert find_parts(out / "term") == [part]
    ds = load_session(out / "term", allow_truncated=False)  # finalized: summary and index present
    assert ds.warnings == ()
    assert ds.part_ends and ds.part_ends[-1]["reason"] == "stop"
    counts = ds.topic_counts
    assert counts[T.gnss_bestpos("rover_a")] > 10 and counts[T.daq_samples("SimDAQ")] > 5
    kinds = [e.kind for _t, e in ds.events]
    assert kinds[-1] is T.EventKind.SESSION_STOP


def _real_ports_config(world: SimWorld, tmp_path: Path) -> Path:
    """sim.toml with the simulated receivers' pseudo-terminals as real ports (what a car's config holds)."""
    doc: dict[str, Any] = tomllib.loads(demo_config_path().read_text())
    cfg = world.cfg
    for table, rc in zip(doc["receivers"], cfg.receivers, strict=True):
        table["port"] = world.port(rc)
        corr = world.correction_port(rc)
        if corr is not None:
            table["correction_device"] = corr
    doc["can"][0]["roles_file"] = str(demo_config_path().parent / "roles" / "vsc_sim.toml")
    del doc["simulation"]
    doc["output"]["directory"] = str(tmp_path / "sessions")
    path = tmp_path / "car.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def test_rig_record_records_devices_on_their_real_ports(tmp_path: Path) -> None:
    world = SimWorld(config("straight:duration_s=10,speed_kmh=40", 1.0), rtk=FAST_RTK, lead_s=0.5)
    world.start()
    try:
        path = _real_ports_config(world, tmp_path)
        result = CliRunner().invoke(app, ["record", str(path), "--name", "car", "--duration", "4", "--no-dashboard"])
    finally:
        world.stop()
    assert result.exit_code == 0, result.output
    ds = load_session(tmp_path / "sessions" / "car", allow_truncated=False)
    counts = ds.topic_counts
    for topic in (T.gnss_bestpos("rover_a"), T.gnss_bestpos("rover_b"), T.gnss_raw("base"), T.TOPIC_RELAY_RAW,
                  T.can_frames("vsc"), T.can_roles("vsc"), T.daq_samples("SimDAQ"), T.TOPIC_TIMEBASE):
        assert counts.get(topic, 0) > 0, topic
    assert "car.toml" in ds.attachments
    # corrections reached the rovers through their correction ports
    pos_types = set(ds.gnss("rover_a").bestpos["pos_type"].tolist())
    assert pos_types & {"PSRDIFF", "NARROW_FLOAT", "NARROW_INT"}, pos_types


def test_record_refuses_simulated_ports_and_sim_record_real_ones(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["record", str(demo_config_path()), "--duration", "1"])
    assert result.exit_code != 0
    assert "rig sim record" in str(result.exception)
    doc: dict[str, Any] = tomllib.loads(demo_config_path().read_text())
    doc["receivers"][0]["port"] = "/dev/ttyUSB7"
    doc["can"][0]["roles_file"] = str(demo_config_path().parent / "roles" / "vsc_sim.toml")
    path = tmp_path / "mixed.toml"
    path.write_text(tomli_w.dumps(doc))
    result = runner.invoke(app, ["sim", "record", str(path), "--out", str(tmp_path)])
    assert result.exit_code != 0
    assert "real ports" in str(result.exception)
