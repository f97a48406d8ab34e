"""Recording pieces that need no simulated world: receiver commands, operator marks, a device
that cannot be opened (an event, the session records on)."""

from __future__ import annotations

import threading
from pathlib import Path

from drivers.can.bus import CanFrame, CanFrameFlag, TimestampSource
from rig.core.config import CanConfig, SessionConfig, load_session
from rig.core.topics import EventKind, Severity
from rig.data import load_session as load_recording
from rig.record.gnss import receiver_commands
from rig.record.recording import Recording
from rig.workflows.demo import demo_config_path


def _config() -> SessionConfig:
    return load_session(demo_config_path())


def test_receiver_commands_configure_rover_and_base() -> None:
    cfg = _config()
    base, rover_a, rover_b = cfg.receivers
    cmds = receiver_commands(rover_a)
    assert cmds[0] == "UNLOGALL"
    # the correction port: set to the baud of the rig's cable to it, then to raw RTCM3
    assert cmds.index("SERIALCONFIG COM2 115200 N 8 1 N OFF") < cmds.index("INTERFACEMODE COM2 RTCMV3 NONE ON")
    assert "MARKCONTROL MARK1 ENABLE POSITIVE" in cmds  # rover_a logs MARKPOS/MARK1TIME
    # logs go to the port the commands came in on (over USB, LOG COM1 would go to the physical COM1)
    assert "LOG THISPORT VERSIONB ONCE" in cmds  # who answers: the receiver's serial number
    assert "LOG THISPORT BESTPOSB ONTIME 0.05" in cmds
    assert "LOG THISPORT MARK1TIMEB ONNEW" in cmds
    assert not any(c.startswith("LOG COM") for c in cmds)
    assert cmds.index("INTERFACEMODE COM2 RTCMV3 NONE ON") < cmds.index("LOG THISPORT BESTPOSB ONTIME 0.05")
    assert not any(c.startswith("MARKCONTROL") for c in receiver_commands(rover_b))
    base_cmds = receiver_commands(base)
    # the fixed height is ellipsoidal: the receiver is told so before FIX reads it (factory: MSL, EGM96)
    assert base_cmds.index("UNDULATION USER 0.0") + 1 == base_cmds.index(
        "FIX POSITION 48.7758000000 9.1829000000 300.0000")
    assert "LOG THISPORT RTCM1077 ONTIME 1" in base_cmds
    assert not any(c.startswith(("INTERFACEMODE", "SERIALCONFIG")) for c in base_cmds)
    msl = receiver_commands(base.model_copy(update={"fix_height": "msl"}))
    assert "UNDULATION EGM96" in msl and "UNDULATION USER 0.0" not in msl


def test_marks_and_a_device_that_cannot_open(tmp_path: Path) -> None:
    cfg = _config()
    bad = CanConfig(name="chassis", interface="no_such_interface", channel="can9", dbc=cfg.can[0].dbc)
    cfg = cfg.model_copy(update={"receivers": (), "relay": None, "daq": None, "simulation": None,
                                 "can": (cfg.can[0].model_copy(update={"channel": "vsc-unit"}), bad)})
    session = Recording(cfg, out_dir=tmp_path, name="unit")
    session.start()
    try:
        host = session.clock.now_ns()
        session.mark("cone 3", host_ns=host)
        session.run(threading.Event(), duration_s=0.3)
    finally:
        summary = session.stop()
    assert summary.recording.finalized
    assert summary.device_errors["can.chassis"] >= 1
    assert summary.device_errors["can.vsc"] == 0
    ds = load_recording(tmp_path / "unit")
    events = [e for _t, e in ds.events]
    marks = [e for e in events if e.kind is EventKind.MARK]
    assert len(marks) == 1 and marks[0].text == "cone 3" and marks[0].details["host_ns"] == host
    errors = [e for e in events if e.source == "can.chassis" and e.severity is Severity.ERROR]
    assert errors and "cannot open" in errors[0].text
    assert any(e.kind is EventKind.CONNECT and e.source == "can.vsc" for e in events)


def _can_only_session(tmp_path: Path, channel: str) -> Recording:
    """A started recording session of the demo's CAN bus alone, on virtual channel ``channel``."""
    cfg = _config()
    cfg = cfg.model_copy(update={"receivers": (), "relay": None, "daq": None, "simulation": None,
                                 "can": (cfg.can[0].model_copy(update={"channel": channel}),)})
    session = Recording(cfg, out_dir=tmp_path, name="unit")
    session.start()
    return session


def _host_stamped_frame(host_ns: int) -> CanFrame:
    """An empty frame as an interface without its own stamps gives it (host receive time only)."""
    return CanFrame(None, host_ns, 0x7FF, False, False, 0, b"", CanFrameFlag.NONE, TimestampSource.HOST, "unit")


