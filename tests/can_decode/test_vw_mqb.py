"""The public VW MQB DBC with the shipped role mapping: SI values, MQB CRC and counters, both paths.

Frames are built with cantools from chosen physical values; counters and CRCs are filled in by a
bit-by-bit CRC-8H2F written here (not the production table code). Real ESP_21 frames logged on a
car check the CRC data IDs and the decoding of vehicle speed.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from cantools.database.can import Database

from drivers.can.checks import FrameFlag
from drivers.can.dbc import load_dbc
from drivers.can.roles import RoleDecoder, RoleMap
from drivers.can.vector_decode import FrameBatch, VectorRoleDecoder

REPO = Path(__file__).resolve().parents[2]
ROLES = REPO / "examples" / "roles" / "vw_mqb.toml"
DATA = Path(__file__).parent / "data"
G0 = 9.80665
DEG = math.pi / 180
DATA_ID = {"ESP_02": 0xAA, "LWI_01": 0x86, "ESP_05": 0x07}  # constant data IDs of these messages


def _crc8h2f(data: bytes) -> int:
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x2F) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


@pytest.fixture
def vw(shared_dir: Path) -> tuple[Database, RoleMap]:
    db = load_dbc(shared_dir / "dbc" / "vw_mqb.dbc")
    return db, RoleMap.from_toml(ROLES, db)


def _frame(db: Database, name: str, values: dict[str, float], counter: int | None = None) -> bytes:
    msg = db.get_message_by_name(name)
    full = {s.name: 0 for s in msg.signals}
    # Physical zero is outside the range of offset signals; start from their raw zero instead.
    for s in msg.signals:
        full[s.name] = s.offset if s.offset else 0
    full.update(values)
    if counter is not None:
        full["COUNTER"] = counter
    data = bytearray(msg.encode(full, strict=False))
    if name in DATA_ID:
        data[0] = _crc8h2f(bytes(data[1:]) + bytes([DATA_ID[name]]))
    return bytes(data)


def _esp02(db: Database, counter: int) -> bytes:
    return _frame(
        db,
        "ESP_02",
        {"ESP_Gierrate": 28.65, "ESP_VZ_Gierrate": 1, "ESP_Querbeschleunigung": 0.35, "ESP_Laengsbeschl": -2.0},
        counter,
    )


def _lwi01(db: Database, counter: int) -> bytes:
    values = {
        "LWI_Lenkradwinkel": 45.0,
        "LWI_VZ_Lenkradwinkel": 0,
        "LWI_Lenkradw_Geschw": 100,
        "LWI_VZ_Lenkradw_Geschw": 1,
    }
    return _frame(db, "LWI_01", values, counter)


def _esp19(db: Database) -> bytes:
    values = {
        "ESP_VL_Radgeschw_02": 72.0,
        "ESP_VR_Radgeschw_02": 36.0,
        "ESP_HL_Radgeschw_02": 18.0,
        "ESP_HR_Radgeschw_02": 0.0,
    }
    return _frame(db, "ESP_19", values)


def _esp05(db: Database, counter: int) -> bytes:
    return _frame(db, "ESP_05", {"ESP_Bremsdruck": 60.0, "ESP_QBit_Bremsdruck": 0}, counter)


EXPECTED = {
    "yaw_rate": -28.65 * DEG,  # sign bit set: negative (turning right)
    "lat_accel": 0.35 * G0,
    "long_accel": -2.0,
    "swa": 45.0 * DEG,
    "swa_rate": -100.0 * DEG,
    "wheel_speed_fl": 20.0,
    "wheel_speed_fr": 10.0,
    "wheel_speed_rl": 5.0,
    "wheel_speed_rr": 0.0,
    "mc_pressure": 60.0e5,
}


def _stream(db: Database) -> tuple[list[tuple[int, int, bytes]], dict[str, set[int]]]:
    """20 cycles of 10 ms of the four messages, with faults; returns frames and expected flags by index."""
    frames: list[tuple[int, int, bytes]] = []
    expect: dict[str, set[int]] = {"CHECKSUM": set(), "COUNTER": set(), "WRONG_LENGTH": set(), "UNKNOWN_ID": set()}
    t = 1_700_000_000_000_000_000
    lwi_counter = 0
    for k in range(20):
        t += 10_000_000
        esp02 = _esp02(db, k % 16)
        if k == 5:  # one bit flipped in transit
            esp02 = esp02[:3] + bytes([esp02[3] ^ 0x04]) + esp02[4:]
            expect["CHECKSUM"].add(len(frames))
        if k == 6:  # a rejected frame does not count as received: the next counter is a jump (E2E)
            expect["COUNTER"].add(len(frames))
        frames.append((t, 0x101, esp02))
        if k == 12:  # an LWI_01 frame is lost: the next one's counter jumps by 2
            lwi_counter += 1
            expect["COUNTER"].add(len(frames))
        frames.append((t + 1_000_000, 0x086, _lwi01(db, lwi_counter % 16)))
        lwi_counter += 1
        frames.append((t + 2_000_000, 0x0B2, _esp19(db)))
        esp05 = _esp05(db, k % 16)
        if k == 9:
            esp05 = esp05[:6]
            expect["WRONG_LENGTH"].add(len(frames))
        if k == 10:
            expect["COUNTER"].add(len(frames))
        frames.append((t + 3_000_000, 0x106, esp05))
        if k == 15:
            expect["UNKNOWN_ID"].add(len(frames))
            frames.append((t + 4_000_000, 0x7E8, b"\x02\x01\x00"))
    return frames, expect


def test_roles_in_si_through_live_and_vectorised_paths(vw: tuple[Database, RoleMap]) -> None:
    db, rm = vw
    frames, expect = _stream(db)

    live = RoleDecoder(db, rm)
    decoded = [live.decode(fid, data, t) for t, fid, data in frames]
    for name, indices in expect.items():
        flagged = {i for i, d in enumerate(decoded) if d.flags & FrameFlag[name]}
        assert flagged == indices, name
    for i, d in enumerate(decoded):
        if d.flags:
            assert d.samples == ()
            continue
        for s in d.samples:
            if s.role in EXPECTED:
                assert s.value == pytest.approx(EXPECTED[s.role], rel=1e-9, abs=1e-12), (i, s)
            assert s.flags == FrameFlag.OK, s  # all quality bits are set to "valid" (0)
    stats = live.stats()
    assert stats.unknown_ids == {0x7E8: 1}

    batch = FrameBatch.from_frames(frames)
    result = VectorRoleDecoder(db, rm).decode(batch)
    assert dict(result.unknown_ids) == {0x7E8: 1}
    for role, value in EXPECTED.items():
        series = result.roles[role]
        ok = series.flags == 0
        assert ok.sum() > 10
        assert np.allclose(series.values[ok], value, rtol=1e-9, atol=1e-12), role
        assert np.isnan(series.values[~ok]).all()
        # Same rows flagged as the live path, and the same values where both have them.
        live_values = [
            next(s.value for s in decoded[b].samples if s.role == role)
            for b in series.batch_index[ok].tolist()
        ]
        assert series.values[ok].tolist() == live_values
        for b, f in zip(series.batch_index.tolist(), series.flags.tolist(), strict=True):
            assert f == int(decoded[b].flags)


def _real_esp21() -> list[tuple[int, bytes]]:
    rows = []
    for line in (DATA / "mqb_esp21_real.csv").read_text().splitlines():
        if line.startswith(("#", "Time")) or not line.strip():
            continue
        f = line.split(",")
        rows.append((int(f[0]) * 1000, bytes(int(x, 16) for x in f[6:14])))
    return rows


def test_real_esp21_frames_pass_crc_and_decode_vehicle_speed(vw: tuple[Database, RoleMap]) -> None:
    db, rm = vw
    rows = _real_esp21()
    batch = FrameBatch.from_frames([(t, 0x0FD, d) for t, d in rows])
    series = VectorRoleDecoder(db, rm).decode(batch).roles["vehicle_speed"]
    # The capture is four excerpts of one drive; each join skips counter values.
    assert np.flatnonzero(series.flags & FrameFlag.COUNTER).tolist() == [16, 32, 34, 35]
    assert not (series.flags & FrameFlag.CHECKSUM).any()
    msg = db.get_message_by_name("ESP_21")
    for i, (_, data) in enumerate(rows):
        if series.flags[i]:
            continue
        kmh = msg.decode(data, decode_choices=False)["ESP_v_Signal"]
        assert series.values[i] == pytest.approx(kmh / 3.6, rel=1e-12)
    assert series.values[17] == pytest.approx(0x2FC5 * 0.01 / 3.6)  # 122.29 km/h on the motorway

    live = RoleDecoder(db, rm)
    flags = [live.decode(0x0FD, d, t).flags for t, d in rows]
    assert [i for i, f in enumerate(flags) if f] == [16, 32, 34, 35]
    assert all(f == FrameFlag.COUNTER for f in flags if f)
