"""The relay end to end on pseudo-terminals and sockets: whole checked frames only, the tap, a source
that disappears and comes back, file replay paced by an injected clock, statistics."""

from __future__ import annotations

import json
import os
import random
import socket
import threading
import time
from pathlib import Path

import pytest
from pyrtcm import RTCMReader

from drivers.relay import (
    Backoff,
    CallbackSink,
    FileSource,
    PushSource,
    Relay,
    open_sink,
    open_source,
)
from drivers.relay.endpoints import FileEndpoint
from rig.core.topics import SCHEMA_RELAY_STATS, validate_json
from tests.relay.helpers import NOVATEL_RTCA_BLOCK, PtyPeer, base_epoch, cmr_by_hand
from vsccore.clock import ScaledClock

FAST = Backoff(initial_s=0.02, max_s=0.1)


class Frames:
    """CallbackSink target: every call is one frame; signals when ``n`` have arrived."""

    def __init__(self, n: int) -> None:
        self.items: list[bytes] = []
        self.n = n
        self.done = threading.Event()
        self._lock = threading.Lock()

    def __call__(self, data: bytes) -> None:
        with self._lock:
            self.items.append(data)
            if len(self.items) >= self.n:
                self.done.set()


def test_only_whole_checked_frames_reach_the_rovers_and_the_tap_sees_every_byte() -> None:
    rng = random.Random(11)
    good: list[bytes] = []
    stream = b""
    corrupted = 0
    for k in range(5):
        for frame in base_epoch(345_600_000 + 1000 * k):
            if rng.random() < 0.2:
                bad = bytearray(frame)
                bad[rng.randrange(5, len(bad))] ^= 0x04
                stream += bytes(bad)
                corrupted += 1
            else:
                stream += frame
                good.append(frame)
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 8)))  # line noise
    cmr = cmr_by_hand(0x93, bytes([0x20, 0x08]) + bytes(20))
    stream += NOVATEL_RTCA_BLOCK + cmr
    good += [NOVATEL_RTCA_BLOCK, cmr]

    src, a, b = PtyPeer(), PtyPeer().start_reader(), PtyPeer().start_reader()
    tapped: list[tuple[int, bytes]] = []
    relay = Relay(
        open_source(src.path),
        [open_sink(a.path, backoff=FAST), open_sink(b.path, backoff=FAST)],
        tap=lambda t, d: tapped.append((t, d)),
        backoff=FAST,
    )
    relay.start()
    try:
        assert all(s.wait_connected(True, 5) for s in relay.sinks)
        assert relay.wait_until(lambda s: s.state == "running", 5)
        for i in range(0, len(stream), 97):  # arbitrary pieces, frames split across reads
            src.write(stream[i : i + 97])
        expected = b"".join(good)
        assert a.read_exactly(len(expected), 5) == expected
        assert b.read_exactly(len(expected), 5) == expected
        assert relay.wait_until(lambda s: s.bytes_in == len(stream), 5)
        assert all(x.drain(5) for x in relay.sinks)  # their workers have counted what they wrote
        s = relay.stats()
    finally:
        relay.stop()
        for p in (src, a, b):
            p.close()
    assert b"".join(d for _, d in tapped) == stream
    times = [t for t, _ in tapped]
    assert times == sorted(times)
    assert s.frames_in == len(good)
    assert s.rejected_frames == corrupted
    n1077 = sum(1 for f in good if f[0] == 0xD3 and RTCMReader.parse(f).identity == "1077")
    assert s.frames_by_type["RTCM 1077"] == n1077
    assert s.frames_by_type["RTCA 4"] == 1 and s.frames_by_type["CMR 0"] == 1
    assert all(x.frames_out == len(good) and x.dropped_total == 0 for x in s.sinks)


def test_split_reads_forward_whole_frames() -> None:
    epoch = base_epoch()
    stream = b"".join(epoch)
    got = Frames(len(epoch))
    source = PushSource("push")
    relay = Relay(source, [CallbackSink("rover", got, max_age_s=None)])
    relay.start()
    try:
        for i in range(0, len(stream), 3):
            source.feed(stream[i : i + 3])
        assert got.done.wait(5)
    finally:
        relay.stop()
    assert got.items == epoch  # one write per frame, each whole


