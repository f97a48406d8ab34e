"""The command parser: OEM7 syntax, defaults and the error texts."""

from __future__ import annotations

import pytest

from sim_devices.gnss.commands import (
    EventInCommand,
    FixCommand,
    InterfaceModeCommand,
    LogCommand,
    LogFormat,
    ReceiverCommandError,
    SerialConfigCommand,
    Trigger,
    UnlogAllCommand,
    parse_command,
)

KNOWN = frozenset({"BESTPOS", "BESTVEL", "MARKPOS", "INSPVA", "RTCM1006"})


def test_log_forms() -> None:
    assert parse_command("LOG BESTPOSB ONTIME 0.05", KNOWN) == LogCommand(None, "BESTPOS", LogFormat.BINARY,
                                                                          Trigger.ONTIME, 0.05, 0.0)
    assert parse_command("log com2 bestvela ontime 1 0.5", KNOWN) == LogCommand(
        "COM2", "BESTVEL", LogFormat.ASCII, Trigger.ONTIME, 1.0, 0.5
    )
    assert parse_command("LOG MARKPOS ONNEW", KNOWN).fmt is LogFormat.ABBREVIATED
    assert parse_command("LOG BESTPOSA", KNOWN).trigger is Trigger.ONCE
    assert parse_command("LOG INSPVA ONTIME 1", KNOWN).name == "INSPVA"  # a name ending in A
    assert parse_command("LOG THISPORT RTCM1006 ONTIME 10 0 HOLD", KNOWN).port == "THISPORT"


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("FOO", "Invalid Message ID"),
        ("LOG", "Message Missing Field"),
        ("LOG COM1 NOSUCHLOGB ONTIME 1", "Invalid Message. Field = 3"),
        ("LOG BESTPOSB SOMETIMES 1", "Invalid Message. Field = 3"),
        ("LOG BESTPOSB ONTIME 0.01", "Parameter 4 Out Of Range"),
        ("LOG BESTPOSB ONTIME 0.3", "Parameter 4 Out Of Range"),
        ("LOG BESTPOSB ONTIME", "Parameter 4 Out Of Range"),
        ("LOG BESTPOSB ONTIME 1 1", "Parameter 5 Out Of Range"),
        ("SERIALCONFIG COM1 12345", "Parameter 3 Out Of Range"),
        ("INTERFACEMODE COM2 BOGUS NONE", "Invalid Message. Field = 3"),
        ("FIX POSITION 91 0 0", "Parameter 3 Out Of Range"),
        ("FIX POSITION 45 9", "Message Missing Field"),
        ("SAVECONFIG NOW", "Invalid Message. Field = 2"),
    ],
)
def test_rejections(line: str, reason: str) -> None:
    with pytest.raises(ReceiverCommandError) as info:
        parse_command(line, KNOWN)
    assert info.value.reason == reason


def test_other_commands() -> None:
    assert parse_command("UNLOGALL", KNOWN) == UnlogAllCommand(None, False)
    assert parse_command("UNLOGALL COM2 TRUE", KNOWN) == UnlogAllCommand("COM2", True)
    assert parse_command("INTERFACEMODE COM2 RTCMV3 NONE OFF", KNOWN) == InterfaceModeCommand(
        "COM2", "RTCMV3", "NONE", False
    )
    assert parse_command("SERIALCONFIG COM1 460800 N 8 1 N OFF", KNOWN) == SerialConfigCommand("COM1", 460800)
    assert parse_command("COM COM2 9600", KNOWN).baud == 9600  # OEMV spelling
    assert parse_command("FIX POSITION 48.7758 9.1829 252.1", KNOWN) == FixCommand("POSITION",
                                                                                   (48.7758, 9.1829, 252.1))
    assert parse_command("EVENTINCONTROL MARK1 EVENT POSITIVE 250 10", KNOWN) == EventInCommand(
        "MARK1", True, True, 250, 10
    )
    assert parse_command("MARKCONTROL MARK1 DISABLE", KNOWN).enabled is False