class _HeldSource:
    """A recorder source whose first put of ``/can/vsc/frames`` waits until released."""

    def __init__(self) -> None:
        self.puts: list[int] = []
        self.first_in = threading.Event()
        self.release = threading.Event()
        self.second_in = threading.Event()
        self._lock = threading.Lock()

    def put(self, topic: str, log_time_ns: int, publish_ns: int, data: object) -> None:
        if not topic.endswith("/frames"):
            return
        with self._lock:
            first = not self.puts and not self.first_in.is_set()
        if first:
            self.first_in.set()
            assert self.release.wait(10.0)
        else:
            self.second_in.set()
        with self._lock:
            self.puts.append(log_time_ns)


def test_can_blocks_flushed_from_two_threads_are_put_in_order(tmp_path: Path) -> None:
    """The housekeeping thread flushes an old block while the reader fills and flushes the next: the
    older block must reach the recorder first (before, it could be overtaken: log_time clamped)."""
    session = _can_only_session(tmp_path, "vsc-flush")
    dev = session.can[0]
    source = dev.source
    held = _HeldSource()
    dev.source = held  # type: ignore[assignment]
    t0 = session.clock.now_ns() + 3_600_000_000_000  # an hour ahead: the session's own flushes leave them

    def frame(k: int) -> CanFrame:
        return _host_stamped_frame(t0 + k * 1_000_000)

    dev._on_frame(frame(0))
    housekeeping = threading.Thread(target=dev.flush, name="housekeeping-flush")
    housekeeping.start()
    try:
        assert held.first_in.wait(10.0)
        dev._on_frame(frame(1))
        reader = threading.Thread(target=dev.flush, name="reader-flush")
        reader.start()
        # the old flush put the reader's block at once, ahead of the held one; now it waits its turn
        overtaken = held.second_in.wait(0.2)
        held.release.set()
        reader.join(10.0)
        assert not reader.is_alive()
    finally:
        held.release.set()
        housekeeping.join(10.0)
        dev.source = source
        session.stop()
    assert not overtaken
    assert held.puts == sorted(held.puts) and len(held.puts) == 2


class _Puts:
    """A recorder source that keeps the log times put per topic."""

    def __init__(self) -> None:
        self.times: dict[str, list[int]] = {}

    def put(self, topic: str, log_time_ns: int, publish_ns: int, data: object) -> None:
        self.times.setdefault(topic, []).append(log_time_ns)


def test_host_stamped_can_blocks_never_run_back_when_the_host_map_moves_back(tmp_path: Path) -> None:
    """An interface without its own stamps (host receive time): the blocks' log time comes from the host → GPS
    map, which a refit can move back (more than the 1 ms between these frames here); the channel must not
    run back with it (before, the block took the plain map: back 4 ms)."""
    session = _can_only_session(tmp_path, "vsc-host-stamped")
    dev = session.can[0]
    source = dev.source
    puts = _Puts()
    dev.source = puts  # type: ignore[assignment]
    tb = session.timebase
    shift = {"ns": 0}
    plain = tb.host_to_utc
    t0 = session.clock.now_ns() + 3_600_000_000_000  # an hour ahead: the session's own flushes leave them
    try:
        tb.host_to_utc = lambda host_ns: plain(host_ns) + shift["ns"]  # type: ignore[method-assign]
        for k in range(4):
            if k == 2:
                shift["ns"] = -5_000_000  # a refit moved the map back 5 ms
            dev._on_frame(_host_stamped_frame(t0 + k * 1_000_000))
            dev.flush()
    finally:
        dev.source = source
        del tb.host_to_utc
        session.stop()
    blocks = puts.times[dev.topic_frames]
    assert len(blocks) == 4
    assert blocks == sorted(blocks), [b - blocks[0] for b in blocks]


def test_only_finesteering_logs_feed_the_clock_fit(tmp_path: Path) -> None:
    """After power-up or a reset a receiver's GPS time is its coarse guess (UNKNOWN, COARSE): such logs are
    recorded but give the time base no (GPS time, host time) pair; FINESTEERING ones do."""
    from drivers.novatel import Framer, TimeStatus, encode_binary, make_header
    from drivers.novatel.receiver import ReceivedChunk
    from tests.novatel.gen import sample_bestpos

    cfg = _config()
    rover = next(r for r in cfg.receivers if r.name == "rover_a").model_copy(
        update={"port": str(tmp_path / "no-such-port"), "correction_device": None})
    cfg = cfg.model_copy(update={"receivers": (rover,), "relay": None, "daq": None, "simulation": None, "can": ()})
    session = Recording(cfg, out_dir=tmp_path, name="fine")
    session.start()
    try:
        dev = session.gnss["rover_a"]
        clock = session.timebase.gnss_clock("rover_a")
        for k, status in enumerate((TimeStatus.UNKNOWN, TimeStatus.COARSE, TimeStatus.FINESTEERING)):
            body = sample_bestpos(k)
            raw = encode_binary(make_header(body, week=2400, seconds=345600.0 + k, time_status=status), body)
            frames = Framer().feed(raw)
            dev._on_data(ReceivedChunk("rover_a", session.clock.now_ns(), raw, tuple(frames), 1))
            assert clock.n == (1 if status is TimeStatus.FINESTEERING else 0), status
    finally:
        session.stop()
