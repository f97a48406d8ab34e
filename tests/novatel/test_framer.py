"""Framer on mixed and corrupt streams: any chunking gives the same frames; garbage, truncated and
corrupted frames are rejected and counted by kind, never accepted; NMEA checked with pynmea2 and
RTCM3 with pyrtcm; random bytes never raise.

Every test of this module runs twice: with the install's ``Framer.feed`` (the C entry,
drivers/novatel/_feed.c, where it is built) and with its pure-Python twin (``framer._PyFeedGate.feed``,
what an install without a C compiler runs), so both give the same frames and counts."""

from __future__ import annotations

import io
import shutil
import struct
import sysconfig
import zlib
from collections.abc import Iterator
from typing import Any

import pynmea2
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pyrtcm import RTCMReader
from pyrtcm.rtcmhelpers import calc_crc24q

from drivers.novatel import (
    BestPos,
    Frame,
    FrameKind,
    Framer,
    Log,
    Prompt,
    Response,
    SkipReason,
    crc24q,
    decode_ascii,
    decode_binary,
    encode_abbreviated,
    encode_ascii,
    encode_binary,
    iter_frames,
    make_header,
    xor_checksum,
)
from drivers.novatel import framer as framer_module
from drivers.novatel.framer import FEED_IMPLEMENTATION, LOG_KINDS, FramerStats, _PyFeedGate
from tests.novatel.gen import mixed_stream, nmea_gga, rtcm_1005, sample_bestpos

#: The framer with the pure-Python feed (the twin of the C entry), whatever this install runs.
PyFeedFramer = type("PyFeedFramer", (Framer,), {"feed": _PyFeedGate.feed})


@pytest.fixture(scope="module", autouse=True, params=["installed", "python"])
def feed_implementation(request: pytest.FixtureRequest) -> Iterator[str]:
    """This module's tests, once with the installed ``Framer`` and once with the pure-Python feed (the
    name ``Framer`` in this module is rebound; module scope: hypothesis allows no function-scoped fixture)."""
    global Framer
    installed = Framer
    if request.param == "python":
        Framer = PyFeedFramer  # type: ignore[misc]
    try:
        yield request.param
    finally:
        Framer = installed  # type: ignore[misc]


def test_the_c_feed_is_built_where_a_c_compiler_is() -> None:
    """setup.py builds drivers/novatel/_feed.c as an optional extension; where the machine has the C
    compiler Python was built with, a silent fall-back to the slower pure-Python feed is a broken build."""
    compiler = (sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:
        pytest.skip(f"no C compiler ({compiler}) on this machine: the pure-Python feed is expected")
    assert FEED_IMPLEMENTATION == "c", "drivers.novatel._feed did not build or import (pip install -e . -v shows why)"
    assert framer_module.Framer.feed is not _PyFeedGate.feed


def test_the_c_feed_rejects_what_bytearray_concatenation_rejects() -> None:
    """A chunk that is not bytes-like is a TypeError naming its type (as ``bytearray += x`` says), and a
    framer whose state was never set up says which attribute is missing, in both implementations."""
    framer = Framer()
    with pytest.raises(TypeError, match="str"):
        framer.feed("#BESTPOSA")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="int"):
        framer.feed(5)  # type: ignore[arg-type]
    assert framer.pending_bytes == 0
    bare = Framer.__new__(Framer)
    with pytest.raises(AttributeError, match="_acc"):
        bare.feed(b"x")


PROPS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])

MIXED = mixed_stream()
STREAM = b"".join(wire for _, wire, _ in MIXED)
#: Bytes that start no frame and are no line end: garbage that the framer must count exactly.
INERT = bytes(b for b in range(256) if b not in b"#%<[$\xaa\xd3\r\n")
#: Kinds whose frames carry a CRC or checksum.
CHECKED = {
    FrameKind.NOVATEL_BINARY,
    FrameKind.NOVATEL_SHORT_BINARY,
    FrameKind.NOVATEL_ASCII,
    FrameKind.NOVATEL_SHORT_ASCII,
    FrameKind.NMEA,
    FrameKind.RTCM3,
}


def run(chunks: list[bytes], **options: Any) -> tuple[list[Frame], FramerStats]:
    framer = Framer(**options)
    frames: list[Frame] = []
    for chunk in chunks:
        frames += framer.feed(chunk)
    frames += framer.finish()
    assert framer.pending_bytes == 0
    return frames, framer.stats


def kind_is_text(kind: FrameKind) -> bool:
    return kind in (FrameKind.NOVATEL_ASCII, FrameKind.NOVATEL_SHORT_ASCII, FrameKind.NMEA)


def same_message(a: Frame, b: Frame) -> bool:
    if a.kind is FrameKind.NMEA:
        return bool(a.message.data == b.message.data)
    return bool(a.message == b.message)


