"""The columnar NovAtel decoder against the per-message Framer: every field of every row, and the counts.

Ground truth is the per-message decode (``drivers.novatel.Framer``, itself tested against public
vectors and an independent CRC): on the public vectors, on hypothesis-generated mixed ASCII + binary
streams over the full wire range of every field (enum values outside the tables, extreme floats
printed with hundreds of digits, quoted station IDs with commas, measurement-source suffixes), and
on damaged streams (flipped bits, cuts, garbage), whose rejected frames must be counted as the
Framer counts its CRC failures, truncations and decode errors. Values are compared exactly (floats
bit for bit); the tolerance is zero.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.novatel import (
    BestPos,
    BestVel,
    ClockModelStatus,
    Frame,
    FrameKind,
    Framer,
    Heading,
    Heading2,
    Log,
    MarkTime,
    PositionType,
    PsrDop,
    SolutionStatus,
    Time,
    TimeStatus,
    UTCStatus,
    encode_ascii,
    encode_binary,
    make_header,
    make_short_header,
)
from drivers.novatel.columns import (
    HEADER_COLUMNS,
    MISSING_INT,
    SHORT_HEADER_LOGS,
    ColumnBatch,
    LogColumns,
    RejectReason,
    decode_columns,
    empty_columns,
)
from drivers.novatel.crc import novatel_crc32
from drivers.novatel.layouts import CODECS_BY_NAME, Kind
from tests.novatel.gen import GARBAGE, TYPED, body_strategy, damage, long_header_strategy, nmea_gga, sample_bestpos
from vsccore.errors import ConfigError, EncodeError
from vsccore.gpstime import gps_to_ns

LONG_KINDS = (FrameKind.NOVATEL_ASCII, FrameKind.NOVATEL_BINARY)
NOVATEL_KINDS = (*LONG_KINDS, FrameKind.NOVATEL_SHORT_ASCII, FrameKind.NOVATEL_SHORT_BINARY)

# --- the reference: the per-message Framer ------------------------------------------------------


def _int64_or_missing(compute: Any) -> int:
    try:
        v = int(compute())
    except (ValueError, OverflowError):
        return MISSING_INT
    return v if -(2**63) < v < 2**63 else MISSING_INT


def _plain(v: Any) -> Any:
    return int(v) if hasattr(v, "value") and isinstance(v, int) else v


def expected_row(frame: Frame) -> dict[str, Any]:
    """The columns' values of one frame, from the per-message decode."""
    lg = frame.log
    assert lg is not None
    h = lg.header
    row = {f"h.{name}": _plain(getattr(h, name)) for name in HEADER_COLUMNS[:-1]}
    row["h.gps_ns"] = _int64_or_missing(lambda: h.gps_ns)
    for f in fields(lg.body):
        value = getattr(lg.body, f.name)
        row[f"b.{f.name}"] = tuple(value) if f.name == "prns" else _plain(value)
    if lg.name in ("MARKTIME", "MARK1TIME", "MARK2TIME"):
        row["b.event_gps_ns"] = _int64_or_missing(lambda: gps_to_ns(lg.body.week, lg.body.seconds))  # type: ignore[union-attr]
    if lg.name == "TIME":
        row["b.leap_seconds"] = _int64_or_missing(lambda: lg.body.leap_seconds)  # type: ignore[union-attr]
    row["binary"] = frame.kind is FrameKind.NOVATEL_BINARY
    row["raw"] = frame.raw
    return row


def actual_row(cols: LogColumns, i: int, data: bytes) -> dict[str, Any]:
    row: dict[str, Any] = {}
    for name, col in cols.header.items():
        row[f"h.{name}"] = col[i].item() if isinstance(col[i], np.generic) else col[i]
    for name, col in cols.body.items():
        row[f"b.{name}"] = col[i].item() if isinstance(col[i], np.generic) else col[i]
    row["binary"] = bool(cols.binary[i])
    row["raw"] = data[int(cols.offset[i]) : int(cols.offset[i] + cols.length[i])]
    return row


