"""GNSS tables decoded again from the raw port bytes agree with the decoded topics, row by row.

Two levels: the record mapping (:func:`rig.data.session.gnss_record_columns`) against the
recorder's own record builders (:mod:`rig.record.gnss`) on every log kind in ASCII and binary,
read back through the same JSON → column path as the decoded topics; and a short simulated session
recorded by the real ``rig record`` path (rover_b switched to ASCII logs), where
``Session.gnss(receiver, source="raw")`` must give the tables of ``Session.gnss(receiver)``: same
columns, dtypes, values, times and host receive times.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields, replace
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.novatel import (
    BestVel,
    ClockModelStatus,
    Framer,
    Heading,
    Heading2,
    MarkPos,
    MarkTime,
    PositionType,
    SolutionStatus,
    Time,
    TimeStatus,
    UTCStatus,
    encode_ascii,
    encode_binary,
    make_header,
)
from drivers.novatel.columns import decode_columns
from rig.core.config import load_session as load_config
from rig.data import Session, Table, load_session
from rig.data.session import _columns, gnss_record_columns
from rig.record.gnss import _heading, _marktime, _position, _time, _velocity
from rig.sim.record import record_simulated
from rig.workflows.demo import demo_config_path
from sim_devices.vehicle.scenarios import make_scenario
from tests.novatel.gen import sample_bestpos
from vsccore.errors import AnalysisError, ConfigError


def assert_same_columns(want: dict[str, npt.NDArray[Any]], got: dict[str, npt.NDArray[Any]], what: str) -> None:
    assert list(got) == list(want), (what, list(got), list(want))
    for name, w in want.items():
        g = got[name]
        assert g.dtype == w.dtype, (what, name, g.dtype, w.dtype)
        if w.dtype.kind == "f":
            assert np.array_equal(g, w, equal_nan=True), (what, name)
        else:
            assert np.array_equal(g, w), (what, name, g[:3], w[:3])


# --- the mapping, against the recorder's record builders --------------------------------------------


def _stream() -> bytes:
    parts = []
    for i in range(12):
        enc = encode_binary if i % 2 else encode_ascii
        t = 1000.0 + i * 0.05
        pos = sample_bestpos(i)
        if i == 3:
            pos = replace(pos, undulation_m=math.nan)
        status = TimeStatus.FINESTEERING if i % 3 else TimeStatus.COARSE
        parts.append(enc(make_header(pos, week=2300, seconds=t, time_status=status), pos))
        vel = BestVel(SolutionStatus.SOL_COMPUTED if i % 4 else SolutionStatus.INSUFFICIENT_OBS,
                      PositionType.DOPPLER_VELOCITY, 0.02, 1.0, 20.0 + i, 45.0 + i, -0.1, 0.0)
        parts.append(enc(make_header(vel, week=2300, seconds=t, time_status=status), vel))
        cls = Heading if i % 2 else Heading2
        extra = ("R222", "AAAA") if cls is Heading2 else ("0",)
        hd = cls(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 1.2, 10.0 + i, -1.0, 0.0, 0.2, 0.3,  # type: ignore[call-arg]
                 *extra, 18, 17, 17, 16, 0, 1, 0, 0x33)
        parts.append(enc(make_header(hd, week=2300, seconds=t, time_status=status), hd))
        if i % 4 == 0:
            mp = MarkPos(**{f.name: getattr(pos, f.name) for f in fields(pos)})
            parts.append(enc(make_header(mp, week=2300, seconds=t, time_status=status), mp))
            mt = MarkTime(2300, t - 0.0123, 1e-9, 2e-9, -18.0, ClockModelStatus.VALID)
            parts.append(enc(make_header(mt, week=2300, seconds=t, time_status=status), mt))
            tm = Time(ClockModelStatus.VALID, 1e-9, 2e-9, -18.0, 2024, 2, 29, 23, 59, 59_999, UTCStatus.VALID)
            parts.append(enc(make_header(tm, week=2300, seconds=t, time_status=status), tm))
    return b"\r\n".join(parts)


def _records_from_framer(data: bytes) -> dict[str, list[dict[str, Any]]]:
    """What the recorder writes to each decoded topic (rig.record.gnss.GnssDevice._on_data)."""
    out: dict[str, list[dict[str, Any]]] = {k: [] for k in ("bestpos", "bestvel", "heading", "markpos", "marktime",
                                                            "time")}
    for fr in Framer().feed(data):
        lg = fr.log
        assert lg is not None
        b = lg.body
        if lg.name == "BESTPOS":
            out["bestpos"].append(_position(lg.header, b))  # type: ignore[arg-type]
        elif lg.name == "MARKPOS":
            out["markpos"].append(_position(lg.header, b))  # type: ignore[arg-type]
        elif lg.name == "BESTVEL":
            out["bestvel"].append(_velocity(lg.header, b))  # type: ignore[arg-type]
        elif lg.name == "MARKTIME":
            out["marktime"].append(_marktime(b))  # type: ignore[arg-type]
        elif lg.name == "TIME":
            out["time"].append(_time(lg.header, b))  # type: ignore[arg-type]
        else:
            out["heading"].append(_heading(lg.header, b))  # type: ignore[arg-type]
    return out


def test_record_columns_equal_the_recorders_records_read_back_from_json() -> None:
    data = _stream()
    got = gnss_record_columns(decode_columns(data))
    topics = {"bestpos": T.gnss_bestpos("r"), "bestvel": T.gnss_bestvel("r"), "heading": T.gnss_heading("r"),
              "markpos": T.gnss_markpos("r"), "marktime": T.gnss_marktime("r"), "time": T.gnss_time("r")}
    for kind, records in _records_from_framer(data).items():
        assert records, kind
        rows = [json.loads(T.encode_json(r)) for r in records]  # as the recorder stores them, and reads them
        assert_same_columns(_columns(rows, topics[kind]), got[kind].columns, kind)
        assert np.array_equal(got[kind].gps_ns, got[kind].columns["gps_time_ns"])
    assert got["heading"].columns["heading_deg"].tolist() == [10.0 + i for i in range(12)]
    assert np.isnan(got["bestpos"].columns["undulation_m"][3])


# --- a recorded session --------------------------------------------------------------------------------

ASCII_LOGS = [{"name": "BESTPOSA", "period_s": 0.05}, {"name": "BESTVELA", "period_s": 0.05},
              {"name": "TIMEA", "period_s": 1.0}]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Session:
    out = tmp_path_factory.mktemp("rawgnss")
    cfg = load_config(demo_config_path(), {"simulation.speed": 2.0, "receivers.2.logs": ASCII_LOGS})
    rec = record_simulated(cfg, out, name="rec", drive=make_scenario("straight", speed_kmh=40.0, duration_s=3.0),
                           lead_s=2.0)
    assert rec.completed and rec.summary.recording.error is None
    return load_session(out / "rec")


def _assert_tables_equal(want: Table, got: Table, what: str) -> None:
    assert len(got) == len(want), (what, len(got), len(want))
    assert got.topic == want.topic
    assert_same_columns(dict(want.columns), dict(got.columns), what)
    assert np.array_equal(got.time_ns, want.time_ns), what
    assert np.array_equal(got.host_ns, want.host_ns), what
    assert np.array_equal(got.valid, want.valid), what


@pytest.mark.parametrize("receiver", ["rover_a", "rover_b"])
def test_raw_decode_gives_the_decoded_topics_row_by_row(recorded: Session, receiver: str) -> None:
    ds = recorded
    decoded = ds.gnss(receiver)
    raw = ds.gnss(receiver, source="raw")
    for kind in ("bestpos", "bestvel", "heading", "markpos", "marktime", "time"):
        _assert_tables_equal(getattr(decoded, kind), getattr(raw, kind), f"{receiver} {kind}")
    # a real comparison: logs at 20 Hz for the whole recording, and the ASCII receiver really is ASCII
    assert len(raw.bestpos) > 60 and len(raw.bestvel) > 60 and len(raw.time) >= 2
    assert np.all(np.diff(raw.bestpos.time_ns) > 0)
    assert ds.gnss(receiver, source="raw") is raw  # cached


def test_the_receivers_really_sent_binary_and_ascii(recorded: Session) -> None:
    chunks = {r: b"".join(recorded._raw_chunks(r)[1]) for r in ("rover_a", "rover_b")}
    a = decode_columns(chunks["rover_a"]).log("BESTPOS")
    b = decode_columns(chunks["rover_b"]).log("BESTPOS")
    assert a.binary.all() and len(a) > 60
    assert not b.binary.any() and len(b) > 60


def test_source_argument_errors(recorded: Session) -> None:
    with pytest.raises(ConfigError, match="neither"):
        recorded.gnss("rover_a", source="json")
    with pytest.raises(AnalysisError, match="no raw GNSS stream"):
        recorded.gnss("nobody", source="raw")
    assert set(recorded.raw_gnss_receivers()) >= {"base", "rover_a", "rover_b"}


def test_raw_path_without_the_decoded_topics(recorded: Session) -> None:
    # a reader that loaded nothing but the raw stream still decodes it (leap seconds from the raw TIME logs)
    only_raw = load_session(recorded.path, topics=[T.gnss_raw("rover_b")])
    assert only_raw.leap_seconds is None and len(only_raw.gnss("rover_b").bestpos) == 0
    raw = only_raw.gnss("rover_b", source="raw")
    want = recorded.gnss("rover_b")
    _assert_tables_equal(want.bestpos, raw.bestpos, "rover_b bestpos, raw only")


def test_ascii_log_transmission_times_use_the_same_frame_lengths(recorded: Session) -> None:
    # the latency model measures each ASCII log's frame in the raw stream (Session._raw_frame_lengths);
    # the columnar decoder's frame lengths of the same logs must give the same figures
    g = recorded.gnss("rover_b").bestpos["gps_time_ns"]
    latency = recorded.gnss_log_latency_ns("rover_b", "BESTPOS", g)
    cols = decode_columns(b"".join(recorded._raw_chunks("rover_b")[1])).log("BESTPOS")
    length_by_time = dict(zip(cols.header["gps_ns"].tolist(), cols.length.tolist(), strict=True))
    lengths = np.asarray([length_by_time[t] for t in g.tolist()], dtype=np.float64)
    assert lengths.min() > 150  # ASCII lines, not the 104-byte binary log
    baud = recorded.config["receivers"][2]["baud"]
    want = recorded.gnss_output_latency_ns("rover_b") + np.round(lengths * (10e9 / baud)).astype(np.int64)
    assert np.array_equal(latency, want)


def test_the_gnss_field_table_fills_each_topic_schema() -> None:
    # The recorder and the raw path both build records from T.GNSS_RECORD_FIELDS: every key it gives
    # (plus the per-kind extras) is a property of the topic's JSON schema, and every required one is given.
    extras = {"marktime": {"event_input"}, "time": {"utc_iso"}}
    schemas = {"position": [T.SCHEMA_BESTPOS, T.SCHEMA_MARKPOS], "velocity": [T.SCHEMA_BESTVEL],
               "heading": [T.SCHEMA_HEADING], "marktime": [T.SCHEMA_MARKTIME], "time": [T.SCHEMA_TIME]}
    assert set(schemas) == set(T.GNSS_RECORD_FIELDS)
    for kind, specs in schemas.items():
        keys = [f.json_key for f in T.GNSS_RECORD_FIELDS[kind]]  # gps_time ({week, tow_ns}) for gps_time_ns
        assert len(keys) == len(set(keys)), kind
        given = set(keys) | extras.get(kind, set())
        for spec in specs:
            doc = spec.document
            assert given <= set(doc["properties"]), (kind, sorted(given - set(doc["properties"])))
            assert set(doc.get("required", ())) <= given, (kind, sorted(set(doc["required"]) - given))
