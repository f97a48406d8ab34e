"""The live channels over the Foxglove WebSocket protocol (``foxglove.websocket.v1``), with the
``foxglove-sdk`` package's server.

One :class:`foxglove.Context` per server, so two live views (tests) never share channels. A
recorded topic keeps its recorded JSON schema (``foxglove.LocationFix`` for ``/gnss/*/fix``, the
``vsc_rig.*`` schemas for the rest) and its messages go out as recorded, byte for byte;
``/live/log`` uses the SDK's typed ``foxglove.Log``. The server advertises no capability (no client
publishing, services or parameters): clients can only subscribe.
"""

from __future__ import annotations

import logging
import threading

import foxglove
from foxglove.channels import LogChannel
from foxglove.messages import Log, LogLevel, Timestamp

import rig.topics as T  # noqa: N812 - topics used as a namespace
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

    def __init__(self, *, host: str, port: int, name: str) -> None:
        self.context = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self._lock = threading.Lock()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context,
                                                capabilities=[])
        except Exception as exc:  # the SDK raises its own RuntimeError for a bind failure
            raise ConfigError(f"--live {port} --live-bind {host}: cannot start the Foxglove server: {exc}") from exc
        self._log = LogChannel(TOPIC_LIVE_LOG, context=self.context)

    @property
    def port(self) -> int:
        return int(self.server.port)

    def publish(self, topic: str, schema: T.SchemaSpec, data: bytes, log_time_ns: int) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    ch = foxglove.Channel(
                        topic, message_encoding=schema.message_encoding, context=self.context,
                        schema=foxglove.Schema(name=schema.name, encoding=schema.schema_encoding, data=schema.data),
                    )
                    self._channels[topic] = ch
        ch.log(data, log_time=log_time_ns)

    def log(self, log_time_ns: int, severity: str, text: str, source: str) -> None:
        sec, nsec = divmod(log_time_ns, 1_000_000_000)
        self._log.log(Log(timestamp=Timestamp(sec=sec, nsec=nsec), level=_LEVELS.get(severity, LogLevel.Info),
                          message=text, name=source), log_time=log_time_ns)

    def stop(self) -> None:
        """Stop the server (clients are disconnected) and close the channels."""
        self.server.stop()
        for ch in self._channels.values():
            ch.close()
        self._log.close()