def same(a: Any, b: Any) -> bool:
    """Equal, floats bit for bit (NaN equal to NaN)."""
    if isinstance(a, float) or isinstance(b, float):
        if not (isinstance(a, float) and isinstance(b, float)):
            return False
        return (math.isnan(a) and math.isnan(b)) or struct.pack("<d", a) == struct.pack("<d", b)
    return bool(a == b) and type(a) is type(b)


def framer_decode(data: bytes) -> tuple[dict[str, list[Frame]], Framer]:
    framer = Framer()
    frames = framer.feed(data) + framer.finish()
    out: dict[str, list[Frame]] = {}
    for fr in frames:
        lg = fr.log
        if fr.kind in LONG_KINDS and lg is not None and fr.error is None and type(lg.body).__name__ != "RawBody":
            out.setdefault(lg.name, []).append(fr)
    return out, framer


def assert_matches_framer(data: bytes, batch: ColumnBatch | None = None) -> ColumnBatch:
    """Every row of every log equals the Framer's decode; the rejections are counted as it counts them."""
    batch = decode_columns(data) if batch is None else batch
    want, framer = framer_decode(data)
    assert sorted(batch.logs) == sorted(want), (sorted(batch.logs), sorted(want))
    for name, frames in want.items():
        cols = batch.logs[name]
        assert len(cols) == len(frames), (name, len(cols), len(frames))
        for i, fr in enumerate(frames):
            exp, got = expected_row(fr), actual_row(cols, i, data)
            assert exp.keys() == got.keys(), (name, sorted(exp.keys() ^ got.keys()))
            diff = {k: (exp[k], got[k]) for k in exp if not same(exp[k], got[k])}
            assert not diff, f"{name} row {i}: {diff}"
    st_ = framer.stats
    assert batch.rejected[RejectReason.CRC_FAILURE] == sum(st_.crc_failures[k] for k in NOVATEL_KINDS)
    assert batch.rejected[RejectReason.TRUNCATED] == st_.truncated
    assert batch.rejected[RejectReason.OVERSIZE] == sum(st_.oversize[k] for k in NOVATEL_KINDS)
    assert batch.rejected[RejectReason.MALFORMED] == sum(st_.decode_errors[k] for k in LONG_KINDS)
    short = st_.frames[FrameKind.NOVATEL_SHORT_ASCII] + st_.frames[FrameKind.NOVATEL_SHORT_BINARY]
    assert batch.other.get(SHORT_HEADER_LOGS, 0) == short
    return batch


# --- public vectors -------------------------------------------------------------------------------


def _vector_stream(shared_dir: Path) -> bytes:
    folder = shared_dir / "vectors" / "novatel"
    if not folder.is_dir():
        pytest.skip(f"no NovAtel vectors at {folder}")
    parts: list[bytes] = []
    for line in (folder / "ascii_logs.txt").read_text().splitlines():
        if line.startswith("#") and line[1:2].isupper():
            parts.append(line.encode("latin-1") + b"\r\n")
    hex_lines = [ln for ln in (folder / "bestpos_binary.hex").read_text().splitlines() if not ln.startswith("#")]
    parts.append(bytes.fromhex("".join(hex_lines)))
    parts.append((folder / "abbreviated_ascii.txt").read_bytes())  # not decoded into columns; must not disturb
    return b"".join(parts)


