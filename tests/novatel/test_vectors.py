"""Public NovAtel vectors (../shared/vectors/novatel): every line decodes to the values it holds and
its CRC verifies, against a bit-by-bit CRC-32 written from the NovAtel reference (not zlib)."""

from __future__ import annotations

import dataclasses
import json
import struct
from datetime import UTC, datetime, timedelta
from enum import Enum
from pathlib import Path
from typing import Any

import pytest

from drivers.novatel import (
    BestPos,
    FrameKind,
    Framer,
    Header,
    Log,
    Prompt,
    SkipReason,
    Time,
    decode_ascii,
    decode_binary,
    encode_ascii,
    encode_binary,
    novatel_crc32,
)
from tests.novatel.gen import assert_body_close
from vsccore.errors import EncodeError
from vsccore.gpstime import NS_PER_S, gps_ns_to_unix_ns

DATA = Path(__file__).parent / "data"
EXPECTED: dict[str, Any] = json.loads((DATA / "vectors_expected.json").read_text())
HEX_FIELDS = {"receiver_status", "reserved", "ext_sol_stat", "galileo_beidou_sig_mask", "gps_glonass_sig_mask",
              "sol_source"}


def crc32_reference(data: bytes) -> int:
    """NovAtel CRC-32 exactly as the OEM7 manual's C example computes it (CRC32Value per byte)."""
    crc = 0
    for byte in data:
        tmp1 = (crc >> 8) & 0x00FFFFFF
        value = (crc ^ byte) & 0xFF
        for _ in range(8):
            value = (value >> 1) ^ 0xEDB88320 if value & 1 else value >> 1
        crc = tmp1 ^ value
    return crc


def _vector_dir(shared_dir: Path) -> Path:
    return shared_dir / "vectors" / "novatel"


def _ascii_lines(shared_dir: Path) -> list[str]:
    text = (_vector_dir(shared_dir) / "ascii_logs.txt").read_text()
    return [line for line in text.splitlines() if line.startswith("#") and not line.startswith("# ")]


def _binary_vector(shared_dir: Path) -> bytes:
    text = (_vector_dir(shared_dir) / "bestpos_binary.hex").read_text()
    return bytes.fromhex("".join(line for line in text.splitlines() if not line.startswith("#")))


def _check_values(obj: Any, expected: dict[str, Any]) -> None:
    for name, want in expected.items():
        got = getattr(obj, name)
        if isinstance(got, Enum):
            assert got.name == want, f"{name}: {got.name} != {want}"
        elif name in HEX_FIELDS and isinstance(want, str):
            assert got == int(want, 16), f"{name}: {got:x} != {want}"
        else:
            assert got == want, f"{name}: {got!r} != {want!r}"


def test_crc_reference_agrees_with_fast_crc() -> None:
    for data in (b"", b"\x00", b"123456789", bytes(range(256)) * 3):
        assert novatel_crc32(data) == crc32_reference(data)


def test_every_ascii_vector_crc_verifies_and_decodes_to_its_values(shared_dir: Path) -> None:
    lines = _ascii_lines(shared_dir)
    expected = EXPECTED["ascii_logs.txt"]
    assert len(lines) == len(expected) >= 8
    seen = set()
    for line in lines:
        star = line.rindex("*")
        crc_text = line[star + 1 :]
        assert crc32_reference(line[1:star].encode()) == int(crc_text, 16), line
        want = expected[crc_text]
        seen.add(crc_text)
        log = decode_ascii(line)
        _check_values(log.header, want["header"])
        _check_values(log.body, want["body"])
        if "leap_seconds" in want:
            assert isinstance(log.body, Time)
            assert log.body.leap_seconds == want["leap_seconds"]
    assert seen == set(expected)


def test_time_vector_utc_fields_match_gps_time_minus_reported_leap_seconds(shared_dir: Path) -> None:
    """The receiver's own UTC fields equal its header GPS time shifted by the leap seconds it reports."""
    checked = 0
    for line in _ascii_lines(shared_dir):
        crc_text = line[line.rindex("*") + 1 :]
        if not EXPECTED["ascii_logs.txt"][crc_text].get("header_time_is_utc_fields"):
            continue
        log = decode_ascii(line)
        body = log.body
        assert isinstance(body, Time)
        utc = datetime(body.utc_year, body.utc_month, body.utc_day, body.utc_hour, body.utc_min, tzinfo=UTC)
        utc += timedelta(milliseconds=body.utc_ms)
        unix_ns = gps_ns_to_unix_ns(log.header.gps_ns, body.leap_seconds)
        assert unix_ns == round(utc.timestamp()) * NS_PER_S
        # independent of vsccore.gpstime: the GPS epoch with datetime arithmetic
        gps_epoch = datetime(1980, 1, 6, tzinfo=UTC)
        assert gps_epoch + timedelta(weeks=log.header.week, seconds=log.header.seconds - body.leap_seconds) == utc
        checked += 1
    assert checked >= 1


