"""Live CAN bus session: one python-can interface, every frame with its device and host time.

:class:`CanBusLink` opens any python-can interface named in a :class:`CanBusConfig`
(``socketcan``, ``pcan``, ``kvaser``, ``vector``, ``slcan``, ``socketcand``, ``virtual``, …) and
runs one reader thread that hands every frame, error frames included, to a consumer callback as
a frozen :class:`CanFrame`. It keeps bus statistics (frames/s, bus load from the frames' bit
lengths with their stuff bits, error-frame counts, controller state) and recovers by itself from
a bus-off controller and from an interface that disappears (a USB adapter pulled, a socketcand
server gone): close, back off on the stop event, reopen, and report the gap as a :class:`BusGap`
event with its start and end host times. ``stop()`` returns promptly, even during a back-off.

What differs between interfaces lives beside this module: option names, listen-only and clocks in
:mod:`drivers.can.interfaces`, controller-state decoding in :mod:`drivers.can.controller`, PCAN FD
timing in :mod:`drivers.can.timing`, SocketCAN bring-up checks in :mod:`drivers.can.socketcan_link`.
Every frame says which clock its device stamp came from (:class:`TimestampSource`); whether that
stamp or the host receive time places it on the session's time base is the bus's
:class:`FrameTime`. The host receive time always comes from the injected
:class:`~vsccore.clock.Clock` so simulated sessions stay on one time base.

Only python-can ``Message`` objects are handled here; decoding signals is ``drivers.can.roles``'s job.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import logging
import os
import re
import socket
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import can
from can.util import len2dlc

from drivers.can._records import positional_constructor
from drivers.can.controller import (
    BusState,
    ControllerMonitor,
    ControllerReport,
    controller_monitor_for,
    error_counters_from_error_frame,
    state_from_error_frame,
)
from drivers.can.interfaces import (
    TIMESTAMP_SOURCES,
    FrameTime,
    ListenOnly,
    TimestampSource,
    check_options,
    default_frame_time,
    listen_only_options,
    profile_for,
    timestamp_source_for,
)
from drivers.can.socketcan_link import SocketcanLink, check_link, read_link
from drivers.can.timing import DEFAULT_DATA_SAMPLE_POINT, DEFAULT_SAMPLE_POINT, PCAN_FD_TIMING_KEYS, pcan_fd_timing
from vsccore.clock import Clock
from vsccore.errors import ConfigError, DeviceError, DeviceTimeoutError

__all__ = [
    "TIMESTAMP_SOURCES",
    "BusEvent",
    "BusGap",
    "BusLoadMeter",
    "BusLost",
    "BusOpened",
    "BusState",
    "BusStateChanged",
    "BusStats",
    "CanBusConfig",
    "CanBusLink",
    "CanFrame",
    "CanFrameFlag",
    "FrameTime",
    "TimestampSource",
    "bus_notes",
    "crc15_can",
    "error_counters_from_error_frame",
    "frame_bit_times",
    "open_bus",
    "pcan_options",
    "state_from_error_frame",
    "timestamp_source_for",
]

log = logging.getLogger(__name__)


class CanFrameFlag(enum.Flag):
    """Properties of a received frame besides identifier and payload."""

    NONE = 0
    ERROR_FRAME = enum.auto()
    """An error report from the controller (its encoding depends on the interface: drivers.can.controller)."""
    REMOTE = enum.auto()
    BITRATE_SWITCH = enum.auto()
    ERROR_STATE_INDICATOR = enum.auto()
    TX_ECHO = enum.auto()
    """The interface's echo of a frame this host sent (``msg.is_rx`` false)."""


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One frame as received, with both its times."""

    device_ts_ns: int | None
    """``msg.timestamp`` in ns on the clock named by ``timestamp_source`` (None if the interface gave none)."""
    host_ts_ns: int
    """Host receive time from the session's :class:`~vsccore.clock.Clock` (ns since the Unix epoch)."""
    arbitration_id: int
    is_extended: bool
    is_fd: bool
    dlc: int
    """Data length code as on the wire (0..15; for CAN FD the code, not the byte count)."""
    data: bytes
    flags: CanFrameFlag
    timestamp_source: TimestampSource
    channel: str


_new_frame = positional_constructor(CanFrame)
_NO_FLAGS = CanFrameFlag.NONE

# --- events ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BusOpened:
    """The interface was opened (at start and after every recovery)."""

    host_ts_ns: int
    bus: str
    interface: str
    channel: str
    channel_info: str
    timestamp_source: TimestampSource
    frame_time: FrameTime = FrameTime.INTERFACE
    """Whether the interface's stamps or the host receive times place the frames on the time base."""
    listen_only: bool | None = None
    """The listen-only setting asked for (None: the interface's own default)."""
    notes: tuple[str, ...] = ()
    """What the rig could not set or check on this interface (worth a warning)."""


@dataclass(frozen=True, slots=True)
class BusLost:
    """Reception stopped: the interface failed, went bus-off or fell silent; a gap begins."""

    host_ts_ns: int
    bus: str
    reason: str


@dataclass(frozen=True, slots=True)
class BusGap:
    """A span without reception, reported when it ends (reopened or restarted) or when the session stops."""

    start_ns: int
    """Host time at which the loss was detected."""
    end_ns: int
    """Host time at which the interface was open again, or the controller back from bus-off (or the session stopped)."""
    bus: str
    reason: str
    reopen_attempts: int
    """0 when the controller came back by itself (SocketCAN's ``restart-ms``) without a reopen."""
    recovered: bool
    """False when the session was stopped before the interface came back."""
    last_frame_ns: int | None
    """Host time of the last frame received before the gap (None if there was none)."""


@dataclass(frozen=True, slots=True)
class BusStateChanged:
    """The controller state changed (as the interface reports it: drivers.can.controller)."""

    host_ts_ns: int
    bus: str
    previous: BusState
    state: BusState


@dataclass(frozen=True, slots=True)
class BusStats:
    """Statistics of the bus: totals since start, rates over the last ``window_s``."""

    host_ts_ns: int
    bus: str
    state: BusState
    frames_total: int
    error_frames_total: int
    gaps_total: int
    frames_per_s: float
    error_frames_per_s: float
    bus_load_pct: float | None
    """Share of bit time occupied by the frames in the window (None when the bitrate is unknown)."""
    window_s: float
    tx_error_counter: int | None = None
    """The controller's transmit error counter (TEC) from its last error report (None: never reported)."""
    rx_error_counter: int | None = None
    """The controller's receive error counter (REC) from its last error report (None: never reported)."""


