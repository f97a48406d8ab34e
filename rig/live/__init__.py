"""The live view of a recording session: Foxglove WebSocket channels and a status page for a phone.

``rig record … --live`` attaches a :class:`LiveView` to the running :class:`~rig.record.recording.Recording`:

- the recorder's writer thread hands every written message to :meth:`LiveFeed.offer` (the
  recorder's ``tap``), which appends it to a bounded drop-oldest queue and returns: the live view
  never makes the recorder wait, a slow phone costs live messages, never recorded ones;
- one thread of its own (:class:`LiveFeed`) drains that queue, decimates every plot channel to
  ``max_rate_hz`` (50 Hz, ``full_rate`` for everything), derives what is not a recorded topic (the
  live β reference against the VSC estimate, LTR, the status document) and publishes it through
  the Foxglove SDK's WebSocket server (:mod:`rig.live.server`);
- a small HTTP server (:mod:`rig.live.page`) serves the status page and its JSON.

Binding anything but a loopback address needs a token (``--live-token`` or ``RIG_LIVE_TOKEN``).
The status page and its JSON check it on every request. The Foxglove SDK (0.30) has no hook to
accept or refuse a WebSocket connection, so with a token its server listens on 127.0.0.1 only and
the token gate (:mod:`rig.live.gate`) on the bound address refuses a WebSocket upgrade without the
token (HTTP 401) and relays the authenticated ones. The server advertises no capability that lets a
client publish, call services or set parameters. The token is a
:class:`~drivers.relay.endpoints.Secret`: the addresses shown and logged carry ``token=***``.
"""

from rig.live.feed import LIVE_TOPICS, LiveFeed, LiveOptions, LiveSink, foxglove_time
from rig.live.view import LiveView

__all__ = ["LIVE_TOPICS", "LiveFeed", "LiveOptions", "LiveSink", "LiveView", "foxglove_time"]
