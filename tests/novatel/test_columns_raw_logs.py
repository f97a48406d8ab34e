"""The columnar decoder on the logs the stream decoders keep raw (RANGECMP, GPSEPHEM, GLOEPHEMERIS) and
on its fast paths: RANGECMP records unpacked in bulk, and text-frame candidates inside good binary frames
left unscanned.

The reference is the per-message path: :class:`drivers.novatel.Framer` plus the
:mod:`drivers.novatel.rawobs` decoders. Every value must be the same bit for bit, and every frame the
framer rejects (CRC, truncated, oversize) or cannot decode must be counted alike, on clean streams,
streams with garbage, damaged streams and every prefix of a stream. RANGECMP is also checked against
NovAtel's EDIE (decompressed to RANGE).
"""

from __future__ import annotations

import math
import struct
from dataclasses import fields, replace
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.novatel import (
    Frame,
    FrameKind,
    Framer,
    Header,
    RawBody,
    ShortHeader,
    TimeStatus,
    encode_ascii,
    encode_binary,
    make_header,
)
from drivers.novatel.columns import (
    HEADER_COLUMNS,
    SHORT_HEADER_LOGS,
    ColumnBatch,
    RejectReason,
    decode_columns,
    empty_columns,
)
from drivers.novatel.crc import novatel_crc32
from drivers.novatel.messages import BodyFormat
from drivers.novatel.rawobs import (
    Bool,
    GloEphemeris,
    GpsEphem,
    RangeCmp,
    RangeCmpRecord,
    decode_gloephemeris,
    decode_gpsephem,
    decode_rangecmp,
    encode_gloephemeris,
    encode_gpsephem,
)
from tests.novatel.gen import GARBAGE, damage, long_header_strategy, sample_bestpos
from vsccore.errors import DecodeError

LONG_KINDS = (FrameKind.NOVATEL_ASCII, FrameKind.NOVATEL_BINARY)
NOVATEL_KINDS = (*LONG_KINDS, FrameKind.NOVATEL_SHORT_ASCII, FrameKind.NOVATEL_SHORT_BINARY)
RAW_DECODERS = {"RANGECMP": decode_rangecmp, "GPSEPHEM": decode_gpsephem, "GLOEPHEMERIS": decode_gloephemeris}
RECORD_FIELDS = tuple(f.name for f in fields(RangeCmpRecord))
PROPS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                         HealthCheck.data_too_large])

# --- the reference: Framer + rawobs decoders ----------------------------------------------------------


def _plain(v: Any) -> Any:
    return int(v) if hasattr(v, "value") and isinstance(v, int) else v


