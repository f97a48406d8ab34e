"""Files written before decision record 0005 carry integer-ns times as plain JSON integers (``gps_time_ns``,
``device_time_ns``, ``offset_ns``, ``start_ns``/``end_ns``); newer files carry them as two integers each
(``gps_time: {week, tow_ns}``, ``foxglove.Time``, ``foxglove.Duration``). ``rig.data`` and the exports
read both to the same int64 ns columns."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.dataset as pads
import pytest

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.data import Session, Table, load_session
from rig.export.parquet import export_parquet
from rig.store import Recorder, RecorderOptions, session_metadata
from tests.test_dataset_raw_gnss import assert_same_columns
from vsccore.gpstime import gps_ns_to_unix_ns, gps_to_ns

LEAP = 18
G0 = gps_to_ns(2400, 345_600.0) + 123_456_789  # ns digits a double would lose
N = 40


def _gnss_records() -> dict[str, list[dict[str, Any]]]:
    """Old-form records (plain ``gps_time_ns``) of every decoded GNSS topic."""
    out: dict[str, list[dict[str, Any]]] = {k: [] for k in ("bestpos", "bestvel", "heading", "markpos", "marktime",
                                                            "time")}
    for k in range(N):
        g = G0 + k * 50_000_001
        pos = {"gps_time_ns": g, "time_status": "FINESTEERING", "sol_status": "SOL_COMPUTED", "pos_type": "NARROW_INT",
               "lat_deg": 48.7 + k * 1e-6, "lon_deg": 9.18, "height_msl_m": 300.0, "lat_std_m": 0.01,
               "lon_std_m": 0.01, "height_std_m": 0.02, "num_svs": 20}
        out["bestpos"].append(pos)
        out["bestvel"].append({"gps_time_ns": g, "sol_status": "SOL_COMPUTED", "vel_type": "DOPPLER_VELOCITY",
                               "latency_s": 0.0, "hor_speed_mps": 20.0, "track_over_ground_deg": 90.0,
                               "vert_speed_mps": 0.0})
        out["heading"].append({"gps_time_ns": g, "sol_status": "SOL_COMPUTED", "pos_type": "NARROW_INT",
                               "length_m": 1.2, "heading_deg": 10.0 + k, "pitch_deg": 0.5})
        if k % 10 == 0:
            out["markpos"].append({**pos, "event_input": "MARK1"})
            out["marktime"].append({"gps_time_ns": g - 12_345, "clock_status": "VALID", "event_input": "MARK1"})
            out["time"].append({"gps_time_ns": g, "clock_status": "VALID", "utc_offset_s": -float(LEAP),
                                "leap_seconds": LEAP, "utc_status": "VALID", "utc_iso": "2026-01-07T12:00:00.000Z"})
    return out


def _roles(k: int) -> dict[str, Any]:
    dev = None if k % 7 == 3 else gps_ns_to_unix_ns(G0, LEAP) + k * 10_000_003  # the interface gave none
    return {"can_id": 257, "message": "ESC_SensorCluster", "device_time_ns": dev,
            "roles": {"yaw_rate": 0.01 * k}, "valid": True, "flags": []}


def _timebase(k: int) -> dict[str, Any]:
    return {"clock": f"gnss:rx{k % 2}", "method": "lower_envelope", "reference": "host", "status": "ok", "n": k,
            "span_s": 1.0 * k, "offset_ns": None if k == 0 else 315_964_782_000_093_696 + k, "drift_ppm": 1.5}


def _events() -> list[T.Event]:
    u0 = gps_ns_to_unix_ns(G0, LEAP)
    return [T.Event(T.EventKind.GAP, "can:can0", "gap", T.Severity.WARNING, u0 + 1, u0 + 999_999_999,
                    {"host_ns": u0 + 7, "frames": 3}),
            T.Event(T.EventKind.MARK, "operator", "mark"),
            T.Event(T.EventKind.TIMEBASE, "rig", "step", details={"verdicts": {"gaps": [{"start_ns": u0}]}})]


def _old_event(ev: T.Event) -> dict[str, Any]:
    """An event as files before decision record 0005 wrote it: plain integers, no start/end objects."""
    doc = {"kind": ev.kind.value, "severity": ev.severity.value, "source": ev.source, "text": ev.text,
           "details": dict(ev.details)}
    if ev.start_ns is not None:
        doc["start_ns"] = ev.start_ns
    if ev.end_ns is not None:
        doc["end_ns"] = ev.end_ns
    return doc


def _new(rec: dict[str, Any]) -> dict[str, Any]:
    """The record in the current form, with the helpers the recorder uses."""
    fields = {f.column: f for f in (T.GPS_TIME, T.CAN_DEVICE_TIME, T.TIMEBASE_OFFSET)}
    return {(fields[k].key if k in fields else k): (fields[k].to_json(v) if k in fields else v) for k, v in rec.items()}


def _write(out: Path, name: str, *, old: bool) -> Path:
    meta = session_metadata(session={"output": {"name": name}}, vehicle={}, calibration={})
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0, validate_json=not old)
    form = (lambda r: {k: v for k, v in r.items() if v is not None}) if old else _new
    with Recorder(out, name, meta, options=opts) as rec:
        src = rec.source("rx")
        for kind, records in _gnss_records().items():
            topic = getattr(T, f"gnss_{kind}")("rx")
            for r in records:
                t = gps_ns_to_unix_ns(r["gps_time_ns"], LEAP)
                src.put(topic, t, t + 1000, T.encode_record(form(r)))
        u0 = gps_ns_to_unix_ns(G0, LEAP)
        for k in range(N):
            src.put(T.can_roles("can0"), u0 + k * 10_000_000, u0 + k * 10_000_000 + 5, T.encode_record(form(_roles(k))))
        for k in range(6):
            src.put(T.TOPIC_TIMEBASE, u0 + k * 10**9, u0 + k * 10**9, T.encode_record(form(_timebase(k))))
        for k, ev in enumerate(_events()):
            src.put(T.TOPIC_EVENTS, u0 + k, u0 + k, T.encode_record(_old_event(ev) if old else ev.to_json()))
    return out / name


def _json_integers(path: Path) -> list[tuple[str, int]]:
    from mcap.reader import make_reader

    found: list[tuple[str, int]] = []

    def walk(v: Any, where: str) -> None:
        if isinstance(v, bool):
            return
        if isinstance(v, int):
            found.append((where, v))
        elif isinstance(v, dict):
            for k, sub in v.items():
                walk(sub, f"{where}.{k}")
        elif isinstance(v, list):
            for sub in v:
                walk(sub, f"{where}[]")

    for part in sorted(path.parent.glob(f"{path.name}*.mcap")):
        with part.open("rb") as fh:
            for _s, channel, message in make_reader(fh).iter_messages():
                if channel.message_encoding == T.JSON_ENCODING:
                    walk(json.loads(message.data), channel.topic)
    return found


@pytest.fixture(scope="module")
def both(tmp_path_factory: pytest.TempPathFactory) -> tuple[Session, Session]:
    out = tmp_path_factory.mktemp("ns")
    topics = [*(getattr(T, f"gnss_{k}")("rx") for k in ("bestpos", "bestvel", "heading", "markpos", "marktime",
                                                        "time")), T.can_roles("can0"), T.TOPIC_TIMEBASE, T.TOPIC_EVENTS]
    return (load_session(_write(out, "old", old=True), topics=topics),
            load_session(_write(out, "new", old=False), topics=topics))


def _same_table(old: Table, new: Table, what: str) -> None:
    assert len(old) == len(new) > 0, what
    assert np.array_equal(old.time_ns, new.time_ns) and np.array_equal(old.host_ns, new.host_ns), what
    assert_same_columns(old.columns, new.columns, what)


def test_the_old_file_has_the_plain_integers_the_new_one_none(both: tuple[Session, Session]) -> None:
    old, new = both
    big_old = {w for w, v in _json_integers(old.path) if abs(v) >= T.JS_EXACT_INT}
    assert {"/gnss/rx/bestpos.gps_time_ns", "/can/can0/roles.device_time_ns", "/rig/timebase.offset_ns",
            "/rig/events.start_ns", "/rig/events.details.host_ns"} <= big_old
    assert [(w, v) for w, v in _json_integers(new.path) if abs(v) >= T.JS_EXACT_INT] == []


def test_gnss_tables_are_the_same_int64_ns_columns_from_either_form(both: tuple[Session, Session]) -> None:
    old, new = both
    g_old, g_new = old.gnss("rx"), new.gnss("rx")
    for kind in ("bestpos", "bestvel", "heading", "markpos", "marktime", "time"):
        a, b = getattr(g_old, kind), getattr(g_new, kind)
        _same_table(a, b, kind)
        assert b["gps_time_ns"].dtype == np.int64 and next(iter(b.columns)) == "gps_time_ns"
    want = np.asarray([r["gps_time_ns"] for r in _gnss_records()["bestpos"]], dtype=np.int64)
    assert np.array_equal(g_new.bestpos["gps_time_ns"], want)  # exact to the ns
    assert np.array_equal(g_new.bestpos.time_ns, new.gps_to_utc(want))


def test_can_roles_timebase_and_events_read_the_same(both: tuple[Session, Session]) -> None:
    old, new = both
    roles_old, roles_new = old._table(T.can_roles("can0")), new._table(T.can_roles("can0"))
    _same_table(roles_old, roles_new, "roles")
    dev = roles_new["device_time_ns"]  # nullable: float with NaN where the interface gave no time, as before
    assert dev.dtype == np.float64 and int(np.isnan(dev).sum()) == len([k for k in range(N) if k % 7 == 3])
    _same_table(old.timebase_records(), new.timebase_records(), "timebase")
    off = new.timebase_records()["offset_ns"]
    assert np.isnan(off[0]) and off[1] == float(315_964_782_000_093_697)
    mine = [[(t, e) for t, e in s.events if e.source != "recorder"] for s in both]  # not its start/stop
    assert mine[0] == mine[1]
    assert [e for _t, e in mine[1]] == _events()  # details, intervals: the exact integers


def test_exports_give_the_same_ns_columns_from_either_form(both: tuple[Session, Session], tmp_path: Path) -> None:
    tables = []
    for s, name in zip(both, ("old", "new"), strict=True):
        export_parquet(s.path, tmp_path / name)
        tables.append({g: pads.dataset(tmp_path / name / g, partitioning="hive").to_table()
                       for g in ("gnss_rx_bestpos", "gnss_rx_marktime", "timebase", "events")})
    old, new = tables
    want = [r["gps_time_ns"] for r in _gnss_records()["bestpos"]]
    assert new["gnss_rx_bestpos"].column("gps_time_ns").to_pylist() == want
    for group, column in (("gnss_rx_bestpos", "gps_time_ns"), ("gnss_rx_marktime", "gps_time_ns"),
                          ("timebase", "offset_ns"), ("events", "start_ns"), ("events", "end_ns")):
        assert new[group].column(column).to_pylist() == old[group].column(column).to_pylist(), (group, column)
        assert "gps_time" not in new[group].column_names and "offset" not in new[group].column_names
