"""RecordSession pieces that need no simulated world: receiver commands, operator marks, a device
that cannot be opened (an event, the session records on)."""

from __future__ import annotations

import threading
from pathlib import Path

from rig.config import CanConfig, SessionConfig, load_session
from rig.dataset import load_session as load_recording
from rig.demo import demo_config_path
from rig.session import RecordSession, receiver_commands
from rig.topics import EventKind, Severity


def _config() -> SessionConfig:
    return load_session(demo_config_path())


def test_receiver_commands_configure_rover_and_base() -> None:
    cfg = _config()
    base, rover_a, rover_b = cfg.receivers
    cmds = receiver_commands(rover_a)
    assert cmds[0] == "UNLOGALL"
    assert "INTERFACEMODE COM2 RTCMV3 NONE ON" in cmds
    assert "MARKCONTROL MARK1 ENABLE POSITIVE" in cmds  # rover_a logs MARKPOS/MARKTIME
    assert "LOG COM1 BESTPOSB ONTIME 0.05" in cmds
    assert "LOG COM1 MARKTIMEB ONNEW" in cmds
    assert cmds.index("INTERFACEMODE COM2 RTCMV3 NONE ON") < cmds.index("LOG COM1 BESTPOSB ONTIME 0.05")
    assert not any(c.startswith("MARKCONTROL") for c in receiver_commands(rover_b))
    base_cmds = receiver_commands(base)
    assert "FIX POSITION 48.7758000000 9.1829000000 300.0000" in base_cmds
    assert "LOG COM1 RTCM1077 ONTIME 1" in base_cmds
    assert not any(c.startswith("INTERFACEMODE") for c in base_cmds)


def test_marks_and_a_device_that_cannot_open(tmp_path: Path) -> None:
    cfg = _config()
    bad = CanConfig(name="chassis", interface="no_such_interface", channel="can9", dbc=cfg.can[0].dbc)
    cfg = cfg.model_copy(update={"receivers": (), "relay": None, "daq": None, "simulation": None,
                                 "can": (cfg.can[0].model_copy(update={"channel": "vsc-unit"}), bad)})
    session = RecordSession(cfg, out_dir=tmp_path, name="unit")
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