def test_text_crc_digits_in_either_case_are_the_same_frame() -> None:
    texts = [(kind, raw) for kind, _, raw in MIXED if kind_is_text(kind) and kind in CHECKED]
    assert {kind for kind, _ in texts} == {FrameKind.NOVATEL_ASCII, FrameKind.NOVATEL_SHORT_ASCII, FrameKind.NMEA}
    for kind, raw in texts:
        star = raw.rfind(b"*")
        swapped = raw[: star + 1] + raw[star + 1 :].swapcase()
        frames, stats = run([swapped + b"\r\n"])
        assert signature(frames) == [(kind, swapped)] and stats.total_skipped == 0
        assert same_message(frames[0], run([raw])[0][0])


def signature(frames: list[Frame]) -> list[tuple[FrameKind, bytes]]:
    return [(f.kind, f.raw) for f in frames]


def assert_accounted(stats: FramerStats) -> None:
    """Every input byte is in a frame, a line end or a skipped run."""
    assert stats.bytes_in == stats.bytes_in_frames + stats.total_skipped + stats.line_end_bytes


def verify_independently(frame: Frame) -> None:
    """A returned frame checks by an independent route (decoder with CRC check, pynmea2, pyrtcm)."""
    if frame.kind in (FrameKind.NOVATEL_BINARY, FrameKind.NOVATEL_SHORT_BINARY):
        decode_binary(frame.raw)
    elif frame.kind in (FrameKind.NOVATEL_ASCII, FrameKind.NOVATEL_SHORT_ASCII):
        decode_ascii(frame.raw)
    elif frame.kind is FrameKind.NMEA:
        pynmea2.parse(frame.raw.decode("ascii"), check=True)
    elif frame.kind is FrameKind.RTCM3:
        assert calc_crc24q(frame.raw[:-3]) == int.from_bytes(frame.raw[-3:], "big")


# --- the mixed stream ------------------------------------------------------------------------


def test_mixed_stream_gives_every_frame_in_order() -> None:
    frames, stats = run([STREAM])
    assert signature(frames) == [(kind, raw) for kind, _, raw in MIXED]
    assert all(f.error is None for f in frames)
    assert stats.total_skipped == 0
    assert stats.bytes_in_frames + stats.line_end_bytes == len(STREAM)
    for frame in frames:
        verify_independently(frame)
        if frame.kind in LOG_KINDS:
            assert isinstance(frame.message, Log)
    responses = [f.message for f in frames if f.kind is FrameKind.RESPONSE]
    assert responses == [Response(True, "OK"), Response(False, "Invalid Message ID")]
    prompts = [f.message for f in frames if f.kind is FrameKind.PROMPT]
    assert prompts == [Prompt("COM1"), Prompt("ICOM1")]


def test_nmea_frame_matches_pynmea2() -> None:
    sentence = nmea_gga(7)
    frames, _ = run([b"garbage" + sentence + b"\r\n"])
    (frame,) = frames
    assert frame.kind is FrameKind.NMEA and frame.raw == sentence
    reference = pynmea2.parse(sentence.decode(), check=True)
    assert frame.message.data == reference.data
    assert frame.message.latitude == pytest.approx(48 + 7.038 / 60, abs=1e-12)
    assert frame.message.num_sats == "12"
    star = sentence.index(b"*")
    assert xor_checksum(sentence[1:star]) == int(sentence[star + 1 :], 16)


def test_rtcm3_frame_crc_and_fields_match_pyrtcm() -> None:
    frame_bytes = rtcm_1005(2003, 4_177_000.1234, 855_000.5678, 4_727_000.9)
    frames, _ = run([b"\x00\x01" + frame_bytes + b"\xff"])
    (frame,) = frames
    assert frame.kind is FrameKind.RTCM3 and frame.raw == frame_bytes
    # the framer's CRC-24Q is pyrtcm's, and over the whole frame it leaves 0
    assert crc24q(frame_bytes[:-3]) == calc_crc24q(frame_bytes[:-3])
    assert crc24q(frame_bytes) == 0
    msg = frame.message
    assert msg.identity == "1005"
    assert msg.DF003 == 2003
    assert pytest.approx(4_177_000.1234, abs=1e-4) == msg.DF025
    assert pytest.approx(855_000.5678, abs=1e-4) == msg.DF026
    assert pytest.approx(4_727_000.9, abs=1e-4) == msg.DF027
    assert RTCMReader.parse(frame_bytes).DF025 == msg.DF025


@pytest.mark.parametrize("station", [0, 1, 4095])
def test_rtcm3_crc24q_agrees_with_pyrtcm(station: int) -> None:
    frame_bytes = rtcm_1005(station, -1.0, 2.5, 6_371_000.0)
    assert crc24q(frame_bytes[:-3]) == calc_crc24q(frame_bytes[:-3])


