"""The live WebSocket checks the token: with one, the Foxglove SDK's server sits behind the token gate
(:mod:`rig.live.gate`), which refuses a client without the right token at the upgrade (HTTP 401) and
relays an authenticated one, subprotocol negotiation included."""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from websockets.asyncio.client import connect
from websockets.datastructures import Headers
from websockets.exceptions import InvalidStatus
from websockets.typing import Subprotocol

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.relay.endpoints import Secret
from rig.live import LiveOptions
from rig.live.feed import TOPIC_LIVE_STATUS
from rig.live.gate import TokenGate, token_of_request
from rig.live.server import FoxgloveSink
from tests.live.conftest import LiveRun, run_live
from tests.live.wsclient import SUBPROTOCOLS, collect
from vsccore.errors import ConfigError

TOKEN = "tablet-4b1e9d07c2"
FIX = "/gnss/rover_a/fix"
TICK = "/test/tick"


def _refusal(url: str, subprotocols: tuple[str, ...] = SUBPROTOCOLS, headers: dict[str, str] | None = None) -> int:
    """The HTTP status with which the server refuses the WebSocket upgrade (fails if it accepts)."""

    async def attempt() -> int:
        try:
            async with connect(url, subprotocols=[Subprotocol(p) for p in subprotocols], additional_headers=headers,
                               open_timeout=10.0):
                pass
        except InvalidStatus as exc:
            return int(exc.response.status_code)
        raise AssertionError(f"{url}: the upgrade was accepted")

    return asyncio.run(attempt())


@pytest.fixture
def token_run(tmp_path: Path) -> Iterator[LiveRun]:
    yield from run_live(tmp_path, LiveOptions(port=0, status_port=0, token=Secret(TOKEN)))


