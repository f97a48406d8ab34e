"""What the rig knows of each python-can interface: its clock, how it goes listen-only, the options it takes.

Checked against python-can 4.6's interface pages and its sources (``can/interfaces/*``): the option
names are the constructor parameters and the ``kwargs`` keys each backend reads. A ``[[can]]``
table's ``options`` are checked against :data:`PROFILES` before python-can sees them, because most
backends take ``**kwargs`` and silently drop a misspelt key.

Listen-only (:class:`ListenOnly`), per interface:

- ``pcan``: python-can's ``state=BusState.PASSIVE`` sets ``PCAN_LISTEN_ONLY`` (the controller
  neither acknowledges nor transmits);
- ``vector``: ``listen_only=True`` sets the channel's output mode to ``XL_OUTPUT_MODE_SILENT``
  (needs init access to the channel);
- ``kvaser``: ``driver_mode=False`` (python-can's ``DRIVER_MODE_SILENT``) sets ``canDRIVER_SILENT``;
- ``socketcan``: an ``ip link`` setting (``listen-only on``) that python-can cannot make; the rig
  reads it back (:mod:`drivers.can.socketcan_link`) and refuses an interface that would acknowledge;
- ``socketcand``: the protocol has no such command: it is the server's ``ip link`` setting, which the
  rig cannot see;
- ``virtual``: there is no controller and nothing to acknowledge.
"""

from __future__ import annotations

import difflib
import enum
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from vsccore.errors import ConfigError

__all__ = [
    "PROFILES",
    "RIG_KEYS",
    "TIMESTAMP_SOURCES",
    "FrameTime",
    "InterfaceProfile",
    "ListenOnly",
    "TimestampSource",
    "check_options",
    "default_frame_time",
    "listen_only_options",
    "profile_for",
    "timestamp_source_for",
]


class TimestampSource(enum.Enum):
    """Which clock a frame's device timestamp (``msg.timestamp``) was read from."""

    HARDWARE = "hardware"
    """The adapter's own counter, latched at the frame's end of frame (PCAN, Kvaser, Vector, …)."""
    KERNEL = "kernel"
    """Linux ``SO_TIMESTAMP(NS)`` taken in the CAN driver's receive path (SocketCAN; socketcand
    forwards the *server host's* kernel stamp, so it is a remote clock)."""
    HOST = "host"
    """python-can stamped ``time.time()`` in user space (virtual bus, slcan, serial adapters);
    as good as the host receive time and no better."""


class FrameTime(enum.Enum):
    """Which time places a frame on the session's time base (the ``[[can]]`` key ``timestamp_source``)."""

    INTERFACE = "interface"
    """The interface's stamp (``msg.timestamp``): its clock is fitted to the host's like any device clock."""
    HOST = "host"
    """The host receive time; the interface's stamp is still recorded as the frame's device time."""


class ListenOnly(enum.Enum):
    """How an interface is kept from acknowledging and transmitting on the bus."""

    OPTION = "option"
    """A python-can option sets it when the bus is opened (PCAN, Vector, Kvaser)."""
    IP_LINK = "ip_link"
    """An ``ip link`` setting of the interface, which the rig checks (SocketCAN)."""
    SERVER = "server"
    """Up to the server's interface; the rig cannot see it (socketcand)."""
    NONE = "none"
    """No controller: nothing is acknowledged (virtual bus)."""


# Per python-can interface name. Interfaces not listed are taken as HOST, the conservative choice:
# the time estimator then treats their stamps as carrying host latency.
TIMESTAMP_SOURCES: Mapping[str, TimestampSource] = MappingProxyType(
    {
        "socketcan": TimestampSource.KERNEL,
        "socketcand": TimestampSource.KERNEL,
        "pcan": TimestampSource.HARDWARE,
        "kvaser": TimestampSource.HARDWARE,
        "vector": TimestampSource.HARDWARE,
        "ixxat": TimestampSource.HARDWARE,
        "neovi": TimestampSource.HARDWARE,
        "etas": TimestampSource.HARDWARE,
        "nican": TimestampSource.HARDWARE,
        "nixnet": TimestampSource.HARDWARE,
        "systec": TimestampSource.HARDWARE,
        "virtual": TimestampSource.HOST,
        "slcan": TimestampSource.HOST,
        "serial": TimestampSource.HOST,
        "seeedstudio": TimestampSource.HOST,
        "udp_multicast": TimestampSource.HOST,
    }
)


def timestamp_source_for(interface: str) -> TimestampSource:
    """The clock that python-can's ``interface`` stamps received frames with (HOST if unknown)."""
    return TIMESTAMP_SOURCES.get(interface.lower(), TimestampSource.HOST)


def default_frame_time(interface: str) -> FrameTime:
    """Whether a frame's time comes from the interface's stamp or the host receive time, by default.

    INTERFACE where the stamp is taken closer to the bus than the rig's receive: the adapter's
    counter, the kernel's receive stamp (SocketCAN; socketcand forwards the server's), and the
    virtual bus, whose stamp is the *sender's* send time (``time.time()`` in ``send``, or the
    sender's own stamp with ``preserve_timestamps``, as the simulated ECU sends). HOST elsewhere: a
    stamp python-can takes in user space after the read (slcan, unknown interfaces) is no better.
    """
    name = interface.lower()
    if name == "virtual" or timestamp_source_for(name) is not TimestampSource.HOST:
        return FrameTime.INTERFACE
    return FrameTime.HOST