def test_split_at_every_byte_position() -> None:
    expected = signature(run([STREAM])[0])
    reference_stats = run([STREAM])[1].to_dict()
    for cut in range(len(STREAM) + 1):
        frames, stats = run([STREAM[:cut], STREAM[cut:]])
        assert signature(frames) == expected, f"split at byte {cut}"
        assert stats.to_dict() == reference_stats, f"split at byte {cut}"


@PROPS
@given(cuts=st.lists(st.integers(0, len(STREAM)), max_size=40))
def test_any_chunking_gives_identical_frames(cuts: list[int]) -> None:
    points = sorted({0, len(STREAM), *cuts})
    chunks = [STREAM[a:b] for a, b in zip(points, points[1:], strict=False)]
    frames, stats = run(chunks)
    one_shot, one_stats = run([STREAM])
    assert signature(frames) == signature(one_shot)
    assert stats.to_dict() == one_stats.to_dict()


def test_byte_by_byte_feed() -> None:
    frames, stats = run([STREAM[i : i + 1] for i in range(len(STREAM))])
    assert signature(frames) == [(kind, raw) for kind, _, raw in MIXED]
    assert_accounted(stats)


def test_frame_reader_and_iter_frames_read_a_file_object() -> None:
    frames = list(iter_frames(io.BytesIO(STREAM)))
    assert signature(frames) == [(kind, raw) for kind, _, raw in MIXED]


# --- garbage -------------------------------------------------------------------------------


@PROPS
@given(
    prefix=st.binary(max_size=200).map(lambda b: bytes(INERT[x % len(INERT)] for x in b)),
    middle=st.binary(max_size=200).map(lambda b: bytes(INERT[x % len(INERT)] for x in b)),
    suffix=st.binary(max_size=200).map(lambda b: bytes(INERT[x % len(INERT)] for x in b)),
    where=st.integers(0, len(MIXED)),
)
def test_inert_garbage_is_skipped_and_counted_exactly(prefix: bytes, middle: bytes, suffix: bytes, where: int) -> None:
    parts = [wire for _, wire, _ in MIXED]
    if MIXED[where - 1][0] is FrameKind.NOVATEL_ABBREV if where else False:
        where -= 1  # garbage right after an abbreviated log would be read as its end: keep it apart
    stream = prefix + b"".join(parts[:where]) + middle + b"".join(parts[where:]) + suffix
    frames, stats = run([stream])
    assert signature(frames) == [(kind, raw) for kind, _, raw in MIXED]
    assert stats.bytes_skipped[SkipReason.GARBAGE] == len(prefix) + len(middle) + len(suffix)
    assert sum(stats.crc_failures.values()) == 0
    assert_accounted(stats)


@PROPS
@given(garbage=st.lists(st.binary(max_size=120), min_size=len(MIXED) + 1, max_size=len(MIXED) + 1))
def test_any_garbage_between_frames_never_hides_a_frame(garbage: list[bytes]) -> None:
    """Arbitrary bytes (sync bytes included) between frames: every real frame is still found, in order.

    The garbage may itself hold something frame-like; whatever else is returned must verify.
    """
    stream = b""
    previous = None
    for junk, (kind, wire, _) in zip(garbage, [*MIXED, (None, b"", b"")], strict=True):
        # An abbreviated log has neither CRC nor end marker: its continuation lines are '<' + blanks +
        # fields, so a garbage line of that shape right after one is, by the protocol, more of it.
        assume(not (previous is FrameKind.NOVATEL_ABBREV and junk[:1] == b"<" and junk[1:2] in (b" ", b"\t")))
        stream += junk + b"\r\n" + wire
        previous = kind
    frames, stats = run([stream])
    want = iter((kind, raw) for kind, _, raw in MIXED)
    pending: tuple[Any, bytes] | None = next(want)
    for frame in frames:
        verify_independently(frame)
        if pending is not None and (frame.kind, frame.raw) == pending:
            pending = next(want, None)
    assert pending is None, f"frame not found: {pending}"
    assert_accounted(stats)


# --- truncated frames ----------------------------------------------------------------------


