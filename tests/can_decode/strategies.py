"""Hypothesis strategies shared by the CAN decoder tests: signal conversions and multiplexed messages."""

from __future__ import annotations

from cantools.database.can import Message, Signal
from cantools.database.conversion import BaseConversion
from hypothesis import strategies as st

SCALES = st.one_of(
    st.integers(-7, 7).filter(lambda v: v != 0),
    st.floats(1e-4, 1e3, allow_nan=False).flatmap(lambda v: st.sampled_from([v, -v])),
    st.sampled_from([0.1, 0.01, 0.0075, 0.03125, 1.0, 1, 5]),
)
OFFSETS = st.one_of(st.integers(-1000, 1000), st.floats(-1e4, 1e4, allow_nan=False), st.just(0))


@st.composite
def mux_message(draw: st.DrawFn) -> tuple[Message, list[bytes]]:
    """An 8-byte message 0x321 ``MX``: multiplexer ``MUX`` (3 bits), a nested multiplexer ``NESTED``
    under it, one to five children ``P<i>`` of either (random byte order, sign, scale and offset) and
    an unmultiplexed ``ALWAYS`` in the last byte; with 8–40 random payloads."""
    ids = st.lists(st.integers(0, 7), min_size=1, max_size=4, unique=True)
    signals = [Signal("MUX", 0, 3, is_multiplexer=True)]
    signals.append(Signal("NESTED", 3, 2, is_multiplexer=True, multiplexer_ids=draw(ids), multiplexer_signal="MUX"))
    byte = 1  # children get separate byte ranges (cantools cannot decode overlapping signals)
    for i in range(draw(st.integers(1, 5))):
        nbytes = draw(st.integers(1, 2))
        if byte + nbytes > 7:
            break
        parent = draw(st.sampled_from(["MUX", "NESTED"]))
        parent_ids = draw(ids) if parent == "MUX" else draw(st.lists(st.integers(0, 3), min_size=1, max_size=3))
        big = draw(st.booleans())
        length = draw(st.integers(1, 8 * nbytes))
        first = 8 * byte + draw(st.integers(0, 8 * nbytes - length))
        start = 8 * (first // 8) + 7 - first % 8 if big else first
        byte += nbytes
        signals.append(
            Signal(
                f"P{i}",
                start,
                length,
                byte_order="big_endian" if big else "little_endian",
                is_signed=draw(st.booleans()),
                conversion=BaseConversion.factory(scale=draw(SCALES), offset=draw(OFFSETS)),
                multiplexer_ids=parent_ids,
                multiplexer_signal=parent,
            )
        )
    signals.append(Signal("ALWAYS", 56, 8))
    message = Message(frame_id=0x321, name="MX", length=8, signals=signals, strict=False)
    payloads = draw(st.lists(st.binary(min_size=8, max_size=8), min_size=8, max_size=40))
    return message, payloads