def test_binary_vector_decodes_to_its_values(shared_dir: Path) -> None:
    frame = _binary_vector(shared_dir)
    (crc,) = struct.unpack_from("<I", frame, len(frame) - 4)
    assert crc32_reference(frame[:-4]) == crc
    log = decode_binary(frame)
    want = EXPECTED["bestpos_binary.hex"]
    _check_values(log.header, want["header"])
    _check_values(log.body, want["body"])
    assert log.header.gps_ns == (2163 * 604_800 + 329_807) * NS_PER_S
    # re-encoding gives the captured bytes back exactly
    assert encode_binary(log.header, log.body) == frame


def test_binary_vector_as_ascii_agrees(shared_dir: Path) -> None:
    log = decode_binary(_binary_vector(shared_dir))
    again = decode_ascii(encode_ascii(log.header, log.body))
    assert again.header == log.header
    assert_body_close(log.body, again.body, ascii_=True)


def test_ascii_vectors_through_binary_agree(shared_dir: Path) -> None:
    """Each ASCII vector sent again as binary decodes to the same values (float32 fields at float32)."""
    for line in _ascii_lines(shared_dir):
        log = decode_ascii(line)
        assert isinstance(log.header, Header)
        if log.header.sw_version > 0xFFFF:  # a Rust parser's vector puts a date there: no binary form
            with pytest.raises(EncodeError, match=log.name):
                encode_binary(log.header, log.body)
            header = dataclasses.replace(log.header, sw_version=0)
        else:
            header = log.header
        binary = decode_binary(encode_binary(header, log.body))
        assert binary.header == header
        assert_body_close(log.body, binary.body, ascii_=False, float32=True)


def test_oem7_ascii_vectors_reencode_byte_exact(shared_dir: Path) -> None:
    """The logs printed by OEM7 firmware (novatel_edie captures) come back byte for byte."""
    text = (_vector_dir(shared_dir) / "ascii_logs.txt").read_text().splitlines()
    source = ""
    checked = 0
    for line in text:
        if line.startswith("# source:"):
            source = line
        elif line.startswith("#") and "novatel_edie" in source:
            log = decode_ascii(line)
            assert encode_ascii(log.header, log.body) == line.encode() + b"\r\n"
            checked += 1
    assert checked >= 2


def test_vectors_through_the_framer_in_one_stream(shared_dir: Path) -> None:
    """All vector files in one stream: every log is found, comment lines are skipped as garbage."""
    vdir = _vector_dir(shared_dir)
    ascii_text = (vdir / "ascii_logs.txt").read_bytes()
    abbrev_text = (vdir / "abbreviated_ascii.txt").read_bytes()
    binary = _binary_vector(shared_dir)
    framer = Framer()
    frames = framer.feed(ascii_text + binary + abbrev_text) + framer.finish()
    kinds = [f.kind for f in frames]
    assert kinds.count(FrameKind.NOVATEL_ASCII) == len(_ascii_lines(shared_dir))
    assert kinds.count(FrameKind.NOVATEL_BINARY) == 1
    assert kinds[-2:] == [FrameKind.NOVATEL_ABBREV, FrameKind.PROMPT]
    assert all(f.error is None for f in frames)
    assert sum(framer.stats.crc_failures.values()) == 0
    # every byte is accounted for: frames, line ends, and the comment lines as garbage
    comments = sum(len(line) for line in (ascii_text + abbrev_text).split(b"\n") if line.startswith(b"# "))
    stats = framer.stats
    assert stats.bytes_skipped[SkipReason.GARBAGE] == comments
    assert stats.bytes_in == stats.bytes_in_frames + stats.total_skipped + stats.line_end_bytes


def test_abbreviated_vector_and_prompt(shared_dir: Path) -> None:
    data = (_vector_dir(shared_dir) / "abbreviated_ascii.txt").read_bytes()
    lines = b"".join(line + b"\n" for line in data.splitlines() if not line.startswith(b"#"))
    framer = Framer()
    frames = framer.feed(lines) + framer.finish()
    assert [f.kind for f in frames] == [FrameKind.NOVATEL_ABBREV, FrameKind.PROMPT]
    log = frames[0].message
    assert isinstance(log, Log) and isinstance(log.body, BestPos)
    want = EXPECTED["abbreviated_ascii.txt"]
    _check_values(log.header, want["header"])
    _check_values(log.body, want["body"])
    assert frames[1].message == Prompt(want["prompt"])


@pytest.mark.parametrize("split", [1, 7, 40, 100])
def test_abbreviated_vector_split_across_reads(shared_dir: Path, split: int) -> None:
    data = (_vector_dir(shared_dir) / "abbreviated_ascii.txt").read_bytes()
    lines = b"".join(line + b"\r\n" for line in data.splitlines() if not line.startswith(b"#"))
    framer = Framer()
    frames = []
    for i in range(0, len(lines), split):
        frames += framer.feed(lines[i : i + split])
    frames += framer.finish()
    assert [f.kind for f in frames] == [FrameKind.NOVATEL_ABBREV, FrameKind.PROMPT]