BusEvent = BusOpened | BusLost | BusGap | BusStateChanged | BusStats


# --- configuration and opening -----------------------------------------------------------------

_FRAME_TIMES = {t.value: t for t in FrameTime}
_CLOCKS = {s.value: s for s in TimestampSource if s is not TimestampSource.HOST}


@dataclass(frozen=True, slots=True)
class CanBusConfig:
    """How to open one CAN bus through python-can.

    ``options`` are passed to ``can.Bus`` as they are (``host``/``port`` for socketcand,
    ``receive_own_messages``, vendor options …), checked first against what the interface takes
    (:func:`drivers.can.interfaces.check_options`). ``listen_only``: True keeps the controller from
    acknowledging and transmitting (how, per interface: :mod:`drivers.can.interfaces`), False makes it
    active, None leaves python-can's default (active; :class:`CanBusLink`, which only reads, takes
    None as True). ``frame_time`` overrides the per-interface default of
    :func:`drivers.can.interfaces.default_frame_time`; ``timestamp_source`` the clock of the stamps
    (:func:`timestamp_source_for`, e.g. an slcan adapter with hardware stamps). ``sample_point`` and
    ``data_sample_point`` (fractions) are used where the rig derives a timing (PCAN FD).
    """

    interface: str
    channel: str
    bitrate: int | None = 500_000
    fd: bool = False
    data_bitrate: int | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    name: str = "can"
    timestamp_source: TimestampSource | None = None
    listen_only: bool | None = None
    frame_time: FrameTime | None = None
    sample_point: float | None = None
    data_sample_point: float | None = None

    def __post_init__(self) -> None:
        where = f"can {self.name!r}"
        if not self.interface:
            raise ConfigError(f"{where}.interface: must name a python-can interface")
        if self.bitrate is not None and self.bitrate <= 0:
            raise ConfigError(f"{where}.bitrate: must be > 0, got {self.bitrate}")
        if self.data_bitrate is not None:
            if not self.fd:
                raise ConfigError(f"{where}.data_bitrate: given but fd is false")
            if self.data_bitrate <= 0:
                raise ConfigError(f"{where}.data_bitrate: must be > 0, got {self.data_bitrate}")
        for key in ("sample_point", "data_sample_point"):
            value = getattr(self, key)
            if value is not None and not 0.5 <= value < 1.0:
                raise ConfigError(f"{where}.{key}: a fraction of the bit time in [0.5, 1), got {value}")
        check_options(self.interface, self.options, where=f"{where}.options")
        pcan_options(self)  # a PCAN FD bus without a derivable timing is refused here, naming the keys

    @property
    def clock(self) -> TimestampSource:
        """The clock of ``msg.timestamp`` for this interface."""
        return self.timestamp_source or timestamp_source_for(self.interface)

    @property
    def time_from(self) -> FrameTime:
        """Whether the interface's stamps or the host receive times place frames on the time base."""
        return self.frame_time or default_frame_time(self.interface)

    @property
    def uses_interface_stamps(self) -> bool:
        """True when the frames' device stamps (not their host receive times) are to be trusted."""
        return self.time_from is FrameTime.INTERFACE

    def describe(self) -> str:
        """``"name (interface channel)"`` for messages and logs."""
        return f"CAN bus {self.name!r} ({self.interface} {self.channel})"

    @classmethod
    def from_mapping(cls, table: Mapping[str, Any], **overrides: Any) -> CanBusConfig:
        """Build from a ``[[can]]`` table of the session configuration (e.g. a pydantic ``model_dump()``).

        Reads ``name``, ``interface``, ``channel``, ``bitrate``, ``fd``, ``data_bitrate``,
        ``listen_only``, ``timestamp_source`` (``"interface"`` or ``"host"``; ``"hardware"`` or
        ``"kernel"`` name the stamps' clock and mean ``"interface"``), ``sample_point``,
        ``data_sample_point``, and ``host`` / ``port`` (socketcand), which go into ``options``; an
        ``options`` table is passed to python-can as it is. Other keys (``dbc``, ``roles`` …) are
        ignored here. ``overrides`` replace fields (e.g. ``channel=`` from a command-line option);
        ``None`` values in ``table`` or ``overrides`` mean "not given".

        Raises:
            ConfigError: a missing interface or channel, or an invalid value (the key is named).
        """
        merged = {k: v for k, v in table.items() if v is not None}
        merged.update({k: v for k, v in overrides.items() if v is not None})
        name = str(merged.get("name", "can"))
        options: dict[str, Any] = dict(merged.get("options") or {})
        for key in ("host", "port"):
            if key in merged:
                options[key] = merged[key]
        for key in ("interface", "channel"):
            if not merged.get(key):
                raise ConfigError(f"can {name!r}.{key}: missing (required)")
        source = merged.get("timestamp_source")
        clock: TimestampSource | None = None
        frame_time: FrameTime | None = None
        if isinstance(source, FrameTime):
            frame_time = source
        elif isinstance(source, TimestampSource):
            clock = source
        elif source is not None:
            text = str(source).lower()
            if text in _FRAME_TIMES:
                frame_time = _FRAME_TIMES[text]
            elif text in _CLOCKS:
                clock, frame_time = _CLOCKS[text], FrameTime.INTERFACE
            else:
                raise ConfigError(f"can {name!r}.timestamp_source: {source!r} is not one of interface, host "
                                  "(or the stamps' clock: hardware, kernel)")
        return cls(
            interface=str(merged["interface"]),
            channel=str(merged["channel"]),
            bitrate=merged.get("bitrate", 500_000),
            fd=bool(merged.get("fd", False)),
            data_bitrate=merged.get("data_bitrate"),
            options=options,
            name=name,
            timestamp_source=clock,
            listen_only=merged.get("listen_only"),
            frame_time=frame_time,
            sample_point=merged.get("sample_point"),
            data_sample_point=merged.get("data_sample_point"),
        )


