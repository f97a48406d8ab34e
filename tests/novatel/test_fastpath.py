"""The fast decode paths give exactly what the generic (reference) paths give, and the fast CRC is
the NovAtel CRC.

- CRC-32: ``zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF`` against the bit-by-bit reference of the
  NovAtel manual, and the zero residue over a frame with its CRC appended.
- Records built through slot twins (``messages.fast_constructor`` / ``RecordEmitter``) are ordinary
  frozen dataclass instances: equal, same hash, pickle, ``dataclasses.replace``, frozen.
- Generated whole-frame decoders (binary and ASCII) against the generic decoders, for bodies over
  the full wire range (unknown enum values, station IDs with commas, source suffixes, odd ports,
  response bit, non-standard header length, short headers, extra and missing fields): equal logs
  and equal error texts.
"""

from __future__ import annotations

import contextlib
import dataclasses
import pickle
import struct
import zlib
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.novatel import (
    BestPos,
    Datum,
    Frame,
    FrameKind,
    Framer,
    Header,
    Log,
    PositionType,
    RawBody,
    SolutionStatus,
    encode_ascii,
    encode_binary,
    make_header,
    novatel_crc32,
)
from drivers.novatel.ascii import (
    FAST_ASCII_DECODERS,
    decode_ascii_text,
    decode_ascii_verified,
    decode_ascii_verified_reference,
)
from drivers.novatel.binary import compile_long_frame_decoders, decode_verified, decode_verified_reference
from drivers.novatel.crc import novatel_crc32_residue_ok
from drivers.novatel.messages import BodyFormat, RecordEmitter, ShortHeader, fast_constructor, slot_twin
from tests.novatel.gen import TYPED, body_strategy, long_header_strategy, short_header_strategy
from tests.novatel.test_vectors import crc32_reference

PROPS = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
NAMES = [cls.__name__ for cls in TYPED]


# --- CRC ---------------------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(data=st.binary(max_size=300))
def test_zlib_relation_is_the_novatel_crc(data: bytes) -> None:
    # zlib: register starts at value ^ 0xFFFFFFFF and ends XOR 0xFFFFFFFF; NovAtel: starts at 0,
    # no final XOR. value = 0xFFFFFFFF starts the register at 0; XOR-ing the result undoes the end.
    assert zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF == crc32_reference(data)
    assert novatel_crc32(data) == crc32_reference(data)


