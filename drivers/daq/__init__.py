"""DAQ layer: backend interface and registry, reader session, channel health and sync-edge detection.

Backends are chosen by name (:func:`create_backend`): ``nidaqmx`` for National Instruments
hardware, ``sim`` for the simulated DAQ, and any third-party backend registered under the
entry-point group ``vsc_rig.daq_backends``.
"""

from .base import (
    DaqBackend,
    DaqBlock,
    DaqChannelConfig,
    DaqEvent,
    DaqEventKind,
    LostSamples,
    TerminalConfig,
)
from .health import ChannelHealth, HealthLimits
from .link import DaqLink, ReconnectPolicy
from .registry import ENTRY_POINT_GROUP, create_backend, known_backends, resolve_backend
from .sync import Edge, EdgePolarity, SampleClockFit, SyncEdgeDetector, find_edges, fit_sample_clock

__all__ = [
    "ENTRY_POINT_GROUP",
    "ChannelHealth",
    "DaqBackend",
    "DaqBlock",
    "DaqChannelConfig",
    "DaqEvent",
    "DaqEventKind",
    "DaqLink",
    "Edge",
    "EdgePolarity",
    "HealthLimits",
    "LostSamples",
    "ReconnectPolicy",
    "SampleClockFit",
    "SyncEdgeDetector",
    "TerminalConfig",
    "create_backend",
    "find_edges",
    "fit_sample_clock",
    "known_backends",
    "resolve_backend",
]
