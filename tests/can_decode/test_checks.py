"""Checksums and counter checks against published vectors and real MQB frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.checks import (
    CounterTracker,
    FrameFlag,
    NoChecksum,
    VwMqbCrc8,
    available_checksums,
    counter_errors,
    crc8_8h2f_table,
    get_checksum,
    register_checksum,
)
from vsccore.errors import ConfigError, DecodeError

DATA = Path(__file__).parent / "data"


def _crc8h2f_bitwise(data: bytes) -> int:
    """CRC-8/AUTOSAR written out bit by bit (no table): poly 0x2F, init 0xFF, xorout 0xFF."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x2F) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def _crc_with_table(data: bytes) -> int:
    table = crc8_8h2f_table()
    crc = 0xFF
    for byte in data:
        crc = int(table[crc ^ byte])
    return crc ^ 0xFF


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        # CRC catalogue check value of CRC-8/AUTOSAR.
        (b"123456789", 0xDF),
        # AUTOSAR SWS CRC Library, CRC8H2F example table.
        (bytes.fromhex("00000000"), 0x12),
        (bytes.fromhex("F20183"), 0xC2),
        (bytes.fromhex("0FAA0055"), 0xC6),
        (bytes.fromhex("00FF5511"), 0x77),
        (bytes.fromhex("332255AABBCCDDEEFF"), 0x11),
        (bytes.fromhex("926B55"), 0x33),
        (bytes.fromhex("FFFFFFFF"), 0x6C),
    ],
)
def test_crc8h2f_table_matches_published_vectors(data: bytes, expected: int) -> None:
    assert _crc_with_table(data) == expected
    assert _crc8h2f_bitwise(data) == expected


def _real_esp21_frames() -> list[bytes]:
    frames = []
    for line in (DATA / "mqb_esp21_real.csv").read_text().splitlines():
        if line.startswith(("#", "Time")) or not line.strip():
            continue
        fields = line.split(",")
        frames.append(bytes(int(x, 16) for x in fields[6:14]))
    return frames


def test_vw_mqb_crc_verifies_real_esp21_frames_for_every_counter_value() -> None:
    frames = _real_esp21_frames()
    algo = VwMqbCrc8()
    assert {f[1] & 0x0F for f in frames} == set(range(16))  # every data-ID entry is exercised
    for frame in frames:
        assert algo.compute(0x0FD, frame) == frame[0], frame.hex()
    many = algo.compute_many(0x0FD, np.frombuffer(b"".join(frames), dtype=np.uint8).reshape(-1, 8))
    assert many.tolist() == [f[0] for f in frames]


def test_vw_mqb_crc_is_the_autosar_crc_over_payload_and_data_id() -> None:
    # Independent formulation: CRC-8H2F over bytes 1..7 followed by the data-ID byte.
    rng = np.random.default_rng(7)
    algo = VwMqbCrc8()
    for frame_id, data_id in ((0x101, 0xAA), (0x086, 0x86), (0x106, 0x07)):
        for _ in range(50):
            payload = bytes(rng.integers(0, 256, 8, dtype=np.uint8))
            assert algo.compute(frame_id, payload) == _crc8h2f_bitwise(payload[1:] + bytes([data_id]))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.binary(min_size=8, max_size=8), min_size=1, max_size=20))
def test_vw_mqb_crc_vectorised_equals_per_frame(frames: list[bytes]) -> None:
    algo = VwMqbCrc8()
    arr = np.frombuffer(b"".join(frames), dtype=np.uint8).reshape(-1, 8)
    assert algo.compute_many(0x0FD, arr).tolist() == [algo.compute(0x0FD, f) for f in frames]


def test_vw_mqb_crc_unknown_message_is_a_clear_error() -> None:
    algo = VwMqbCrc8()
    assert not algo.supports(0x123)
    with pytest.raises(DecodeError, match="0x123"):
        algo.compute(0x123, bytes(8))


def test_registry_lookup_and_suggestions() -> None:
    assert get_checksum("vw_mqb_crc8").name == "vw_mqb_crc8"
    assert isinstance(get_checksum("none"), NoChecksum)
    with pytest.raises(ConfigError, match=r"vw_mqb_crc8") as info:
        get_checksum("vw_mqb_crc", where="checks.ESP_02.algorithm")
    assert "checks.ESP_02.algorithm" in str(info.value)
    with pytest.raises(ConfigError, match="already registered"):
        register_checksum(VwMqbCrc8())
    assert "none" in available_checksums()


def test_counter_errors_known_sequences() -> None:
    seq = np.array([14, 15, 0, 1, 1, 2, 5, 6])
    #                ok  ok  ok ok rep ok jump ok
    assert counter_errors(seq, 16).tolist() == [False, False, False, False, True, False, True, False]
    assert counter_errors(seq, 16, max_delta=3).tolist() == [False, False, False, False, True, False, False, False]
    assert counter_errors(np.array([], dtype=np.int64), 16).tolist() == []


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(0, 15), max_size=60), st.integers(1, 4))
def test_counter_tracker_matches_vectorised(seq: list[int], max_delta: int) -> None:
    tracker = CounterTracker(16, max_delta)
    live = [tracker.check(c) for c in seq]
    assert live == counter_errors(np.array(seq, dtype=np.int64), 16, max_delta).tolist()


def test_frame_flag_names() -> None:
    flags = FrameFlag.CHECKSUM | FrameFlag.COUNTER
    assert flags.names() == ["CHECKSUM", "COUNTER"]
    assert FrameFlag.OK.names() == []
    assert FrameFlag.INVALID & FrameFlag.frame_level() == 0