@pytest.mark.parametrize("index", [i for i, (kind, _, _) in enumerate(MIXED) if kind in CHECKED])
def test_frame_cut_at_end_of_stream_is_counted_as_truncated(index: int) -> None:
    kind, _, raw = MIXED[index]
    for keep in range(5, len(raw) - 1, max(1, len(raw) // 17)):  # 5 bytes: every sync is recognisable
        frames, stats = run([raw[:keep]])
        assert frames == []
        assert stats.truncated == 1, (kind, keep)
        assert stats.bytes_skipped[SkipReason.TRUNCATED] == keep, (kind, keep)
        assert_accounted(stats)


@pytest.mark.parametrize("cut", [10, 50, 120])
def test_ascii_log_cut_by_a_line_break_is_truncated_and_the_next_log_found(cut: int) -> None:
    body = sample_bestpos()
    line = encode_ascii(make_header(body, week=2300, seconds=10.0), body)
    frames, stats = run([line[:cut] + b"\r\n" + line])
    assert signature(frames) == [(FrameKind.NOVATEL_ASCII, line.rstrip())]
    assert stats.truncated == 1
    assert stats.bytes_skipped[SkipReason.TRUNCATED] == cut
    assert_accounted(stats)


def test_binary_log_cut_short_then_another_is_rejected_not_accepted() -> None:
    body = sample_bestpos()
    frame = encode_binary(make_header(body, week=2300, seconds=10.0), body)
    for keep in (5, 28, 60, len(frame) - 1):
        frames, stats = run([frame[:keep] + frame + frame])
        assert signature(frames) == [(FrameKind.NOVATEL_BINARY, frame)] * 2
        assert stats.bytes_skipped[SkipReason.CRC_FAILURE] + stats.bytes_skipped[SkipReason.TRUNCATED] == keep
        assert_accounted(stats)


# --- corrupted frames ------------------------------------------------------------------------


def _flip_crc(kind: FrameKind, raw: bytes, which: int, bit: int) -> bytes:
    """Corrupt the CRC / checksum field of a frame (a hex digit becomes another hex digit)."""
    data = bytearray(raw)
    if kind in (FrameKind.NOVATEL_BINARY, FrameKind.NOVATEL_SHORT_BINARY, FrameKind.RTCM3):
        width = 3 if kind is FrameKind.RTCM3 else 4
        data[len(data) - width + which % width] ^= 1 << bit
    else:
        width = 2 if kind is FrameKind.NMEA else 8
        pos = len(data) - width + which % width
        digits = b"0123456789abcdef" if kind is not FrameKind.NMEA else b"0123456789ABCDEF"
        old = digits.index(bytes([data[pos]]).lower() if kind is not FrameKind.NMEA else bytes([data[pos]]))
        data[pos] = digits[(old + 1 + bit) % 16]
    return bytes(data)


@PROPS
@given(
    index=st.sampled_from([i for i, (kind, _, _) in enumerate(MIXED) if kind in CHECKED]),
    which=st.integers(0, 7),
    bit=st.integers(0, 7),
)
def test_corrupted_crc_is_rejected_and_counted_by_kind(index: int, which: int, bit: int) -> None:
    kind, wire, raw = MIXED[index]
    bad = _flip_crc(kind, raw, which, bit)
    assert bad != raw
    tail = wire[len(raw) :]
    frames, stats = run([bad + tail + wire])
    assert signature(frames) == [(kind, raw)]
    assert stats.crc_failures == {k: int(k is kind) for k in FrameKind}
    assert stats.bytes_skipped[SkipReason.CRC_FAILURE] == len(raw)
    assert_accounted(stats)


@PROPS
@given(index=st.sampled_from([i for i, (kind, _, _) in enumerate(MIXED) if kind in CHECKED]), data=st.data())
def test_a_flipped_bit_anywhere_is_never_accepted(index: int, data: st.DataObject) -> None:
    _, wire, raw = MIXED[index]
    position = data.draw(st.integers(0, len(raw) - 1))
    bit = data.draw(st.integers(0, 7))
    bad = bytearray(raw)
    bad[position] ^= 1 << bit
    follower = MIXED[(index + 1) % len(MIXED)]
    if follower[0] is FrameKind.NOVATEL_ABBREV:
        follower = MIXED[0]
    stream = bytes(bad) + wire[len(raw) :] + follower[1]
    frames, stats = run([stream])
    # Text CRCs are hex in either case (the public vectors have both): bit 5 of a hex letter after
    # the '*' changes only the case, so that frame is the same frame and must still be accepted.
    star = raw.rfind(b"*") if kind_is_text(MIXED[index][0]) else -1
    case_only = 0 <= star < position and bit == 5 and chr(raw[position]) in "abcdefABCDEF"
    for frame in frames:
        verify_independently(frame)
        if frame.raw == bytes(bad):
            assert case_only, "a frame with a flipped bit was accepted"
            assert same_message(frame, run([raw])[0][0])
    if case_only:
        assert (MIXED[index][0], bytes(bad)) in signature(frames)
    assert (follower[0], follower[2]) in signature(frames)
    assert_accounted(stats)


def test_oversize_binary_claim_is_counted_and_does_not_stall() -> None:
    body = sample_bestpos()
    frame = encode_binary(make_header(body, week=2300, seconds=10.0), body)
    liar = bytearray(frame[:28])
    struct.pack_into("<H", liar, 8, 60000)
    frames, stats = run([bytes(liar) + frame], max_frame_len=4096)
    assert signature(frames) == [(FrameKind.NOVATEL_BINARY, frame)]
    assert stats.oversize[FrameKind.NOVATEL_BINARY] == 1
    assert_accounted(stats)


def test_text_without_line_end_is_bounded() -> None:
    frames, stats = run([b"#BESTPOSA," + b"A" * 5000], max_frame_len=1024)
    assert frames == []
    assert stats.bytes_skipped[SkipReason.GARBAGE] + stats.bytes_skipped[SkipReason.OVERSIZE] == 5010
    assert_accounted(stats)


# --- robustness ------------------------------------------------------------------------------


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.binary(max_size=3000), cuts=st.lists(st.integers(0, 3000), max_size=8))
def test_random_bytes_never_raise(data: bytes, cuts: list[int]) -> None:
    points = sorted({0, len(data), *(c for c in cuts if c <= len(data))})
    frames, stats = run([data[a:b] for a, b in zip(points, points[1:], strict=False)])
    for frame in frames:
        verify_independently(frame)
    assert_accounted(stats)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.lists(st.sampled_from([*(wire for _, wire, _ in MIXED), b"\xaa", b"\xaa\x44\x12", b"#B", b"$G", b"<",
                                       b"[", b"\xd3\x00", b"*", b"\r\n", b";", b","]), max_size=60))
