"""The Foxglove layout: every topic and field path it names exists in a demo-like recorded session or
in the live channels of the same session; the shipped examples/foxglove-layout.json is `rig layout`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from typer.testing import CliRunner

from rig.cli.main import app
from rig.live import LIVE_TOPICS, LiveOptions
from rig.live.layout import layout_json, message_paths, session_layout
from rig.store.reader import find_parts
from rig.workflows.demo import demo_config_path
from tests.live.conftest import run_live
from tests.live.wsclient import Received, collect

EXAMPLE = Path(__file__).resolve().parents[2] / "rig" / "examples" / "foxglove-layout.json"


def _has(msg: Any, fields: list[str]) -> bool:
    for f in fields:
        if not isinstance(msg, dict) or f not in msg:
            return False
        msg = msg[f]
    return True


def _split(path: str, topics: set[str]) -> tuple[str, list[str]]:
    for t in sorted(topics, key=len, reverse=True):
        if path == t or path.startswith(t + "."):
            return t, [f for f in path[len(t) + 1:].split(".") if f]
    raise AssertionError(f"layout names {path!r}: no such topic recorded or served live ({sorted(topics)})")


def _has_ltr_value(got: Received) -> bool:
    return any(json.loads(p).get("ltr") is not None for _ns, p in got.messages.get("/live/ltr", ()))


def test_every_layout_path_exists_in_a_recorded_session_or_the_live_channels(tmp_path: Path) -> None:
    doc = json.loads(layout_json(session_layout()))
    paths = sorted(set(message_paths(doc)))
    assert len(paths) >= 15, paths
    live_topics = list(LIVE_TOPICS)
    messages: dict[str, list[Any]] = {}
    # LTR needs 2 s of a_y history before its first value: read the live channels for a few seconds
    counts = {"/live/sideslip": 60, "/live/ltr": 8, "/live/status": 3, "/live/log": 1}
    for run in run_live(tmp_path, LiveOptions(port=0), drive="step_steer:lead_s=1,hold_s=8"):
        # under load the first LTR values can come late: read until one has arrived, not a fixed count
        got = collect(run.view.ws_url, live_topics, counts=counts, timeout_s=90.0, until=_has_ltr_value)
        for t in live_topics:
            assert got.messages.get(t), f"live channel {t} sent nothing; server status: {got.statuses}"
        for t, msgs in got.messages.items():
            if t in LIVE_TOPICS and LIVE_TOPICS[t] is not None:
                messages[t] = [json.loads(p) for _ns, p in msgs]
            else:  # foxglove.Log (protobuf): the topic exists, its fields are Foxglove's own
                messages[t] = []
        assert run.finished.wait(180.0), "the simulated drive did not end"
    recorded: set[str] = set()
    for part in find_parts(tmp_path / "live"):
        with part.open("rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages():
                recorded.add(channel.topic)
                if channel.message_encoding == "json":
                    messages.setdefault(channel.topic, []).append(json.loads(message.data))
    topics = recorded | set(live_topics)
    for path in paths:
        topic, fields = _split(path, topics)
        if fields:
            assert any(_has(m, fields) for m in messages.get(topic, [])), f"{path}: no {topic} message has it"
    # the β reference and LTR are live-only, and the layout says so
    assert "/live/sideslip" not in recorded and "/live/ltr" not in recorded
    assert all(t in json.dumps(doc) for t in live_topics)
    assert {"/gnss/rover_a/fix", "/gnss/rover_b/fix", "/can/vsc/roles.roles.yaw_rate", "/can/vsc/roles.roles.lat_accel",
            "/can/vsc/roles.roles.swa", "/live/sideslip.beta_vsc_deg", "/live/ltr.ltr", "/rig/events.text",
            "/gnss/rover_a/bestpos.pos_type"} <= set(paths)


def test_the_shipped_layout_is_what_rig_layout_writes(tmp_path: Path) -> None:
    out = tmp_path / "layout.json"
    r = CliRunner().invoke(app, ["layout", "--config", str(demo_config_path()), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_text(encoding="utf-8") == EXAMPLE.read_text(encoding="utf-8")
    r = CliRunner().invoke(app, ["layout", "--config", str(demo_config_path()), "--bus", "chassis"])
    assert r.exit_code != 0 and "--bus chassis" in str(r.exception or r.output)
