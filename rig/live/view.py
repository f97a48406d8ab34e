"""The live view of one recording session: the feed, the Foxglove server and the status page together."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from drivers.relay.endpoints import MASK
from rig.live.feed import LiveFeed, LiveOptions
from rig.live.gate import UPSTREAM_HOST, TokenGate
from rig.live.page import StatusPage
from rig.live.server import FoxgloveSink

if TYPE_CHECKING:
    from rig.session import RecordSession

__all__ = ["LiveView"]

log = logging.getLogger(__name__)


class LiveView:
    """Serve a running :class:`~rig.session.RecordSession` live (see :mod:`rig.live`).

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
        self._session: RecordSession | None = None

    def attach(self, session: RecordSession) -> None:
        opts = self.options
        cfg = session.cfg
        by_antenna = {r.antenna: r.name for r in cfg.receivers if r.role == "rover" and r.antenna}
        gated = opts.token is not None
        sink = FoxgloveSink(host=UPSTREAM_HOST if gated else opts.bind, port=0 if gated else opts.port,
                            name=f"vsc-rig {session.name}")
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

    def detach(self, session: RecordSession | None = None) -> None:
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