def test_public_vectors_decode_as_the_framer_decodes_them(shared_dir: Path) -> None:
    data = _vector_stream(shared_dir)
    batch = assert_matches_framer(data)
    assert {name: len(c) for name, c in batch.logs.items()} == {"BESTPOS": 4, "BESTVEL": 2, "HEADING2": 1, "TIME": 2}
    pos = batch.log("BESTPOS")
    binary = np.flatnonzero(pos.binary)
    assert binary.size == 1
    # the published values of the binary vector (its header comment)
    i = int(binary[0])
    assert pos.header["week"][i] == 2163 and pos.header["seconds"][i] == 329807.0
    assert pos.body["lat_deg"][i] == 51.150436744872394 and pos.body["lon_deg"][i] == -114.03067267518318
    assert pos.body["pos_type"][i] == 16 and pos.body["sol_status"][i] == 0
    t = batch.log("TIME")
    assert t.body["leap_seconds"].tolist() == [16, 18]
    assert not any(batch.rejected.values())


def test_vectors_mixed_several_times_with_garbage_and_a_cut_tail(shared_dir: Path) -> None:
    data = _vector_stream(shared_dir)
    mixed = b"\x00junk#,*" + data + b"\xaa\x44\x12garbage" + data + data[: len(data) // 2]
    assert_matches_framer(mixed)


# --- hypothesis: mixed ASCII + binary streams -------------------------------------------------------

NEAR_FRAMES = st.sampled_from(
    [b"#", b"#B", b"#BESTPOSA,", b"*", b"*12345678", b"\r\n", b"%", b"\xaa\x44\x12", b",", b";"]
)


@st.composite
def log_frames(draw: st.DrawFn) -> bytes:
    cls = draw(st.sampled_from(TYPED))
    binary = draw(st.booleans())
    header = draw(long_header_strategy(cls, binary=binary))
    body = draw(body_strategy(cls))
    try:
        if binary:
            return encode_binary(header, body)
        return encode_ascii(header, body)
    except EncodeError:
        return b""


STREAM = st.lists(st.one_of(log_frames(), log_frames(), log_frames(), GARBAGE, NEAR_FRAMES), max_size=10).map(b"".join)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(STREAM)
def test_random_mixed_streams_match_the_framer(data: bytes) -> None:
    assert_matches_framer(data)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(log_frames(), min_size=1, max_size=6).map(b"".join), st.data())
def test_damaged_streams_count_rejections_as_the_framer_does(clean: bytes, data: st.DataObject) -> None:
    assert_matches_framer(damage(clean, data))


def receiver_like_body(cls: type[Any]) -> st.SearchStrategy[Any]:
    """Bodies with the magnitudes a receiver prints (the full-range strategy makes most floats hundreds
    of digits long in ASCII, which only the per-message path takes); enums mostly known, some not."""
    codec = CODECS_BY_NAME[cls.MESSAGE_NAME]
    kwargs: dict[str, st.SearchStrategy[Any]] = {}
    for spec in codec.specs:
        if spec.kind is Kind.FLOAT:
            # short decimals, as receivers print them (repr-printed fields stay short too); some full doubles
            kwargs[spec.name] = st.one_of(st.integers(-40_000_000, 40_000_000).map(lambda k: k / 1e5),
                                          st.sampled_from([0.0, -0.0, 1.5, -17.0]), st.floats(-400.0, 400.0))
        elif spec.kind is Kind.ENUM:
            assert spec.enum is not None
            kwargs[spec.name] = st.sampled_from([*spec.enum, spec.enum(299)])  # 299: printed as a number
        elif spec.kind is Kind.STR:
            kwargs[spec.name] = st.text("AB0123 ", max_size=4)
        else:
            kwargs[spec.name] = st.integers(0, 255 if spec.code == "B" else 70000)
    return st.builds(cls, **kwargs)


