"""The live (cantools, per frame) and vectorised role decoders agree frame by frame, faults included."""

from __future__ import annotations

import math

import numpy as np
from cantools.database.can import Database
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap
from drivers.can.vector_decode import FrameBatch, VectorRoleDecoder
from tests.can_decode.conftest import DATA, XOR, small_roles

_DB = load_dbc(DATA / "small.dbc", strict=True)
_RM = RoleMap.from_mapping(small_roles(), _DB)

_kinds = st.sampled_from(["imu", "imu", "steer", "steer", "mux", "unknown"])
_faults = st.sampled_from(["none"] * 6 + ["crc", "skip", "repeat", "short", "long"])


@st.composite
def _stream(draw: st.DrawFn) -> list[tuple[int, int, bytes]]:
    frames: list[tuple[int, int, bytes]] = []
    counters = {"imu": 0, "steer": 0}
    t = 0
    for _ in range(draw(st.integers(1, 60))):
        t += draw(st.integers(1, 10_000_000))
        kind = draw(_kinds)
        fault = draw(_faults)
        payload = bytearray(draw(st.binary(min_size=8, max_size=8)))
        if kind == "unknown":
            frames.append((t, 0x555, bytes(payload[: draw(st.integers(0, 8))])))
            continue
        if kind == "mux":
            payload[0] = (payload[0] & 0xFC) | draw(st.integers(0, 3))  # page 2/3 are undecodable
            frame_id = 0x300
        else:
            if fault == "skip":
                counters[kind] += draw(st.integers(2, 5))
            elif fault == "repeat":
                counters[kind] -= 1
            c = counters[kind] % 16
            counters[kind] += 1
            if kind == "imu":
                frame_id = 0x100
                payload[6] = (payload[6] & 0xF0) | c
                payload[7] = XOR.compute(0x100, bytes(payload))
                if fault == "crc":
                    payload[7] ^= 0x01
            else:
                frame_id = 0x200
                payload[7] = (payload[7] & 0x0F) | (c << 4)
        if fault == "short":
            payload = payload[: draw(st.integers(0, 7))]
        elif fault == "long":
            payload += b"\x00"
        frames.append((t, frame_id, bytes(payload)))
    return frames


def _check(db: Database, rm: RoleMap, frames: list[tuple[int, int, bytes]]) -> None:
    live = RoleDecoder(db, rm)
    decoded = [live.decode(fid, data, t) for t, fid, data in frames]
    result = VectorRoleDecoder(db, rm).decode(FrameBatch.from_frames(frames, width=16))
    assert dict(result.unknown_ids) == dict(live.stats().unknown_ids)
    for message in result.messages.values():
        for b, f in zip(message.batch_index.tolist(), message.flags.tolist(), strict=True):
            assert f == int(decoded[b].flags), (b, frames[b])
    for role, series in result.roles.items():
        rows = dict(zip(series.batch_index.tolist(), range(len(series)), strict=True))
        for b, frame in enumerate(decoded):
            sample = next((s for s in frame.samples if s.role == role), None)
            j = rows.get(b)
            if sample is None:
                assert j is None or series.flags[j] != 0 or math.isnan(series.values[j]) is False
                if j is not None:
                    assert int(series.flags[j]) == int(frame.flags) and frame.flags
                continue
            assert j is not None, (role, b)
            assert series.values[j] == sample.value, (role, b)
            assert int(series.flags[j]) == int(sample.flags), (role, b)
            assert series.raw[j] == sample.raw
            assert series.labels()[j] == sample.label


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_stream())
def test_live_and_vectorised_agree(frames: list[tuple[int, int, bytes]]) -> None:
    _check(_DB, _RM, frames)


def test_every_fault_kind_is_seen_by_both_paths() -> None:
    imu = _DB.get_message_by_name("IMU_01")
    frames = []
    for k in range(6):
        data = bytearray(imu.encode({"IMU_Yaw": k, "IMU_Ay": 0.1, "IMU_Ay_Valid": k % 2, "IMU_Status": 0,
                                     "IMU_Counter_BZ": k if k < 4 else k + 5, "IMU_CRC": 0}))
        data[7] = XOR.compute(0x100, bytes(data)) ^ (1 if k == 2 else 0)
        frames.append((k, 0x100, bytes(data)))
    frames.append((9, 0x100, b"\x00"))
    _check(_DB, _RM, frames)
    flags = VectorRoleDecoder(_DB, _RM).decode(FrameBatch.from_frames(frames)).roles["lat_accel"].flags
    # k=0 ok but invalid (quality bit 0), k=2 checksum, k=3 counter (2 was rejected, so 1 -> 3),
    # k=4 jump (3 -> 9), k=5 counter 10 follows 9 (a jump re-synchronises, as AUTOSAR E2E does) and
    # its quality bit is 1 (valid), k=6 short
    assert flags.tolist() == [32, 0, 4, 8, 8, 0, 2]
    assert np.isnan(VectorRoleDecoder(_DB, _RM).decode(FrameBatch.from_frames(frames)).roles["yaw_rate"].values[2])
