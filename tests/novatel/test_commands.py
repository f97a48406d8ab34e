"""Configuration command text, and raw logs (RANGECMPB, RAWEPHEMB) that are kept byte-exact."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.novatel import (
    BodyFormat,
    FrameKind,
    Framer,
    Header,
    RawBody,
    TimeStatus,
    decode_ascii,
    decode_binary,
    encode_ascii,
    encode_binary,
)
from drivers.novatel.commands import (
    LogRequest,
    LogTrigger,
    fix_position_command,
    interfacemode_command,
    log_command,
    markcontrol_command,
    serialconfig_command,
    standard_configuration,
    unlogall_command,
)
from vsccore.errors import EncodeError


def test_log_commands() -> None:
    assert log_command("COM1", LogRequest("BESTPOSB", LogTrigger.ONTIME, 0.05)) == "LOG COM1 BESTPOSB ONTIME 0.05"
    assert log_command("COM1", LogRequest("TIMEB", LogTrigger.ONTIME, 1.0)) == "LOG COM1 TIMEB ONTIME 1"
    assert log_command("USB1", LogRequest("MARKPOSB", LogTrigger.ONNEW)) == "LOG USB1 MARKPOSB ONNEW"
    assert log_command("COM1", LogRequest("RAWEPHEMB", LogTrigger.ONCHANGED)) == "LOG COM1 RAWEPHEMB ONCHANGED"
    rangecmp = LogRequest("RANGECMPB", LogTrigger.ONTIME, 0.1, 0.05)
    assert log_command("COM1", rangecmp) == "LOG COM1 RANGECMPB ONTIME 0.1 0.05"
    with pytest.raises(EncodeError, match="ONTIME needs a period"):
        log_command("COM1", LogRequest("BESTPOSB"))
    with pytest.raises(EncodeError, match="only valid with ONTIME"):
        log_command("COM1", LogRequest("MARKPOSB", LogTrigger.ONNEW, 1.0))
    with pytest.raises(EncodeError, match="not a NovAtel port"):
        log_command("COMX", LogRequest("BESTPOSB", LogTrigger.ONTIME, 1.0))
    with pytest.raises(EncodeError, match="not a log name"):
        log_command("COM1", LogRequest("bestpos; FRESET", LogTrigger.ONCE))


def test_port_and_mode_commands() -> None:
    assert unlogall_command() == "UNLOGALL"
    assert unlogall_command("COM2") == "UNLOGALL COM2"
    assert interfacemode_command("COM2", "RTCMV3", "NONE", responses=False) == "INTERFACEMODE COM2 RTCMV3 NONE OFF"
    assert serialconfig_command("COM2", 115200) == "SERIALCONFIG COM2 115200 N 8 1 N ON"
    assert markcontrol_command() == "MARKCONTROL MARK1 ENABLE POSITIVE"
    assert fix_position_command(51.11663, -114.03879, 1048.2) == "FIX POSITION 51.1166300000 -114.0387900000 1048.2000"
    with pytest.raises(EncodeError, match="FIX POSITION"):
        fix_position_command(91.0, 0.0, 0.0)
    with pytest.raises(EncodeError, match="SERIALCONFIG"):
        serialconfig_command("COM2", 0)
    with pytest.raises(EncodeError, match="INTERFACEMODE"):
        interfacemode_command("COM2", "rtcm v3", "NONE")


def test_standard_configuration_order_for_a_base() -> None:
    commands = standard_configuration(
        "COM1",
        [LogRequest("BESTPOSB", LogTrigger.ONTIME, 1.0), LogRequest("RTCM1005B", LogTrigger.ONTIME, 10.0)],
        interface_modes=[("COM2", "NONE", "RTCMV3")],
        serial_configs=[("COM2", 57600)],
        fix_position=(51.0, -114.0, 1000.0),
        extra=["SAVECONFIG"],
    )
    assert commands == (
        "UNLOGALL",
        "SERIALCONFIG COM2 57600 N 8 1 N OFF",
        "INTERFACEMODE COM2 NONE RTCMV3 ON",
        "UNDULATION USER 0.0",  # the height is ellipsoidal (the default), sent before FIX reads it
        "FIX POSITION 51.0000000000 -114.0000000000 1000.0000",
        "LOG COM1 BESTPOSB ONTIME 1",
        "LOG COM1 RTCM1005B ONTIME 10",
        "SAVECONFIG",
    )
    msl = standard_configuration("COM1", [], fix_position=(51.0, -114.0, 1000.0), fix_height_ellipsoidal=False)
    assert msl[-2:] == ("UNDULATION EGM96", "FIX POSITION 51.0000000000 -114.0000000000 1000.0000")
    with pytest.raises(EncodeError, match="line break"):
        standard_configuration("COM1", [], extra=["A\nB"])


@settings(max_examples=30, deadline=None)
@given(body=st.binary(max_size=600), message_id=st.sampled_from([140, 41, 43, 9999]))
def test_raw_logs_are_kept_byte_exact(body: bytes, message_id: int) -> None:
    """RANGECMPB (140), RAWEPHEMB (41), RANGEB (43) and unknown IDs pass through as raw bytes."""
    names = {140: "RANGECMP", 41: "RAWEPHEM", 43: "RANGE", 9999: "MSG9999"}
    header = Header(names[message_id], message_id, "COM1", 7, 50.0, TimeStatus.FINESTEERING, 2300, 12.5, 0, 0, 0)
    frame = encode_binary(header, RawBody(body, BodyFormat.BINARY))
    framer = Framer()
    (got,) = framer.feed(b"\x00" + frame + b"\x00")
    assert got.kind is FrameKind.NOVATEL_BINARY and got.raw == frame
    assert got.log is not None and got.log.header == header
    assert got.log.body == RawBody(body, BodyFormat.BINARY)
    assert decode_binary(frame) == got.log
    assert encode_binary(got.log.header, got.log.body) == frame


def test_raw_ascii_log_keeps_its_body_text() -> None:
    header = Header("RANGECMP", 140, "COM1", 0, 50.0, TimeStatus.FINESTEERING, 2300, 12.5, 0, 0, 0)
    line = encode_ascii(header, RawBody(b"2,049c1c0b,1f2e3d4c", BodyFormat.ASCII))
    log = decode_ascii(line)
    assert log.body == RawBody(b"2,049c1c0b,1f2e3d4c", BodyFormat.ASCII)
    assert encode_ascii(log.header, log.body) == line