def test_frame_fragments_in_any_order_never_raise(data: list[bytes]) -> None:
    stream = b"".join(data)
    frames, stats = run([stream])
    for frame in frames:
        verify_independently(frame)
    assert_accounted(stats)


def test_flush_completes_an_abbreviated_log_after_a_read_timeout() -> None:
    body = sample_bestpos()
    from drivers.novatel import encode_abbreviated

    text = encode_abbreviated(make_header(body, week=2300, seconds=10.0), body)
    framer = Framer()
    assert framer.feed(text) == ()  # the next byte could be another continuation line
    (frame,) = framer.flush()
    assert frame.kind is FrameKind.NOVATEL_ABBREV
    assert isinstance(frame.message, Log) and isinstance(frame.message.body, BestPos)
    assert frame.message.body == decode_ascii(encode_ascii(frame.message.header, frame.message.body)).body


# --- chunking: same result, linear cost ------------------------------------------------------

def _tiny_rtcm3() -> bytes:
    # The shortest plausible RTCM3 frame: a 2-byte payload holding message number 1005.
    frame = b"\xd3\x00\x02\x3e\xd0"
    return frame + crc24q(frame).to_bytes(3, "big")


def _tiny_nmea() -> bytes:
    return b"$AB,*%02X" % xor_checksum(b"AB,")


FRAGMENTS = [*(wire for _, wire, _ in MIXED), b"\xaa", b"\xaa\x44\x12", b"#B", b"$G", b"<", b"[", b"\xd3\x00",
             b"*", b"\r\n", b";", b",", b"<     1\r\n", b"#BESTPOSA,COM1,", b"$GPGGA,", b"*1", b"[COM", b"0\x44",
             # frames that complete within a few bytes, and a run of garbage longer than the framer holds
             b"[A]", _tiny_rtcm3(), _tiny_nmea(), (INERT * 3)[:600]]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(parts=st.lists(st.sampled_from(FRAGMENTS), max_size=40), data=st.data())
def test_fragments_in_any_order_give_the_same_frames_and_counts_for_any_chunking(
    parts: list[bytes], data: st.DataObject
) -> None:
    stream = b"".join(parts)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=60), label="cuts")
    points = sorted({0, len(stream), *cuts})
    chunks = [stream[a:b] for a, b in zip(points, points[1:], strict=False)]
    one_frames, one_stats = run([stream])
    frames, stats = run(chunks)
    assert signature(frames) == signature(one_frames)
    assert stats.to_dict() == one_stats.to_dict()
    byte_frames, byte_stats = run([stream[i : i + 1] for i in range(len(stream))])
    assert signature(byte_frames) == signature(one_frames)
    assert byte_stats.to_dict() == one_stats.to_dict()


def test_each_frame_comes_out_of_the_feed_that_completes_it() -> None:
    """Waiting for more bytes never holds back a complete frame.

    A frame is known complete at its last byte; a response at its line end (it has no end marker); an
    abbreviated log at the first byte after its line end (that byte could start a continuation line).
    """
    framer = Framer()
    got: list[tuple[int, FrameKind]] = []
    for i in range(len(STREAM)):
        got += [(i, f.kind) for f in framer.feed(STREAM[i : i + 1])]
    expected = []
    offset = 0
    for kind, wire, raw in MIXED:
        if kind is FrameKind.NOVATEL_ABBREV:
            expected.append((offset + len(wire), kind))
        elif kind is FrameKind.RESPONSE:
            expected.append((offset + len(wire) - 1, kind))
        else:
            expected.append((offset + len(raw) - 1, kind))
        offset += len(wire)
    assert got == expected


def _count_parser_calls(framer: Framer) -> list[int]:
    calls = [0]
    for key, parse in list(framer._parsers.items()):

        def counted(*args: Any, _parse: Any = parse) -> Any:
            calls[0] += 1
            return _parse(*args)

        framer._parsers[key] = counted
    return calls


