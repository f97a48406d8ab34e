"""RTK correction relay: whole RTCM3 / RTCA / CMR frames from one source to several rover ports.

- :mod:`~drivers.relay.frames`: pure framing and checks (:class:`CorrectionFramer`).
- :mod:`~drivers.relay.endpoints`: endpoint strings (serial, ``ntrip://``, ``tcp://``, ``file:``).
- :mod:`~drivers.relay.ntrip`: NTRIP 1/2 protocol pieces (requests, responses, chunked, GGA).
- :mod:`~drivers.relay.sources` / :mod:`~drivers.relay.sinks`: transports; each sink has its own
  worker and bounded queue.
- :mod:`~drivers.relay.relay`: :class:`Relay` (reader thread, fan-out, tap, statistics).

Typical use::

    relay = Relay(open_source("/dev/ttyUSB0@115200"), [open_sink("/dev/ttyUSB1"), open_sink("/dev/ttyUSB2")],
                  tap=recorder_tap)
    relay.start(); ...; relay.stats(); relay.stop()
"""

from drivers.relay.endpoints import (
    Endpoint,
    FileEndpoint,
    NtripEndpoint,
    Secret,
    SerialEndpoint,
    TcpEndpoint,
    mask_credentials,
    parse_endpoint,
)
from drivers.relay.frames import CorrectionFrame, CorrectionFramer, CorrectionFramerStats, CorrectionKind
from drivers.relay.relay import Relay, RelayState, RelayStats, RoverAge, TapCallback
from drivers.relay.sinks import Backoff, CallbackSink, FileSink, SerialSink, Sink, SinkStats, TcpSink, open_sink
from drivers.relay.sources import (
    FATAL_SOURCE_ERRORS,
    EndOfStream,
    FileSource,
    GgaProvider,
    NtripSource,
    PushSource,
    SerialSource,
    Source,
    TcpSource,
    open_source,
)

__all__ = [
    "FATAL_SOURCE_ERRORS",
    "Backoff",
    "CallbackSink",
    "CorrectionFrame",
    "CorrectionFramer",
    "CorrectionFramerStats",
    "CorrectionKind",
    "EndOfStream",
    "Endpoint",
    "FileEndpoint",
    "FileSink",
    "FileSource",
    "GgaProvider",
    "NtripEndpoint",
    "NtripSource",
    "PushSource",
    "Relay",
    "RelayState",
    "RelayStats",
    "RoverAge",
    "Secret",
    "SerialEndpoint",
    "SerialSink",
    "SerialSource",
    "Sink",
    "SinkStats",
    "Source",
    "TapCallback",
    "TcpEndpoint",
    "TcpSink",
    "TcpSource",
    "mask_credentials",
    "open_sink",
    "open_source",
    "parse_endpoint",
]