_COMMON = frozenset({"can_filters"})
"""Taken by every backend (``BusABC.__init__``)."""

RIG_KEYS: Mapping[str, str] = MappingProxyType(
    {
        "interface": "interface",
        "channel": "channel",
        "bitrate": "bitrate",
        "fd": "fd",
        "data_bitrate": "data_bitrate",
        "config_context": "the rig never reads python-can's configuration files for a [[can]] bus",
        "ignore_config": "the rig never reads python-can's configuration files for a [[can]] bus",
    }
)
"""Keys that are ``[[can]]`` keys of their own, not options (option → the key or reason to give)."""


@dataclass(frozen=True, slots=True)
class InterfaceProfile:
    """One python-can interface as the rig drives it."""

    name: str
    options: frozenset[str]
    """Option names its constructor takes (besides ``channel``, ``bitrate``, ``fd``, ``data_bitrate``)."""
    listen_only: ListenOnly
    listen_only_key: str | None = None
    """The python-can option that sets listen-only (set by the rig's ``listen_only`` key, not in ``options``)."""
    listen_only_values: tuple[Any, Any] = (None, None)
    """``(value for listen-only, value for active)`` of ``listen_only_key``."""


PROFILES: Mapping[str, InterfaceProfile] = MappingProxyType(
    {
        "socketcan": InterfaceProfile(
            "socketcan",
            _COMMON | {"receive_own_messages", "local_loopback", "ignore_rx_error_frames"},
            ListenOnly.IP_LINK,
        ),
        "socketcand": InterfaceProfile(
            "socketcand", _COMMON | {"host", "port", "tcp_tune"}, ListenOnly.SERVER
        ),
        "virtual": InterfaceProfile(
            "virtual",
            _COMMON | {"receive_own_messages", "rx_queue_size", "preserve_timestamps", "protocol"},
            ListenOnly.NONE,
        ),
        "pcan": InterfaceProfile(
            "pcan",
            _COMMON | {"device_id", "receive_own_messages", "auto_reset", "f_clock", "f_clock_mhz",
                       "nom_brp", "nom_tseg1", "nom_tseg2", "nom_sjw",
                       "data_brp", "data_tseg1", "data_tseg2", "data_sjw"},
            ListenOnly.OPTION,
            "state",
            ("PASSIVE", "ACTIVE"),  # python-can turns the name into can.BusState
        ),
        "vector": InterfaceProfile(
            "vector",
            _COMMON | {"poll_interval", "receive_own_messages", "rx_queue_size", "app_name", "serial",
                       "channel_index", "sjw_abr", "tseg1_abr", "tseg2_abr", "sjw_dbr", "tseg1_dbr", "tseg2_dbr"},
            ListenOnly.OPTION,
            "listen_only",
            (True, False),
        ),
        "kvaser": InterfaceProfile(
            "kvaser",
            _COMMON | {"tseg1", "tseg2", "sjw", "no_samp", "single_handle", "receive_own_messages", "exclusive",
                       "override_exclusive", "accept_virtual", "no_init_access", "fd_non_iso"},
            ListenOnly.OPTION,
            "driver_mode",
            (False, True),  # python-can's DRIVER_MODE_SILENT / DRIVER_MODE_NORMAL
        ),
    }
)
"""The interfaces whose options, listen-only setting and controller state the rig knows."""


def profile_for(interface: str) -> InterfaceProfile | None:
    """The profile of ``interface`` (None: an interface the rig passes to python-can unchecked)."""
    return PROFILES.get(interface.lower())


def check_options(interface: str, options: Mapping[str, Any], *, where: str) -> None:
    """Refuse an option ``interface`` does not take, naming the key, the interface and the fix.

    ``where`` is the key path of the options table (``"can 'vsc'.options"``). Interfaces without a
    profile are not checked (a third-party backend may take anything).

    Raises:
        ConfigError: an option is a ``[[can]]`` key of its own, the interface's listen-only switch
            (set with ``listen_only``), or not an option of that interface.
    """
    profile = profile_for(interface)
    for key in options:
        if key in RIG_KEYS:
            fix = RIG_KEYS[key]
            hint = f"give the [[can]] key {fix!r} instead" if fix == key else fix
            raise ConfigError(f"{where}.{key}: not an option ({hint})")
        if profile is None:
            continue
        if key == profile.listen_only_key:
            raise ConfigError(
                f"{where}.{key}: python-can's {profile.name!r} interface sets listen-only with {key!r}; "
                "give the [[can]] key listen_only = true | false instead"
            )
        if key not in profile.options:
            close = difflib.get_close_matches(key, sorted(profile.options), n=2)
            hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            raise ConfigError(
                f"{where}.{key}: python-can's {profile.name!r} interface takes no option {key!r}{hint} "
                f"(it takes: {', '.join(sorted(profile.options))})"
            )


def listen_only_options(interface: str, listen_only: bool | None) -> dict[str, Any]:
    """The python-can option that puts ``interface`` in listen-only (or active) mode; empty where
    python-can has none (SocketCAN, socketcand, virtual, unknown interfaces) or when not asked."""
    profile = profile_for(interface)
    if listen_only is None or profile is None or profile.listen_only_key is None:
        return {}
    silent, active = profile.listen_only_values
    return {profile.listen_only_key: silent if listen_only else active}
