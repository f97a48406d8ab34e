"""Every JSON-schema'd topic validates with a standard validator (jsonschema, Draft 2020-12).

Nullable fields used to carry the non-standard annotation ``"x-nullable": true`` and be written as
``null``, which standard validators reject (all of ``/rig/events`` and ``/rig/timebase``, part of
``/optical/body``). A field that can be unknown is now optional and left out while unknown.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from mcap.reader import make_reader

import rig.core.topics as T  # noqa: N812 - topics used as a namespace

jsonschema = pytest.importorskip("jsonschema")


def _json_schemas() -> list[T.TopicSpec]:
    return [spec for spec in T.TOPICS if spec.schema.message_encoding == T.JSON_ENCODING]


@pytest.mark.parametrize("spec", _json_schemas(), ids=lambda s: s.schema.name)
def test_every_schema_is_a_valid_draft_2020_12_schema_with_one_type_per_field(spec: T.TopicSpec) -> None:
    doc = spec.schema.document
    jsonschema.Draft202012Validator.check_schema(doc)

    def walk(node: dict, path: str) -> None:
        # Foxglove's schema reader: one "type" string per field, "properties" on every object
        for key, sub in node.get("properties", {}).items():
            assert isinstance(sub.get("type"), str) or "oneOf" in sub, f"{spec.schema.name}: {path}{key}"
            assert "x-nullable" not in sub, f"{spec.schema.name}: {path}{key}"
            if sub.get("type") == "object":
                walk(sub, f"{path}{key}.")

    walk(doc, "")


def test_a_record_with_unknown_values_leaves_them_out_and_validates() -> None:
    event = T.Event(T.EventKind.MARK, "operator", "lane change")
    data = T.encode_record(event.to_json())
    obj = json.loads(data)
    assert "start_ns" not in obj
    assert "end_ns" not in obj
    schema = next(s for s in _json_schemas() if s.match(T.TOPIC_EVENTS) is not None).schema.document
    jsonschema.Draft202012Validator(schema).validate(obj)
    assert T.Event.from_json(obj) == event
    # NaN and inf are unknown too, also inside maps; arrays keep their length
    rec = json.loads(T.encode_record({"a": math.nan, "b": 1.5, "m": {"x": None, "y": 2}, "v": [1.0, math.inf]}))
    assert rec == {"b": 1.5, "m": {"y": 2}, "v": [1.0, None]}
    # the fast path is unchanged for complete records
    assert T.encode_record({"a": 1, "s": "nullable"}) == b'{"a":1,"s":"nullable"}'


def _validate_session(path: Path) -> tuple[int, list[str]]:
    checked = 0
    failures: list[str] = []
    validators: dict[int, object] = {}
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.message_encoding != T.JSON_ENCODING:
                continue
            if schema.id not in validators:
                validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
            err = jsonschema.exceptions.best_match(validators[schema.id].iter_errors(json.loads(message.data)))
            checked += 1
            if err is not None:
                failures.append(f"{channel.topic} seq {message.sequence}: {err.message}")
    return checked, failures
