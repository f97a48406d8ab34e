"""The vectorised decoder against cantools ``Message.decode`` over random layouts and payloads."""

from __future__ import annotations

import math

import cantools.database.errors
import numpy as np
import pytest
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.can.checks import FrameFlag
from drivers.can.vector_decode import FrameBatch, MessageDecoder, VectorDecoder
from tests.can_decode.strategies import OFFSETS, SCALES, mux_message
from vsccore.errors import DecodeError

_LENGTHS = [1, 2, 3, 5, 8, 8, 8, 8, 12, 16, 24, 32, 64]



@st.composite
def _signal(draw: st.DrawFn, index: int, length_bytes: int) -> Signal | None:
    total = 8 * length_bytes
    is_float = draw(st.integers(0, 5)) == 0
    length = draw(st.sampled_from([32, 64])) if is_float else draw(st.integers(1, 64))
    if length > total:
        return None
    big = draw(st.booleans())
    if big:
        msb_lin = draw(st.integers(0, total - length))  # position in the big-endian bit string
        start = 8 * (msb_lin // 8) + 7 - msb_lin % 8  # DBC sawtooth numbering of the MSB
    else:
        start = draw(st.integers(0, total - length))
    conversion = BaseConversion.factory(scale=draw(SCALES), offset=draw(OFFSETS), choices=None, is_float=is_float)
    return Signal(
        name=f"S{index}",
        start=start,
        length=length,
        byte_order="big_endian" if big else "little_endian",
        is_signed=False if is_float else draw(st.booleans()),
        conversion=conversion,
    )


def _bits(signal: Signal) -> set[int]:
    """DBC bit numbers (8 * byte + bit) a signal occupies."""
    if signal.byte_order == "little_endian":
        return set(range(signal.start, signal.start + signal.length))
    msb_lin = 8 * (signal.start // 8) + 7 - signal.start % 8
    return {8 * (p // 8) + 7 - p % 8 for p in range(msb_lin, msb_lin + signal.length)}


@st.composite
def _message_and_payloads(draw: st.DrawFn) -> tuple[Message, list[bytes]]:
    length_bytes = draw(st.sampled_from(_LENGTHS))
    signals: list[Signal] = []
    used: set[int] = set()
    for i in range(draw(st.integers(1, 6))):
        s = draw(_signal(i, length_bytes))
        # cantools cannot decode overlapping signals reliably, so the reference layouts do not overlap.
        if s is not None and not (_bits(s) & used):
            signals.append(s)
            used |= _bits(s)
    if not signals:
        signals = [Signal("S0", 0, 1)]
    message = Message(
        frame_id=0x123, name="M", length=length_bytes, signals=signals, strict=False, is_fd=length_bytes > 8
    )
    payloads = draw(st.lists(st.binary(min_size=length_bytes, max_size=length_bytes), min_size=1, max_size=25))
    # Include the extreme patterns that exercise sign extension and 64-bit values.
    payloads += [b"\xff" * length_bytes, b"\x00" * length_bytes, b"\x80" * length_bytes]
    return message, payloads


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


def _as_array(payloads: list[bytes], width: int) -> np.ndarray:
    arr = np.zeros((len(payloads), width), dtype=np.uint8)
    for i, p in enumerate(payloads):
        arr[i, : len(p)] = np.frombuffer(p, dtype=np.uint8)
    return arr


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_message_and_payloads())
def test_matches_cantools_on_random_layouts(case: tuple[Message, list[bytes]]) -> None:
    message, payloads = case
    width = 8 if message.length <= 8 else 64
    decoded = MessageDecoder(message).decode(_as_array(payloads, width), np.full(len(payloads), message.length))
    assert decoded.flags.tolist() == [0] * len(payloads)
    for i, payload in enumerate(payloads):
        raw = message.decode(payload, decode_choices=False, scaling=False)
        phys = message.decode(payload, decode_choices=False, scaling=True)
        for signal in message.signals:
            ours_raw = decoded.raw[signal.name][i].item()
            assert _same(float(ours_raw), float(raw[signal.name])), (signal, payload.hex())
            if not signal.is_float:
                assert int(ours_raw) == raw[signal.name], (signal, payload.hex())
            assert _same(float(decoded.values[signal.name][i]), float(phys[signal.name])), (signal, payload.hex())


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mux_message())
def test_multiplexed_messages_match_cantools(case: tuple[Message, list[bytes]]) -> None:
    message, payloads = case
    decoded = MessageDecoder(message).decode(_as_array(payloads, 8))
    for i, payload in enumerate(payloads):
        try:
            phys = message.decode(payload, decode_choices=False, scaling=True)
        except cantools.database.errors.DecodeError:
            assert decoded.flags[i] & FrameFlag.DECODE_ERROR, payload.hex()
            assert all(math.isnan(v[i]) for v in decoded.values.values())
            continue
        assert decoded.flags[i] == 0, payload.hex()
        present = {name for name, mask in decoded.present.items() if mask[i]}
        assert present == set(phys), payload.hex()
        for name, value in phys.items():
            assert _same(float(decoded.values[name][i]), float(value))
        for name in set(decoded.values) - present:
            assert math.isnan(decoded.values[name][i])


def test_known_motorola_and_intel_layouts() -> None:
    # Hand-worked example: Motorola 12-bit signal, MSB at bit 7 of byte 0 (start 7), so it is
    # byte0 << 4 | byte1 >> 4; Intel signed 10-bit at start 20 spans bytes 2..3.
    sig_be = Signal("BE", 7, 12, byte_order="big_endian")
    sig_le = Signal("LE", 20, 10, is_signed=True, conversion=BaseConversion.factory(0.5, -1.0))
    msg = Message(0x10, "K", 8, [sig_be, sig_le], strict=False)
    payload = bytes([0xAB, 0xC0, 0x00, 0x3F, 0, 0, 0, 0])
    le_raw = (int.from_bytes(payload, "little") >> 20) & 0x3FF  # = 0x3F0
    le_signed = le_raw - 1024 if le_raw & 0x200 else le_raw
    decoded = MessageDecoder(msg).decode(_as_array([payload], 8))
    assert decoded.raw["BE"][0] == 0xABC
    assert decoded.raw["LE"][0] == le_signed == -16
    assert decoded.values["LE"][0] == -16 * 0.5 - 1.0


def test_wrong_length_frames_are_flagged_and_give_no_values() -> None:
    msg = Message(0x10, "K", 8, [Signal("A", 0, 8)], strict=False)
    db = Database(messages=[msg])
    batch = FrameBatch.from_frames(
        [(1, 0x10, bytes(8)), (2, 0x10, b"\x05\x06"), (3, 0x11, b"\x01"), (4, 0x10, b"\x07" * 8)]
    )
    result = VectorDecoder(db).decode(batch)
    k = result.messages["K"]
    assert k.flags.tolist() == [0, int(FrameFlag.WRONG_LENGTH), 0]
    assert k.values["A"][0] == 0 and math.isnan(k.values["A"][1]) and k.values["A"][2] == 7
    assert k.batch_index.tolist() == [0, 1, 3]
    assert k.timestamps_ns.tolist() == [1, 2, 4]
    assert dict(result.unknown_ids) == {0x11: 1}


def test_can_fd_64_byte_payload() -> None:
    sig = Signal("TAIL", 8 * 60, 32, is_signed=True)
    sig_be = Signal("BE", 8 * 62 + 7, 16, byte_order="big_endian")
    msg = Message(0x200, "FD", 64, [sig, sig_be], strict=False, is_fd=True)
    payload = bytes(60) + bytes([0x01, 0x02, 0x03, 0x84])
    decoded = MessageDecoder(msg).decode(_as_array([payload], 64))
    assert decoded.raw["TAIL"][0] == int.from_bytes(payload[60:], "little", signed=True)
    assert decoded.raw["BE"][0] == 0x0384


def test_frame_batch_rejects_inconsistent_shapes() -> None:
    with pytest.raises(DecodeError, match="lengths differ"):
        FrameBatch(np.zeros(2, np.int64), np.zeros(3, np.uint32), np.zeros((2, 8), np.uint8), np.zeros(2))
    with pytest.raises(DecodeError, match="dlc outside"):
        FrameBatch(np.zeros(1, np.int64), np.zeros(1, np.uint32), np.zeros((1, 8), np.uint8), np.array([9]))
    with pytest.raises(DecodeError, match="does not fit"):
        FrameBatch.from_frames([(0, 1, bytes(12))], width=8)


def test_base_and_extended_frames_with_the_same_number_are_different_messages() -> None:
    from drivers.can.checks import CAN_EFF_FLAG, frame_key
    from drivers.can.roles import RoleDecoder, RoleMap

    base = Message(0x101, "BASE", 8, [Signal("A", 0, 8)], strict=False)
    ext = Message(0x101, "EXT", 8, [Signal("B", 8, 8)], strict=False, is_extended_frame=True)
    db = Database(messages=[base, ext])
    payload = bytes([1, 2, 3, 4, 5, 6, 7, 8])
    assert frame_key(0x101, True) == 0x101 | CAN_EFF_FLAG == frame_key(0x101 | CAN_EFF_FLAG)
    batch = FrameBatch.from_frames(
        [(1, 0x101, payload), (2, frame_key(0x101, True), payload), (3, frame_key(0x102, True), payload)]
    )
    result = VectorDecoder(db).decode(batch)
    assert result.messages["BASE"].values["A"].tolist() == [1.0]
    assert result.messages["EXT"].values["B"].tolist() == [2.0]
    assert dict(result.unknown_ids) == {0x102 | CAN_EFF_FLAG: 1}
    roles = RoleMap.from_mapping(
        {"roles": {"a": {"message": "BASE", "signal": "A"}, "b": {"message": "EXT", "signal": "B"}}}, db
    )
    live = RoleDecoder(db, roles)
    assert [s.value for s in live.decode(0x101, payload, 1).samples] == [1.0]
    assert [s.value for s in live.decode(0x101, payload, 2, is_extended=True).samples] == [2.0]
    assert live.decode(0x102, payload, 3, is_extended=True).flags == FrameFlag.UNKNOWN_ID
    assert dict(live.stats().unknown_ids) == {0x102 | CAN_EFF_FLAG: 1}
