"""The live view over the Foxglove WebSocket protocol during a simulated recording: a real client
(``websockets``, subprotocol ``foxglove.websocket.v1``) subscribes and receives decimated messages."""

from __future__ import annotations

import json

import numpy as np

from rig.live.feed import TOPIC_LIVE_LOG, TOPIC_LIVE_SIDESLIP, TOPIC_LIVE_STATUS
from rig.live.server import FoxgloveSink
from rig.live.view import upfront_channels
from tests.live.conftest import LiveRun
from tests.live.wsclient import collect

FIX = "/gnss/rover_a/fix"
ROLES = "/can/vsc/roles"


def test_client_subscribes_and_receives_during_a_simulated_recording(live_run: LiveRun) -> None:
    url = live_run.view.ws_url
    # loopback without a token: the SDK's server itself on the port, no gate in front
    assert live_run.view.gate is None and live_run.view.sink is not None
    assert url == f"ws://127.0.0.1:{live_run.view.sink.port}"
    got = collect(url, [FIX, ROLES, TOPIC_LIVE_SIDESLIP, TOPIC_LIVE_STATUS],
                  counts={FIX: 20, ROLES: 100, TOPIC_LIVE_SIDESLIP: 20, TOPIC_LIVE_STATUS: 2}, timeout_s=60.0)
    assert got.server_info.get("name", "").startswith("vsc-rig")
    # no capability that lets a phone write: subscribe only
    assert not set(got.server_info.get("capabilities", [])) & {"clientPublish", "services", "parameters"}
    assert not got.statuses, got.statuses  # no subscription refused
    for topic in (FIX, ROLES, TOPIC_LIVE_SIDESLIP, TOPIC_LIVE_STATUS):
        assert len(got.messages.get(topic, ())) >= 2, f"{topic}: {len(got.messages.get(topic, ()))} messages"
    # the recorded schema goes out unchanged: the map reads foxglove.LocationFix
    assert got.advertised[FIX]["schemaName"] == "foxglove.LocationFix"
    assert got.advertised[FIX]["encoding"] == "json"
    fix = json.loads(got.messages[FIX][-1][1])
    assert abs(fix["latitude"]) > 1.0 and set(fix["timestamp"]) == {"sec", "nsec"}
    # raw topics are not served to a phone
    assert not any(t.endswith(("/raw", "/frames", "/samples")) for t in got.advertised)
    assert TOPIC_LIVE_LOG in got.advertised and got.advertised[TOPIC_LIVE_LOG]["schemaName"] == "foxglove.Log"
    # decimation: per CAN message at most 50 Hz on the log-time axis (the ECU sends 100 Hz frames)
    by_id: dict[int, list[int]] = {}
    for t, payload in got.messages[ROLES]:
        by_id.setdefault(json.loads(payload)["can_id"], []).append(t)
    for can_id, times in by_id.items():
        if len(times) > 3:
            assert np.min(np.diff(times)) >= 20_000_000 - 1, f"can id {can_id:#x} faster than 50 Hz"
    # the live sideslip channel carries foxglove.Time stamps and the VSC estimate
    side = [json.loads(p) for _t, p in got.messages[TOPIC_LIVE_SIDESLIP]]
    assert all(set(m["stamp"]) == {"sec", "nsec"} for m in side)
    assert any("beta_vsc_deg" in m for m in side)
    status = json.loads(got.messages[TOPIC_LIVE_STATUS][-1][1])
    assert [r["name"] for r in status["rovers"]] == ["rover_a", "rover_b"]
    assert live_run.view.feed is not None and live_run.view.feed.stats.dropped == 0


def test_the_layouts_channels_exist_before_the_server_listens() -> None:
    """foxglove-sdk 0.30.3 can advertise a channel created while a client connects without entering it in
    that client's table, and then refuses the client's subscription ("Unknown channel ID"): the live view
    creates the channels it knows of before it listens, so a client finds them all at its first advertise."""
    channels = upfront_channels("rover_a", "rover_b", ["vsc"])
    assert {FIX, ROLES, "/gnss/rover_b/fix", TOPIC_LIVE_SIDESLIP, TOPIC_LIVE_STATUS, "/live/ltr"} <= set(channels)
    sink = FoxgloveSink(host="127.0.0.1", port=0, name="vsc-rig upfront", channels=channels)
    try:
        assert set(sink.topics) == set(channels) | {TOPIC_LIVE_LOG}
        # no message published at all: what the client sees was advertised before it connected
        got = collect(f"ws://127.0.0.1:{sink.port}", [], timeout_s=10.0,
                      until=lambda r: set(channels) <= set(r.advertised))
    finally:
        sink.stop()
    assert set(channels) | {TOPIC_LIVE_LOG} <= set(got.advertised)
    assert got.advertised[FIX]["schemaName"] == "foxglove.LocationFix"
