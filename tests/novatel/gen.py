"""Hypothesis strategies and comparison helpers for the NovAtel codec tests.

Bodies are generated over the whole wire range of each field (float32 fields get float32 values,
integers their full unsigned/signed width, enums any 32-bit value, known or not). ASCII carries a
fixed number of decimals per field, so ASCII comparisons use the field's printed resolution as
the tolerance: half a unit of the last printed digit (plus one ulp of the value).
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

from hypothesis import strategies as st

from drivers.novatel import (
    BestPos,
    BestVel,
    BestXyz,
    Header,
    Heading,
    Heading2,
    Mark2Pos,
    Mark2Time,
    MarkPos,
    MarkTime,
    PsrDop,
    ShortHeader,
    Time,
    TimeStatus,
)
from drivers.novatel.enums import PORT_NAME_BY_BYTE
from drivers.novatel.layouts import CODECS_BY_CLASS, FieldSpec, Kind

TYPED = (BestPos, BestVel, BestXyz, MarkPos, Mark2Pos, MarkTime, Mark2Time, Time, Heading, Heading2, PsrDop)

#: Characters a station ID may hold on the wire in every form (no quote, no '*', no line break).
STN_ALPHABET = "".join(chr(c) for c in range(0x20, 0x7F) if chr(c) not in '"*')

#: Port names as ASCII headers print them (any), and those that survive the one-byte binary field.
ASCII_PORTS = ("COM1", "COM2", "COM3", "USB1", "USB2", "ICOM1", "ICOM3", "XCOM1", "COM1_3", "THISPORT", "FILE")
BINARY_PORTS = tuple(sorted(PORT_NAME_BY_BYTE.values()))

U8 = st.integers(0, 0xFF)
U16 = st.integers(0, 0xFFFF)
U32 = st.integers(0, 0xFFFF_FFFF)
I32 = st.integers(-(2**31), 2**31 - 1)
F32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
#: Doubles short of the top of the range: printed with 9 significant digits, 1.7976931348e308
#: would round up past the largest double (no receiver value comes near).
F64 = st.floats(min_value=-1e300, max_value=1e300, allow_nan=False, allow_infinity=False)


def _enum_values(enum: Any) -> st.SearchStrategy[Any]:
    return st.one_of(st.sampled_from(list(enum)), U32.map(enum))


def _enum_byte(enum: Any) -> st.SearchStrategy[Any]:
    return st.one_of(st.sampled_from(list(enum)), U8.map(enum))


def _field_strategy(spec: FieldSpec) -> st.SearchStrategy[Any]:
    if spec.kind is Kind.ENUM:
        return _enum_values(spec.enum)
    if spec.kind is Kind.STR:
        return st.text(alphabet=STN_ALPHABET, max_size=4)
    if spec.kind is Kind.FLOAT:
        return F32 if spec.code == "f" else F64
    return {"B": U8, "I": U32, "i": I32, "H": U16}[spec.code]


def body_strategy(cls: type[Any]) -> st.SearchStrategy[Any]:
    """Any body of a typed log class, over the full wire range of each field."""
    codec = CODECS_BY_CLASS[cls]
    kwargs = {spec.name: _field_strategy(spec) for spec in codec.specs}
    if cls is PsrDop:
        kwargs["prns"] = st.lists(U32, max_size=40).map(tuple)
    return st.builds(cls, **kwargs)


def long_header_strategy(cls: type[Any], *, binary: bool) -> st.SearchStrategy[Header]:
    """A long header for a typed body; ``binary`` limits ports to those a binary header can name."""
    return st.builds(
        Header,
        message_name=st.just(cls.MESSAGE_NAME),
        message_id=st.just(cls.MESSAGE_ID),
        port=st.sampled_from(BINARY_PORTS if binary else ASCII_PORTS),
        sequence=U16,
        idle_time_pct=st.integers(0, 255).map(lambda k: k * 0.5),
        time_status=_enum_byte(TimeStatus) if binary else st.sampled_from(list(TimeStatus)),
        week=U16,
        seconds=st.integers(0, 604_800_000 - 1).map(lambda ms: ms / 1000),
        receiver_status=U32,
        reserved=U16,
        sw_version=U16,
        source=st.integers(0, 31),
        response=st.just(False),
    )


def short_header_strategy(cls: type[Any]) -> st.SearchStrategy[ShortHeader]:
    return st.builds(
        ShortHeader,
        message_name=st.just(cls.MESSAGE_NAME),
        message_id=st.just(cls.MESSAGE_ID),
        week=U16,
        seconds=st.integers(0, 604_800_000 - 1).map(lambda ms: ms / 1000),
    )


def ascii_abs_tol(spec: FieldSpec, value: float) -> tuple[float, float]:
    """(absolute, relative) tolerance of a float field after an ASCII round trip."""
    ulp = math.ulp(value) if math.isfinite(value) else 0.0
    fmt = spec.fmt
    if not fmt:  # printed with repr: exact
        return 0.0, 0.0
    digits = int(fmt[1:-1])
    if fmt.endswith("f"):
        return 0.5 * 10.0**-digits * (1 + 1e-9) + 2 * ulp, 0.0
    # exponent form: relative resolution
    return 2 * ulp, 0.5 * 10.0**-digits * (1 + 1e-6)


def assert_body_close(expected: Any, actual: Any, *, ascii_: bool, float32: bool = False) -> None:
    """Field-by-field equality of two bodies; floats within the ASCII resolution when ``ascii_``.

    ``float32``: the values went through the binary layout, so float32 fields are compared at
    float32 precision (relative 2**-24).
    """
    assert type(expected) is type(actual), (type(expected), type(actual))
    specs = {s.name: s for s in CODECS_BY_CLASS[type(expected)].specs}
    for f in fields(expected):
        want = getattr(expected, f.name)
        got = getattr(actual, f.name)
        spec = specs.get(f.name)
        if spec is None or spec.kind is not Kind.FLOAT:
            assert got == want, f"{type(expected).__name__}.{f.name}: {got!r} != {want!r}"
            continue
        abs_tol, rel_tol = ascii_abs_tol(spec, want) if ascii_ else (0.0, 0.0)
        if float32 and spec.code == "f":
            rel_tol = max(rel_tol, 2.0**-24)
            abs_tol = max(abs_tol, 1e-45)
        assert math.isclose(got, want, rel_tol=rel_tol, abs_tol=abs_tol), (
            f"{type(expected).__name__}.{f.name}: {got!r} != {want!r} (abs {abs_tol:g}, rel {rel_tol:g})"
        )


# --- sample streams ------------------------------------------------------------------------


def rtcm_1005(station_id: int, x_m: float, y_m: float, z_m: float) -> bytes:
    """An RTCM3 1005 frame (reference station ARP) built by pyrtcm from a bit-packed payload."""
    from pyrtcm import RTCMMessage

    fields = [
        (1005, 12),
        (station_id, 12),
        (0, 6),
        (1, 1),  # GPS
        (1, 1),  # GLONASS
        (0, 1),
        (0, 1),
        (round(x_m * 10_000), 38),
        (0, 1),
        (0, 1),
        (round(y_m * 10_000), 38),
        (0, 2),
        (round(z_m * 10_000), 38),
    ]
    value = 0
    width = 0
    for field_value, bits in fields:
        value = (value << bits) | (field_value & ((1 << bits) - 1))
        width += bits
    pad = -width % 8
    payload = (value << pad).to_bytes((width + pad) // 8, "big")
    frame: bytes = RTCMMessage(payload=payload).serialize()
    return frame


def nmea_gga(seq: int) -> bytes:
    """A GGA sentence rendered (with its checksum) by pynmea2."""
    import pynmea2

    msg = pynmea2.GGA(
        "GP",
        "GGA",
        (f"1200{seq % 60:02d}.00", "4807.038", "N", "01131.000", "E", "4", "12", "0.9", "545.4", "M", "46.9", "M",
         "1.0", "0131"),
    )
    return str(msg).encode("ascii")


def sample_bestpos(i: int = 0) -> BestPos:
    from drivers.novatel import Datum, PositionType, SolutionStatus

    return BestPos(
        SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 48.1173 + i * 1e-7, 11.5167, 545.4, 46.9, Datum.WGS84,
        0.012, 0.011, 0.021, "131", 1.0, 0.0, 20, 18, 18, 16, 0, 0x02, 0x11, 0x33,
    )


def mixed_stream() -> list[tuple[Any, bytes, bytes]]:
    """One frame of every kind, as (kind, bytes on the wire, expected Frame.raw)."""
    from drivers.novatel import (
        BestVel,
        FrameKind,
        PositionType,
        SolutionStatus,
        encode_abbreviated,
        encode_ascii,
        encode_binary,
        encode_error,
        encode_ok,
        encode_prompt,
        make_header,
        make_short_header,
    )

    pos = sample_bestpos()
    vel = BestVel(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 0.05, 1.0, 13.5, 87.25, -0.02, 0.0)
    head = make_header(pos, week=2300, seconds=345600.05, port="COM1", sequence=1, idle_time_pct=80.0)
    vhead = make_header(vel, week=2300, seconds=345600.05, port="USB1")

    def line(kind: Any, data: bytes) -> tuple[Any, bytes, bytes]:
        return kind, data, data.rstrip(b"\r\n")

    binary = encode_binary(head, pos)
    short = encode_binary(make_short_header(vel, week=2300, seconds=345600.1), vel)
    rtcm = rtcm_1005(2003, 4_177_000.1234, 855_000.5678, 4_727_000.9)
    abbrev = encode_abbreviated(head, pos)
    return [
        line(FrameKind.PROMPT, encode_prompt("COM1")),
        line(FrameKind.RESPONSE, encode_ok()),
        (FrameKind.NOVATEL_BINARY, binary, binary),
        line(FrameKind.NOVATEL_ASCII, encode_ascii(vhead, vel)),
        line(FrameKind.NMEA, nmea_gga(1) + b"\r\n"),
        (FrameKind.RTCM3, rtcm, rtcm),
        line(FrameKind.RESPONSE, encode_error("Invalid Message ID")),
        (FrameKind.NOVATEL_SHORT_BINARY, short, short),
        line(FrameKind.NOVATEL_SHORT_ASCII, encode_ascii(make_short_header(pos, week=2300, seconds=1.5), pos)),
        line(FrameKind.NOVATEL_ABBREV, abbrev),
        line(FrameKind.PROMPT, encode_prompt("ICOM1")),
    ]


GARBAGE = st.binary(max_size=12).map(lambda b: b.translate(None, b"$<[\xd3"))  # no NMEA/abbrev/prompt/RTCM starts
"""Bytes between frames that start no frame of any kind."""


def damage(clean: bytes, data: st.DataObject) -> bytes:
    """``clean`` with 1-3 damages drawn from ``data``: a flipped bit, the end cut off, bytes dropped, garbage
    inserted (the damage a serial line does)."""
    damaged = bytearray(clean)
    for _ in range(data.draw(st.integers(1, 3), label="damages")):
        if not damaged:
            break
        at = data.draw(st.integers(0, len(damaged) - 1), label="at")
        how = data.draw(st.sampled_from(["flip", "cut", "drop", "insert"]), label="how")
        if how == "flip":
            damaged[at] ^= 1 << data.draw(st.integers(0, 7), label="bit")
        elif how == "cut":
            del damaged[at:]
        elif how == "drop":
            del damaged[at : at + data.draw(st.integers(1, 40), label="n")]
        else:
            damaged[at:at] = data.draw(GARBAGE, label="garbage")
    return bytes(damaged)
