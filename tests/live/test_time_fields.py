"""Integer nanoseconds reach JavaScript readers exactly: /rig/events carries start/end as foxglove.Time
beside start_ns/end_ns (which the dataset readers keep using)."""

from __future__ import annotations

import json

import jsonschema

import rig.topics as T  # noqa: N812 - topics used as a namespace


def test_event_interval_as_foxglove_time_is_exact_where_a_double_is_not() -> None:
    start, end = 1_717_171_717_123_456_789, 1_717_171_718_000_000_001
    ev = T.Event(T.EventKind.GAP, "can:vsc", "gap", start_ns=start, end_ns=end)
    doc = json.loads(T.encode_record(ev.to_json()))
    jsonschema.Draft202012Validator(T.SCHEMA_EVENT.document).validate(doc)
    assert int(float(doc["start_ns"])) != start  # what a JavaScript reader makes of the integer (a double)
    assert doc["start"]["sec"] * 1_000_000_000 + doc["start"]["nsec"] == start  # exact, also as doubles
    assert (doc["end"]["sec"], doc["end"]["nsec"]) == (1_717_171_718, 1)
    assert T.Event.from_json(doc) == ev  # the readers still use start_ns/end_ns
    plain = json.loads(T.encode_record(T.Event(T.EventKind.MARK, "operator", "m").to_json()))
    assert "start" not in plain and "end" not in plain
    jsonschema.Draft202012Validator(T.SCHEMA_EVENT.document).validate(plain)