def pcan_options(config: CanBusConfig) -> dict[str, int]:
    """The PCAN FD timing options python-can needs for ``config`` (empty when not a PCAN FD bus).

    A timing given in ``options`` is used as it is when complete; otherwise it is derived from
    ``bitrate`` and ``data_bitrate`` (:func:`drivers.can.timing.pcan_fd_timing`).

    Raises:
        ConfigError: a partial timing in ``options``, no ``data_bitrate``, or no PCAN timing giving
            both bitrates exactly; the message names the keys to give.
    """
    if config.interface.lower() != "pcan" or not config.fd:
        return {}
    where = f"can {config.name!r}"
    given = [k for k in ("f_clock", "f_clock_mhz", *PCAN_FD_TIMING_KEYS) if k in config.options]
    if given:
        missing = [k for k in PCAN_FD_TIMING_KEYS if k not in config.options]
        if "f_clock" not in config.options and "f_clock_mhz" not in config.options:
            missing.insert(0, "f_clock (or f_clock_mhz)")
        if missing:
            raise ConfigError(f"{where}.options: a PCAN FD timing needs all of its keys; missing {', '.join(missing)} "
                              f"(or give none, and bitrate, data_bitrate and sample points to derive it)")
        return {}
    if config.bitrate is None or config.data_bitrate is None:
        raise ConfigError(f"{where}.data_bitrate: a PCAN FD bus needs bitrate and data_bitrate to derive its timing "
                          f"(or the timing in options: f_clock, {', '.join(PCAN_FD_TIMING_KEYS)})")
    timing = pcan_fd_timing(
        config.bitrate, config.data_bitrate,
        sample_point=config.sample_point or DEFAULT_SAMPLE_POINT,
        data_sample_point=config.data_sample_point or DEFAULT_DATA_SAMPLE_POINT,
        where=where,
    )
    return timing.as_options()


def bus_notes(config: CanBusConfig, *, read_socketcan: Callable[[str], SocketcanLink] = read_link
              ) -> tuple[str, ...]:
    """What the rig cannot set or see on ``config``'s interface (listen-only, controller state), and
    for SocketCAN what its ``ip link`` settings are worth a warning for (``restart-ms`` 0)."""
    notes: list[str] = []
    if config.interface.lower() == "socketcan":
        with contextlib.suppress(DeviceError):  # open_bus refuses such an interface with the same message
            notes.extend(check_link(read_socketcan(str(config.channel)), bitrate=config.bitrate,
                                    listen_only=config.listen_only, where=config.describe()))
    profile = profile_for(config.interface)
    if config.listen_only:
        if profile is None:
            notes.append(f"listen-only is not known for interface {config.interface!r}: check the adapter's settings")
        elif profile.listen_only is ListenOnly.SERVER:
            notes.append("listen-only is the socketcand server's interface setting (ip link … listen-only on), "
                         "which the rig cannot check")
    monitor_note = controller_monitor_for(config.interface).note
    if monitor_note:
        notes.append(monitor_note)
    if config.interface.lower() == "socketcan" and config.options.get("ignore_rx_error_frames"):
        notes.append("ignore_rx_error_frames: the controller's error frames, and so its state, are not received")
    return tuple(notes)