@settings(max_examples=100, deadline=None)
@given(data=st.binary(max_size=300), flip=st.integers(0, 8 * 300 + 31))
def test_residue_over_frame_and_crc_is_zero_and_any_flip_breaks_it(data: bytes, flip: int) -> None:
    frame = data + struct.pack("<I", crc32_reference(data))
    assert crc32_reference(frame) == 0  # no final XOR: the register ends at 0
    assert novatel_crc32_residue_ok(frame)
    bad = bytearray(frame)
    bad[(flip // 8) % len(frame)] ^= 1 << (flip % 8)
    assert not novatel_crc32_residue_ok(bytes(bad))


# --- Records built through slot twins ------------------------------------------------------------


@pytest.mark.parametrize("use_twin", [True, False], ids=["twin", "descriptors"])
@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
@PROPS
@given(data=st.data())
def test_fast_constructor_gives_ordinary_frozen_instances(cls: type[Any], use_twin: bool, data: st.DataObject) -> None:
    body: Any = data.draw(body_strategy(cls))
    values = [getattr(body, f.name) for f in dataclasses.fields(body)]
    built: Any = fast_constructor(cls, use_twin=use_twin)(*values)
    assert type(built) is cls
    assert built == body and hash(built) == hash(body) and repr(built) == repr(body)
    assert pickle.loads(pickle.dumps(built)) == body
    first = dataclasses.fields(body)[0].name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(built, first, values[0])
    assert dataclasses.replace(built) == body


def test_record_emitter_refuses_unknown_and_unset_fields() -> None:
    emit = RecordEmitter(Log, "lg", {})
    emit.begin()
    with pytest.raises(TypeError, match="no field 'nope'"):
        emit.store("nope", "1")
    emit.store("header", "None")
    with pytest.raises(TypeError, match="leaves fields unset: body"):
        emit.end()


def test_every_hot_record_has_a_slot_twin() -> None:
    # Without a twin the emitter falls back to slower descriptor stores; on CPython all have one.
    for cls in (*TYPED, Header, ShortHeader, Log, RawBody, Frame):
        assert slot_twin(cls) is not None, cls.__name__


# --- Binary: generated frame decoders against the generic path -----------------------------------


def _same(fast: tuple[Log, str | None], reference: tuple[Log, str | None]) -> None:
    assert fast == reference
    assert type(fast[0].body) is type(reference[0].body)
    assert type(fast[0].header.time_status if isinstance(fast[0].header, Header) else None) is type(
        reference[0].header.time_status if isinstance(reference[0].header, Header) else None
    )


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
@PROPS
@given(data=st.data())
def test_binary_long_fast_path_equals_reference(cls: type, data: st.DataObject) -> None:
    body = data.draw(body_strategy(cls))
    header = data.draw(long_header_strategy(cls, binary=True))
    frame = encode_binary(header, body)
    _same(decode_verified(frame, False), decode_verified_reference(frame, False))
    frames = Framer().feed(frame)
    assert [f.kind for f in frames] == [FrameKind.NOVATEL_BINARY]
    assert (frames[0].message, frames[0].error) == decode_verified_reference(frame, False)


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
@PROPS
@given(data=st.data())
def test_binary_short_fast_path_equals_reference(cls: type, data: st.DataObject) -> None:
    body = data.draw(body_strategy(cls))
    try:
        frame = encode_binary(data.draw(short_header_strategy(cls)), body)
    except Exception:  # PSRDOP with many PRNs does not fit a short header
        return
    _same(decode_verified(frame, True), decode_verified_reference(frame, True))


def _reframe(frame: bytes, *, header: bytes | None = None, body: bytes | None = None) -> bytes:
    """A long-header frame with its header and/or body replaced, lengths and CRC recomputed."""
    hdr_len = frame[3]
    head = bytearray(frame[:hdr_len] if header is None else header)
    payload = frame[hdr_len:-4] if body is None else body
    head[3] = len(head)
    head[8:10] = struct.pack("<H", len(payload))
    out = bytes(head) + payload
    return out + struct.pack("<I", novatel_crc32(out))


def _bestpos_frame(**changes: Any) -> bytes:
    body = dataclasses.replace(
        BestPos(*(getattr(_BASE_BODY, f.name) for f in dataclasses.fields(BestPos))), **changes
    )
    return encode_binary(make_header(body, week=2300, seconds=345600.05, port="COM1"), body)


_BASE_BODY = BestPos(
    SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 51.1, -114.0, 1097.7, -17.0, Datum.WGS84, 0.01, 0.01, 0.02,
    "AB,C", 1.0, 0.0, 24, 22, 22, 20, 0, 2, 0x11, 0x33,
)


@pytest.mark.parametrize(
    "case",
    ["unknown_enum", "unknown_port", "unknown_time_status", "response_bit", "long_header", "short_body",
     "unknown_message", "raw_unknown_port"],
)
def test_binary_edge_cases_take_the_generic_path_with_the_same_result(case: str) -> None:
    frame = _bestpos_frame()
    if case == "unknown_enum":
        frame = _bestpos_frame(pos_type=200)
    elif case == "unknown_port":
        frame = _reframe(frame, header=frame[:7] + b"\x85" + frame[8:28])
    elif case == "unknown_time_status":
        frame = _reframe(frame, header=frame[:13] + b"\x07" + frame[14:28])
    elif case == "response_bit":
        frame = _reframe(frame, header=frame[:6] + bytes([frame[6] | 0x80]) + frame[7:28])
    elif case == "long_header":  # a header longer than 28 bytes (future firmware): body after it
        frame = _reframe(frame, header=frame[:28] + b"\x00\x00\x00\x00")
    elif case == "short_body":
        frame = _reframe(frame, body=frame[28:60])
    elif case == "unknown_message":
        frame = _reframe(frame, header=frame[:4] + struct.pack("<H", 4321) + frame[6:28])
    else:
        frame = _reframe(frame, header=frame[:4] + struct.pack("<H", 4321) + frame[6:7] + b"\x85" + frame[8:28])
    # The generated decoder declines (None) or raises KeyError, so the generic path is exercised.
    by_id, raw_decoder = compile_long_frame_decoders()
    assert by_id[42](_bestpos_frame()) is not None
    if frame[3] == 28:
        with contextlib.suppress(KeyError):
            assert by_id.get(frame[4] | frame[5] << 8, raw_decoder)(frame) is None
    reference = decode_verified_reference(frame, False)
    _same(decode_verified(frame, False), reference)
    frames = Framer().feed(frame)
    assert len(frames) == 1 and (frames[0].message, frames[0].error) == reference
    log = reference[0]
    if case in ("response_bit", "short_body", "unknown_message", "raw_unknown_port"):
        assert isinstance(log.body, RawBody) and log.body.fmt is BodyFormat.BINARY
    else:
        assert isinstance(log.body, BestPos)
    if case == "unknown_enum":
        assert log.body.pos_type.name == "UNKNOWN_200"  # type: ignore[union-attr]
    if case == "short_body":
        assert reference[1] is not None and "layout needs 72" in reference[1]


# --- ASCII: generated log decoders against the generic path ---------------------------------------


def _ascii_both(line: bytes) -> tuple[Any, Any]:
    text = line.rstrip(b"\r\n")
    star = text.rfind(b"*")

    def run(fn: Any, arg: Any) -> Any:
        try:
            return fn(arg)
        except Exception as exc:  # both paths must fail the same way
            return type(exc), str(exc)

    fast = run(decode_ascii_verified, text)
    assert fast == run(lambda t: decode_ascii_text(t[0], t[1 : star].decode("latin-1")), text)
    return fast, run(decode_ascii_verified_reference, text)


@pytest.mark.parametrize("cls", TYPED, ids=NAMES)
@PROPS
@given(data=st.data())
def test_ascii_fast_path_equals_reference(cls: type, data: st.DataObject) -> None:
    body = data.draw(body_strategy(cls))
    header = data.draw(long_header_strategy(cls, binary=False))
    fast, reference = _ascii_both(encode_ascii(header, body))
    assert fast == reference
    assert type(fast[0].body) is type(reference[0].body)


def _ascii_line(body_text: str, name: str = "BESTPOSA", head: str | None = None) -> bytes:
    head = head or "COM1,0,80.0,FINESTEERING,2300,345600.050,02000000,b1f6,16248"
    text = f"{name},{head};{body_text}".encode("latin-1")
    return b"#" + text + b"*" + f"{novatel_crc32(text):08x}".encode() + b"\r\n"


_GOOD_BODY = ("SOL_COMPUTED,NARROW_INT,51.15043874397,-114.03066788586,1097.6822,-17.0000,WGS84,0.0123,0.0098,"
              '0.0211,"131",1.000,0.000,24,22,22,20,00,02,11,33')


@pytest.mark.parametrize(
    ("body_text", "name", "head", "fast_takes_it"),
    [
        (_GOOD_BODY, "BESTPOSA", None, True),
        (_GOOD_BODY.replace('"131"', '"1,3"'), "BESTPOSA", None, False),  # quoted comma: csv split
        (_GOOD_BODY.replace('"131"', '"13'), "BESTPOSA", None, False),  # unbalanced quote
        (_GOOD_BODY.replace('"131"', "131"), "BESTPOSA", None, True),  # unquoted station ID
        (_GOOD_BODY.replace("NARROW_INT", "50"), "BESTPOSA", None, False),  # enum as a number
        (_GOOD_BODY.replace("NARROW_INT", "NARROW_INTX"), "BESTPOSA", None, False),  # unknown enum name
        (_GOOD_BODY.replace("1097.6822", "1097.68x2"), "BESTPOSA", None, False),  # bad float: names the field
        (_GOOD_BODY + ",7,8", "BESTPOSA", None, True),  # extra trailing fields (old firmware)
        (_GOOD_BODY.rsplit(",", 2)[0], "BESTPOSA", None, False),  # too few fields
        (_GOOD_BODY, "BESTPOSA_1", None, False),  # measurement source suffix
        (_GOOD_BODY, "BESTPOSA", "COM1,0,80.0,NO_SUCH_STATUS,2300,345600.050,02000000,b1f6,16248", False),
        (_GOOD_BODY, "BESTPOSA", "COM1,0,80.0,FINESTEERING,2300,345600.050,02000000,b1f6", False),  # 9 fields
        (_GOOD_BODY, "BESTPOSA", "COM1,x,80.0,FINESTEERING,2300,345600.050,02000000,b1f6,16248", False),
    ],
)
def test_ascii_edge_cases_take_the_generic_path_with_the_same_result(
    body_text: str, name: str, head: str | None, fast_takes_it: bool
) -> None:
    line = _ascii_line(body_text, name, head)
    text = line[1 : line.rfind(b"*")].decode("latin-1")
    head_text, _, rest = text.partition(";")
    decoder = FAST_ASCII_DECODERS.get(head_text.split(",")[0])
    if fast_takes_it:
        assert decoder is not None and isinstance(decoder(head_text.split(","), rest.split(",")), Log)
    elif decoder is not None:  # the generated decoder declines, so the generic path is exercised
        with pytest.raises((KeyError, ValueError, IndexError)):
            decoder(head_text.split(","), rest.split(","))
    fast, reference = _ascii_both(line)
    assert fast == reference
    frames = Framer().feed(line)
    assert len(frames) == 1 and frames[0].kind is FrameKind.NOVATEL_ASCII
    if isinstance(reference, tuple) and isinstance(reference[0], Log):
        assert (frames[0].message, frames[0].error) == reference
    else:  # the header did not parse: a frame with its error and no message
        assert frames[0].message is None and frames[0].error == reference[1]
