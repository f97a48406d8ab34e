"""The simulated ECU's vectorised payload encoder against cantools, and its cheap frame copy.

The ECU packs all rows of a message at once from the DBC bit layout (``sim_devices.vsc_ecu._Encoder``)
instead of calling cantools per frame. These tests hold it to byte equality with cantools'
``Message.encode(..., strict=True)`` row by row, with the checksum from the per-frame
``ChecksumAlgorithm.compute``: on a simulated drive with the sim DBC, on every message of the real
VW MQB DBC with random values, and on random layouts that mix Intel and Motorola signals.
"""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from cantools.database.can import Database, Signal
from cantools.database.can import Message as DbcMessage
from cantools.database.conversion import BaseConversion
from hypothesis import given
from hypothesis import strategies as st

from drivers.can.checks import get_checksum
from sim_devices.vsc_ecu import VscEcuConfig, _Encoder, _SentFrame, frames, simulate_ecu, vsc_sim_dbc_path
from tests.can_live.truth_builders import steady_circle
from vsccore.errors import SimulationError


@pytest.fixture(scope="module")
def sim_db() -> Database:
    return _load(vsc_sim_dbc_path())


def _load(path: Path) -> Database:
    db = cantools.database.load_file(path, strict=False)  # cantools' own loader, not the project's
    assert isinstance(db, Database)
    return db


def _reference_rows(message: DbcMessage, values: dict[str, np.ndarray], n: int, algorithm_name: str | None,
                    ) -> list[bytes]:
    """cantools, one row at a time, as the ECU encoded before (counter, checksum 0, then the CRC)."""
    names = {s.name for s in message.signals}
    mux = next((s for s in message.signals if s.is_multiplexer), None)
    algorithm = get_checksum(algorithm_name) if algorithm_name else None
    out = []
    for i in range(n):
        row = {k: float(v[i]) for k, v in values.items()}
        if "COUNTER" in names:
            row["COUNTER"] = i % 16
        if "CHECKSUM" in names:
            row["CHECKSUM"] = 0
        if mux is not None:
            page = int(row[mux.name])
            row = {mux.name: page, **{s.name: row[s.name] for s in message.signals
                                      if s.multiplexer_ids is not None and page in s.multiplexer_ids}}
        data = bytearray(message.encode(row, scaling=True, padding=False, strict=True))
        if algorithm is not None:
            data[0] = algorithm.compute(message.frame_id, bytes(data))
        out.append(bytes(data))
    return out


def test_drive_payloads_equal_cantools_row_by_row(sim_db) -> None:
    truth = steady_circle(15.0, 100.0, 3.0)
    cfg = VscEcuConfig(seed=5)
    out = simulate_ecu(truth, cfg)
    total = 0
    for name, series in out.messages.items():
        message = sim_db.get_message_by_name(name)
        n = int(series.t.size)
        enc = _Encoder(message, get_checksum(cfg.checksums[name]) if name in cfg.checksums else None)
        got = enc.encode_many(series.signals, n)
        want = _reference_rows(message, dict(series.signals), n, cfg.checksums.get(name))
        assert [bytes(r) for r in got] == want, name
        total += n
    assert total > 1000


def test_counter_continues_across_calls_and_single_rows(sim_db) -> None:
    message = sim_db.get_message_by_name("ESC_SensorCluster")
    values = {s.name: np.zeros(20) for s in message.signals if s.name not in ("COUNTER", "CHECKSUM")}
    whole = _Encoder(message, get_checksum("vw_mqb_crc8")).encode_many(values, 20)
    split = _Encoder(message, get_checksum("vw_mqb_crc8"))
    parts = [split.encode_many({k: v[:7] for k, v in values.items()}, 7)]
    parts += [np.frombuffer(split.encode(dict.fromkeys(values, 0.0)), dtype=np.uint8)[None, :] for _ in range(13)]
    assert np.array_equal(np.vstack(parts), whole)
    assert (whole[:, 1] & 0x0F).tolist() == [i % 16 for i in range(20)]


