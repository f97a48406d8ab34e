"""The live channels over the Foxglove WebSocket protocol (``foxglove.websocket.v1``), with the
``foxglove-sdk`` package's server.

One :class:`foxglove.Context` per server, so two live views (tests) never share channels. A
recorded topic keeps its recorded JSON schema (``foxglove.LocationFix`` for ``/gnss/*/fix``, the
``vsc_rig.*`` schemas for the rest) and its messages go out as recorded, byte for byte;
``/live/log`` uses the SDK's typed ``foxglove.Log``. The server advertises no capability (no client
publishing, services or parameters): clients can only subscribe.

The channels known at the start are created before the server listens: foxglove-sdk 0.30.3 can advertise
a channel created while a client connects without entering it in that client's channel table, so the
client's subscribe is refused ("Unknown channel ID") and the topic stays empty for that client until it
reconnects (seen in 7 of 20 trials of a connect racing 20 channel creations). Channels of topics not
foreseen are still created on first use.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping

import foxglove
from foxglove.channels import LogChannel
from foxglove.messages import Log, LogLevel, Timestamp

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.live.feed import TOPIC_LIVE_LOG
from vsccore.errors import ConfigError

__all__ = ["FoxgloveSink"]

log = logging.getLogger(__name__)

_LEVELS = {"info": LogLevel.Info, "warning": LogLevel.Warning, "error": LogLevel.Error}


class FoxgloveSink:
    """A running Foxglove WebSocket server and its channels (a :class:`~rig.live.feed.LiveSink`).

    Raises:
        ConfigError: the address or port cannot be bound (in use, not an address of this host).
    """

    def __init__(self, *, host: str, port: int, name: str, channels: Mapping[str, T.SchemaSpec] | None = None) -> None:
        self.context = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self._lock = threading.Lock()
        self._log = LogChannel(TOPIC_LIVE_LOG, context=self.context)
        for topic, schema in (channels or {}).items():  # before the server listens: see the module docstring
            self._channels[topic] = self._channel(topic, schema)
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context,
                                                capabilities=[])
        except Exception as exc:  # the SDK raises its own RuntimeError for a bind failure
            self._close_channels()
            raise ConfigError(f"--live {port} --live-bind {host}: cannot start the Foxglove server: {exc}") from exc

    def _channel(self, topic: str, schema: T.SchemaSpec) -> foxglove.Channel:
        return foxglove.Channel(
            topic, message_encoding=schema.message_encoding, context=self.context,
            schema=foxglove.Schema(name=schema.name, encoding=schema.schema_encoding, data=schema.data),
        )

    @property
    def topics(self) -> list[str]:
        """The channels created so far (``/live/log`` included)."""
        return [TOPIC_LIVE_LOG, *self._channels]

    @property
    def port(self) -> int:
        return int(self.server.port)

    def publish(self, topic: str, schema: T.SchemaSpec, data: bytes, log_time_ns: int) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    ch = self._channels[topic] = self._channel(topic, schema)
        ch.log(data, log_time=log_time_ns)

    def log(self, log_time_ns: int, severity: str, text: str, source: str) -> None:
        sec, nsec = divmod(log_time_ns, 1_000_000_000)
        self._log.log(Log(timestamp=Timestamp(sec=sec, nsec=nsec), level=_LEVELS.get(severity, LogLevel.Info),
                          message=text, name=source), log_time=log_time_ns)

    def stop(self) -> None:
        """Stop the server (clients are disconnected) and close the channels."""
        self.server.stop()
        self._close_channels()

    def _close_channels(self) -> None:
        for ch in self._channels.values():
            ch.close()
        self._log.close()
