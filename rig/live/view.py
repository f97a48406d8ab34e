"""The live view of one recording session: the feed, the Foxglove server and the status page together."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from rig.live.feed import LiveFeed, LiveOptions
from rig.live.page import StatusPage
from rig.live.server import FoxgloveSink

if TYPE_CHECKING:
    from rig.session import RecordSession

__all__ = ["LiveView"]

log = logging.getLogger(__name__)


class LiveView:
    """Serve a running :class:`~rig.session.RecordSession` live (see :mod:`rig.live`).

    :meth:`attach` once the session records (it hooks the feed onto the recorder's tap and starts the
    servers); :meth:`detach` unhooks it, stops the feed's thread and both servers (idempotent).
    """

    def __init__(self, options: LiveOptions) -> None:
        self.options = options
        self.feed: LiveFeed | None = None
        self.sink: FoxgloveSink | None = None
        self.page: StatusPage | None = None
        self._session: RecordSession | None = None

    def attach(self, session: RecordSession) -> None:
        opts = self.options
        cfg = session.cfg
        by_antenna = {r.antenna: r.name for r in cfg.receivers if r.role == "rover" and r.antenna}
        sink = FoxgloveSink(host=opts.bind, port=opts.port, name=f"vsc-rig {session.name}")
        try:
            feed = LiveFeed(
                sink, opts, antenna_a=by_antenna.get("a"), antenna_b=by_antenna.get("b"),
                rovers={r.name: r.antenna or "-" for r in cfg.receivers if r.role == "rover"},
                mount_offset_deg=cfg.profile.calibration.mount_offset_deg,
                baseline_nominal_m=cfg.profile.antennas.baseline_length_m,
                status=lambda: session.board.snapshot(session.clock.now_ns()), now_ns=session.clock.now_ns,
            )
            page = StatusPage(feed.status_document, host=opts.bind, port=opts.page_port, token=opts.token)
        except BaseException:
            sink.stop()
            raise
        feed.start()
        self.sink, self.feed, self.page, self._session = sink, feed, page, session
        session.recorder.tap = feed.offer
        log.info("live view: ws://%s:%d (Foxglove), status page %s", opts.bind, sink.port, page.url(opts.bind))

    def detach(self, session: RecordSession | None = None) -> None:
        s = session or self._session
        if s is not None and s.recorder.tap is not None:
            s.recorder.tap = None
        if self.feed is not None:
            self.feed.stop()
        if self.page is not None:
            self.page.stop()
        if self.sink is not None:
            self.sink.stop()
        self.feed = self.page = self.sink = None
        self._session = None

    @property
    def ws_url(self) -> str:
        assert self.sink is not None
        return f"ws://{self.options.bind}:{self.sink.port}"

    @property
    def page_url(self) -> str:
        assert self.page is not None
        return self.page.url(self.options.bind)