@st.composite
def mostly_constant_runs(draw: st.DrawFn) -> bytes:
    """A run of one log, ASCII, where each field keeps one value except in a few random rows: the
    decoder settles a column that is the same in every row from its first row, so a change in any
    single row (not only the rows it samples) must be seen."""
    cls = draw(st.sampled_from((BestPos, BestVel, Heading, Heading2, Time)))
    n = draw(st.integers(8, 24))
    base = draw(receiver_like_body(cls))
    head = draw(long_header_strategy(cls, binary=False))
    names = [f.name for f in fields(cls)]
    out = []
    for i in range(n):
        changes: dict[str, Any] = {}
        if draw(st.integers(0, 3)) == 0:  # this row differs in a few fields
            other = draw(receiver_like_body(cls))
            for name in draw(st.lists(st.sampled_from(names), min_size=1, max_size=3)):
                changes[name] = getattr(other, name)
        body = replace(base, **changes)
        header = replace(head, seconds=head.seconds if draw(st.integers(0, 4)) else float(i))
        try:
            out.append(encode_ascii(header, body))
        except EncodeError:
            continue
    return b"".join(out)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(mostly_constant_runs())
def test_runs_of_mostly_constant_columns_match_the_framer(data: bytes) -> None:
    assert_matches_framer(data)


# --- many rows: the vectorised path itself (not the per-message fallback) -------------------------


def _series(n: int, binary: bool, **changes: Any) -> bytes:
    encode = encode_binary if binary else encode_ascii
    out = []
    for i in range(n):
        body = replace(sample_bestpos(i), lat_deg=-33.0 - i * 1.3e-9, hgt_m=(-1) ** i * (i % 97) * 0.0137,
                       diff_age_s=float(i % 7), num_svs=i % 40, ext_sol_stat=i % 256, **changes)
        header = make_header(body, week=2300, seconds=345600.0 + i * 0.05, sequence=i % 3,
                             receiver_status=0x02000000 + i, idle_time_pct=50.0 + i % 3)
        out.append(encode(header, body))
        if i % 5 == 0:
            vel = BestVel(body.sol_status, body.pos_type, 0.02, 1.5, 20.0 + i * 0.001, (i * 7.3) % 360, -0.01, 0.0)
            out.append(encode(make_header(vel, week=2300, seconds=345600.0 + i * 0.05), vel))
    return b"".join(out)