def test_the_live_websocket_refuses_a_client_without_the_token(token_run: LiveRun,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    view = token_run.view
    assert view.gate is not None and view.sink is not None
    assert view.ws_port == view.gate.port != view.sink.port
    assert view.ws_url == f"ws://127.0.0.1:{view.gate.port}/?token=***"  # what the terminal shows
    base = f"ws://127.0.0.1:{view.ws_port}/"
    assert _refusal(base) == 401
    assert _refusal(base + "?token=wrong-token-of-17") == 401
    assert _refusal(base + "?token=" + TOKEN[:-1]) == 401
    assert _refusal(base, headers={"Authorization": "Bearer not-" + TOKEN}) == 401
    # the right token: subscribed and served, through the gate, during the recording
    got = collect(base + "?token=" + TOKEN, [FIX, TOPIC_LIVE_STATUS], counts={FIX: 5, TOPIC_LIVE_STATUS: 2},
                  timeout_s=60.0)
    assert got.subprotocol == "foxglove.sdk.v1"  # the SDK's choice among the client's offer
    assert got.server_info.get("name", "").startswith("vsc-rig")
    assert got.advertised[FIX]["schemaName"] == "foxglove.LocationFix"
    assert len(got.messages[FIX]) >= 5 and abs(json.loads(got.messages[FIX][-1][1])["latitude"]) > 1.0
    status = json.loads(got.messages[TOPIC_LIVE_STATUS][-1][1])
    assert [r["name"] for r in status["rovers"]] == ["rover_a", "rover_b"]
    # the token in a header does as well (a script's client)
    by_header = collect(base, [TOPIC_LIVE_STATUS], timeout_s=60.0, headers={"Authorization": f"Bearer {TOKEN}"})
    assert by_header.messages.get(TOPIC_LIVE_STATUS)
    # neither the refusals nor the served clients logged it (the test's own client logs its requests)
    server_side = [r for r in caplog.records if r.name.startswith(("rig.", "foxglove"))]
    assert server_side and not [r.getMessage() for r in server_side if TOKEN in r.getMessage()]


@pytest.fixture
def gated_sink() -> Iterator[tuple[FoxgloveSink, TokenGate]]:
    """The SDK server with a test channel on 127.0.0.1 and the gate in front of it, no recording."""
    sink = FoxgloveSink(host="127.0.0.1", port=0, name="vsc-rig gate test")
    try:
        gate = TokenGate(host="127.0.0.1", port=0, upstream_port=sink.port, token=Secret(TOKEN))
    except BaseException:
        sink.stop()
        raise
    try:
        yield sink, gate
    finally:
        gate.stop()
        sink.stop()


def _publishing(sink: FoxgloveSink, stop: threading.Event) -> threading.Thread:
    schema = T.SchemaSpec("test.Tick", "json", "jsonschema", {"type": "object"})

    def body() -> None:
        n = 0
        while not stop.wait(0.01):
            n += 1
            sink.publish(TICK, schema, T.encode_record({"n": n}), n * 10_000_000)

    th = threading.Thread(target=body, name="test-publish")
    th.start()
    return th


def test_the_gate_relays_both_ways_and_passes_on_the_sdks_subprotocol_choice(
        gated_sink: tuple[FoxgloveSink, TokenGate]) -> None:
    sink, gate = gated_sink
    stop = threading.Event()
    th = _publishing(sink, stop)
    try:
        # the client's subscribe goes up, the SDK's binary message data comes down, in order
        got = collect(f"ws://127.0.0.1:{gate.port}/?token={TOKEN}", [TICK], counts={TICK: 20}, timeout_s=30.0)
    finally:
        stop.set()
        th.join(5.0)
    ns = [json.loads(p)["n"] for _t, p in got.messages[TICK]]
    assert len(ns) >= 20 and ns == sorted(ns) and len(set(ns)) == len(ns)
    assert [t for t, _p in got.messages[TICK]] == [n * 10_000_000 for n in ns]  # log times relayed exactly
    # negotiation is the SDK's, status for status: a client offering only a subprotocol it does not speak
    # gets the same refusal through the gate as straight from the SDK
    direct = _refusal(f"ws://127.0.0.1:{sink.port}/", subprotocols=("foxglove.unknown.v9",))
    assert _refusal(f"ws://127.0.0.1:{gate.port}/?token={TOKEN}", subprotocols=("foxglove.unknown.v9",)) == direct
    assert direct >= 400


def test_stopping_the_gate_closes_a_connected_client(gated_sink: tuple[FoxgloveSink, TokenGate]) -> None:
    _sink, gate = gated_sink

    async def connected_until_closed(ready: threading.Event) -> int | None:
        async with connect(f"ws://127.0.0.1:{gate.port}/", subprotocols=[Subprotocol(SUBPROTOCOLS[0])],
                           additional_headers={"Authorization": f"Bearer {TOKEN}"}) as ws:
            assert json.loads(await ws.recv())["op"] == "serverInfo"
            ready.set()
            await ws.wait_closed()
            return ws.close_code

    ready = threading.Event()
    codes: list[int | None] = []
    th = threading.Thread(target=lambda: codes.append(asyncio.run(connected_until_closed(ready))),
                          name="test-ws-client")
    th.start()
    try:
        assert ready.wait(30.0), "the client did not get the server info through the gate"
        gate.stop()
    finally:
        th.join(30.0)
    assert not th.is_alive() and codes == [1001]  # "going away": the server shut down


def test_token_of_request_reads_the_query_then_the_bearer_header() -> None:
    assert token_of_request("/?token=abc", Headers()) == "abc"
    assert token_of_request("/?x=1&token=abc", Headers({"Authorization": "Bearer other"})) == "abc"
    assert token_of_request("/", Headers({"Authorization": "Bearer abc "})) == "abc"
    assert token_of_request("/", Headers({"Authorization": "Basic YWJjOmRlZg=="})) == ""
    assert token_of_request("/", Headers()) == ""


def test_a_gate_on_a_port_in_use_is_a_config_error(gated_sink: tuple[FoxgloveSink, TokenGate]) -> None:
    _sink, gate = gated_sink
    with pytest.raises(ConfigError, match=f"--live {gate.port} --live-bind 127.0.0.1: cannot serve the live WebSocket"):
        TokenGate(host="127.0.0.1", port=gate.port, upstream_port=1, token=Secret(TOKEN))
