"""Property tests: every typed log survives encode → decode in binary, short binary, ASCII, short
ASCII and abbreviated ASCII; the ASCII and binary forms of one log agree; encoders refuse what
does not fit the wire."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.novatel import (
    BestPos,
    ClockModelStatus,
    Datum,
    FrameKind,
    Framer,
    Header,
    Log,
    PositionType,
    PsrDop,
    RawBody,
    SolutionStatus,
    Time,
    UTCStatus,
    decode_abbreviated,
    decode_ascii,
    decode_binary,
    encode_abbreviated,
    encode_ascii,
    encode_binary,
    make_header,
    make_short_header,
)
from drivers.novatel.layouts import CODECS_BY_CLASS
from drivers.novatel.messages import BodyFormat
from tests.novatel.gen import (
    TYPED,
    assert_body_close,
    body_strategy,
    long_header_strategy,
    short_header_strategy,
)
from vsccore.errors import EncodeError
from vsccore.gpstime import NS_PER_S, gps_ns_to_unix_ns, gps_to_ns

PROPS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
NAMES = [cls.__name__ for cls in TYPED]


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
def test_binary_long_header_round_trip_is_exact(cls: type) -> None:
    @PROPS
    @given(header=long_header_strategy(cls, binary=True), body=body_strategy(cls))
    def check(header: Header, body: object) -> None:
        frame = encode_binary(header, body)  # type: ignore[arg-type]
        assert frame[:3] == b"\xaa\x44\x12"
        log = decode_binary(frame)
        assert log == Log(header, body)  # type: ignore[arg-type]
        assert encode_binary(log.header, log.body) == frame

    check()


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
def test_binary_short_header_round_trip_is_exact(cls: Any) -> None:
    @PROPS
    @given(header=short_header_strategy(cls), body=body_strategy(cls))
    def check(header: object, body: object) -> None:
        size = len(CODECS_BY_CLASS[cls].encode_binary(body))
        if size > 255:  # a short header holds a one-byte length (PSRDOP with many PRNs)
            with pytest.raises(EncodeError, match=cls.MESSAGE_NAME):
                encode_binary(header, body)  # type: ignore[arg-type]
            return
        frame = encode_binary(header, body)  # type: ignore[arg-type]
        assert frame[:3] == b"\xaa\x44\x13"
        assert len(frame) == 12 + size + 4
        assert decode_binary(frame) == Log(header, body)  # type: ignore[arg-type]

    check()


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
def test_ascii_round_trip_within_printed_resolution(cls: type) -> None:
    @PROPS
    @given(header=long_header_strategy(cls, binary=False), body=body_strategy(cls))
    def check(header: Header, body: object) -> None:
        line = encode_ascii(header, body)  # type: ignore[arg-type]
        assert line.startswith(b"#") and line.endswith(b"\r\n")
        log = decode_ascii(line)
        assert log.header == header
        assert_body_close(body, log.body, ascii_=True)
        # a second pass is a fixed point: what ASCII can carry is carried exactly
        assert encode_ascii(log.header, log.body) == line

    check()


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
def test_short_ascii_round_trip(cls: Any) -> None:
    @PROPS
    @given(header=short_header_strategy(cls), body=body_strategy(cls))
    def check(header: object, body: object) -> None:
        line = encode_ascii(header, body)  # type: ignore[arg-type]
        assert line.startswith(b"%" + cls.MESSAGE_NAME.encode() + b"A,")
        log = decode_ascii(line)
        assert log.header == header
        assert_body_close(body, log.body, ascii_=True)

    check()


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
def test_abbreviated_round_trip(cls: type) -> None:
    @PROPS
    @given(header=long_header_strategy(cls, binary=False), body=body_strategy(cls))
    def check(header: Header, body: object) -> None:
        text = encode_abbreviated(header, body)  # type: ignore[arg-type]
        log = decode_abbreviated(text)
        assert log.header == header
        assert_body_close(body, log.body, ascii_=True)

    check()


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
def test_ascii_and_binary_of_one_log_agree(cls: type) -> None:
    """Decode the same log sent in both forms (through the framer, as from a port): they agree."""

    @PROPS
    @given(header=long_header_strategy(cls, binary=True), body=body_strategy(cls))
    def check(header: Header, body: object) -> None:
        framer = Framer()
        frames = framer.feed(encode_binary(header, body) + encode_ascii(header, body))  # type: ignore[arg-type]
        assert [f.kind for f in frames] == [FrameKind.NOVATEL_BINARY, FrameKind.NOVATEL_ASCII]
        binary, ascii_ = (f.log for f in frames)
        assert binary is not None and ascii_ is not None
        assert binary.header == ascii_.header
        assert_body_close(binary.body, ascii_.body, ascii_=True)

    check()


@PROPS
@given(leap=st.integers(0, 60), week=st.integers(0, 4000), ms=st.integers(0, 604_800_000 - 1))
def test_time_utc_offset_gives_leap_seconds_and_utc(leap: int, week: int, ms: int) -> None:
    """TIME's UTC offset is carried in every form; UTC = GPS − leap seconds (from the log)."""
    body = Time(ClockModelStatus.VALID, 1e-9, 2e-9, float(-leap), 2024, 1, 1, 0, 0, 0, UTCStatus.VALID)
    header = make_header(body, week=week, seconds=ms / 1000)
    for decoded in (decode_binary(encode_binary(header, body)), decode_ascii(encode_ascii(header, body))):
        assert isinstance(decoded.body, Time)
        assert decoded.body.leap_seconds == leap
        gps_ns = decoded.header.gps_ns
        assert gps_ns == week * 604_800 * NS_PER_S + ms * 1_000_000
        unix_ns = gps_ns_to_unix_ns(gps_ns, decoded.body.leap_seconds)
        # GPS epoch 1980-01-06 is Unix 315964800 s
        assert unix_ns == (315_964_800 + week * 604_800 - leap) * NS_PER_S + ms * 1_000_000
        assert gps_to_ns(week, ms / 1000) == gps_ns