def _item(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v


def same(a: Any, b: Any) -> bool:
    """Equal, floats bit for bit (NaN equal to NaN)."""
    if isinstance(a, float) or isinstance(b, float):
        if not (isinstance(a, float) and isinstance(b, float)):
            return False
        return (math.isnan(a) and math.isnan(b)) or struct.pack("<d", a) == struct.pack("<d", b)
    return bool(a == b) and type(a) is type(b)


def reference(data: bytes) -> tuple[dict[str, list[tuple[Frame, Any]]], int, Framer]:
    """The logs the columns must hold (frame, decoded body) by name, the frames that do not decode, and
    the framer (for its counts)."""
    framer = Framer()
    frames = framer.feed(data) + framer.finish()
    out: dict[str, list[tuple[Frame, Any]]] = {}
    malformed = 0
    for fr in frames:
        lg = fr.log
        if fr.kind not in LONG_KINDS or lg is None or fr.error is not None:
            continue
        body: Any = lg.body
        if isinstance(body, RawBody):
            decode = RAW_DECODERS.get(lg.name)
            if decode is None or lg.header.response:  # type: ignore[union-attr]
                continue
            try:
                body = decode(body)
            except DecodeError:
                malformed += 1
                continue
        out.setdefault(lg.name, []).append((fr, body))
    return out, malformed, framer


def assert_matches_reference(data: bytes, batch: ColumnBatch | None = None) -> ColumnBatch:
    batch = decode_columns(data) if batch is None else batch
    want, malformed, framer = reference(data)
    assert sorted(batch.logs) == sorted(want)
    for name, rows in want.items():
        cols = batch.logs[name]
        assert len(cols) == len(rows), name
        derived = {"event_gps_ns", "leap_seconds", "num_obs"}
        assert [k for k in cols.body if k not in derived] == [f.name for f in fields(rows[0][1]) if f.name != "records"]
        for i, (fr, body) in enumerate(rows):
            h = fr.log.header  # type: ignore[union-attr]
            for key in HEADER_COLUMNS[:-1]:
                assert same(_item(cols.header[key][i]), _plain(getattr(h, key))), (name, i, key)
            assert data[int(cols.offset[i]) : int(cols.end[i])] == fr.raw
            assert bool(cols.binary[i]) == (fr.kind is FrameKind.NOVATEL_BINARY)
            if isinstance(body, RangeCmp):
                assert cols.record_start is not None
                first, last = int(cols.record_start[i]), int(cols.record_start[i + 1])
                assert cols.body["num_obs"][i] == last - first == len(body.records)
                for j, rec in enumerate(body.records):
                    for key in RECORD_FIELDS:
                        assert same(_item(cols.records[key][first + j]), getattr(rec, key)), (i, j, key)
                continue
            for f in fields(body):
                assert same(_item(cols.body[f.name][i]), _plain(getattr(body, f.name))), (name, i, f.name)
    rc = batch.logs.get("RANGECMP")
    if rc is not None:
        assert rc.record_start is not None and rc.record_start[-1] == len(rc.records["prn"])
        for key in RECORD_FIELDS:
            assert rc.records[key].dtype == (np.int64 if key in ("tracking_status", "prn", "cn0_dbhz", "glonass_fcn")
                                             else np.float64), key
    st_ = framer.stats
    assert batch.rejected[RejectReason.CRC_FAILURE] == sum(st_.crc_failures[k] for k in NOVATEL_KINDS)
    assert batch.rejected[RejectReason.TRUNCATED] == st_.truncated
    assert batch.rejected[RejectReason.OVERSIZE] == sum(st_.oversize[k] for k in NOVATEL_KINDS)
    assert batch.rejected[RejectReason.MALFORMED] == sum(st_.decode_errors[k] for k in LONG_KINDS) + malformed
    short = st_.frames[FrameKind.NOVATEL_SHORT_ASCII] + st_.frames[FrameKind.NOVATEL_SHORT_BINARY]
    assert batch.other.get(SHORT_HEADER_LOGS, 0) == short
    return batch


# --- frames -------------------------------------------------------------------------------------------


def _header(name: str, message_id: int, seconds: float = 345600.0, **kw: Any) -> Header:
    return Header(message_name=name, message_id=message_id, port=kw.pop("port", "COM1"), sequence=kw.pop("sequence", 0),
                  idle_time_pct=kw.pop("idle_time_pct", 50.0), time_status=TimeStatus.FINESTEERING, week=2300,
                  seconds=seconds, receiver_status=kw.pop("receiver_status", 0x02000000), reserved=0xB1F6,
                  sw_version=16248, **kw)


def record(*, status: int, doppler: int, psr: int, adr: int, psr_std: int = 5, adr_std: int = 3, prn: int = 7,
           lock: int = 1000, cn0: int = 25, fcn: int = 0) -> bytes:
    """One 24-byte RANGECMP record from raw field values (signed ones as two's complement)."""
    v = status & 0xFFFF_FFFF
    v |= (doppler & 0xFFF_FFFF) << 32
    v |= (psr & 0xF_FFFF_FFFF) << 60
    v |= (adr & 0xFFFF_FFFF) << 96
    v |= (psr_std & 0xF) << 128 | (adr_std & 0xF) << 132 | (prn & 0xFF) << 136
    v |= (lock & 0x1F_FFFF) << 144 | (cn0 & 0x1F) << 165 | (fcn & 0x3F) << 170
    return v.to_bytes(24, "little")


def gps_l1(prn: int, psr_m: float, adr_cycles: float, doppler_hz: float = -737.0) -> bytes:
    status = 0x1810_1C04 if prn % 2 else 0x1810_1C24  # GPS L1 C/A, phase and code locked
    adr = round(adr_cycles * 256)
    return record(status=status, doppler=round(doppler_hz * 256), psr=round(psr_m * 128),
                  adr=((adr + (1 << 31)) % (1 << 32)) - (1 << 31), prn=prn)


def rangecmp_frame(records: list[bytes], *, binary: bool = True, seconds: float = 345600.0,
                   count: int | None = None, **header: Any) -> bytes:
    n = len(records) if count is None else count
    head = _header("RANGECMP", 140, seconds, **header)
    if binary:
        return encode_binary(head, RawBody(struct.pack("<I", n) + b"".join(records), BodyFormat.BINARY))
    text = ",".join([str(n), *(r.hex() for r in records)])
    return encode_ascii(head, RawBody(text.encode("ascii"), BodyFormat.ASCII))


def _ephemeris() -> GpsEphem:
    return GpsEphem(
        prn=7, tow_s=345600.0, health=0, iode1=12, iode2=12, week=2300, z_week=2300, toe_s=352800.0, a_m=26_559_700.0,
        delta_n_rad_s=4.3e-9, m0_rad=-1.2345678901, ecc=0.0123456789, omega_rad=0.987654321, cuc_rad=1.2e-6,
        cus_rad=-3.4e-6, crc_m=210.5, crs_m=-15.25, cic_rad=7.4e-8, cis_rad=-1.1e-7, i0_rad=0.96, idot_rad_s=2.1e-10,
        omega0_rad=2.5, omega_dot_rad_s=-8.1e-9, iodc=12, toc_s=352800.0, tgd_s=-1.1e-8, af0_s=1.2345e-4,
        af1_s_s=-3.4e-12, af2_s_s2=0.0, anti_spoofing=Bool.TRUE,
        n_rad_s=1.4585e-4, ura_var_m2=4.0,
    )


def _glonass(sloto: int = 42) -> GloEphemeris:
    return GloEphemeris(
        sloto=sloto, freqo=8, sat_type=1, false_iod=0, ephem_week=2300, ephem_time_ms=344718000, time_offset_s=10782,
        nt_day=39, reserved1=0, reserved2=0, issue=11, health=0, pos_x_m=22396884.41949337, pos_y_m=-6774743.633618057,
        pos_z_m=10156257.822155189, vel_x_mps=-1297.2053802480195, vel_y_mps=526.6747013868717,
        vel_z_mps=3211.8435097761185, ls_acc_x_mps2=0.0, ls_acc_y_mps2=1.862645149230957e-06,
        ls_acc_z_mps2=-9.313225746154785e-07, tau_n_s=1.45863384e-05, delta_tau_n_s=0.0, gamma_n=1.2e-12, tk_s=9000,
        p=0, ft=0, age_days=0, flags=5,
    )


def ephemeris_frames(*, binary: bool = True) -> bytes:
    fmt = BodyFormat.BINARY if binary else BodyFormat.ASCII
    encode = encode_binary if binary else encode_ascii
    return (encode(_header("GPSEPHEM", 7), encode_gpsephem(_ephemeris(), fmt))
            + encode(_header("GLOEPHEMERIS", 723), encode_gloephemeris(_glonass(), fmt)))


def _bestpos(i: int, binary: bool = True) -> bytes:
    body = sample_bestpos(i)
    head = make_header(body, week=2300, seconds=345600.0 + i * 0.05)
    return encode_binary(head, body) if binary else encode_ascii(head, body)


# --- RANGECMP records --------------------------------------------------------------------------------

#: (system, signal type) pairs: known wavelengths (GPS L1/L2/L5, GLONASS L1/L2, QZSS, SBAS) and unknown ones.
SIGNALS = [(0, 0), (0, 5), (0, 9), (0, 14), (0, 16), (0, 17), (1, 0), (1, 1), (1, 5), (1, 2), (2, 0), (3, 2),
           (4, 0), (5, 0), (5, 9), (7, 31)]


@st.composite
def records(draw: st.DrawFn) -> bytes:
    """A record with any bit fields; its system and signal mostly ones whose wavelength is known, and
    pseudorange and ADR either random or consistent (ADR near −psr/λ, rolled over as a receiver does)."""
    if draw(st.integers(0, 5)) == 0:
        return draw(st.binary(min_size=24, max_size=24))
    system, signal = draw(st.sampled_from(SIGNALS))
    status = draw(st.integers(0, 0xFFFF_FFFF)) & ~(0x7 << 16 | 0x1F << 21) | system << 16 | signal << 21
    fcn = draw(st.integers(0, 63))
    psr = draw(st.integers(0, (1 << 36) - 1))
    if draw(st.booleans()):
        lam = 299_792_458.0 / (1602.0e6 + (fcn - 7) * 0.5625e6 if system == 1 else 1575.42e6)
        cycles = -psr / 128 / lam + draw(st.floats(-1e6, 1e6))
        adr = ((round(cycles * 256) + (1 << 31)) % (1 << 32)) - (1 << 31)
    else:
        adr = draw(st.integers(-(1 << 31), (1 << 31) - 1))
    return record(status=status, doppler=draw(st.integers(-(1 << 27), (1 << 27) - 1)), psr=psr, adr=adr,
                  psr_std=draw(st.integers(0, 15)), adr_std=draw(st.integers(0, 15)), prn=draw(st.integers(0, 255)),
                  lock=draw(st.integers(0, (1 << 21) - 1)), cn0=draw(st.integers(0, 31)), fcn=fcn)


@PROPS
@given(st.lists(st.lists(records(), max_size=5), min_size=1, max_size=6))
def test_bulk_rangecmp_records_are_the_per_record_decoders_bit_for_bit(epochs: list[list[bytes]]) -> None:
    data = b"".join(rangecmp_frame(recs, seconds=345600.0 + i) for i, recs in enumerate(epochs))
    batch = assert_matches_reference(data)
    rc = batch.log("RANGECMP")
    assert rc.body["num_obs"].tolist() == [len(r) for r in epochs]
    assert rc.record_rows().tolist() == [i for i, r in enumerate(epochs) for _ in r]


def test_rangecmp_roll_over_and_signed_fields() -> None:
    """ADR rolled over both ways, negative Doppler and ADR, a GLONASS channel, an unknown signal (ADR as sent)."""
    recs = [
        gps_l1(3, 21_234_567.125, -111_589_123.5),  # rolled over: the wire ADR is ~ -111.6e6 + k * 2**32 / 256
        gps_l1(4, 24_000_000.5, 8_388_607.99, doppler_hz=1234.5),
        record(status=1 << 16 | 0x1C04, doppler=-5, psr=(1 << 36) - 1, adr=-(1 << 31), prn=45, fcn=3),  # GLONASS L1
        record(status=7 << 16 | 31 << 21, doppler=(1 << 27) - 1, psr=0, adr=(1 << 31) - 1, prn=1),  # unknown signal
    ]
    batch = assert_matches_reference(rangecmp_frame(recs))
    rc = batch.log("RANGECMP")
    ref = decode_rangecmp(struct.pack("<I", 4) + b"".join(recs)).records
    assert rc.records["adr_cycles"].tolist() == [r.adr_cycles for r in ref]
    assert rc.records["adr_cycles"][0] == pytest.approx(-111_589_123.5, abs=1 / 256)
    assert rc.records["adr_cycles"][3] == rc.records["adr_raw_cycles"][3] == ((1 << 31) - 1) / 256
    assert rc.records["doppler_hz"][2] == -5 / 256 and rc.records["glonass_fcn"][2] == 3
    assert rc["prn"].tolist() == [3, 4, 45, 1]  # __getitem__ reaches the record columns


def test_rangecmp_roll_over_rounds_half_away_from_zero_as_the_per_record_decoder() -> None:
    """ADRs whose roll count is within a few 1e-9 of a half, on both sides, above and below zero."""
    lam = 299_792_458.0 / 1575.42e6  # GPS L1
    recs = []
    rolls = []
    for target, psr_m in ((-0.5, 1e5), (0.5, 1e6), (1.5, 2e6), (12.5, 2e7)):
        for eps in (-3e-9, -1e-9, 0.0, 1e-9, 3e-9):
            psr = round(psr_m * 128)
            adr = round(256 * ((target + eps) * 8388608.0 - psr / 128 / lam))
            assert -(1 << 31) <= adr < 1 << 31
            recs.append(record(status=0x1810_1C04, doppler=0, psr=psr, adr=adr))
            rolls.append((psr / 128 / lam + adr / 256) / 8388608.0)
    assert any(0 < r - 0.5 < 1e-8 for r in rolls) and any(0 < -0.5 - r < 1e-8 for r in rolls)
    rc = assert_matches_reference(rangecmp_frame(recs)).log("RANGECMP")
    assert sorted(set((rc.records["adr_raw_cycles"] - rc.records["adr_cycles"]) / 8388608.0)) == [-1, 0, 1, 2, 12, 13]


def test_the_bulk_path_takes_standard_rangecmp_frames(monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.novatel.columns as columns

    calls: list[Any] = []
    original = columns.decode_verified

    def counting(*args: Any) -> Any:
        calls.append(args)
        return original(*args)

    monkeypatch.setattr(columns, "decode_verified", counting)
    data = b"".join(rangecmp_frame([gps_l1(p, 2.1e7 + p, -1.1e8 + p) for p in range(1, 1 + i % 9)],
                                   seconds=345600.0 + i) for i in range(40))
    assert len(decode_columns(data).log("RANGECMP")) == 40
    assert calls == []


def test_odd_rangecmp_frames_take_the_per_message_path_or_are_counted() -> None:
    """ASCII, a longer binary header, a count the body does not hold (malformed), the response bit and a short
    header (counted, not decoded); the records of the bulk and per-message rows end up in buffer order."""
    recs = [gps_l1(5, 22_000_000.0, -115_000_000.25), gps_l1(6, 23_000_000.0, 5.5)]
    good = rangecmp_frame(recs)
    long_hdr = bytearray(good[:28] + b"\x00" * 4 + good[28:-4])
    long_hdr[3] = 32
    long_frame = bytes(long_hdr) + struct.pack("<I", novatel_crc32(bytes(long_hdr)))
    response = bytearray(good[:-4])
    response[6] |= 0x80
    response_frame = bytes(response) + struct.pack("<I", novatel_crc32(bytes(response)))
    short = ShortHeader("RANGECMP", 140, 2300, 345600.0)
    short_frame = encode_binary(short, RawBody(struct.pack("<I", 1) + recs[0], BodyFormat.BINARY))
    data = b"".join([
        good, rangecmp_frame(recs[:1], binary=False), long_frame, rangecmp_frame(recs, count=3),
        rangecmp_frame(recs, binary=False, count=1), response_frame, short_frame, rangecmp_frame(recs[1:]), good,
    ])
    batch = assert_matches_reference(data)
    rc = batch.log("RANGECMP")
    assert rc.binary.tolist() == [True, False, True, True, True]
    assert rc.body["num_obs"].tolist() == [2, 1, 2, 1, 2]
    assert rc.records["prn"].tolist() == [5, 6, 5, 5, 6, 6, 5, 6]
    assert batch.rejected[RejectReason.MALFORMED] == 2
    assert batch.other == {"RANGECMP": 1, SHORT_HEADER_LOGS: 1}


def test_ephemerides_decode_as_rawobs_decodes_them() -> None:
    bad_slot = encode_binary(_header("GLOEPHEMERIS", 723), encode_gloephemeris(_glonass(sloto=5)))
    data = ephemeris_frames() + ephemeris_frames(binary=False) + bad_slot + ephemeris_frames()
    batch = assert_matches_reference(data)
    assert batch.log("GPSEPHEM").body["a_m"].tolist() == [26_559_700.0] * 3
    assert batch.log("GLOEPHEMERIS").body["sloto"].tolist() == [42] * 3
    assert batch.rejected[RejectReason.MALFORMED] == 1  # slot 5 - 37: decode_gloephemeris refuses it


def test_logs_argument_and_empty_columns() -> None:
    data = rangecmp_frame([gps_l1(1, 2e7, -1e8)]) + ephemeris_frames() + _bestpos(0)
    only = decode_columns(data, logs=["RANGECMP"])
    assert list(only.logs) == ["RANGECMP"]
    assert only.other == {"GPSEPHEM": 1, "GLOEPHEMERIS": 1, "BESTPOS": 1}
    none = decode_columns(_bestpos(0))
    for empty in (none.log("RANGECMP"), empty_columns("RANGECMP")):
        assert len(empty) == 0 and empty.record_start is not None and empty.record_start.tolist() == [0]
        assert list(empty.records) == list(RECORD_FIELDS) and list(empty.body) == ["num_obs"]
        assert empty.records["prn"].dtype == np.int64 and empty.records["psr_std_m"].dtype == np.float64
        assert empty.record_rows().tolist() == []
    assert empty_columns("GPSEPHEM").body["anti_spoofing"].dtype == np.int64
    assert empty_columns("BESTPOS").record_start is None and not empty_columns("BESTPOS").records


# --- streams: garbage, damage, every prefix ------------------------------------------------------------

NEAR_FRAMES = st.sampled_from([b"#", b"#RANGECMPA,", b"*", b"*12345678", b"\r\n", b"%", b"\xaa\x44\x12", b",", b";",
                               b"\xaa\x44\x12\x1c\x8c\x00"])


@st.composite
def frames(draw: st.DrawFn) -> bytes:
    kind = draw(st.integers(0, 9))
    if kind <= 5:
        head = draw(long_header_strategy(RangeCmp, binary=kind <= 3))
        recs = draw(st.lists(records(), max_size=4))
        count = len(recs) + (1 if kind == 3 else 0)  # now and then a count the body does not hold
        body = struct.pack("<I", count) + b"".join(recs)
        if kind <= 3:
            return encode_binary(head, RawBody(body, BodyFormat.BINARY))
        text = ",".join([str(count), *(r.hex() for r in recs)])
        return encode_ascii(head, RawBody(text.encode("ascii"), BodyFormat.ASCII))
    if kind <= 7:
        return _bestpos(draw(st.integers(0, 1000)), binary=kind == 6)
    return ephemeris_frames(binary=kind == 8)


STREAM = st.lists(st.one_of(frames(), frames(), GARBAGE, NEAR_FRAMES), max_size=10).map(b"".join)


@PROPS
@given(STREAM)
def test_mixed_streams_with_garbage_match_the_per_message_path(data: bytes) -> None:
    assert_matches_reference(data)


@PROPS
@given(st.lists(frames(), min_size=1, max_size=6).map(b"".join), st.data())
def test_damaged_streams_count_rejections_as_the_framer_does(clean: bytes, data: st.DataObject) -> None:
    assert_matches_reference(damage(clean, data))


def test_every_prefix_of_a_stream_matches_the_per_message_path() -> None:
    """A buffer cut at every offset (a capture that ends mid-frame): same logs, same truncation counts."""
    recs = [gps_l1(9, 20_500_000.0, -107_000_000.0), gps_l1(10, 22_500_000.5, 3.25)]
    data = (b"\x00\x07" + rangecmp_frame(recs) + _bestpos(1) + b"garbage" + rangecmp_frame(recs[:1], binary=False)
            + rangecmp_frame(recs[1:], seconds=345601.0))
    for cut in range(len(data) + 1):
        assert_matches_reference(data[:cut])


def test_a_bad_crc_is_rejected_in_every_byte() -> None:
    frame = rangecmp_frame([gps_l1(2, 21_000_000.0, -110_000_000.0)])
    clean = _bestpos(0) + frame + _bestpos(1)
    for at in range(len(_bestpos(0)), len(_bestpos(0)) + len(frame)):
        damaged = bytearray(clean)
        damaged[at] ^= 0x10
        batch = assert_matches_reference(bytes(damaged))
        assert "RANGECMP" not in batch.logs and len(batch.log("BESTPOS")) == 2


# --- text frames inside binary frames -------------------------------------------------------------------


def _ascii_inside(record_bytes_for: bytes) -> bytes:
    """A RANGECMP body whose record bytes hold a complete ASCII log."""
    padded = record_bytes_for + b"\x00" * (-len(record_bytes_for) % 24)
    return struct.pack("<I", len(padded) // 24) + padded


def test_text_frames_inside_a_binary_frame_are_not_logs() -> None:
    """The framer never looks at a '#' inside an accepted binary frame, even a complete good ASCII log."""
    inner = _bestpos(7, binary=False)
    outer = encode_binary(_header("RANGECMP", 140), RawBody(_ascii_inside(inner), BodyFormat.BINARY))
    data = outer + _bestpos(8) + outer
    assert data.count(b"#BESTPOSA") == 2
    batch = assert_matches_reference(data)
    assert len(batch.log("RANGECMP")) == 2 and batch.log("BESTPOS").binary.tolist() == [True]


def test_a_text_frame_inside_a_binary_frame_that_is_not_accepted_counts(monkeypatch: pytest.MonkeyPatch) -> None:
    """Frame B2 starts inside frame B1 (so the framer, having taken B1, never takes B2) and runs past B1's
    end; a good ASCII log inside B2 after B1's end is a log. The fast path left it out as being inside a
    good binary frame, and must find that B2 was not accepted."""
    ascii_log = _bestpos(3, binary=False)
    q = 40  # B2 starts at this offset of B1
    b1_body_len = 60
    b1_len = 28 + b1_body_len + 4
    b2_body_len = (b1_len - q - 28) + 16 + len(ascii_log) + 8
    # B2's header inside B1's body; B1's CRC, 16 filler bytes and the ASCII log inside B2's body
    b2_head = b"\xaa\x44\x12" + struct.pack("<BHBBHHBBHIIHH", 28, 43, 0, 0x20, b2_body_len, 0, 0, 180, 2300, 0, 0, 0, 0)
    b1_head = b"\xaa\x44\x12" + struct.pack("<BHBBHHBBHIIHH", 28, 43, 0, 0x20, b1_body_len, 0, 0, 180, 2300, 0, 0, 0, 0)
    b1_wo_crc = b1_head + bytes(q - 28) + b2_head + bytes(b1_body_len - (q - 28) - 28)
    assert len(b1_wo_crc) == b1_len - 4
    b1 = b1_wo_crc + struct.pack("<I", novatel_crc32(b1_wo_crc))
    b2_wo_crc = b1[q:] + bytes(16) + ascii_log + bytes(8)
    assert len(b2_wo_crc) == 28 + b2_body_len
    data = b1 + bytes(16) + ascii_log + bytes(8) + struct.pack("<I", novatel_crc32(b2_wo_crc))
    assert data[q : q + len(b2_wo_crc) + 4] == b2_wo_crc + struct.pack("<I", novatel_crc32(b2_wo_crc))
    import drivers.novatel.columns as columns

    skips: list[bool] = []
    original = columns._locate

    def recording(*args: Any, skip_inside_binary: bool) -> Any:
        skips.append(skip_inside_binary)
        return original(*args, skip_inside_binary=skip_inside_binary)

    monkeypatch.setattr(columns, "_locate", recording)
    batch = assert_matches_reference(data)
    assert skips == [True, False]  # the fast scan, then the full one
    pos = batch.log("BESTPOS")
    assert len(pos) == 1 and pos.binary.tolist() == [False] and int(pos.offset[0]) == b1_len + 16
    assert batch.other == {"RANGE": 1}  # B1 (RANGE, no typed layout); B2 was never taken


# --- against NovAtel EDIE ---------------------------------------------------------------------------------


def test_rangecmp_columns_equal_edies_decompressed_range() -> None:
    ne = pytest.importorskip("novatel_edie")
    oem = pytest.importorskip("novatel_edie.oem")
    from sim_devices.gnss.antenna import AntennaState
    from sim_devices.gnss.constellation import Constellation
    from sim_devices.gnss.observations import ObservationGenerator
    from sim_devices.gnss.rawlogs import rangecmp_binary

    gen = ObservationGenerator(Constellation(), seed=5)
    ant = AntennaState(48.1, 11.5, 520.0, 10.0, 3.0, 0.0)
    epochs = [gen.epoch(ant, 2300 * 604_800 * 10**9 + (345_600 + 30 * i) * 10**9) for i in range(6)]
    head = _header("RANGECMP", 140)
    data = b"".join(encode_binary(replace(head, seconds=345600.0 + 30 * i), RawBody(rangecmp_binary(o),
                                  BodyFormat.BINARY)) for i, o in enumerate(epochs))
    data += rangecmp_frame([record(status=1 << 16 | 5 << 21 | 0x1C04, doppler=-(1 << 27), psr=(1 << 36) - 1,
                                   adr=-(1 << 31), prn=50, fcn=13, cn0=31, lock=(1 << 21) - 1, psr_std=15)])
    parser = oem.Parser()
    parser.decompress_range_cmp = True
    parser.write(data)
    edie = []
    while True:
        try:
            edie.append(parser.read().to_dict())
        except ne.BufferEmptyException:
            break
    rc = decode_columns(data).log("RANGECMP")
    assert len(rc) == len(edie) == 7
    assert rc.record_start is not None
    pairs = {"sv_prn": "prn", "sv_freq": "glonass_fcn", "psr": "pseudorange_m", "adr": "adr_cycles",
             "c_status": "tracking_status"}
    single = {"sd_psr": "psr_std_m", "sd_adr": "adr_std_cycles", "dop": "doppler_hz", "C_No": "cn0_dbhz",
              "lock_time": "lock_time_s"}  # single precision in EDIE's RANGE
    for i, msg in enumerate(edie):
        obs = msg["obs"]
        first = int(rc.record_start[i])
        assert len(obs) == int(rc.record_start[i + 1]) - first
        for j, ob in enumerate(obs):
            for theirs, ours in pairs.items():
                assert rc.records[ours][first + j] == ob[theirs], (i, j, theirs)
            for theirs, ours in single.items():
                assert float(np.float32(rc.records[ours][first + j])) == ob[theirs], (i, j, theirs)


def test_bestpos_binary_header_and_body_unchanged_beside_rangecmp() -> None:
    """The typed logs keep their bulk path and values with RANGECMP frames between them."""
    data = b"".join(_bestpos(i) + rangecmp_frame([gps_l1(1 + i % 30, 2e7 + i, -1e8 - i)], seconds=345600.0 + i)
                    for i in range(30))
    batch = assert_matches_reference(data)
    assert batch.log("BESTPOS").body["lat_deg"].tolist() == [sample_bestpos(i).lat_deg for i in range(30)]