@pytest.mark.parametrize("binary", [False, True])
def test_a_long_series_takes_the_vectorised_path_and_matches(binary: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.novatel.columns as columns

    per_message: list[tuple[Any, ...]] = []

    def counting(original: Any) -> Any:
        def call(*args: Any) -> Any:
            per_message.append(args)
            return original(*args)

        return call

    for name in ("decode_ascii_text", "decode_verified"):
        monkeypatch.setattr(columns, name, counting(getattr(columns, name)))
    data = _series(600, binary)
    batch = assert_matches_framer(data)
    assert not per_message  # clean logs: not one went through the per-message decoder
    decode_columns(_ascii_line(EDGE_LINES["quoted comma"]))
    assert len(per_message) == 1  # (the spy does see the per-message path when it is taken)
    assert len(batch.log("BESTPOS")) == 600 and len(batch.log("BESTVEL")) == 120
    mixed = _series(300, binary) + _series(300, not binary)
    assert_matches_framer(mixed)


def test_long_runs_are_parsed_in_chunks_with_the_same_result(monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.novatel.columns as columns

    data = _series(90, False) + _ascii_line(EDGE_LINES["quoted comma"]) + _series(40, False)
    whole = decode_columns(data)
    monkeypatch.setattr(columns, "_ASCII_CHUNK", 16)
    chunked = assert_matches_framer(data)
    for name in ("BESTPOS", "BESTVEL"):
        a, b = whole.log(name), chunked.log(name)
        assert np.array_equal(a.offset, b.offset)
        for col in a.body:
            assert np.array_equal(a.body[col], b.body[col]), (name, col)


def test_column_dtypes() -> None:
    batch = decode_columns(_series(20, False) + _series(20, True))
    pos = batch.log("BESTPOS")
    assert pos.body["lat_deg"].dtype == np.float64 and pos.body["undulation_m"].dtype == np.float64
    assert pos.body["sol_status"].dtype == np.int64 and pos.body["num_svs"].dtype == np.int64
    assert pos.body["stn_id"].dtype.kind == "U" and pos.header["port"].dtype.kind == "U"
    assert pos.header["gps_ns"].dtype == np.int64 and pos.offset.dtype == np.int64
    empty = empty_columns("BESTPOS")
    assert list(empty.header) == list(pos.header) and list(empty.body) == list(pos.body)
    for part in ("header", "body"):
        for name, col in getattr(empty, part).items():
            assert col.dtype.kind == getattr(pos, part)[name].dtype.kind, name
    assert batch.log("HEADING").body["heading_deg"].shape == (0,)


# --- edge cases, each against the Framer ---------------------------------------------------------


def _ascii_line(text: str) -> bytes:
    inner = text.encode("latin-1")
    return b"#" + inner + f"*{novatel_crc32(inner):08x}\r\n".encode()


EDGE_LINES = {
    "quoted comma": 'BESTPOSA,COM1,0,60.5,FINESTEERING,2166,327153.000,02000000,b1f6,16248;SOL_COMPUTED,WAAS,'
    '51.15043699323,-114.03067932462,1096.9772,-17.0000,WGS84,0.6074,0.5792,0.9564,"1,3",7.000,0.000,42,34,34,28,'
    "00,0b,1f,37",
    "numbers for enums": "BESTPOSA,COM1,0,60.5,180,2166,327153.000,02000000,b1f6,16248;0,50,"
    "51.15043699323,-114.03067932462,1096.9772,-17.0000,61,0.6074,0.5792,0.9564,131,7.000,0.000,42,34,34,28,"
    "00,0b,1f,37",
    "extra field": "BESTVELA,COM1,0,92.5,FINESTEERING,1775,325508.000,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323,-0.0270,0.0,99",
    "source suffix": "HEADINGA_1,COM1,0,39.5,FINESTEERING,1622,422892.200,02040000,f9bf,6521;SOL_COMPUTED,"
    "NARROW_INT,0.927607417,178.347869873,-1.3037414550,0,0.261901051,0.391376048,\"R222\",18,17,17,16,0,01,0,33",
    "exponents": "TIMEA,COM1,0,48.5,FINESTEERING,1702,47.848,00000000,ddae,7053;VALID,-3.432839221e-09,"
    "6.603391298e-08,-16.00000000000,2013,11,6,15,40,51000,VALID",
    "too few fields": "BESTVELA,COM1,0,92.5,FINESTEERING,1775,325508.000,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323",
    "not a number": "BESTVELA,COM1,0,92.5,FINESTEERING,1775,325508.000,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,x.000,0.0154,286.538323,-0.0270,0.0",
    "header fields": "BESTVELA,COM1,0,92.5,FINESTEERING,1775,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323,-0.0270,0.0",
    "no semicolon": "BESTVELA,COM1,0,92.5,FINESTEERING,1775,325508.000,00000000,0141,10985,SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323,-0.0270,0.0",
    "odd numbers": "BESTVELA,COM1,+0,92.5,FINESTEERING,1775,325508.,0x0,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,.150, 0.000,1e-3,nan,-inf,1_0.0",
    "negative week": "BESTVELA,COM1,0,92.5,FINESTEERING,-1,325508.000,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323,-0.0270,0.0",
    "huge seconds": "BESTVELA,COM1,0,92.5,FINESTEERING,15249,999999999999.999,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323,-0.0270,0.0",
    "psrdop": "PSRDOPA,COM1,0,60.5,FINESTEERING,2166,327153.000,02000000,b1f6,16248;1.6,1.2,0.8,1.0,0.9,5.0,3,"
    "2,5,7",
    "raw log": "RANGEA,COM1,0,60.5,FINESTEERING,2166,327153.000,02000000,b1f6,16248;0",
    "no A": "BESTVEL,COM1,0,92.5,FINESTEERING,1775,325508.000,00000000,0141,10985;SOL_COMPUTED,"
    "DOPPLER_VELOCITY,0.150,0.000,0.0154,286.538323,-0.0270,0.0",
}


@pytest.mark.parametrize("case", sorted(EDGE_LINES))
def test_ascii_edge_cases_match_the_framer(case: str) -> None:
    line = _ascii_line(EDGE_LINES[case])
    # alone, and inside a run of ordinary logs so that the vectorised path sees it next to good rows
    assert_matches_framer(line)
    assert_matches_framer(_series(8, False) + line + _series(8, False))


def test_an_ascii_integer_beyond_int64_is_the_one_documented_difference() -> None:
    line = _ascii_line(
        "BESTPOSA,COM1,0,60.5,FINESTEERING,2166,327153.000,02000000,b1f6,16248;SOL_COMPUTED,WAAS,51.15043699323,"
        "-114.03067932462,1096.9772,-17.0000,WGS84,0.6074,0.5792,0.9564,131,7.000,0.000,99999999999999999999,34,"
        "34,28,00,0b,1f,37"
    )
    (frame,) = Framer().feed(line)
    assert frame.log is not None and frame.log.body.num_svs == 99999999999999999999  # type: ignore[union-attr]
    batch = decode_columns(_series(3, False) + line)
    assert len(batch.log("BESTPOS")) == 3 and batch.rejected[RejectReason.MALFORMED] == 1


def test_binary_edge_cases_match_the_framer() -> None:
    body = sample_bestpos()
    header = make_header(body, week=2300, seconds=345600.0)
    good = encode_binary(header, body)
    # a response (bit 7 of the message type): kept raw by the per-message path, counted as other here
    resp = bytearray(good[:-4])
    resp[6] |= 0x80
    resp_frame = bytes(resp) + struct.pack("<I", novatel_crc32(bytes(resp)))
    # a longer header (header length 32): the per-message path reads the body after it
    long_hdr = bytearray(good[:28] + b"\x00" * 4 + good[28:-4])
    long_hdr[3] = 32
    long_frame = bytes(long_hdr) + struct.pack("<I", novatel_crc32(bytes(long_hdr)))
    # a body shorter than the layout: a decode error (malformed)
    short = bytearray(good[:28] + good[28:60])
    short[8:10] = struct.pack("<H", 32)
    short_frame = bytes(short) + struct.pack("<I", novatel_crc32(bytes(short)))
    unknown = bytearray(good[:-4])
    unknown[4:6] = struct.pack("<H", 43)  # RANGE: no typed layout
    unknown_frame = bytes(unknown) + struct.pack("<I", novatel_crc32(bytes(unknown)))
    short_header = encode_binary(make_short_header(body, week=2300, seconds=1.0), body)
    short_ascii = encode_ascii(make_short_header(body, week=2300, seconds=1.0), body)
    psrdop = PsrDop(1.6, 1.2, 0.8, 1.0, 0.9, 5.0, (2, 5, 7))
    psr = encode_binary(make_header(psrdop, week=2300, seconds=2.0), psrdop)
    data = good + resp_frame + long_frame + short_frame + unknown_frame + short_header + short_ascii + psr + good
    batch = assert_matches_framer(data)
    assert len(batch.log("BESTPOS")) == 3
    assert batch.rejected[RejectReason.MALFORMED] == 1
    assert batch.other == {"BESTPOS": 1, "RANGE": 1, SHORT_HEADER_LOGS: 2}
    assert batch.log("PSRDOP").body["prns"].tolist() == [(2, 5, 7)]


def test_logs_argument_limits_the_decoding() -> None:
    data = _series(30, False) + _series(30, True)
    batch = decode_columns(data, logs=["BESTVEL"])
    assert list(batch.logs) == ["BESTVEL"] and len(batch.log("BESTVEL")) == 12
    assert batch.other == {"BESTPOS": 60}
    full = decode_columns(data)
    for name, col in batch.log("BESTVEL").body.items():
        assert np.array_equal(col, full.log("BESTVEL").body[name]), name
    with pytest.raises(ConfigError, match="NOPE"):
        decode_columns(data, logs=["NOPE"])
    with pytest.raises(ConfigError, match="NOPE"):
        batch.log("NOPE")


def test_empty_and_garbage_buffers() -> None:
    assert decode_columns(b"").total_logs == 0
    batch = assert_matches_framer(b"#BESTPOSA,COM1" + bytes(range(256)) * 3 + nmea_gga(1))
    assert batch.total_logs == 0


def _heading(stn_id: str) -> Heading:
    return Heading(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 1.0, 90.0, 0.0, 0.0, 0.1, 0.1, stn_id,
                   20, 18, 18, 16, 0, 0, 0, 0)


def test_times_and_derived_columns() -> None:
    t = Time(ClockModelStatus.VALID, 1e-9, 2e-9, -18.0, 2024, 1, 2, 3, 4, 5000, UTCStatus.VALID)
    mt = MarkTime(2300, 100.25, 0.0, 0.0, -18.0, ClockModelStatus.VALID)
    hd = _heading("0")
    data = b"".join(
        enc(make_header(body, week=2300, seconds=5.5, time_status=TimeStatus.FINESTEERING), body)
        for body in (t, mt, hd) for enc in (encode_ascii, encode_binary)
    )
    batch = assert_matches_framer(data)
    assert batch.log("TIME").body["leap_seconds"].tolist() == [18, 18]
    assert batch.log("MARKTIME").body["event_gps_ns"].tolist() == [gps_to_ns(2300, 100.25)] * 2
    assert batch.log("TIME").header["gps_ns"].tolist() == [gps_to_ns(2300, 5.5)] * 2
    assert batch.log("HEADING").binary.tolist() == [False, True]


def test_rows_keep_buffer_order_and_offsets() -> None:
    a = _series(5, True)
    b = _series(5, False)
    data = a + b + a
    pos = decode_columns(data).log("BESTPOS")
    assert np.all(np.diff(pos.offset) > 0)
    assert pos.binary.tolist() == [True] * 5 + [False] * 5 + [True] * 5
    for o, n in zip(pos.offset.tolist(), pos.length.tolist(), strict=True):
        assert Framer().feed(data[o : o + n])[0].log is not None


def _log_of(frame: Frame) -> Log:
    assert frame.log is not None
    return frame.log


def test_every_typed_layout_has_columns() -> None:
    for name in CODECS_BY_NAME:
        cols = empty_columns(name)
        assert set(cols.body) >= {s.name for s in CODECS_BY_NAME[name].specs}


def _frames(data: bytes) -> Sequence[Frame]:
    return Framer().feed(data)


def test_a_heading_series_with_reserved_printed_as_integer() -> None:
    # real receivers print HEADING's reserved float as "0" (swri-robotics vector): the vectorised path takes it
    lines = b"".join(
        _ascii_line(
            f"HEADINGA,COM1,0,39.5,FINESTEERING,1622,{422892.2 + i * 0.05:.3f},02040000,f9bf,6521;SOL_COMPUTED,"
            f"NARROW_INT,0.927607417,{178.347869873 + i * 1e-6:.9f},-1.3037414550,0,0.261901051,0.391376048,"
            f'"R222",18,17,17,16,0,01,0,33'
        )
        for i in range(50)
    )
    batch = assert_matches_framer(lines)
    assert len(batch.log("HEADING")) == 50
    assert _log_of(_frames(lines)[0]).name == "HEADING"


def test_a_short_quoted_station_id() -> None:
    hd = _heading("ab")
    data = encode_ascii(make_header(hd, week=2300, seconds=1.0), hd)
    assert_matches_framer(data)
    assert decode_columns(data).log("HEADING").body["stn_id"].tolist() == ["ab"]
    assert isinstance(_log_of(_frames(data)[0]).body, Heading)
    assert BestPos.MESSAGE_NAME in CODECS_BY_NAME