def _random_physical(message: DbcMessage, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Random in-range physical values (whole raw steps) for every signal; pages of a multiplexer
    drawn from the ids its signals use."""
    values: dict[str, np.ndarray] = {}
    for s in message.signals:
        if s.is_multiplexer:
            ids = sorted({i for x in message.signals for i in (x.multiplexer_ids or ())})
            values[s.name] = rng.choice(ids, n).astype(np.float64)
            continue
        lo_raw = -(1 << (s.length - 1)) if s.is_signed else 0
        hi_raw = (1 << (s.length - 1)) - 1 if s.is_signed else (1 << s.length) - 1
        if s.minimum is not None:
            lo_raw = max(lo_raw, math.ceil((s.minimum - s.offset) / s.scale - 1e-9))
        if s.maximum is not None:
            hi_raw = min(hi_raw, math.floor((s.maximum - s.offset) / s.scale + 1e-9))
        if hi_raw < lo_raw:  # a DBC range the bits cannot reach: any raw value
            lo_raw, hi_raw = (-(1 << (s.length - 1)), 0) if s.is_signed else (0, 1)
        raw = rng.integers(lo_raw, hi_raw, n, endpoint=True, dtype=np.int64)
        values[s.name] = raw * s.scale + s.offset
    return values


def test_every_vw_mqb_message_equals_cantools(shared_dir) -> None:
    db = _load(shared_dir / "dbc" / "vw_mqb.dbc")
    rng = np.random.default_rng(11)
    checked = 0
    crc = get_checksum("vw_mqb_crc8")
    with_crc = overlapping = 0
    for message in db.messages:
        # COUNTER and CHECKSUM are the ECU's own (rolling counter, MQB CRC where the id has a data-ID table)
        algorithm = "vw_mqb_crc8" if crc.supports(message.frame_id) and any(
            s.name == "CHECKSUM" for s in message.signals) else None
        values = _random_physical(message, 40, rng)
        try:
            want = _reference_rows(message, values, 40, algorithm)
        except OverflowError:  # PLA_01: two signals share bits, cantools cannot encode it either
            with pytest.raises(SimulationError, match=f"{re.escape(message.name)}.* overlaps"):
                _Encoder(message, None)
            overlapping += 1
            continue
        got = _Encoder(message, None if algorithm is None else crc).encode_many(values, 40)
        assert [bytes(r) for r in got] == want, message.name
        checked += 1
        with_crc += algorithm is not None
    assert checked + overlapping == len(db.messages) and overlapping <= 1 and with_crc >= 20


@st.composite
def _layouts(draw: st.DrawFn) -> DbcMessage:
    """A message of 1..8 bytes with non-overlapping Intel and Motorola integer signals."""
    length = draw(st.integers(1, 8))
    used: set[tuple[int, int]] = set()
    signals: list[Signal] = []
    for k in range(draw(st.integers(1, 6))):
        big = draw(st.booleans())
        size = draw(st.integers(1, min(32, 8 * length)))
        first = draw(st.integers(0, 8 * length - size))
        if big:  # Motorola: contiguous in the MSB-first numbering; cantools' start is the MSB's sawtooth number
            bits = {(j // 8, 7 - j % 8) for j in range(first, first + size)}
            start = 8 * (first // 8) + 7 - first % 8
        else:
            bits = {(j // 8, j % 8) for j in range(first, first + size)}
            start = first
        if bits & used:
            continue
        used |= bits
        signed = draw(st.booleans()) and size > 1
        scale = draw(st.sampled_from([1, 0.5, 0.01, 0.1, 0.25, 2]))
        offset = draw(st.sampled_from([0, -40, 10.5]))
        conversion = BaseConversion.factory(scale=scale, offset=offset, choices=None, is_float=False)
        signals.append(Signal(f"S{k}", start, size, "big_endian" if big else "little_endian", signed,
                              conversion=conversion))
    return DbcMessage(0x123, "Random", length, signals, strict=True)


@given(message=_layouts(), seed=st.integers(0, 2**32 - 1))
def test_random_layouts_equal_cantools(message: DbcMessage, seed: int) -> None:
    values = _random_physical(message, 16, np.random.default_rng(seed))
    got = _Encoder(message, None).encode_many(values, 16)
    assert [bytes(r) for r in got] == _reference_rows(message, values, 16, None)


def test_out_of_range_value_is_refused_naming_the_signal(sim_db) -> None:
    message = sim_db.get_message_by_name("ESC_SensorCluster")
    values = {s.name: np.zeros(3) for s in message.signals if s.name not in ("COUNTER", "CHECKSUM")}
    values["ESC_LatAccel"] = np.array([0.0, 4.0, 0.0])  # the DBC carries ±3.2768 g
    with pytest.raises(SimulationError, match=re.escape("ESC_SensorCluster.ESC_LatAccel")):
        _Encoder(message, None).encode_many(values, 3)
    del values["ESC_LatAccel"]
    with pytest.raises(SimulationError, match="ESC_LatAccel"):
        _Encoder(message, None).encode_many(values, 3)


def test_frames_are_byte_identical_to_cantools_and_in_time_order(sim_db) -> None:
    truth = steady_circle(15.0, 100.0, 2.0)
    got = list(frames(truth, t0_s=50.0))
    t = np.array([x[0] for x in got])
    assert np.all(np.diff(t) >= 0)
    assert all(m.timestamp == pytest.approx(50.0 + ti, abs=1e-9) for ti, m in got)
    out = simulate_ecu(truth)
    cfg = VscEcuConfig()
    for name, series in out.messages.items():
        message = sim_db.get_message_by_name(name)
        mine = [bytes(m.data) for _, m in got if m.arbitration_id == message.frame_id]
        assert mine == _reference_rows(message, dict(series.signals), int(series.t.size), cfg.checksums.get(name))


def test_sent_frame_copies_are_plain_independent_messages() -> None:
    f = _SentFrame(timestamp=12.5, arbitration_id=0x101, is_extended_id=False, data=b"\x01\x02\x03", dlc=3,
                   channel="x")
    c = copy.deepcopy(f)
    assert type(c) is can.Message
    assert c.equals(f)
    c.data[0] = 0xFF
    assert f.data[0] == 0x01
    assert c.timestamp == 12.5 and c.channel == "x" and c.dlc == 3 and not c.is_extended_id


def test_layouts_numpy_cannot_pack_fall_back_to_cantools() -> None:
    """Float signals and CAN FD lengths go through cantools row by row: the same bytes, the same counter."""
    as_float = BaseConversion.factory(scale=1, offset=0, choices=None, is_float=True)
    linear = BaseConversion.factory(scale=0.1, offset=0, choices=None, is_float=False)
    float_msg = DbcMessage(0x200, "Floaty", 8, [
        Signal("COUNTER", 0, 4, "little_endian", False, conversion=BaseConversion.factory(1, 0, None, False)),
        Signal("Temp", 8, 32, "little_endian", False, conversion=as_float),
        Signal("Level", 40, 16, "little_endian", True, conversion=linear),
    ], strict=True)
    fd_msg = DbcMessage(0x201, "LongOne", 12, [
        Signal("A", 0, 16, "little_endian", True, conversion=linear),
        Signal("B", 80, 16, "little_endian", False, conversion=linear),
    ], strict=True)
    rng = np.random.default_rng(2)
    for message in (float_msg, fd_msg):
        enc = _Encoder(message, None)
        assert enc._layouts is None  # not packed by numpy
        values = {s.name: np.round(rng.uniform(-100, 100, 20), 1) for s in message.signals if s.name != "COUNTER"}
        if message is fd_msg:
            values["B"] = np.abs(values["B"])
        got = enc.encode_many(values, 20)
        assert [bytes(r) for r in got] == _reference_rows(message, values, 20, None), message.name
