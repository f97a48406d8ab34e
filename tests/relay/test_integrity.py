"""The relay against real servers and finite sources: a bare 401 status line, a source that never
connects, a capture file that must lose nothing (backpressure), a live source that drops and says so."""

from __future__ import annotations

import random
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drivers.relay import CallbackSink, FileSink, PushSource, Relay, open_source
from drivers.relay.endpoints import FileEndpoint
from drivers.relay.frames import encode_rtcm3
from drivers.relay.ntrip import ResponseKind, parse_response_head
from rig.cli.main import app, main
from vsccore.errors import NtripAuthError, NtripMountpointError

runner = CliRunner()


class BareStatusCaster:
    """A caster that answers every request with exactly ``answer`` and closes (RTKLIB str2str's
    answer to a wrong password is the bare line ``HTTP/1.0 401 Unauthorized``)."""

    def __init__(self, answer: bytes) -> None:
        self.answer = answer
        self.requests: list[bytes] = []
        self._server = socket.create_server(("127.0.0.1", 0))
        self._server.settimeout(0.2)
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bare-status-caster")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            with conn:
                conn.settimeout(5)
                request = b""
                while b"\r\n\r\n" not in request:
                    chunk = conn.recv(4096)
                    if not chunk:
                        break
                    request += chunk
                self.requests.append(request)
                conn.sendall(self.answer)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._server.close()


@pytest.fixture
def bare() -> Iterator[type[BareStatusCaster]]:
    made: list[BareStatusCaster] = []

    class Made(BareStatusCaster):
        def __init__(self, answer: bytes) -> None:
            super().__init__(answer)
            made.append(self)

    yield Made
    for c in made:
        c.close()


def test_a_status_line_alone_decides_the_answer() -> None:
    for line, kind in ((b"HTTP/1.0 401 Unauthorized\r\n", ResponseKind.UNAUTHORIZED),
                       (b"HTTP/1.1 403 Forbidden\r\n", ResponseKind.FORBIDDEN),
                       (b"HTTP/1.0 404 Not Found\r\n", ResponseKind.NOT_FOUND)):
        head = parse_response_head(line)
        assert head is not None and head.kind is kind, line
    assert parse_response_head(b"HTTP/1.1 200 OK\r\n") is None  # a 200 needs its headers
    closed = parse_response_head(b"HTTP/1.0 401 Unauthorized", eof=True)  # no line end, then closed
    assert closed is not None and closed.kind is ResponseKind.UNAUTHORIZED


@pytest.mark.parametrize("answer", [b"HTTP/1.0 401 Unauthorized\r\n", b"HTTP/1.1 403 Forbidden\r\n"])
def test_bare_refusal_is_an_auth_error_at_once(bare: type[BareStatusCaster], answer: bytes) -> None:
    caster = bare(answer)
    source = open_source(f"ntrip://alice:secret@127.0.0.1:{caster.port}/MOUNT", env={})
    with pytest.raises(NtripAuthError, match=r"credentials refused for user 'alice'"):
        source.open(threading.Event())


def test_rig_relay_stops_on_a_bare_401_with_exit_2_and_no_retry(
    bare: type[BareStatusCaster], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    caster = bare(b"HTTP/1.0 401 Unauthorized\r\n")
    with pytest.raises(SystemExit) as excinfo:
        main(["relay", "--from", f"ntrip://alice:wrong@127.0.0.1:{caster.port}/MOUNT",
              "--to", f"file:{tmp_path / 'o'}", "--duration", "60"])
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert "rig: error:" in err and "credentials refused" in err and "401 Unauthorized" in err
    assert "wrong" not in err
    assert len(caster.requests) == 1  # no retry on bad credentials


def test_a_bare_404_is_an_unknown_mountpoint(bare: type[BareStatusCaster]) -> None:
    caster = bare(b"HTTP/1.0 404 Not Found\r\n")
    source = open_source(f"ntrip://alice:secret@127.0.0.1:{caster.port}/NOPE", env={})
    with pytest.raises(NtripMountpointError, match="no such mountpoint"):
        source.open(threading.Event())


def test_rig_relay_that_never_connected_exits_non_zero_with_the_reason(tmp_path: Path) -> None:
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]  # closed again: connections are refused
    result = runner.invoke(
        app, ["relay", "--from", f"tcp://127.0.0.1:{port}", "--to", f"file:{tmp_path / 'o'}", "--duration", "0.5"]
    )
    assert result.exit_code != 0
    assert isinstance(result.exception, OSError)
    assert "never connected" in str(result.exception) and "cannot connect" in str(result.exception)


def _frames(n: int, seed: int = 7) -> list[bytes]:
    rng = random.Random(seed)
    return [encode_rtcm3(bytes([0x43, 0x50]) + rng.randbytes(rng.randrange(50, 400))) for _ in range(n)]


def test_a_capture_file_waits_for_the_sinks_and_loses_nothing(tmp_path: Path) -> None:
    frames = _frames(300)
    capture = tmp_path / "base.rtcm3"
    capture.write_bytes(b"".join(frames))
    gate = threading.Event()
    slow: list[bytes] = []

    def write(frame: bytes) -> None:  # a rover that takes nothing until the gate opens
        gate.wait(30)
        slow.append(frame)

    out = tmp_path / "out.rtcm3"
    sinks = [CallbackSink("slow", write, queue_frames=4), FileSink(FileEndpoint(str(out)), queue_frames=4)]
    relay = Relay(open_source(f"file:{capture}"), sinks)
    relay.start()
    try:
        # The reader is held by the full queue of the slow sink; before, it dropped the oldest.
        assert relay.wait_until(lambda s: s.sinks[0].queue_depth == 4, 10)
        assert not relay.finished.is_set()
        gate.set()
        assert relay.wait(30)
        assert relay.drain(30)
    finally:
        gate.set()
        relay.stop()
    stats = relay.stats()
    assert stats.state == "finished" and stats.frames_in == 300
    assert slow == frames
    assert out.read_bytes() == b"".join(frames)
    assert all(s.frames_out == 300 and s.dropped_total == 0 for s in stats.sinks)


def test_rig_relay_replays_a_whole_capture_file_every_time(tmp_path: Path) -> None:
    frames = _frames(2000, seed=3)
    capture = tmp_path / "base.rtcm3"
    capture.write_bytes(b"".join(frames))
    for run in range(3):
        outs = [tmp_path / f"out{run}-{i}.rtcm3" for i in range(2)]
        result = runner.invoke(app, ["relay", "--from", f"file:{capture}", "--queue", "2",
                                     *(a for o in outs for a in ("--to", f"file:{o}"))])
        assert result.exit_code == 0, result.output
        assert all(o.read_bytes() == capture.read_bytes() for o in outs)
        assert "2000 frames" in result.stderr


def test_a_live_source_drops_the_oldest_and_counts_them() -> None:
    frames = _frames(50)
    gate = threading.Event()
    got: list[bytes] = []
    source = PushSource("live")
    sink = CallbackSink("slow", lambda f: (gate.wait(30), got.append(f)), queue_frames=5)
    relay = Relay(source, [sink])
    relay.start()
    try:
        for f in frames:
            source.feed(f)
        source.end()
        assert relay.wait(10)  # never held up by the sink
        gate.set()
        assert relay.drain(10)
    finally:
        gate.set()
        relay.stop()
    s = relay.stats().sinks[0]
    assert s.frames_out == len(got) and s.dropped == len(frames) - len(got) > 0
    assert got[-5:] == frames[-5:]  # the newest fill the queue; the older ones were dropped
