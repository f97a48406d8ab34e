"""Whole-frame extraction: RTCM3 (built and framed by pyrtcm), NovAtel RTCA, Trimble CMR."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyrtcm import RTCMReader

from drivers.relay.frames import (
    CorrectionFramer,
    CorrectionKind,
    bit_reverse_bytes,
    encode_cmr,
    encode_rtca,
    encode_rtca_ascii,
    encode_rtcm3,
    rtcm3_message_number,
)
from tests.relay.helpers import (
    NOVATEL_RTCA_BLOCK,
    NOVATEL_RTCAA_EXAMPLE,
    base_epoch,
    cmr_by_hand,
    payload_1005,
    rtcm_frame,
)

EPOCH = base_epoch()
STREAM = b"".join(EPOCH)


def test_pyrtcm_frames_come_out_whole_with_their_message_numbers() -> None:
    framer = CorrectionFramer()
    frames = framer.feed(STREAM)
    assert [f.raw for f in frames] == EPOCH
    assert [f.label for f in frames] == ["RTCM 1005", "RTCM 1006", "RTCM 1033", "RTCM 1077", "RTCM 1087", "RTCM 1230"]
    for f in frames:  # the number read from the first 12 bits is pyrtcm's identity
        assert f.kind is CorrectionKind.RTCM3
        assert f.message_type == int(RTCMReader.parse(f.raw).identity)
    assert framer.stats.bytes_in_frames == len(STREAM)
    assert framer.stats.skipped_bytes == 0
    assert framer.stats.total_rejected == 0


def test_own_rtcm3_encoder_matches_pyrtcm() -> None:
    payload = payload_1005()
    assert encode_rtcm3(payload) == rtcm_frame(payload)
    assert rtcm3_message_number(payload) == 1005


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=len(STREAM) - 1), max_size=40))
def test_any_split_gives_the_same_frames(cuts: list[int]) -> None:
    framer = CorrectionFramer()
    bounds = [0, *sorted(set(cuts)), len(STREAM)]
    frames = []
    for a, b in zip(bounds, bounds[1:], strict=False):
        frames += framer.feed(STREAM[a:b])
    assert [f.raw for f in frames] == EPOCH
    assert framer.pending_bytes == 0


@settings(max_examples=80, deadline=None)
@given(st.integers(min_value=0, max_value=len(EPOCH) - 1), st.data())
def test_a_corrupted_frame_is_never_returned_and_is_counted(index: int, data: st.DataObject) -> None:
    frame = bytearray(EPOCH[index])
    pos = data.draw(st.integers(min_value=3, max_value=len(frame) - 1), label="byte")  # past the length field
    bit = data.draw(st.integers(min_value=0, max_value=7), label="bit")
    frame[pos] ^= 1 << bit
    stream = b"".join(EPOCH[:index]) + bytes(frame) + b"".join(EPOCH[index + 1 :])
    framer = CorrectionFramer()
    frames = framer.feed(stream) + framer.finish()
    assert bytes(frame) not in [f.raw for f in frames]
    assert [f.raw for f in frames] == EPOCH[:index] + EPOCH[index + 1 :]
    assert framer.stats.rejected[CorrectionKind.RTCM3] >= 1


def test_garbage_between_frames_is_skipped_and_counted() -> None:
    rng = random.Random(4)
    garbage = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60))) for _ in EPOCH]
    stream = b"".join(g + f for g, f in zip(garbage, EPOCH, strict=True))
    framer = CorrectionFramer()
    frames = framer.feed(stream) + framer.finish()
    assert [f.raw for f in frames] == EPOCH
    assert framer.stats.skipped_bytes == sum(map(len, garbage))


def test_a_truncated_frame_does_not_hold_back_the_next_frames() -> None:
    # The source is cut in the middle of a 1077 and comes back with a new epoch: the half frame
    # claims more bytes than follow before the next good frame, which is returned at once.
    half = EPOCH[3][: len(EPOCH[3]) // 2]
    framer = CorrectionFramer()
    assert framer.feed(half) == []
    frames = framer.feed(EPOCH[0])
    assert [f.raw for f in frames] == [EPOCH[0]]
    assert framer.stats.truncated == 1
    assert framer.pending_bytes == 0


def test_reset_drops_a_partial_frame() -> None:
    framer = CorrectionFramer()
    framer.feed(EPOCH[3][:20])
    framer.reset()
    assert framer.stats.truncated == 1
    assert [f.raw for f in framer.feed(EPOCH[4])] == [EPOCH[4]]


def test_novatel_rtca_example_checks() -> None:
    """NovAtel's published RTCAA example: the block's CRC-24Q over bit-reversed bytes leaves 0."""
    from drivers.novatel.crc import crc24q

    assert len(NOVATEL_RTCA_BLOCK) == NOVATEL_RTCA_BLOCK[5] == 71  # length byte = whole block
    assert crc24q(bit_reverse_bytes(NOVATEL_RTCA_BLOCK)) == 0
    framer = CorrectionFramer()
    frames = framer.feed(NOVATEL_RTCA_BLOCK + NOVATEL_RTCAA_EXAMPLE)
    assert [f.kind for f in frames] == [CorrectionKind.RTCA, CorrectionKind.RTCA]
    assert frames[0].raw == NOVATEL_RTCA_BLOCK
    assert frames[1].raw == NOVATEL_RTCAA_EXAMPLE
    # Our encoder reproduces the published block from its header fields and body.
    body = NOVATEL_RTCA_BLOCK[6:-3]
    assert encode_rtca(NOVATEL_RTCA_BLOCK[4], body, int.from_bytes(NOVATEL_RTCA_BLOCK[1:4], "big")) == (
        NOVATEL_RTCA_BLOCK
    )
    assert encode_rtca_ascii(NOVATEL_RTCA_BLOCK) == NOVATEL_RTCAA_EXAMPLE


def test_corrupted_rtca_is_rejected() -> None:
    bad = bytearray(NOVATEL_RTCA_BLOCK)
    bad[30] ^= 0x10
    bad_ascii = NOVATEL_RTCAA_EXAMPLE.replace(b"*20", b"*21")
    framer = CorrectionFramer()
    frames = framer.feed(bytes(bad) + bad_ascii + encode_rtca(7, b"\x01\x02\x03"))
    assert [f.label for f in frames] == ["RTCA 7"]
    assert framer.stats.rejected[CorrectionKind.RTCA] == 2


def test_cmr_frames_and_checks() -> None:
    cmr0 = cmr_by_hand(0x93, bytes([0x20, 0x08]) + bytes(range(30)))  # version 1, type 0, 8 SVs
    cmr1 = cmr_by_hand(0x93, bytes([0x20, 0x20]) + bytes(15), status=0x40)  # type 1 (ECEF reference)
    plus = cmr_by_hand(0x94, bytes([3, 0, 2]) + b"abcdef")
    assert encode_cmr(0x93, bytes([0x20, 0x08]) + bytes(range(30))) == cmr0
    bad_sum = bytearray(cmr0)
    bad_sum[-2] ^= 1
    bad_etx = bytearray(cmr1)
    bad_etx[-1] = 0x04
    framer = CorrectionFramer()
    frames = framer.feed(cmr0 + bytes(bad_sum) + cmr1 + bytes(bad_etx) + plus)
    assert [(f.label, f.raw) for f in frames] == [("CMR 0", cmr0), ("CMR 1", cmr1), ("CMR+", plus)]
    assert framer.stats.rejected[CorrectionKind.CMR] == 2


def test_mixed_stream_in_one_byte_reads() -> None:
    cmr = cmr_by_hand(0x93, bytes([0x20, 0x08]) + bytes(12))
    parts = [EPOCH[0], NOVATEL_RTCA_BLOCK, cmr, NOVATEL_RTCAA_EXAMPLE, EPOCH[3], b"$GPGGA,junk*00\r\n", EPOCH[5]]
    stream = b"".join(parts)
    framer = CorrectionFramer()
    frames = []
    for i in range(len(stream)):
        frames += framer.feed(stream[i : i + 1])
    expected = [p for p in parts if not p.startswith(b"$GPGGA")]
    assert [f.raw for f in frames] == expected


def test_kinds_can_be_restricted() -> None:
    cmr = cmr_by_hand(0x93, bytes([0x20, 0x08]) + bytes(12))
    framer = CorrectionFramer([CorrectionKind.RTCM3])
    frames = framer.feed(cmr + EPOCH[0])
    assert [f.raw for f in frames] == [EPOCH[0]]
    with pytest.raises(ValueError, match="at least one"):
        CorrectionFramer([])


def _random_frames(seed: int, count: int) -> list[bytes]:
    """RTCM3 frames with random payloads (MSM-sized): their bytes hold many false sync candidates."""
    rng = random.Random(seed)
    frames = []
    for _ in range(count):
        payload = bytes([0x43, 0x50]) + rng.randbytes(rng.randrange(100, 900))  # message 1077
        frames.append(encode_rtcm3(payload))
    return frames


@pytest.mark.parametrize("piece", [None, 1, 7, 300])
def test_ten_corrupted_frames_count_as_ten_rejected(piece: int | None) -> None:
    # Each corrupted frame has ~60 false sync candidates inside (0xD3, 0x99, '$', 0x02 bytes of its
    # payload); counting every failed candidate gave 12-14 (and here more) for 10 bad frames.
    frames = _random_frames(3, 60)
    rng = random.Random(9)
    corrupted = sorted(rng.sample(range(60), 10))
    stream = bytearray()
    for i, f in enumerate(frames):
        g = bytearray(f)
        if i in corrupted:
            g[rng.randrange(5, len(g) - 3)] ^= 1 << rng.randrange(8)  # a payload bit: length intact
        stream += g
    framer = CorrectionFramer()
    if piece is None:
        got = framer.feed(bytes(stream))
    else:
        got = [f for i in range(0, len(stream), piece) for f in framer.feed(stream[i : i + piece])]
    got += framer.finish()
    assert [f.raw for f in got] == [f for i, f in enumerate(frames) if i not in corrupted]
    stats = framer.stats
    assert stats.rejected == {CorrectionKind.RTCM3: 10, CorrectionKind.RTCA: 0, CorrectionKind.CMR: 0}
    assert stats.truncated == 0
    # the sync search inside the bad frames is counted as skipped bytes, apart
    assert stats.skipped_bytes == sum(len(frames[i]) for i in corrupted)
    assert stats.bytes_in == len(stream) == stats.skipped_bytes + stats.bytes_in_frames


def _nested(outer_payload_prefix: bytes, inner: bytes) -> bytes:
    """A whole RTCM3 frame whose payload carries another whole frame."""
    return encode_rtcm3(outer_payload_prefix + inner + b"\x00\x01")


_PART = st.one_of(
    st.binary(min_size=2, max_size=60).map(lambda p: encode_rtcm3(b"\x3e\xd0" + p)),
    st.binary(max_size=40).map(lambda b: encode_rtca(7, b)),
    st.binary(max_size=30).map(lambda b: encode_rtca_ascii(encode_rtca(1, b))),
    st.binary(min_size=2, max_size=40).map(lambda b: encode_cmr(0x93, b)),
    st.binary(max_size=12),  # garbage
    st.sampled_from([b"\xd3", b"\xd3\x00", b"\xd3\x00\x40", b"\x99", b"$RTCA,99", b"\x02\x00\x93\x10"]),
    st.tuples(st.binary(min_size=2, max_size=40), st.integers(min_value=1, max_value=30)).map(
        lambda t: encode_rtcm3(b"\x3e\xd0" + t[0])[: t[1]]  # a truncated frame
    ),
    st.tuples(st.binary(min_size=2, max_size=40), st.integers(min_value=0, max_value=7)).map(
        lambda t: bytes([*encode_rtcm3(b"\x3e\xd0" + t[0])[:-1], encode_rtcm3(b"\x3e\xd0" + t[0])[-1] ^ (1 << t[1])])
    ),  # a corrupted frame
    st.binary(max_size=10).map(lambda b: _nested(b"\x3e\xd0" + b, encode_rtca(7, b))),
    st.binary(max_size=10).map(lambda b: _nested(b"\x3e\xd0", encode_rtcm3(b"\x3e\xd0" + b))),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(_PART, max_size=25), st.data())
def test_the_frames_do_not_depend_on_the_chunking(parts: list[bytes], data: st.DataObject) -> None:
    stream = b"".join(parts)
    whole = CorrectionFramer()
    expected = whole.feed(stream) + whole.finish()
    cuts = data.draw(st.lists(st.integers(min_value=0, max_value=len(stream)), max_size=60), label="cuts")
    bounds = [0, *sorted(set(cuts)), len(stream)]
    pieces = CorrectionFramer()
    got = [f for a, b in zip(bounds, bounds[1:], strict=False) for f in pieces.feed(stream[a:b])]
    got += pieces.finish()
    assert got == expected
    bytewise = CorrectionFramer()
    assert [f for i in range(len(stream)) for f in bytewise.feed(stream[i : i + 1])] + bytewise.finish() == expected
    for framer in (pieces, bytewise):
        assert framer.stats.rejected == whole.stats.rejected
        assert framer.stats.truncated == whole.stats.truncated
        assert framer.stats.frames_by_label == whole.stats.frames_by_label
        assert framer.stats.bytes_in == len(stream)
