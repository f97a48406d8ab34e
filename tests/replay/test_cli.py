"""``rig replay``: the whole command onto a virtual bus, and its one-line errors."""

from __future__ import annotations

import pytest

from drivers.can.bus import CanBusConfig
from rig.cli.main import main
from rig.data import Session
from tests.replay.receiver import ReceivingRecorder


def test_rig_replay_onto_a_virtual_bus(recorded: Session, channel: str, capsys: pytest.CaptureFixture[str]) -> None:
    n = len(recorded.can_frames("vsc"))
    with ReceivingRecorder(CanBusConfig(interface="virtual", channel=channel, name="rx")) as rx:
        main(["replay", str(recorded.path), "--bus", f"virtual:{channel}", "--speed", "5",
              "--fault", "yaw_rate:offset=0.05@0.5..1", "--role", "yaw_rate", "--role", "swa"])
        out = capsys.readouterr().out
        lines = out.splitlines()
        sent = sum(1 for m in recorded.can_frames("vsc").records["can_id"] if m in (0x101, 0x86))
        assert rx.wait_for(sent, 5.0)
    assert 0 < sent < n and len(rx.frames) == sent
    assert {f.arbitration_id for f in rx.frames} == {0x101, 0x86}
    assert lines[0].startswith(f"replaying bus 'vsc': {sent} frames of 2 identifiers over ")
    assert "faults: yaw_rate:offset=0.05@0.5..1" in lines[0] and f"virtual {channel}" in lines[0]
    assert lines[-1].startswith(f"{sent} frames in 1 pass; send lateness µs: p50 ")


@pytest.mark.parametrize(("args", "message"), [
    (["--fault", "yaw_rate:wobble"],
     "rig: error: --fault 'yaw_rate:wobble': unknown fault kind 'wobble' (known: offset, freeze, dropout)"),
    (["--speed", "0"], "rig: error: rig replay: --speed must be a finite number > 0, got 0.0"),
    (["--id", "NoSuchMessage"], "rig: error: --id 'NoSuchMessage': not a number nor a message of the DBC"),
], ids=["fault", "speed", "id"])
def test_errors_are_one_line_and_exit_2(recorded: Session, channel: str, capsys: pytest.CaptureFixture[str],
                                        args: list[str], message: str) -> None:
    with pytest.raises(SystemExit) as info:
        main(["replay", str(recorded.path), "--bus", f"virtual:{channel}", *args])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [message]


def test_an_unreachable_bus_is_named(recorded: Session, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["replay", str(recorded.path), "--bus", "socketcand:vsc0,host=127.0.0.1,port=1"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rig: error: CAN bus 'replay' (socketcand vsc0): no socketcand server at 127.0.0.1:1")
