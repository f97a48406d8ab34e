"""``rig relay`` end to end: file replay to a file and a pty, NTRIP errors, --duration, Ctrl-C."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from typer.testing import CliRunner

from rig.cli.main import app, main
from sim_devices.ntrip_caster import NtripCaster
from tests.relay.helpers import PtyPeer, base_epoch
from tests.sigint import ctrl_c_reaches_children

REPO = Path(__file__).resolve().parents[2]
runner = CliRunner()


def test_file_source_to_file_and_pty(tmp_path: Path) -> None:
    epoch = base_epoch()
    bad = bytearray(epoch[3])
    bad[50] ^= 0xFF
    capture = tmp_path / "base.rtcm3"
    capture.write_bytes(b"garbage" + b"".join(epoch[:3]) + bytes(bad) + b"".join(epoch[4:]) + b"".join(epoch))
    good = b"".join(epoch[:3] + epoch[4:] + epoch)
    out = tmp_path / "rover.rtcm3"
    rover = PtyPeer().start_reader()
    try:
        result = runner.invoke(app, ["relay", "--from", f"file:{capture}", "--to", f"file:{out}", "--to", rover.path])
        assert result.exit_code == 0, result.output
        assert rover.read_exactly(len(good), 5) == good
    finally:
        rover.close()
    assert out.read_bytes() == good
    assert "11 frames" in result.stderr and "1 rejected" in result.stderr
    assert "RTCM 1077 1" in result.stderr  # one 1077 was corrupted, one came through


def test_wrong_ntrip_password_is_one_line_without_the_password(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    secret = "hunter2-very-secret"
    monkeypatch.setenv("VSC_RIG_NTRIP_PASSWORD", "not-" + secret)
    with NtripCaster(users={"alice": secret}) as caster:
        caster.add_mountpoint("BASE1")
        with pytest.raises(SystemExit) as excinfo:
            main(["relay", "--from", caster.url("BASE1", "alice"), "--to", f"file:{tmp_path / 'o'}"])
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert "rig: error: " in err and "credentials refused" in err and "alice" in err
    assert secret not in err
    assert caster.unauthorized == 1


def test_duration_stops_a_silent_source(tmp_path: Path) -> None:
    server = socket.create_server(("127.0.0.1", 0))
    try:
        port = server.getsockname()[1]
        result = runner.invoke(
            app, ["relay", "--from", f"tcp://127.0.0.1:{port}", "--to", f"file:{tmp_path / 'o'}", "--duration", "0.3"]
        )
    finally:
        server.close()
    assert result.exit_code == 0, result.output
    assert "0 frames" in result.stderr


def test_ctrl_c_stops_cleanly() -> None:
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    accepted = threading.Event()
    conns: list[socket.socket] = []

    def accept() -> None:
        server.settimeout(30)
        try:
            conn, _ = server.accept()
        except OSError:
            return
        conns.append(conn)
        conn.sendall(b"".join(base_epoch()))
        accepted.set()

    t = threading.Thread(target=accept, name="cli-test-server", daemon=True)
    t.start()
    rover = PtyPeer().start_reader()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    with ctrl_c_reaches_children():
        proc = subprocess.Popen(
            [sys.executable, "-m", "rig", "relay", "--from", f"tcp://127.0.0.1:{port}", "--to", rover.path],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
            cwd=REPO,
        )
    expected = b"".join(base_epoch())
    try:
        assert accepted.wait(30)
        assert rover.read_exactly(len(expected), 30) == expected  # relayed: now interrupt it
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        t.join(5)
        for c in conns:
            c.close()
        server.close()
        rover.close()
    text = err.decode()
    assert proc.returncode == 0, text
    assert "stopped (Ctrl-C)" in text
    assert "6 frames" in text
