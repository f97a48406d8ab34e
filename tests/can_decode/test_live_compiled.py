"""The live path's fast forms give exactly what their readable originals give, frame by frame.

- :class:`RoleDecoder` with its compiled per-message decoders against ``compiled=False`` (cantools
  ``Message.decode`` of every signal, then the role specs one by one) over random DBC layouts
  (Intel and Motorola, signed, IEEE float, 1…64 bytes, named values, multiplexers), random role
  maps (units, inverted signs, sign bits, quality bits, counters) and random and faulty payloads,
  and over the real DBCs (the simulated car's and VW MQB with their shipped role maps);
- :func:`drivers.can.bus.frame_bit_times` (integers and tables) against the bit-list reference.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any, cast

import cantools.database.errors
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.can.bus import _frame_bit_times_reference, frame_bit_times
from drivers.can.dbc import load_dbc
from drivers.can.roles import DecodedFrame, MessageCheck, RoleDecoder, RoleMap, RoleSpec, encode_role_frame
from tests.can_decode.conftest import XOR
from tests.can_decode.strategies import OFFSETS, SCALES, mux_message

REPO = Path(__file__).resolve().parents[2]
_UNITS = ("1", "deg", "deg/s", "g", "km/h", "bar", "%")


def _same_value(a: float | int, b: float | int) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b and (not isinstance(a, float) or math.copysign(1, a) == math.copysign(1, b))


def assert_same(fast: DecodedFrame, slow: DecodedFrame, where: str) -> None:
    assert type(fast) is DecodedFrame
    assert (fast.timestamp_ns, fast.arbitration_id, fast.message, fast.flags) == (
        slow.timestamp_ns, slow.arbitration_id, slow.message, slow.flags), where
    assert len(fast.samples) == len(slow.samples), where
    for a, b in zip(fast.samples, slow.samples, strict=True):
        assert (a.role, a.timestamp_ns, a.unit, a.label, a.flags) == (b.role, b.timestamp_ns, b.unit, b.label, b.flags)
        assert _same_value(a.value, b.value), (where, a, b)  # bit for bit, the sign of zero included
        assert _same_value(a.raw, b.raw), (where, a, b)


def _both(db: Database, rolemap: RoleMap) -> tuple[RoleDecoder, RoleDecoder]:
    return RoleDecoder(db, rolemap), RoleDecoder(db, rolemap, compiled=False)


def _run(db: Database, rolemap: RoleMap, frames: list[tuple[int, bytes]]) -> RoleDecoder:
    fast, slow = _both(db, rolemap)
    for t, (frame_id, payload) in enumerate(frames):
        try:
            expected: DecodedFrame | type[Exception] = slow.decode(frame_id, payload, t)
        except (ValueError, cantools.database.errors.Error) as exc:  # e.g. int(NaN) of a float counter
            expected = type(exc)
        if isinstance(expected, DecodedFrame):
            assert_same(fast.decode(frame_id, payload, t), expected, f"frame {t}: {payload.hex()}")
        else:
            try:
                fast.decode(frame_id, payload, t)
            except expected:
                continue
            raise AssertionError(f"frame {t}: the generic path raised {expected.__name__}, the compiled one did not")
    assert fast.stats() == slow.stats()
    return fast


# --- random layouts ----------------------------------------------------------------------------


@st.composite
def _signal(draw: st.DrawFn, name: str, total_bits: int, used: set[int], *, length: int | None = None) -> Signal | None:
    is_float = length is None and draw(st.integers(0, 6)) == 0
    n = length if length is not None else (draw(st.sampled_from([32, 64])) if is_float else draw(st.integers(1, 32)))
    if n > total_bits:
        return None
    big = draw(st.booleans())
    first = draw(st.integers(0, total_bits - n))  # position in the big- or little-endian bit string
    if big:
        bits = {8 * (p // 8) + 7 - p % 8 for p in range(first, first + n)}
        start = 8 * (first // 8) + 7 - first % 8
    else:
        bits = set(range(first, first + n))
        start = first
    if bits & used:
        return None  # cantools cannot decode overlapping signals reliably
    used |= bits
    choices = None
    if not is_float and draw(st.integers(0, 4)) == 0:
        choices = {k: f"V{k}" for k in draw(st.lists(st.integers(0, min(7, (1 << n) - 1)), max_size=3, unique=True))}
    conversion = BaseConversion.factory(scale=draw(SCALES), offset=draw(OFFSETS),
                                        choices=cast(Any, choices or None), is_float=is_float)
    return Signal(name=name, start=start, length=n, byte_order="big_endian" if big else "little_endian",
                  is_signed=False if is_float else draw(st.booleans()), conversion=conversion)


@st.composite
def _layout(draw: st.DrawFn) -> tuple[Database, RoleMap, list[tuple[int, bytes]]]:
    length = draw(st.sampled_from([1, 2, 4, 6, 8, 8, 8, 12, 16, 32, 64]))
    used: set[int] = set()
    signals: list[Signal] = []
    for i in range(draw(st.integers(1, 6))):
        s = draw(_signal(f"S{i}", 8 * length, used))
        if s is not None:
            signals.append(s)
    flags: list[Signal] = []
    for i in range(3):
        flag = draw(_signal(f"F{i}", 8 * length, used, length=1))
        if flag is not None:
            flags.append(flag)
    counter = draw(_signal("CNT", 8 * length, used, length=4)) if draw(st.booleans()) else None
    extra = ([counter] if counter is not None else []) + flags
    if not signals:
        signals = [Signal("S0", min(set(range(8 * length)) - used), 1)]
    message = Message(frame_id=0x123, name="M", length=length, signals=signals + extra, strict=False,
                      is_fd=length > 8)
    db = Database(messages=[message])
    specs = []
    valid_when: st.SearchStrategy[int | tuple[int, ...]] = st.sampled_from([0, 1, (0, 1)])
    for i, s in enumerate(signals):
        use_sign: bool = draw(st.booleans())
        use_valid: bool = draw(st.booleans())
        sign = flags[0].name if flags and use_sign else None
        valid = flags[-1].name if flags and use_valid else None
        specs.append(RoleSpec(role=f"r{i}", message="M", signal=s.name, unit=draw(st.sampled_from(_UNITS)),
                              invert=draw(st.booleans()), sign_signal=sign, sign_negative_when=draw(st.integers(0, 1)),
                              valid_signal=valid, valid_when=draw(valid_when)))
    checks = (MessageCheck("M", counter_signal="CNT", max_counter_delta=draw(st.integers(1, 3))),) if counter else ()
    payloads = draw(st.lists(st.binary(min_size=length, max_size=length), min_size=1, max_size=30))
    payloads += [b"\xff" * length, b"\x00" * length, b"\x80" * length, b"\x01" * (length + 1), b"\x00" * (length - 1)]
    return db, RoleMap(tuple(specs), checks), [(0x123, p) for p in payloads] + [(0x124, b"\x00" * 8)]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_layout())
def test_compiled_decoder_matches_cantools_on_random_layouts(case: tuple[Database, RoleMap, list[tuple[int, bytes]]]
                                                            ) -> None:
    db, rolemap, frames = case
    assert _run(db, rolemap, frames).compiled_messages == ("M",)


@st.composite
def _mux_layout(draw: st.DrawFn) -> tuple[Database, RoleMap, list[tuple[int, bytes]]]:
    message, payloads = draw(mux_message())
    db = Database(messages=[message])
    signals = message.signals
    roles = [s for s in signals if s.name.startswith("P") or s.name == "ALWAYS"]
    specs = tuple(RoleSpec(role=f"r{i}", message="MX", signal=s.name, invert=draw(st.booleans()),
                           sign_signal="ALWAYS" if draw(st.booleans()) else None, sign_negative_when=1)
                  for i, s in enumerate(roles))
    return db, RoleMap(specs), [(0x321, p) for p in payloads]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_mux_layout())
def test_compiled_decoder_matches_cantools_on_multiplexed_messages(
    case: tuple[Database, RoleMap, list[tuple[int, bytes]]],
) -> None:
    db, rolemap, frames = case
    assert _run(db, rolemap, frames).compiled_messages == ("MX",)


# --- the real DBCs ---------------------------------------------------------------------------------


def _stream(db: Database, rolemap: RoleMap, n: int, seed: int) -> list[tuple[int, bytes]]:
    """Good frames (counters in sequence, checksums right) with faults mixed in: random payloads, bit flips,
    skipped and repeated counters, wrong lengths, unknown identifiers."""
    rng = random.Random(seed)
    frames: list[tuple[int, bytes]] = []
    counters = dict.fromkeys(rolemap.messages, 0)
    for _ in range(n):
        name = rng.choice(rolemap.messages)
        msg = db.get_message_by_name(name)
        fault = rng.random()
        if fault < 0.1:
            frames.append((msg.frame_id, rng.randbytes(msg.length)))
            continue
        if fault < 0.13:
            counters[name] += rng.randint(2, 4)
        elif fault < 0.16:
            counters[name] -= 1
        values = {}
        for spec in rolemap.roles_for_message(name):
            s = msg.get_signal_by_name(spec.signal)
            lo = (s.minimum if s.minimum is not None else 0.0) * 0.9
            hi = (s.maximum if s.maximum is not None else 1.0) * 0.9
            physical = rng.uniform(min(lo, hi), max(lo, hi))
            values[spec.signal] = physical
            if spec.sign_signal is not None:
                values[spec.sign_signal] = rng.randint(0, 1)
            if spec.valid_signal is not None and rng.random() < 0.1:
                values[spec.valid_signal] = 1 - spec.valid_values[0]
        try:
            payload = encode_role_frame(db, rolemap, name, {}, counter=counters[name], signals=values)
        except (ValueError, cantools.database.errors.Error):
            payload = rng.randbytes(msg.length)
        counters[name] += 1
        if fault > 0.97:
            flip = bytearray(payload)
            flip[rng.randrange(len(flip))] ^= 1 << rng.randrange(8)
            payload = bytes(flip)
        elif fault > 0.95:
            payload = payload[:-1]
        elif fault > 0.94:
            frames.append((0x7FF, payload))
            continue
        frames.append((msg.frame_id, payload))
    return frames


def test_simulated_car_dbc_with_its_roles() -> None:
    db = load_dbc(REPO / "sim_devices" / "data" / "vsc_sim.dbc")
    rolemap = RoleMap.from_toml(REPO / "rig" / "examples" / "roles" / "vsc_sim.toml", db)
    dec = _run(db, rolemap, _stream(db, rolemap, 6000, seed=1))
    assert set(dec.compiled_messages) == set(rolemap.messages)
    stats = dec.stats()
    assert stats.decoded > 3000 and {"CHECKSUM", "COUNTER", "WRONG_LENGTH"} <= set(stats.flagged)


def test_vw_mqb_dbc_with_its_roles(shared_dir: Path) -> None:
    db = load_dbc(shared_dir / "dbc" / "vw_mqb.dbc")
    rolemap = RoleMap.from_toml(REPO / "examples" / "roles" / "vw_mqb.toml", db)
    dec = _run(db, rolemap, _stream(db, rolemap, 6000, seed=2))
    assert set(dec.compiled_messages) == set(rolemap.messages)
    stats = dec.stats()
    assert stats.decoded > 3000 and {"CHECKSUM", "COUNTER", "WRONG_LENGTH"} <= set(stats.flagged)


def test_custom_checksum_algorithms_go_through_their_compute() -> None:
    """An algorithm without a built-in fast form (the tests' XOR) is called as the generic path calls it."""
    db = load_dbc(Path(__file__).parent / "data" / "small.dbc", strict=True)
    from tests.can_decode.conftest import small_roles

    rolemap = RoleMap.from_mapping(small_roles(), db)
    rng = random.Random(5)
    frames = []
    for k in range(500):
        payload = bytearray(rng.randbytes(8))
        payload[6] = (payload[6] & 0xF0) | (k % 16)
        payload[7] = XOR.compute(0x100, bytes(payload)) ^ (1 if rng.random() < 0.1 else 0)
        frames.append((0x100, bytes(payload)))
        frames.append((rng.choice([0x200, 0x300]), rng.randbytes(8)))
    _run(db, rolemap, frames)


# --- frame bit times ---------------------------------------------------------------------------------


def test_frame_bit_times_match_the_bit_list_reference() -> None:
    rng = random.Random(11)
    for _ in range(30_000):
        ext = rng.random() < 0.3
        ident = rng.choice([0, (1 << (29 if ext else 11)) - 1, rng.getrandbits(29 if ext else 11)])
        fd = rng.random() < 0.25
        n = rng.choice([0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]) if fd else rng.randint(0, 8)
        data = rng.choice([rng.randbytes(n), b"\x00" * n, b"\xff" * n, bytes([0x0F, 0xF0] * 32)[:n]])
        brs = fd and rng.random() < 0.5
        remote = not fd and rng.random() < 0.1
        dlc = rng.randint(0, 15) if not fd and rng.random() < 0.2 else None
        fast = frame_bit_times(ident, ext, data, dlc=dlc, is_remote=remote, is_fd=fd, bitrate_switch=brs)
        ref = _frame_bit_times_reference(ident, ext, data, dlc=dlc, is_remote=remote, is_fd=fd, bitrate_switch=brs)
        assert fast == ref, (hex(ident), ext, data.hex(), dlc, remote, fd, brs)
