"""The live view of one recording session: the feed, the Foxglove server and the status page together."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable
from typing import TYPE_CHECKING

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.relay.endpoints import MASK
from rig.live.feed import LIVE_TOPICS, LiveFeed, LiveOptions
from rig.live.gate import UPSTREAM_HOST, TokenGate
from rig.live.layout import layout_json, message_paths, session_layout
from rig.live.page import StatusPage
from rig.live.server import FoxgloveSink

if TYPE_CHECKING:
    from rig.record.recording import Recording

__all__ = ["LiveView", "upfront_channels"]

log = logging.getLogger(__name__)


def upfront_channels(antenna_a: str, antenna_b: str, buses: Iterable[str]) -> dict[str, T.SchemaSpec]:
    """The JSON channels known before the recording's first message: the live-only ones and every topic
    the Foxglove layout (:func:`~rig.live.layout.session_layout`) names, per CAN bus. The Foxglove server
    creates them before it listens (see :mod:`rig.live.server`)."""
    out = {t: s for t, s in LIVE_TOPICS.items() if s is not None}
    for bus in buses:
        for path in message_paths(json.loads(layout_json(session_layout(antenna_a, antenna_b, bus)))):
            topic = path.split(".", 1)[0]
            if topic in LIVE_TOPICS:
                continue
            try:
                spec, _params = T.spec_for_topic(topic)
            except ValueError:
                continue  # not a recorded topic (the layout test holds every path to one)
            if spec.schema.is_json:
                out[topic] = spec.schema
    return out


class LiveView:
    """Serve a running :class:`~rig.record.recording.Recording` live (see :mod:`rig.live`).

    :meth:`attach` once the session records (it hooks the feed onto the recorder's tap and starts the
    servers); :meth:`detach` unhooks it, stops the feed's thread and the servers (idempotent).

    Without a token the Foxglove SDK's server listens on the bound address itself. With a token it
    listens on 127.0.0.1 on an ephemeral port, behind a :class:`~rig.live.gate.TokenGate` on the bound
    address that refuses a WebSocket without the token (HTTP 401).
    """

    def __init__(self, options: LiveOptions) -> None:
        self.options = options
        self.feed: LiveFeed | None = None
        self.sink: FoxgloveSink | None = None
        self.page: StatusPage | None = None
        self.gate: TokenGate | None = None
        self._session: Recording | None = None

    def attach(self, session: Recording) -> None:
        opts = self.options
        cfg = session.cfg
        by_antenna = {r.antenna: r.name for r in cfg.receivers if r.role == "rover" and r.antenna}
        gated = opts.token is not None
        channels = upfront_channels(by_antenna.get("a", "rover_a"), by_antenna.get("b", "rover_b"),
                                    [c.name for c in cfg.can] or ["vsc"])
        sink = FoxgloveSink(host=UPSTREAM_HOST if gated else opts.bind, port=0 if gated else opts.port,
                            name=f"vsc-rig {session.name}", channels=channels)
        gate: TokenGate | None = None
        try:
            if opts.token is not None:
                gate = TokenGate(host=opts.bind, port=opts.port, upstream_port=sink.port, token=opts.token)
            feed = LiveFeed(
                sink, opts, antenna_a=by_antenna.get("a"), antenna_b=by_antenna.get("b"),
                rovers={r.name: r.antenna or "-" for r in cfg.receivers if r.role == "rover"},
                mount_offset_deg=cfg.profile.calibration.mount_offset_deg,
                baseline_nominal_m=cfg.profile.antennas.baseline_length_m,
                status=lambda: session.board.snapshot(session.clock.now_ns()), now_ns=session.clock.now_ns,
            )
            page = StatusPage(feed.status_document, host=opts.bind, port=opts.page_port, token=opts.token)
        except BaseException:
            if gate is not None:
                gate.stop()
            sink.stop()
            raise
        feed.start()
        self.sink, self.gate, self.feed, self.page, self._session = sink, gate, feed, page, session
        session.recorder.tap = feed.offer
        log.info("live view: %s (Foxglove), status page %s", self.ws_url, page.url(opts.bind))

    def detach(self, session: Recording | None = None) -> None:
        s = session or self._session
        if s is not None and s.recorder.tap is not None:
            s.recorder.tap = None
        if self.feed is not None:
            self.feed.stop()
        if self.page is not None:
            self.page.stop()
        if self.gate is not None:  # clients first, then the server they were relayed to
            self.gate.stop()
        if self.sink is not None:
            self.sink.stop()
        self.feed = self.page = self.sink = self.gate = None
        self._session = None

    @property
    def ws_port(self) -> int:
        """The WebSocket port clients connect to (the gate's with a token, else the SDK server's)."""
        if self.gate is not None:
            return self.gate.port
        assert self.sink is not None
        return self.sink.port

    @property
    def ws_url(self) -> str:
        """The WebSocket address to show: with a token, ``?token=***`` (the user puts theirs there)."""
        base = f"ws://{self.options.bind}:{self.ws_port}"
        return f"{base}/?token={MASK}" if self.options.token else base

    @property
    def page_url(self) -> str:
        """The status page's address to show (the token masked as for :attr:`ws_url`)."""
        assert self.page is not None
        return self.page.url(self.options.bind)