def _ascii_log(body_len: int) -> bytes:
    inner = b"BESTPOSA,COM1,0,80.0,FINESTEERING,2300,345600.000,02000000,cdba,32768;" + b"1," * (body_len // 2)
    return b"#" + inner + b"*%08x\r\n" % (zlib.crc32(inner, 0xFFFFFFFF) ^ 0xFFFFFFFF)  # NovAtel's CRC-32


@pytest.mark.parametrize("name", ["abbreviated", "ascii", "ascii_unterminated", "binary"])
def test_a_long_frame_fed_byte_by_byte_is_parsed_a_bounded_number_of_times(name: str) -> None:
    """Cost linear in bytes: before, every 1-byte feed re-parsed the pending frame from its start."""
    body = sample_bestpos()
    head = make_header(body, week=2300, seconds=10.0)
    if name == "abbreviated":
        stream = encode_abbreviated(head, body).split(b"\r\n", 1)[0] + b"\r\n" + b"<     1\r\n" * 3000 + b"[COM1]"
    elif name == "ascii":
        stream = _ascii_log(20000) + b"[COM1]"
    elif name == "ascii_unterminated":
        stream = b"#BESTPOSA,COM1," + b"x" * 20000 + b"\r\n[COM1]"
    else:
        frame = encode_binary(head, body)
        stream = frame[:3] + bytes([frame[3]]) + frame[4:8] + struct.pack("<H", 20000) + frame[10:28]
        stream += bytes(20000)
        stream += struct.pack("<I", zlib.crc32(stream, 0xFFFFFFFF) ^ 0xFFFFFFFF)  # NovAtel's CRC-32
        stream += b"[COM1]"
    framer = Framer()
    calls = _count_parser_calls(framer)
    frames = []
    frames += _feed_bytewise(framer, stream)
    frames += framer.finish()
    assert frames[-1].kind is FrameKind.PROMPT
    if name in ("binary", "ascii"):  # a long log, framed
        assert len(frames) == 2
        assert frames[0].kind in (FrameKind.NOVATEL_BINARY, FrameKind.NOVATEL_ASCII)
    # a few rescans per frame or line (sync, header, end), never one per byte
    per_unit = calls[0] / (3001 if name == "abbreviated" else 2)
    assert per_unit <= 8, f"{calls[0]} parser calls for {len(stream)} bytes"
    one = Framer()
    assert signature(one.feed(stream) + one.finish()) == signature(frames)


# --- held bytes: what a 1-byte feed waits for ------------------------------------------------


def _binary_log(i: int) -> bytes:
    body = sample_bestpos()
    return encode_binary(make_header(body, week=2300, seconds=10.0 + i, sequence=i % 100), body)


#: (wire bytes, kind or None for bytes that are no frame): the frames that complete within 10 bytes
#: (prompt, response, NMEA, RTCM3), each right after a binary log, after garbage and after a text log's
#: line end, so each waits in every state a 1-byte feed can leave the framer in.
TINY = [
    (_binary_log(0), FrameKind.NOVATEL_BINARY),
    (b"[A]", FrameKind.PROMPT),
    (_binary_log(1), FrameKind.NOVATEL_BINARY),
    (b"<OK\r\n", FrameKind.RESPONSE),
    (_binary_log(2), FrameKind.NOVATEL_BINARY),
    (_tiny_rtcm3(), FrameKind.RTCM3),
    (_binary_log(3), FrameKind.NOVATEL_BINARY),
    (_tiny_nmea(), FrameKind.NMEA),
    (b"\r\n", None),
    (b"[B]", FrameKind.PROMPT),
    (INERT[:40], None),
    (_tiny_rtcm3(), FrameKind.RTCM3),
    (b"\x00x", None),
    (b"[C]", FrameKind.PROMPT),
    (_tiny_nmea(), FrameKind.NMEA),
    (b"\xaa", None),
    (b"[D]", FrameKind.PROMPT),
    (b"\xaa\x44", None),
    (_tiny_rtcm3(), FrameKind.RTCM3),
    ((INERT * 3)[:700], None),
    (_binary_log(4), FrameKind.NOVATEL_BINARY),
    (b"<OK\r\n", FrameKind.RESPONSE),
    (b"[E]", FrameKind.PROMPT),
]


def test_short_frames_come_out_of_the_byte_that_completes_them_in_every_waiting_state() -> None:
    """Bytes held after a frame, after garbage or after a partial sync never hold back a short frame."""
    stream = b"".join(wire for wire, _ in TINY)
    expected = []
    offset = 0
    for wire, kind in TINY:
        if kind is not None:
            expected.append((offset + len(wire) - 1, kind))
        offset += len(wire)
    framer = Framer()
    got: list[tuple[int, FrameKind]] = []
    for i in range(len(stream)):
        got += [(i, f.kind) for f in framer.feed(stream[i : i + 1])]
    assert got == expected
    assert framer.finish() == ()
    one_frames, one_stats = run([stream])
    assert [f.kind for f in one_frames] == [kind for _, kind in expected]
    assert framer.stats.to_dict() == one_stats.to_dict()
    assert framer.stats.bytes_skipped[SkipReason.GARBAGE] == 40 + 2 + 1 + 2 + 700


def _feed_bytewise(framer: Framer, stream: bytes) -> list[Frame]:
    """Feed ``stream`` one byte per call; the frames completed."""
    frames: list[Frame] = []
    for i in range(len(stream)):
        frames += framer.feed(stream[i : i + 1])
    return frames


def _count_calls(framer: Framer, method: str) -> list[int]:
    """Count the calls of one of the framer's methods (``calls[0]``)."""
    calls = [0]
    original = getattr(framer, method)

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        return original(*args, **kwargs)

    setattr(framer, method, counted)
    return calls


def _count_scans(framer: Framer) -> list[int]:
    """Count the looks at the held bytes: the general path of ``feed`` (a scan, or the check of a
    binary log's header or last byte), taken when a fed byte could change a verdict."""
    return _count_calls(framer, "_look")


def test_binary_logs_fed_byte_by_byte_are_scanned_twice_each() -> None:
    """At the header (to learn the length) and at the last byte: before, also at each sync byte."""
    logs = [_binary_log(i) for i in range(50)]
    framer = Framer()
    scans = _count_scans(framer)
    stream = b"".join(logs)
    frames = []
    frames += _feed_bytewise(framer, stream)
    assert signature(frames) == [(FrameKind.NOVATEL_BINARY, log) for log in logs]
    assert scans[0] == 2 * len(logs)


def test_text_frames_fed_byte_by_byte_are_scanned_a_few_times_each() -> None:
    texts = [wire for kind, wire, _ in MIXED if kind in (FrameKind.NOVATEL_ASCII, FrameKind.NMEA)]
    stream = b"".join(texts) * 5
    framer = Framer()
    scans = _count_scans(framer)
    frames = []
    frames += _feed_bytewise(framer, stream)
    assert len(frames) == 5 * len(texts)
    # first bytes (an NMEA '$' alone, then with its next byte), the '*', the CRC, the CR LF: 4 for an
    # ASCII log, 5 for a sentence (one scan per byte would be ~100)
    assert scans[0] <= 5 * len(frames)


def _count_scan_calls(framer: Framer) -> list[int]:
    """Count the full scans of the held bytes (a look that only asks a waiting frame's parser is none)."""
    return _count_calls(framer, "_scan")


@pytest.mark.parametrize("kinds", [(FrameKind.NOVATEL_ASCII,), (FrameKind.NMEA,), (FrameKind.RTCM3,)])
def test_a_text_or_rtcm_frame_fed_byte_by_byte_is_scanned_once_at_its_end(kinds: tuple[FrameKind, ...]) -> None:
    """While a frame at the start of the held bytes waits (its sync byte, header, '*', CRC digits), a
    look asks its parser only, as the scan would first; the one scan is at its last byte, and the CR LF
    after a text frame takes none. Before, every look was a scan: 4-5 per frame."""
    wires = [wire for kind, wire, _ in MIXED if kind in kinds]
    assert wires
    stream = b"".join(wires) * 5
    framer = Framer()
    scans = _count_scan_calls(framer)
    frames = []
    frames += _feed_bytewise(framer, stream)
    frames += framer.finish()  # one more scan
    assert len(frames) == 5 * len(wires)
    assert scans[0] <= len(frames) + 1, f"{scans[0]} scans for {len(frames)} frames"
    one = Framer()
    assert signature(frames) == signature(list(one.feed(stream) + one.finish()))
    assert framer.stats.to_dict() == one.stats.to_dict()


def test_feed_returns_an_immutable_tuple_and_no_allocation_when_nothing_completes() -> None:
    """The common 1-byte feed returns one shared empty tuple (safe to share: it cannot be changed)."""
    framer = Framer()
    log = _binary_log(0)
    empties = [framer.feed(log[i : i + 1]) for i in range(len(log) - 1)]
    assert all(e == () for e in empties)
    assert len({id(e) for e in empties}) == 1
    last = framer.feed(log[-1:])
    assert isinstance(last, tuple) and signature(list(last)) == [(FrameKind.NOVATEL_BINARY, log)]
    assert isinstance(framer.flush(), tuple) and isinstance(framer.finish(), tuple)


def test_garbage_fed_byte_by_byte_is_held_until_a_sync_byte() -> None:
    """Bytes that start no frame are counted in runs, not scanned one by one; counts stay exact."""
    garbage = bytes(INERT[i % len(INERT)] for i in range(5000))
    stream = garbage + _binary_log(0) + garbage
    framer = Framer()
    scans = _count_scans(framer)
    frames = []
    frames += _feed_bytewise(framer, stream)
    assert [f.kind for f in frames] == [FrameKind.NOVATEL_BINARY]
    # per run: one scan per 512 bytes, plus the first (still waiting as after a frame); the log after
    # garbage: at its sync byte, its third byte, its header and its end (one scan per byte: 10 104)
    assert scans[0] <= 2 * (5000 // 512 + 2) + 4
    assert framer.pending_bytes < 512  # the held run is bounded
    frames += framer.finish()
    assert framer.stats.bytes_skipped[SkipReason.GARBAGE] == 2 * len(garbage)
    assert framer.pending_bytes == 0


def test_feed_accepts_bytearray_and_memoryview_chunks() -> None:
    stream = b"".join(wire for wire, _ in TINY)
    for kind in (bytearray, memoryview):
        framer = Framer()
        frames = []
        for i in range(len(stream)):
            frames += framer.feed(kind(stream[i : i + 1]))
        frames += framer.finish()
        assert signature(frames) == signature(run([stream])[0])


def test_a_framer_fed_after_finish_starts_afresh() -> None:
    framer = Framer()
    assert framer.feed(b"#BESTPOSA,COM1,0,80.0") == ()  # a text log waiting for its '*'
    framer.finish()
    got = []
    for i, byte in enumerate(b"[A]"):
        got += [(i, f.kind) for f in framer.feed(bytes([byte]))]
    assert got == [(2, FrameKind.PROMPT)]


def test_held_bytes_count_as_pending_and_as_bytes_in() -> None:
    """1-byte chunks held without a look are still the framer's bytes: pending and counted as fed."""
    log = _binary_log(0)
    framer = Framer()
    for i in range(50):
        assert framer.feed(log[i : i + 1]) == ()
    assert framer.pending_bytes == 50
    assert framer.stats.bytes_in == 50
    assert framer.feed(bytearray(log[50:60])) == ()  # a longer chunk joins the held bytes in order
    assert framer.pending_bytes == 60
    frames = []
    for i in range(60, len(log)):
        frames += framer.feed(log[i : i + 1])
        assert framer.stats.bytes_in == i + 1
    assert signature(frames) == [(FrameKind.NOVATEL_BINARY, log)]
    assert framer.pending_bytes == 0
    assert framer.stats.bytes_in == framer.stats.bytes_in_frames == len(log)


def test_a_reused_read_buffer_changed_after_feed_changes_nothing_held() -> None:
    """A port read into one reusable buffer (``readinto``): the framer keeps copies of mutable chunks."""
    stream = b"".join(wire for wire, _ in TINY) + b"".join(wire for _, wire, _ in MIXED)
    expected = run([stream])
    for view in (False, True):
        framer = Framer()
        buffer = bytearray(1)
        chunk = memoryview(buffer) if view else buffer
        frames = []
        for byte in stream:
            buffer[0] = byte
            frames += framer.feed(chunk)
            buffer[0] = 0xAA  # the next read overwrites it
        frames += framer.finish()
        assert signature(frames) == signature(expected[0])
        assert framer.stats.to_dict() == expected[1].to_dict()


def test_a_read_only_memoryview_byte_may_be_held() -> None:
    """A memoryview of bytes is immutable and hashable: held like the bytes it views, same frames."""
    stream = b"".join(wire for wire, _ in TINY)
    data = memoryview(stream)
    framer = Framer()
    frames = []
    for i in range(len(stream)):
        frames += framer.feed(data[i : i + 1])
    frames += framer.finish()
    assert signature(frames) == signature(run([stream])[0])


def test_an_abbreviated_log_of_many_lines_fed_byte_by_byte_is_scanned_a_few_times() -> None:
    """Its continuation lines are walked in the held bytes; before, each line cost two scans (a copy of
    the log so far and a parse each), 600 here."""
    body = sample_bestpos()
    header = encode_abbreviated(make_header(body, week=2300, seconds=10.0), body).split(b"\r\n", 1)[0]
    log = header + b"\r\n" + b"<     1\r\n" * 300
    stream = log + _binary_log(0) + log + b"[COM1]"
    framer = Framer()
    calls = [0]
    scan = framer._scan

    def counted(final: bool, *given: Any) -> list[Frame]:
        calls[0] += 1
        return scan(final, *given)

    framer._scan = counted  # type: ignore[method-assign]
    frames = []
    frames += _feed_bytewise(framer, stream)
    assert [f.kind for f in frames] == [
        FrameKind.NOVATEL_ABBREV,
        FrameKind.NOVATEL_BINARY,
        FrameKind.NOVATEL_ABBREV,
        FrameKind.PROMPT,
    ]
    assert frames[0].raw == log.rstrip(b"\r\n")
    assert calls[0] <= 4 * 4, f"{calls[0]} scans"
    one = Framer()
    expected = one.feed(stream) + one.finish()
    assert signature(frames) == signature(expected)
    assert [f.message for f in frames] == [f.message for f in expected]
    assert framer.stats.to_dict() == one.stats.to_dict()