def test_psrdop_prn_list_is_variable_length() -> None:
    body = PsrDop(1.5, 1.25, 0.75, 1.0, 0.5, 10.0, (3, 7, 12, 31))
    header = make_header(body, week=2300, seconds=1.0)
    frame = encode_binary(header, body)
    assert len(frame) == 28 + 6 * 4 + 4 + 4 * 4 + 4
    assert decode_binary(frame).body == body
    line = encode_ascii(header, body)
    assert b";1.5000,1.2500,0.7500,1.0000,0.5000,10.0,4,3,7,12,31*" in line


def test_encoders_refuse_values_that_do_not_fit() -> None:
    good = _bestpos("AB")
    header = make_header(good, week=2300, seconds=0.0)
    with pytest.raises(EncodeError, match="stn_id"):
        encode_binary(header, _bestpos("ABCDE"))
    with pytest.raises(EncodeError, match="BESTPOS"):
        encode_binary(header, dataclasses.replace(good, num_svs=256))
    with pytest.raises(EncodeError, match="BESTPOS"):
        encode_binary(make_header(good, week=70000, seconds=0.0), good)
    with pytest.raises(EncodeError, match="seconds"):
        encode_binary(make_header(good, week=1, seconds=-1.0), good)
    with pytest.raises(EncodeError, match="port"):
        encode_binary(make_header(good, week=1, seconds=0.0, port="NOPE"), good)
    with pytest.raises(EncodeError, match=r"'\*'"):
        encode_ascii(header, _bestpos("A*"))
    wrong = Header(**{**_fields(header), "message_name": "BESTVEL", "message_id": 99})  # type: ignore[arg-type]
    with pytest.raises(EncodeError, match="BESTVEL"):
        encode_binary(wrong, good)
    with pytest.raises(EncodeError, match="raw binary"):
        encode_ascii(header, RawBody(b"\x00", BodyFormat.BINARY))


def _bestpos(stn_id: str) -> BestPos:
    return BestPos(
        SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 48.1, 11.5, 520.0, 47.0, Datum.WGS84,
        0.01, 0.01, 0.02, stn_id, 1.0, 0.0, 20, 18, 18, 16, 0, 0, 0, 0,
    )


def _fields(header: Header) -> dict[str, object]:
    return {name: getattr(header, name) for name in Header.__dataclass_fields__}


def test_header_seconds_are_carried_as_milliseconds() -> None:
    body = _bestpos("")
    for seconds in (1.2344, 1.2346, 604799.999):
        want = round(seconds * 1000) / 1000
        frame = encode_binary(make_short_header(body, week=2000, seconds=seconds), body)
        assert decode_binary(frame).header.seconds == want
        line = encode_ascii(make_header(body, week=2000, seconds=seconds), body)
        assert decode_ascii(line).header.seconds == want
        assert math.isclose(want, seconds, abs_tol=0.0005)
