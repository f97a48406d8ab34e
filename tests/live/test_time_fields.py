"""Integer nanoseconds reach JavaScript readers exactly (decision record 0005).

A JavaScript reader (Foxglove) reads a JSON integer as a double: beyond 2^53 it is rounded (ns since
1970 land on a 256 ns grid). So no JSON message carries such an integer: GNSS GPS times are
``gps_time: {week, tow_ns}`` (GPS time scale, not a foxglove.Time), CAN interface times and event
intervals are ``foxglove.Time``, time-base offsets ``foxglove.Duration``, and an event detail beyond
±2^53 is its decimal string. Readers get int ns back, from these files and from older ones.
"""

from __future__ import annotations

import json
import re

import jsonschema
import pytest
from hypothesis import given
from hypothesis import strategies as st

import rig.core.topics as T  # noqa: N812 - topics used as a namespace

_I64 = st.integers(min_value=0, max_value=2**63 - 1)


def _double(v: int) -> int:
    """What a JavaScript reader makes of a JSON integer."""
    return int(float(v))


def test_event_interval_as_foxglove_time_is_exact_where_a_double_is_not() -> None:
    start, end = 1_717_171_717_123_456_789, 1_717_171_718_000_000_001
    assert _double(start) != start  # the plain integer that older files carried
    ev = T.Event(T.EventKind.GAP, "can:vsc", "gap", start_ns=start, end_ns=end)
    doc = json.loads(T.encode_record(ev.to_json()))
    jsonschema.Draft202012Validator(T.SCHEMA_EVENT.document).validate(doc)
    assert "start_ns" not in doc and "end_ns" not in doc
    assert _double(doc["start"]["sec"]) * 1_000_000_000 + _double(doc["start"]["nsec"]) == start
    assert (doc["end"]["sec"], doc["end"]["nsec"]) == (1_717_171_718, 1)
    assert T.Event.from_json(doc) == ev
    plain = json.loads(T.encode_record(T.Event(T.EventKind.MARK, "operator", "m").to_json()))
    assert "start" not in plain and "end" not in plain
    jsonschema.Draft202012Validator(T.SCHEMA_EVENT.document).validate(plain)


def test_event_of_an_older_file_with_plain_integer_interval_reads_the_same() -> None:
    start, end = 1_717_171_717_123_456_789, 1_717_171_718_000_000_001
    old = {"kind": "gap", "severity": "warning", "source": "can:vsc", "text": "gap", "start_ns": start,
           "end_ns": end, "start": {"sec": 1_717_171_717, "nsec": 123_456_789}, "details": {"frames": 3}}
    ev = T.Event.from_json(old)
    assert (ev.start_ns, ev.end_ns, dict(ev.details)) == (start, end, {"frames": 3})
    older = {k: v for k, v in old.items() if k != "start"}  # before foxglove.Time was added beside them
    assert T.Event.from_json(older) == ev


def test_event_details_beyond_2_53_are_decimal_strings_and_read_back_as_integers() -> None:
    host = 1_767_830_378_003_860_862
    details = {"host_ns": host, "step_ns": -221_650, "verdicts": {"gnss": {"gaps": [{"start_ns": host, "n": 2}]}},
               "text": "12345678901234567890", "ok": True}
    ev = T.Event(T.EventKind.TIMEBASE, "rig", "step", details=details)
    doc = json.loads(T.encode_record(ev.to_json()))
    jsonschema.Draft202012Validator(T.SCHEMA_EVENT.document).validate(doc)
    assert doc["details"]["host_ns"] == str(host)
    assert doc["details"]["verdicts"]["gnss"]["gaps"][0] == {"start_ns": str(host), "n": 2}
    assert doc["details"]["step_ns"] == -221_650 and doc["details"]["ok"] is True
    assert T.Event.from_json(doc) == ev  # a 20-digit text stays text: beyond int64, never written for an integer


@given(_I64)
def test_gps_time_is_week_and_time_of_week_each_exact_in_a_double(gps_ns: int) -> None:
    obj = T.GPS_TIME.to_json(gps_ns)
    assert obj == T.gps_week_tow(gps_ns)
    assert set(obj) == {"week", "tow_ns"} and 0 <= obj["tow_ns"] < T.GPS_WEEK_NS
    assert all(_double(v) == v for v in obj.values())
    assert T.GPS_TIME.from_json(obj) == gps_ns
    assert T.GPS_TIME.read({"gps_time": obj}) == gps_ns == T.GPS_TIME.read({"gps_time_ns": gps_ns})
    jsonschema.validate(obj, T.SCHEMA_BESTPOS.document["properties"]["gps_time"])


@given(_I64)
def test_unix_times_are_foxglove_time(ns: int) -> None:
    for field in (T.CAN_DEVICE_TIME, T.EVENT_START, T.EVENT_END):
        obj = field.to_json(ns)
        assert obj == T.foxglove_time(ns) and all(_double(v) == v for v in obj.values())
        assert field.read({field.key: obj}) == ns == field.read({field.column: ns})


@given(st.integers(min_value=-(2**63), max_value=2**63 - 1))
def test_offsets_are_foxglove_duration(ns: int) -> None:
    obj = T.TIMEBASE_OFFSET.to_json(ns)
    assert obj is not None and 0 <= obj["nsec"] < 1_000_000_000 and all(_double(v) == v for v in obj.values())
    assert T.TIMEBASE_OFFSET.from_json(obj) == ns
    jsonschema.validate(obj, T.SCHEMA_TIMEBASE.document["properties"]["offset"])


def test_the_gps_time_is_not_typed_as_a_unix_time_and_the_others_are_foxglove_types() -> None:
    gps = T.SCHEMA_BESTPOS.document["properties"]["gps_time"]
    assert gps["title"] not in ("time", "foxglove.Time") and "sec" not in gps["properties"]
    assert "GPS time scale" in gps["description"] and "not Unix time" in gps["description"]
    assert T.SCHEMA_CAN_ROLES.document["properties"]["device_time"]["title"] == "time"
    assert T.SCHEMA_EVENT.document["properties"]["start"]["title"] == "time"
    assert T.SCHEMA_TIMEBASE.document["properties"]["offset"]["title"] == "duration"
    # every JSON schema: no integer-ns member left that a JavaScript reader would round
    for spec in T.TOPICS:
        if spec.schema.is_json:
            props = spec.schema.document["properties"]
            names = {f.key for f in spec.schema.ns_fields}
            assert names <= set(props), spec.schema.name
            assert not [k for k, p in props.items() if k.endswith("_ns") and p.get("type") == "integer"], \
                spec.schema.name


@pytest.mark.parametrize(("value", "needle"), [
    ({"week": 2400}, "gps_time: expected an object of integers {week, tow_ns}"),
    ({"week": 2400, "tow_ns": 1.5}, "gps_time: expected an object of integers"),
    ({"week": 2400, "tow_ns": T.GPS_WEEK_NS}, "gps_time.tow_ns: 604800000000000 is outside [0, 604800000000000)"),
    (1_451_865_606_750_000_000, "gps_time: expected an object of integers"),
])
def test_a_malformed_time_object_is_named(value: object, needle: str) -> None:
    with pytest.raises(ValueError, match=re.escape(needle)):
        T.GPS_TIME.read({"gps_time": value})
    with pytest.raises(ValueError, match="gps_time_ns: expected integer ns, got '1'"):
        T.GPS_TIME.read({"gps_time_ns": "1"})
