"""The live feed without a network: the token rule, drop-oldest, decimation, the status page's token."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from typing import Any

import pytest
from typer.testing import CliRunner

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.relay.endpoints import Secret
from rig.cli.main import app
from rig.live import LiveFeed, LiveOptions
from rig.live.feed import TOKEN_ENV
from rig.live.page import StatusPage
from rig.workflows.demo import demo_config_path
from vsccore.errors import ConfigError


class ListSink:
    def __init__(self) -> None:
        self.published: list[tuple[str, int, Any]] = []
        self.logs: list[tuple[int, str, str, str]] = []

    def publish(self, topic: str, schema: T.SchemaSpec, data: bytes, log_time_ns: int) -> None:
        self.published.append((topic, log_time_ns, json.loads(data)))

    def log(self, log_time_ns: int, severity: str, text: str, source: str) -> None:
        self.logs.append((log_time_ns, severity, text, source))


def _feed(sink: ListSink, **kw: Any) -> LiveFeed:
    return LiveFeed(sink, LiveOptions(**kw), antenna_a="rover_a", antenna_b="rover_b",
                    rovers={"rover_a": "a", "rover_b": "b"})


def _roles(can_id: int, yaw: float) -> bytes:
    return T.encode_record({"can_id": can_id, "message": "M", "roles": {"yaw_rate": yaw}, "valid": True})


def test_a_lan_address_needs_a_token(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ConfigError, match=f"--live-bind 192.168.1.20.*--live-token.*{TOKEN_ENV}"):
        LiveOptions(bind="192.168.1.20")
    with pytest.raises(ConfigError, match="at least 12 characters"):
        LiveOptions(bind="0.0.0.0", token="short")
    assert LiveOptions(bind="::1").token is None  # loopback: no token needed
    monkeypatch.setenv(TOKEN_ENV, "from-the-environment")
    assert LiveOptions.from_cli(8765, "192.168.1.20", None).token == Secret("from-the-environment")
    opts = LiveOptions.from_cli(8765, "192.168.1.20", "from-the-command-line")
    assert opts.token == Secret("from-the-command-line")
    # the token is a Secret: the options never spell it out (logs, tracebacks)
    assert "from-the-command-line" not in repr(opts) and "from-the-command-line" not in str(opts)
    assert LiveOptions(bind="10.0.0.7", token="a-plain-string-token").token == Secret("a-plain-string-token")


def test_cli_refuses_a_lan_bind_without_token_before_anything_starts(tmp_path: Any,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    r = CliRunner().invoke(app, ["sim", "record", str(demo_config_path()), "--out", str(tmp_path), "--no-dashboard",
                                 "--live", "--live-bind", "10.0.0.7"])
    assert r.exit_code != 0
    assert isinstance(r.exception, ConfigError) and "--live-bind 10.0.0.7" in str(r.exception)
    assert not list(tmp_path.iterdir())  # no session was started


def test_the_queue_drops_the_oldest_and_counts() -> None:
    sink = ListSink()
    feed = _feed(sink, queue_size=3, full_rate=True)
    for i in range(5):
        feed.offer(T.can_roles("vsc"), 1_000_000_000 + i, 0, _roles(0x101, float(i)))
    assert feed.stats.dropped == 2 and feed.stats.offered == 5
    feed.drain()
    assert [m["roles"]["yaw_rate"] for t, _ns, m in sink.published if t == "/can/vsc/roles"] == [2.0, 3.0, 4.0]


def test_plot_channels_are_decimated_per_can_message_unless_full_rate() -> None:
    for full, expect in ((False, 50), (True, 100)):
        sink = ListSink()
        feed = _feed(sink, full_rate=full)
        for i in range(100):  # 1 s of two CAN messages at 100 Hz each
            for can_id in (0x101, 0x102):
                feed.offer(T.can_roles("vsc"), 1_000_000_000 + i * 10_000_000, 0, _roles(can_id, 0.1))
        feed.offer(T.TOPIC_EVENTS, 2_000_000_000, 0, T.encode_record(
            T.Event(T.EventKind.MARK, "operator", "mark 1").to_json()))
        feed.drain()
        for can_id in (0x101, 0x102):
            n = sum(1 for t, _ns, m in sink.published if t == "/can/vsc/roles" and m["can_id"] == can_id)
            assert n == expect, (full, can_id, n)
        assert [e for e in sink.published if e[0] == T.TOPIC_EVENTS]  # events are never decimated
        assert sink.logs == [(2_000_000_000, "info", "mark 1", "operator")]


def test_the_status_page_wants_the_token() -> None:
    page = StatusPage(lambda: {"session": "s", "rovers": [], "recording_s": 65.0}, host="127.0.0.1", port=0,
                      token=Secret("a-token-of-16-chr"))
    try:
        base = f"http://127.0.0.1:{page.port}/"
        for url in (base, base + "status.json", base + "status.json?token=wrong"):
            with pytest.raises(urllib.error.HTTPError) as err:
                urllib.request.urlopen(url, timeout=5.0)
            err.value.close()
            assert err.value.code == 401
        req = urllib.request.Request(base + "status.json", headers={"Authorization": "Bearer a-token-of-16-chr"})
        with urllib.request.urlopen(req, timeout=5.0) as r:
            assert json.loads(r.read())["recording_s"] == 65.0
        assert page.url("127.0.0.1").endswith("/?token=***")  # the address shown and logged
        with urllib.request.urlopen(page.url("127.0.0.1", reveal=True), timeout=5.0) as r:
            assert 'id="recording">1:05<' in r.read().decode()
    finally:
        page.stop()