class FlakyServer:
    """A TCP server that serves one connection per script entry, then hangs up."""

    def __init__(self, scripts: list[bytes]) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.scripts = scripts
        self.connections = 0
        self.hung_up = [threading.Event() for _ in scripts]
        self.go = [threading.Event() for _ in scripts]
        self._thread = threading.Thread(target=self._run, name="flaky-server", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.sock.settimeout(10)
        for i, script in enumerate(self.scripts):
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.connections += 1
            with conn:
                self.go[i].wait(10)
                conn.sendall(script)
            self.hung_up[i].set()

    def close(self) -> None:
        for g in self.go:
            g.set()
        self._thread.join(10)
        self.sock.close()


def test_source_that_disappears_and_comes_back() -> None:
    epoch = base_epoch()
    half = epoch[3][:40]  # the connection drops in the middle of a 1077
    server = FlakyServer([b"".join(epoch[:3]) + half, b"".join(epoch)])
    got = Frames(3 + len(epoch))
    relay = Relay(open_source(f"tcp://127.0.0.1:{server.port}"), [CallbackSink("rover", got)], backoff=FAST)
    relay.start()
    try:
        server.go[0].set()
        assert relay.wait_until(lambda s: s.source_connects >= 1, 5)
        server.go[1].set()
        assert got.done.wait(5)
        assert relay.wait_until(lambda s: s.source_connects == 2, 5)
        s = relay.stats()
    finally:
        relay.stop()
        server.close()
    assert got.items == epoch[:3] + epoch  # the half frame was never forwarded
    assert s.truncated_frames == 1
    assert s.source_error is not None and "127.0.0.1" in s.source_error


@pytest.fixture
def capture(tmp_path: Path) -> tuple[Path, list[bytes]]:
    frames = [f for k in range(4) for f in base_epoch(345_600_000 + 1000 * k)]
    path = tmp_path / "base.rtcm3"
    path.write_bytes(b"".join(frames))
    return path, frames


def test_file_replay_paced_by_an_injected_clock(capture: tuple[Path, list[bytes]]) -> None:
    path, frames = capture
    total = path.stat().st_size
    baud = 9600  # 960 bytes/s: the capture takes about total/960 s of clock time
    clock = ScaledClock(start_ns=1_700_000_000 * 10**9, speed=50.0)
    tapped: list[tuple[int, bytes]] = []
    got = Frames(len(frames))
    source = FileSource(FileEndpoint(str(path), baud), clock=clock)
    relay = Relay(source, [CallbackSink("rover", got)], tap=lambda t, d: tapped.append((t, d)), clock=clock)
    relay.start()
    try:
        assert relay.wait(20), "the replay did not end"
        assert got.done.wait(5)
        s = relay.stats()
    finally:
        relay.stop()
    assert got.items == frames
    assert s.state == "finished"
    # Pacing: the byte at offset k was read no earlier than k/960 s (clock time) after the source started
    # (its own reference: the first tap's stamp is itself late when the relay thread waited for a CPU, and
    # measured from it, reads on schedule looked early under load)
    t0 = source._t0_ns
    assert tapped[0][0] >= t0
    offset = 0
    for t, data in tapped:
        assert (t - t0) / 1e9 >= offset / (baud / 10) - 0.02
        offset += len(data)
    span = (tapped[-1][0] - t0) / 1e9
    expected = (total - len(tapped[-1][1])) / (baud / 10)
    # never early; late only by scheduling (5 s of clock time = 0.1 s of wall time at 50x)
    assert expected - 0.02 <= span <= expected + 5.0


def test_stop_is_prompt_while_a_paced_replay_waits(capture: tuple[Path, list[bytes]]) -> None:
    path, _ = capture
    relay = Relay(open_source(f"file:{path}@300"), [])  # 30 bytes/s: would take a minute
    relay.start()
    assert relay.wait_until(lambda s: s.bytes_in > 0, 5)
    t = time.monotonic()
    relay.stop()
    assert time.monotonic() - t < 1.0


def test_statistics_and_rover_ages(capture: tuple[Path, list[bytes]]) -> None:
    path, frames = capture
    relay = Relay(open_source(f"file:{path}"), [CallbackSink("rover_a", lambda d: None)])
    relay.start()
    try:
        assert relay.wait(5)
        assert relay.sinks[0].drain(5)
        relay.note_rover_diff_age("rover_a", 1.4)
        relay.note_rover_diff_age("rover_b", None)
        s = relay.stats()
    finally:
        relay.stop()
    assert s.frames_in == len(frames) == 24
    assert s.frames_by_type == {f"RTCM {n}": 4 for n in (1005, 1006, 1033, 1077, 1087, 1230)}
    assert sum(s.frames_per_s_by_type.values()) == pytest.approx(s.frames_per_s)
    assert s.bytes_per_s == pytest.approx(s.bytes_in / s.window_s)
    assert s.last_correction_age_s is not None and 0 <= s.last_correction_age_s < 5
    assert s.rovers["rover_a"].age_s == 1.4 and s.rovers["rover_b"].age_s is None
    assert s.format == "rtcmv3"
    record = s.to_topic_dict()
    assert validate_json(SCHEMA_RELAY_STATS.document, json.loads(json.dumps(record))) == []
    assert record["sinks"]["rover_a"]["frames_out"] == len(frames)
    assert record["rover_diff_age_s"] == {"rover_a": 1.4, "rover_b": None}


def test_sink_names_must_differ() -> None:
    with pytest.raises(ValueError, match="distinct"):
        Relay(PushSource("p"), [CallbackSink("x", print), CallbackSink("x", print)])


def test_a_failing_tap_does_not_stop_the_corrections(caplog: pytest.LogCaptureFixture) -> None:
    epoch = base_epoch()
    got = Frames(len(epoch))

    def broken_tap(t_ns: int, data: bytes) -> None:
        raise RuntimeError("recorder queue gone")

    source = PushSource("push")
    relay = Relay(source, [CallbackSink("rover", got)], tap=broken_tap)
    relay.start()
    try:
        for f in epoch:
            source.feed(f)
        assert got.done.wait(5)
        assert relay.wait_until(lambda s: s.callback_errors >= 1, 5)
    finally:
        relay.stop()
    assert got.items == epoch
    assert len([r for r in caplog.records if "callback failed" in r.getMessage()]) == 1  # logged once, then counted


def test_serial_source_unplugged_and_replugged(tmp_path: Path) -> None:
    """The base's port goes away mid-frame and comes back at the same path."""
    epoch = base_epoch()
    link = tmp_path / "base"
    first = PtyPeer()
    os.symlink(first.path, link)
    got = Frames(len(epoch) + 2)
    relay = Relay(open_source(str(link)), [CallbackSink("rover", got)], backoff=FAST)
    relay.start()
    second: PtyPeer | None = None
    try:
        assert relay.wait_until(lambda s: s.source_connects == 1 and s.state == "running", 5)
        first.write(epoch[0] + epoch[1] + epoch[3][:50])
        assert relay.wait_until(lambda s: s.frames_in == 2, 5)
        first.close()  # unplug in the middle of a frame
        assert relay.wait_until(lambda s: s.state in ("waiting", "connecting") and s.source_error is not None, 5)
        second = PtyPeer()
        tmp = tmp_path / "base.new"
        os.symlink(second.path, tmp)
        os.replace(tmp, link)
        assert relay.wait_until(lambda s: s.source_connects == 2 and s.state == "running", 5)
        second.write(b"".join(epoch))
        assert got.done.wait(5)
        s = relay.stats()
    finally:
        relay.stop()
        first.close()
        if second is not None:
            second.close()
    assert got.items == epoch[:2] + epoch
    assert s.truncated_frames == 1