class _SocketcandFragmentFilter(logging.Filter):
    """Drops python-can's socketcand warning for a frame split across TCP reads, which is normal on a
    stream socket (the rest arrives with the next read) and comes hundreds of times a minute."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Got incomplete message")


_SOCKETCAND_LOGGER = "can.interfaces.socketcand.socketcand"
_socketcand_filter = _SocketcandFragmentFilter()


def _probe_socketcand(config: CanBusConfig, timeout_s: float) -> None:
    """Fail fast when no socketcand server answers or it does not serve the channel.

    python-can's client retries ``connect`` for 10 s, waits for ``< hi >`` without a timeout,
    and leaks its socket when the handshake fails; that would make a session's reopen (and so its
    ``stop()``) hang. This probe runs the greeting and ``< open >`` with a short timeout first.
    """
    host = str(config.options.get("host", "127.0.0.1"))
    port = int(config.options.get("port", 29536))
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as sock:
            sock.settimeout(timeout_s)
            greeting = sock.recv(64)
            if not greeting.startswith(b"< hi >"):
                raise DeviceError(
                    f"{config.describe()}: {host}:{port} did not greet as socketcand (got {greeting[:20]!r})"
                )
            sock.sendall(f"< open {config.channel} >".encode("ascii", errors="replace"))
            reply = sock.recv(64)
    except OSError as exc:
        raise DeviceError(f"{config.describe()}: no socketcand server at {host}:{port}: {exc}") from exc
    if not reply.startswith(b"< ok >"):
        raise DeviceError(
            f"{config.describe()}: socketcand server {host}:{port} refused bus {config.channel!r} ({reply[:40]!r})"
        )


_UNEXPECTED_KEY = re.compile(r"unexpected keyword argument '(\w+)'")


def open_bus(config: CanBusConfig, *, probe_timeout_s: float = 1.0,
             read_socketcan: Callable[[str], SocketcanLink] = read_link) -> can.BusABC:
    """Open the python-can interface of ``config``.

    The bitrate is passed when known; ``fd`` and ``data_bitrate`` only for CAN FD, so classic
    interfaces that do not accept them are not bothered; a PCAN FD bus gets its derived timing
    (:func:`pcan_options`); ``listen_only`` becomes the interface's own option
    (:func:`drivers.can.interfaces.listen_only_options`). A SocketCAN interface is checked first
    (:func:`drivers.can.socketcan_link.check_link`: up, bitrate, listen-only); ``read_socketcan``
    replaces :func:`~drivers.can.socketcan_link.read_link` (tests).

    Raises:
        ConfigError: python-can's interface refused an option (the option and the interface are named).
        DeviceError: the interface cannot be opened (unknown interface name, missing driver,
            adapter not present, SocketCAN interface down or not set up, socketcand server not
            answering); the message names the bus and, where known, the fix.
    """
    kwargs: dict[str, Any] = dict(config.options)
    if config.bitrate is not None:
        kwargs["bitrate"] = config.bitrate
    if config.fd:
        kwargs["fd"] = True
        if config.data_bitrate is not None:
            kwargs["data_bitrate"] = config.data_bitrate
    kwargs.update(pcan_options(config))
    kwargs.update(listen_only_options(config.interface, config.listen_only))
    interface = config.interface.lower()
    if interface == "socketcan":
        check_link(read_socketcan(str(config.channel)), bitrate=config.bitrate,
                   data_bitrate=config.data_bitrate if config.fd else None, listen_only=config.listen_only,
                   where=config.describe())
    if interface == "socketcand":
        _probe_socketcand(config, probe_timeout_s)
        logging.getLogger(_SOCKETCAND_LOGGER).addFilter(_socketcand_filter)  # idempotent
        if os.name != "nt":
            # TCP_NODELAY on the client socket (python-can's default is off): without it Nagle's
            # algorithm holds a small ``< send >`` command back until the previous one is
            # acknowledged, and delayed ACKs make that up to 40 ms (a replayed frame sent that late)
            kwargs.setdefault("tcp_tune", True)
    try:
        return can.Bus(interface=config.interface, channel=config.channel, **kwargs)
    except TypeError as exc:
        rejected = _UNEXPECTED_KEY.search(str(exc))
        key = rejected.group(1) if rejected else None
        if key is not None:
            raise ConfigError(f"can {config.name!r}.options.{key}: python-can's {config.interface!r} interface "
                              f"does not take {key!r} ({exc})") from exc
        raise DeviceError(f"{config.describe()}: cannot open: {exc}") from exc
    except ValueError as exc:
        given = ", ".join(sorted(config.options)) or "none given"
        raise DeviceError(f"{config.describe()}: python-can's {config.interface!r} interface refused its settings "
                          f"(options: {given}): {exc}") from exc
    except (can.CanError, OSError, ImportError) as exc:
        raise DeviceError(f"{config.describe()}: cannot open: {exc}") from exc


# --- frame bit lengths and bus load ------------------------------------------------------------

_CRC15_POLY = 0x4599


def crc15_can(bits: list[int]) -> int:
    """CAN CRC-15 (polynomial 0x4599, init 0) over a bit sequence, MSB first."""
    crc = 0
    for bit in bits:
        nxt = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= _CRC15_POLY
    return crc


def _bits(value: int, width: int) -> list[int]:
    return [(value >> i) & 1 for i in range(width - 1, -1, -1)]


def _stuff_bits(bits: list[int]) -> int:
    """Number of stuff bits the transmitter inserts into ``bits`` (after five equal bits, one opposite)."""
    count = 0
    run = 0
    last = -1
    for bit in bits:
        if bit == last:
            run += 1
        else:
            last, run = bit, 1
        if run == 5:
            count += 1
            # the stuff bit is the complement and starts a new run of length 1
            last, run = 1 - bit, 1
    return count


# Fixed-form bits after the CRC: CRC delimiter, ACK slot, ACK delimiter, 7 EOF, 3 intermission.
_TAIL_BITS = 13

# --- the same on integers, table-driven (the live path computes this for every frame) ----------
# A frame's bits are held MSB-first in one int. CRC-15 runs a byte at a time; the bit string is
# zero-padded at the front to whole bytes, which leaves a CRC with initial value 0 unchanged. Stuff
# bits are counted by a state machine over bytes: the state is (last bit, run length 1..4) or
# "start", and a table per chunk width maps (state, chunk) to (next state, stuff bits inserted).


def _crc15_byte_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ _CRC15_POLY) if crc & 0x4000 else crc << 1
            crc &= 0x7FFF
        table.append(crc)
    return tuple(table)


_CRC15_TABLE = _crc15_byte_table()
_N_STUFF_STATES = 9  # 0: start; 1 + 4·last + (run − 1)


def _stuff_tables() -> tuple[tuple[int, ...], ...]:
    """``tables[w][state·256 + chunk]`` for a ``w``-bit chunk = ``next_state·1024 + stuff_bits``."""
    tables: list[tuple[int, ...]] = [()]
    for width in range(1, 9):
        table = [0] * (_N_STUFF_STATES * 256)
        for state in range(_N_STUFF_STATES):
            for chunk in range(1 << width):
                last, run = (-1, 0) if state == 0 else ((state - 1) // 4, (state - 1) % 4 + 1)
                count = 0
                for i in range(width - 1, -1, -1):
                    bit = (chunk >> i) & 1
                    if bit == last:
                        run += 1
                    else:
                        last, run = bit, 1
                    if run == 5:
                        count += 1
                        last, run = 1 - bit, 1
                table[state * 256 + chunk] = (1 + 4 * last + run - 1) * 1024 + count
        tables.append(tuple(table))
    return tuple(tables)


_STUFF_TABLES = _stuff_tables()
_STUFF8 = _STUFF_TABLES[8]


def _stuff_count_int(value: int, n_bits: int) -> int:
    """Stuff bits inserted into the ``n_bits``-bit string ``value`` (MSB first; same as :func:`_stuff_bits`)."""
    if n_bits <= 0:
        return 0
    nbytes = (n_bits + 7) >> 3
    data = value.to_bytes(nbytes, "big")
    r = _STUFF_TABLES[n_bits - 8 * (nbytes - 1)][data[0]]
    count = 0
    table = _STUFF8
    for b in data[1:]:
        count += r & 3
        r = table[(r >> 2) + b]
    return count + (r & 3)


def _crc15_int(value: int, n_bits: int) -> int:
    """CAN CRC-15 of the ``n_bits``-bit string ``value`` (MSB first; same as :func:`crc15_can`)."""
    crc = 0
    table = _CRC15_TABLE
    for b in value.to_bytes((n_bits + 7) >> 3, "big"):
        crc = ((crc << 8) & 0x7FFF) ^ table[((crc >> 7) ^ b) & 0xFF]
    return crc


def frame_bit_times(
    arbitration_id: int,
    is_extended: bool,
    data: bytes,
    *,
    dlc: int | None = None,
    is_remote: bool = False,
    is_fd: bool = False,
    bitrate_switch: bool = False,
) -> tuple[int, int]:
    """Bits on the wire of one frame, as ``(nominal_rate_bits, data_rate_bits)``.

    Classic CAN frames are exact: the CRC-15 is computed and the stuff bits of SOF … CRC are
    counted as the transmitter inserts them; the 3-bit intermission is included. CAN FD frames
    are an estimate: dynamic stuff bits are counted over SOF … data, the CRC field (stuff count,
    CRC-17/21 and its fixed stuff bits) is taken at its nominal length. With bit-rate switching
    the bits from BRS to the CRC delimiter run at the data bitrate and are returned separately.
    (Computed on integers with tables; :func:`_frame_bit_times_reference` is the bit-list original.)
    """
    n = len(data)
    code = (len2dlc(n) if dlc is None else dlc) & 0xF
    # SOF (0) and the identifier: base 11 bits; extended 11 + SRR (1) + IDE (1) + 18
    if is_extended:
        header, h_len = ((((arbitration_id >> 18) & 0x7FF) << 20) | 0xC0000 | (arbitration_id & 0x3FFFF)), 32
    else:
        header, h_len = arbitration_id & 0x7FF, 12
    payload = int.from_bytes(data, "big") if n else 0
    p_len = 8 * n
    if not is_fd:
        # RTR, (IDE, r0) or (r1, r0), DLC
        body = (header << 7) | (64 if is_remote else 0) | code
        b_len = h_len + 7
        if not is_remote:
            body = (body << p_len) | payload
            b_len += p_len
        # _crc15_int and _stuff_count_int inlined (this runs for every frame on the bus)
        crc = 0
        for b in body.to_bytes((b_len + 7) >> 3, "big"):
            crc = ((crc << 8) & 0x7FFF) ^ _CRC15_TABLE[((crc >> 7) ^ b) & 0xFF]
        n_bits = b_len + 15
        nbytes = (n_bits + 7) >> 3
        raw = ((body << 15) | crc).to_bytes(nbytes, "big")
        r = _STUFF_TABLES[n_bits - 8 * (nbytes - 1)][raw[0]]
        stuff = 0
        for b in raw[1:]:
            stuff += r & 3
            r = _STUFF8[(r >> 2) + b]
        return n_bits + stuff + (r & 3) + _TAIL_BITS, 0
    # CAN FD: RRS, IDE (base frames only; extended ones have it above), FDF, res, BRS | ESI, DLC
    if is_extended:
        arb, a_len = (header << 4) | 4 | (1 if bitrate_switch else 0), h_len + 4
    else:
        arb, a_len = (header << 5) | 4 | (1 if bitrate_switch else 0), h_len + 5
    d_len = a_len + 5 + p_len
    dyn_stuff = _stuff_count_int((((arb << 5) | code) << p_len) | payload, d_len)
    crc_len = 17 if n <= 16 else 21
    crc_field = 4 + crc_len + (4 + crc_len + 3) // 4 + 1  # stuff count, CRC, fixed stuff bits
    arb_share = a_len / d_len
    arb_bits = a_len + round(dyn_stuff * arb_share) + _TAIL_BITS
    data_bits = 5 + p_len + (dyn_stuff - round(dyn_stuff * arb_share)) + crc_field
    if bitrate_switch:
        return arb_bits, data_bits
    return arb_bits + data_bits, 0


def _frame_bit_times_reference(
    arbitration_id: int,
    is_extended: bool,
    data: bytes,
    *,
    dlc: int | None = None,
    is_remote: bool = False,
    is_fd: bool = False,
    bitrate_switch: bool = False,
) -> tuple[int, int]:
    """:func:`frame_bit_times` on lists of bits, one bit at a time: the readable reference (tests, benchmark)."""
    n = len(data)
    code = len2dlc(n) if dlc is None else dlc
    payload = [b for byte in data for b in _bits(byte, 8)]
    if is_extended:
        header = [0, *_bits(arbitration_id >> 18, 11), 1, 1, *_bits(arbitration_id & 0x3FFFF, 18)]
    else:
        header = [0, *_bits(arbitration_id, 11)]
    if not is_fd:
        control = [1 if is_remote else 0]  # RTR
        control += [0, 0]  # (IDE, r0) for base frames, (r1, r0) for extended ones
        control += _bits(code & 0xF, 4)
        body = header + control + ([] if is_remote else payload)
        crc = crc15_can(body)
        stuffed = body + _bits(crc, 15)
        total = len(stuffed) + _stuff_bits(stuffed) + _TAIL_BITS
        return total, 0
    # CAN FD: RRS, IDE(std only; ext has it above), FDF, res, BRS | ESI, DLC
    arb = header + [0] + ([] if is_extended else [0]) + [1, 0, 1 if bitrate_switch else 0]
    ctrl = [0, *_bits(code & 0xF, 4)]
    dyn = arb + ctrl + payload
    dyn_stuff = _stuff_bits(dyn)
    crc_len = 17 if n <= 16 else 21
    crc_field = 4 + crc_len + (4 + crc_len + 3) // 4 + 1  # stuff count, CRC, fixed stuff bits
    arb_share = len(arb) / len(dyn)
    arb_bits = len(arb) + round(dyn_stuff * arb_share) + _TAIL_BITS
    data_bits = len(ctrl) + len(payload) + (dyn_stuff - round(dyn_stuff * arb_share)) + crc_field
    if bitrate_switch:
        return arb_bits, data_bits
    return arb_bits + data_bits, 0


FrameDuration = Callable[[Any], float]
"""Bus time (s) of a frame from the description handed to :meth:`BusLoadMeter.add_frame`."""


class BusLoadMeter:
    """Frames/s, error frames/s and bus load over a sliding window of frame times.

    Fed with each frame's time (the device timestamp when the interface has one: adapters deliver
    frames in USB batches, so host times would show bursts that the bus never had) and its
    duration on the wire in seconds. Rates are taken over the frames inside the last ``window_s``:
    ``(n − 1) / (t_last − t_first)``; the load is the mean frame duration times that rate.

    :meth:`add_frame` defers the duration: ``duration_of(frame)`` runs in :meth:`rates`, only for
    the frames still in the window then (computing the stuff bits of every frame was a tenth of a
    CAN reader thread's time; with statistics once a second and a clock running faster than the
    window, most frames leave the window unmeasured).
    """

    def __init__(self, window_s: float = 1.0, duration_of: FrameDuration | None = None) -> None:
        if window_s <= 0:
            raise ValueError(f"bus-load window must be > 0 s, got {window_s}")
        self.window_ns = int(window_s * 1e9)
        self._duration_of = duration_of
        # [t_ns, duration_s or None (not computed yet), is_error, frame or None]
        self._frames: deque[list[Any]] = deque()
        self._errors = 0

    def reset(self) -> None:
        """Forget the window (after a gap: times on either side are not comparable)."""
        self._frames.clear()
        self._errors = 0

    def add(self, t_ns: int, duration_s: float, is_error: bool = False) -> None:
        """Record one frame at ``t_ns`` that took ``duration_s`` of bus time."""
        self._push([t_ns, duration_s, is_error, None])

    def add_frame(self, t_ns: int, frame: object, is_error: bool = False) -> None:
        """Record one frame at ``t_ns`` whose bus time ``duration_of(frame)`` gives when it is needed."""
        if self._duration_of is None:
            raise ValueError("BusLoadMeter.add_frame needs a meter built with duration_of")
        self._push([t_ns, None, is_error, frame])

    def _push(self, entry: list[Any]) -> None:
        t_ns = entry[0]
        frames = self._frames
        if frames and t_ns < frames[-1][0]:
            # a clock that stepped back (adapter reset) starts a new window
            self.reset()
        frames.append(entry)
        if entry[2]:
            self._errors += 1
        cutoff = t_ns - self.window_ns
        while frames[0][0] <= cutoff:
            if frames.popleft()[2]:
                self._errors -= 1

    def rates(self) -> tuple[float, float, float]:
        """``(frames_per_s, error_frames_per_s, busy_fraction)`` over the window (zeros if < 2 frames)."""
        n = len(self._frames)
        if n < 2:
            return 0.0, 0.0, 0.0
        span_s = (self._frames[-1][0] - self._frames[0][0]) / 1e9
        if span_s <= 0:
            return 0.0, 0.0, 0.0
        rate = (n - 1) / span_s
        error_rate = rate * self._errors / n
        busy_s = 0.0
        for entry in self._frames:
            d = entry[1]
            if d is None:
                assert self._duration_of is not None
                d = entry[1] = self._duration_of(entry[3])
                entry[3] = None
            busy_s += d
        busy = max(busy_s, 0.0) / n * rate
        return rate, error_rate, busy


class _LostError(Exception):
    """Internal: the interface is to be closed and reopened for ``reason``.

    ``start_ns`` is when the loss began if earlier than now (a bus-off that did not restart in
    time); ``announced`` when its :class:`BusLost` was already reported.
    """

    def __init__(self, reason: str, *, start_ns: int | None = None, announced: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.start_ns = start_ns
        self.announced = announced


# --- the session -------------------------------------------------------------------------------


class CanBusLink:
    """Reads one CAN bus on a thread; frames and events go to callbacks on that thread.

    ``on_frame`` gets every frame (error frames too) as a :class:`CanFrame`; ``on_event`` gets
    :data:`BusEvent` records (opened, lost, gap, state changes and, every ``stats_period_s``,
    :class:`BusStats`). Callbacks run on the reader thread and must not block for long. If a
    callback raises, the session stops, closes the bus and keeps the exception in
    :attr:`failure` (the reader never swallows a consumer's error silently).

    The link only reads: a config with ``listen_only`` None is opened listen-only (where the
    interface can be; :mod:`drivers.can.interfaces`). The controller's state comes from the
    interface's :class:`~drivers.can.controller.ControllerMonitor` (error frames, status polls every
    ``state_poll_s``, the state behind a failed ``recv``).

    Recovery: a ``can.CanError`` or ``OSError`` from ``recv`` (unless the interface says it is only
    error warning or passive), a bus-off state, or (when ``silence_timeout_s`` is set) no frame for
    that long, closes the interface; it is reopened after a back-off that doubles from
    ``backoff_initial_s`` to ``backoff_max_s`` and waits on the stop event. A bus-off on an
    interface whose controller restarts by itself (SocketCAN's ``restart-ms``; socketcand and the
    virtual bus report it the same way) is waited for instead, up to ``busoff_restart_s``, before
    falling back to a reopen. Either way the span is reported as one :class:`BusGap`.

    ``bus_factory`` opens the interface (default :func:`open_bus`); tests pass a fault-injecting one.
    """

    def __init__(
        self,
        config: CanBusConfig,
        on_frame: Callable[[CanFrame], None],
        on_event: Callable[[BusEvent], None] | None = None,
        *,
        clock: Clock,
        bus_factory: Callable[[CanBusConfig], can.BusABC] = open_bus,
        recv_timeout_s: float = 0.05,
        backoff_initial_s: float = 0.1,
        backoff_max_s: float = 5.0,
        silence_timeout_s: float | None = None,
        stats_window_s: float = 1.0,
        stats_period_s: float | None = 1.0,
        state_poll_s: float = 0.5,
        busoff_restart_s: float = 1.0,
        controller: ControllerMonitor | None = None,
    ) -> None:
        if recv_timeout_s <= 0 or backoff_initial_s <= 0 or backoff_max_s < backoff_initial_s:
            raise ConfigError(
                f"{config.describe()}: need recv_timeout_s > 0 and 0 < backoff_initial_s <= backoff_max_s"
            )
        if config.listen_only is None:
            config = dataclasses.replace(config, listen_only=True)
        self.config = config
        self._on_frame = on_frame
        self._on_event = on_event
        self._clock = clock
        self._factory = bus_factory
        self._recv_timeout_s = recv_timeout_s
        self._backoff_initial_s = backoff_initial_s
        self._backoff_max_s = backoff_max_s
        self._silence_ns = None if silence_timeout_s is None else int(silence_timeout_s * 1e9)
        self._stats_period_ns = None if stats_period_s is None else int(stats_period_s * 1e9)
        self._state_poll_ns = int(state_poll_s * 1e9)
        self._busoff_restart_ns = int(busoff_restart_s * 1e9)
        self._source = config.clock
        self._use_device_time = config.uses_interface_stamps
        self._channel = str(config.channel)
        self._monitor = controller or controller_monitor_for(config.interface)
        self._notes = bus_notes(config)

        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bus: can.BusABC | None = None
        self._lock = threading.Lock()
        self._meter = BusLoadMeter(stats_window_s, self._frame_duration)
        self._state = BusState.DISCONNECTED
        self._frames_total = 0
        self._errors_total = 0
        self._gaps_total = 0
        self._last_frame_ns: int | None = None
        self._counters: tuple[int, int] | None = None
        self._busoff_since: int | None = None
        """Host time the controller went bus-off while the interface stays open for its restart."""
        self._busoff_last_frame: int | None = None
        self._failure: BaseException | None = None
        self.stopped = threading.Event()
        """Set when the reader thread has finished (after ``stop()`` or a consumer failure)."""

    # -- lifecycle --

    def start(self) -> None:
        """Open the interface and start reading.

        Raises:
            DeviceError: the first open fails (misconfiguration shows at once; failures after a
                successful start are recovered instead).
            ConfigError: python-can refused an option.
            RuntimeError: already started.
        """
        if self._thread is not None:
            raise RuntimeError(f"{self.config.describe()}: session already started")
        try:
            self._open()
        except _LostError as lost:
            raise DeviceError(f"{self.config.describe()}: {lost.reason}") from None
        self._thread = threading.Thread(target=self._run, name=f"can-{self.config.name}", daemon=False)
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop reading, close the interface and join the thread.

        Raises:
            DeviceTimeoutError: the thread did not finish within ``timeout_s`` (a driver call that
                cannot be interrupted); the message names the bus.
        """
        self._stop.set()
        thread = self._thread
        if thread is None:
            self._close()
            return
        thread.join(timeout_s)
        if thread.is_alive():
            raise DeviceTimeoutError(f"{self.config.describe()}: reader thread did not stop within {timeout_s} s")

    def __enter__(self) -> CanBusLink:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def failure(self) -> BaseException | None:
        """The exception a callback raised, which stopped the session (None otherwise)."""
        return self._failure

    @property
    def state(self) -> BusState:
        with self._lock:
            return self._state

    @property
    def bus(self) -> can.BusABC | None:
        """The open python-can bus (None while disconnected)."""
        return self._bus

    def stats(self) -> BusStats:
        """A snapshot of the statistics (thread-safe)."""
        now = self._clock.now_ns()
        with self._lock:
            rate, err_rate, busy = self._meter.rates()
            return BusStats(
                host_ts_ns=now,
                bus=self.config.name,
                state=self._state,
                frames_total=self._frames_total,
                error_frames_total=self._errors_total,
                gaps_total=self._gaps_total,
                frames_per_s=rate,
                error_frames_per_s=err_rate,
                bus_load_pct=None if self.config.bitrate is None else 100.0 * busy,
                window_s=self._meter.window_ns / 1e9,
                tx_error_counter=None if self._counters is None else self._counters[0],
                rx_error_counter=None if self._counters is None else self._counters[1],
            )

    # -- internals --

    def _frame_duration(self, frame: tuple[int, bool, bytes, int, bool, bool, bool]) -> float:
        """Bus time (s) of a data or remote frame described as in :meth:`_deliver` (needs the bitrate)."""
        arbitration_id, is_extended, data, dlc, is_remote, is_fd, brs = frame
        bitrate = self.config.bitrate
        assert bitrate is not None
        if is_fd or is_remote:
            nominal, fast = frame_bit_times(arbitration_id, is_extended, data, dlc=dlc, is_remote=is_remote,
                                            is_fd=is_fd, bitrate_switch=brs)
        else:
            nominal, fast = frame_bit_times(arbitration_id, is_extended, data, dlc=dlc)
        duration_s = nominal / bitrate
        if fast:
            duration_s += fast / (self.config.data_bitrate or bitrate)
        return duration_s

    def _emit(self, event: BusEvent) -> None:
        if self._on_event is not None:
            self._on_event(event)

    def _set_state(self, state: BusState, now_ns: int) -> None:
        with self._lock:
            previous, self._state = self._state, state
        if previous is not state:
            log.info("%s: state %s -> %s", self.config.describe(), previous.value, state.value)
            self._emit(BusStateChanged(now_ns, self.config.name, previous, state))

    def _report(self, report: ControllerReport, now_ns: int) -> None:
        """Take in what the controller reported: its counters, and its state when it said one."""
        counters = report.counters
        if counters is not None:
            with self._lock:
                self._counters = counters
        if report.state is not None:
            self._set_state(report.state, now_ns)

    def _open(self) -> None:
        bus = self._factory(self.config)
        self._bus = bus
        self._monitor.attach(bus)
        now = self._clock.now_ns()
        with self._lock:
            self._meter.reset()
        self._emit(
            BusOpened(
                host_ts_ns=now,
                bus=self.config.name,
                interface=self.config.interface,
                channel=str(self.config.channel),
                channel_info=str(getattr(bus, "channel_info", "")),
                timestamp_source=self._source,
                frame_time=self.config.time_from,
                listen_only=self.config.listen_only,
                notes=self._notes,
            )
        )
        report = self._monitor.poll(bus)
        if report is not None and report.state is BusState.BUS_OFF:
            self._close()
            raise _LostError("controller still bus-off after reopening")
        if report is not None and report.state is not None:
            self._report(report, now)
        else:
            self._set_state(BusState.UNKNOWN, now)

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is None:
            return
        try:
            bus.shutdown()
        except (can.CanError, OSError) as exc:
            # a vanished adapter often fails its own shutdown; the handle is gone either way
            log.warning("%s: error while closing: %s", self.config.describe(), exc)

    def _run(self) -> None:
        try:
            self._read_loop()
            self._end_bus_off(self._clock.now_ns(), recovered=False)
        except BaseException as exc:  # a consumer callback failed: stop, and keep it for the owner
            log.exception("%s: reader stopped by an error", self.config.describe())
            self._failure = exc
        finally:
            self._close()
            with self._lock:
                self._state = BusState.DISCONNECTED
            self.stopped.set()

    def _read_loop(self) -> None:
        next_stats = next_state_poll = self._clock.now_ns()
        last_rx = next_stats
        monitor = self._monitor
        while not self._stop.is_set():
            bus = self._bus
            if bus is None:
                return
            try:
                try:
                    msg = bus.recv(timeout=self._recv_timeout_s)
                except (can.CanError, OSError) as exc:
                    report = monitor.on_receive_error(bus, exc)
                    if report is None or report.state in (None, BusState.ACTIVE, BusState.UNKNOWN):
                        raise _LostError(f"receive failed: {exc}") from exc
                    self._report(report, self._clock.now_ns())
                    msg = None
                    if report.state is not BusState.BUS_OFF:
                        # error warning or passive: reading goes on, without spinning on a failing recv
                        self._stop.wait(self._recv_timeout_s)
                now = self._clock.now_ns()
                if msg is not None:
                    last_rx = now
                    self._deliver(msg, now)
                elif (self._silence_ns is not None and self._busoff_since is None
                      and now - last_rx > self._silence_ns):
                    raise _LostError(f"no frame for {self._silence_ns / 1e9:.1f} s")
                if now >= next_state_poll:
                    next_state_poll = now + self._state_poll_ns
                    report = monitor.poll(bus)
                    if report is not None:
                        self._report(report, now)
                self._check_bus_off(now)
            except _LostError as lost:
                if not self._recover(lost.reason, start_ns=lost.start_ns, announced=lost.announced):
                    return
                last_rx = next_state_poll = self._clock.now_ns()
                continue
            if self._stats_period_ns is not None and now >= next_stats:
                next_stats = now + self._stats_period_ns
                self._emit(self.stats())

    def _check_bus_off(self, now_ns: int) -> None:
        """Start, wait out or end a bus-off (this thread's own state: read without the lock).

        Raises:
            _LostError: bus-off on an interface reopened to restart it, or no restart in time.
        """
        state = self._state
        since = self._busoff_since
        if state is BusState.BUS_OFF:
            if since is None:
                self._busoff_since = now_ns
                with self._lock:
                    self._busoff_last_frame = self._last_frame_ns
                if not self._monitor.restarts_itself:
                    raise _LostError("controller is bus-off")
                log.warning("%s: controller bus-off; waiting for its restart", self.config.describe())
                self._emit(BusLost(now_ns, self.config.name, "controller is bus-off"))
            elif now_ns - since > self._busoff_restart_ns:
                raise _LostError(
                    f"controller is bus-off and did not restart within {self._busoff_restart_ns / 1e9:g} s "
                    "(SocketCAN: is restart-ms set?)", start_ns=since, announced=True)
        elif since is not None and state is not BusState.DISCONNECTED:
            self._end_bus_off(now_ns, recovered=True)

    def _end_bus_off(self, now_ns: int, *, recovered: bool) -> None:
        """Report the gap of a bus-off waited out with the interface open (nothing if there is none)."""
        since, self._busoff_since = self._busoff_since, None
        if since is None:
            return
        with self._lock:
            self._gaps_total += 1
            last = self._busoff_last_frame
        if recovered:
            log.info("%s: controller back from bus-off", self.config.describe())
        self._emit(BusGap(since, now_ns, self.config.name, "controller is bus-off", 0, recovered, last))

    def _deliver(self, msg: can.Message, now_ns: int) -> None:
        # Runs for every frame on the bus (8000/s at full load on 1 Mbit/s): no enum arithmetic in
        # the common case, the frame record built without its dataclass __init__.
        is_error = bool(msg.is_error_frame)
        if is_error or msg.is_remote_frame or msg.bitrate_switch or msg.error_state_indicator or not msg.is_rx:
            flags = CanFrameFlag.NONE
            if is_error:
                flags |= CanFrameFlag.ERROR_FRAME
            if msg.is_remote_frame:
                flags |= CanFrameFlag.REMOTE
            if msg.bitrate_switch:
                flags |= CanFrameFlag.BITRATE_SWITCH
            if msg.error_state_indicator:
                flags |= CanFrameFlag.ERROR_STATE_INDICATOR
            if not msg.is_rx:
                flags |= CanFrameFlag.TX_ECHO
        else:
            flags = _NO_FLAGS
        data = bytes(msg.data or b"")
        is_fd = bool(msg.is_fd)
        dlc = len2dlc(len(data)) if is_fd else int(msg.dlc)
        stamp = msg.timestamp
        device_ns = round(stamp * 1e9) if stamp and stamp > 0 else None
        arbitration_id = int(msg.arbitration_id)
        is_extended = bool(msg.is_extended_id)
        frame = _new_frame(device_ns, now_ns, arbitration_id, is_extended, is_fd, dlc, data, flags, self._source,
                           self._channel)
        with self._lock:
            self._frames_total += 1
            self._errors_total += is_error
            self._last_frame_ns = now_ns
            t_meter = device_ns if device_ns is not None and self._use_device_time else now_ns
            if is_error or self.config.bitrate is None:
                # error reports carry no bus time of their own (the destroyed frame is unknown)
                self._meter.add(t_meter, 0.0, is_error)
            elif is_fd or msg.is_remote_frame:
                self._meter.add_frame(t_meter, (arbitration_id, is_extended, data, dlc, bool(msg.is_remote_frame),
                                                is_fd, bool(msg.bitrate_switch)))
            else:
                self._meter.add_frame(t_meter, (arbitration_id, is_extended, data, dlc, False, False, False))
        if is_error:
            report = self._monitor.from_error_frame(msg)
            if report is not None:
                self._report(report, now_ns)
        elif self._busoff_since is not None and msg.is_rx:
            # a frame received: the controller is back on the bus, whether or not its restart was reported
            self._set_state(BusState.ACTIVE, now_ns)
        self._on_frame(frame)

    def _recover(self, reason: str, *, start_ns: int | None = None, announced: bool = False) -> bool:
        """Close, back off and reopen until open or stopped; report the gap. False when stopped."""
        now = self._clock.now_ns()
        start = now if start_ns is None else start_ns
        log.warning("%s: lost (%s); reopening", self.config.describe(), reason)
        self._close()
        with self._lock:
            last_frame = self._last_frame_ns if start_ns is None else self._busoff_last_frame
        self._busoff_since = None
        if not announced:
            self._emit(BusLost(start, self.config.name, reason))
        self._set_state(BusState.DISCONNECTED, now)
        delay = self._backoff_initial_s
        attempts = 0
        recovered = False
        while not self._stop.wait(delay):
            attempts += 1
            try:
                self._open()
            except (DeviceError, can.CanError, OSError, _LostError) as exc:
                log.info("%s: reopen attempt %d failed: %s", self.config.describe(), attempts, exc)
                delay = min(2.0 * delay, self._backoff_max_s)
                continue
            recovered = True
            break
        end = self._clock.now_ns()
        with self._lock:
            self._gaps_total += 1
        self._emit(BusGap(start, end, self.config.name, reason, attempts, recovered, last_frame))
        return recovered
