"""The engine of a simulated NovAtel receiver: serial ports on ptys, commands, and a GPS-time log schedule.

:class:`SimReceiver` runs one thread that waits (``select``) on its pty masters, a wake-up pipe and
the next due time on the injected :class:`~vsccore.clock.Clock` (a ``ScaledClock`` makes it run
faster than real time), and

- answers abbreviated-ASCII commands (:mod:`sim_devices.gnss.commands`) with ``<OK`` or
  ``<ERROR:reason`` followed by the port prompt ``[COM1]``, as an OEM7 does;
- produces the logged messages on GPS time: ``ONTIME period [offset]`` on the grid of GPS seconds
  of week, ``ONNEW``/``ONCHANGED`` at every solution epoch (``solution_rate_hz``) or, for
  asynchronous logs (MARKPOS …), at every event; ``ONCE``, ``ONNEXT``, ``ONMARK``;
- writes each message ``output_latency_s`` (+ uniform jitter) after its data time, serialised on
  its port at the port's baud rate (a 104-byte BESTPOSB takes 9 ms at 115200 Bd); logs beyond what
  the baud rate carries (more than 1 s of backlog) are dropped and counted (:meth:`bytes_overrun`),
  and so are bytes the pty could not take while a reader had it open (:meth:`bytes_lost`);
- routes a log to the port it was requested on (the port the command came in on, or a named
  port); a named port that is not wired to a pty swallows its output, as on a real receiver.

Faults for other modules' tests: :meth:`unplug` / :meth:`replug` a port (the stable symlink
``port_path`` points at the new pty), :meth:`inject` raw bytes, :meth:`pause_logs` /
:meth:`resume_logs`, :meth:`set_unresponsive` (commands are read and ignored). Requests from other
threads run on the receiver's own thread, so there are no races on the file descriptors.

Where the real receiver fails, the twin fails alike (OEM7 Commands and Logs Reference, the pages
named in each place):

- every receiver has the ports COM1-COM3, USB1-USB3 and ICOM1, wired to a pty or not; a COM port
  starts at the factory 9600 N 8 1 (SERIALCONFIG) unless ``baud`` says how it was set up; USB and
  ICOM ports have no baud rate; every port's interface mode is NOVATEL NOVATEL (INTERFACEMODE), so raw
  RTCM3 is no correction until a port is set to RTCMV3 (or AUTO) receive; on a NOVATEL port the
  corrections come as logs with a NovAtel header (Transmitting and receiving corrections,
  Configuration notes);
- a port whose logs outrun its baud rate drops them and says so in the receiver status word of every
  header and in RXSTATUS (COM port tx buffer overrun, and the port's bit in the auxiliary words);
- the output latency is the receiver's own, drawn per seed in 15-50 ms (MARK1TIME: "typically 20-30 ms
  (50 ms maximum)"); the rig is never told this;
- ``RESET`` / :meth:`reset`: silent for a moment, the saved configuration back (unsaved logs gone), the
  time status UNKNOWN → COARSE → FINESTEERING, no RTK before FINESTEERING;
- ``FIX POSITION`` heights are MSL under the factory ``UNDULATION EGM96`` (the EGM96 geoid of the
  site, :mod:`sim_devices.gnss.geoid`), ellipsoidal after ``UNDULATION USER 0``; a fixed position
  25-50 m from the antenna is INTEGRITY_WARNING, worse INVALID_FIX, and no corrections go out (FIX).

Subclasses (:class:`~sim_devices.gnss.rover.SimRover`, :class:`~sim_devices.gnss.base.SimBase`)
supply the antenna, the RTK state and the message bodies.
"""

from __future__ import annotations

import abc
import contextlib
import datetime as dt
import logging
import math
import os
import queue
import select
import shutil
import tempfile
import threading
import zlib
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import IntFlag
from pathlib import Path
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from drivers.novatel import (
    Body,
    BodyFormat,
    ClockModelStatus,
    FrameKind,
    Framer,
    Header,
    Message,
    PositionType,
    RawBody,
    SolutionStatus,
    Time,
    TimeStatus,
    UTCStatus,
    decode_ascii,
    decode_binary,
    encode_abbreviated,
    encode_ascii,
    encode_binary,
    encode_error,
    encode_ok,
    encode_prompt,
)
from drivers.novatel.crc import crc24q
from drivers.novatel.messages import LOG_IDS
from sim_devices.gnss import bodies
from sim_devices.gnss.antenna import AntennaState
from sim_devices.gnss.commands import (
    Command,
    EventInCommand,
    FixCommand,
    InterfaceModeCommand,
    LogCommand,
    LogFormat,
    ReceiverCommandError,
    SerialConfigCommand,
    SimpleCommand,
    Trigger,
    UndulationCommand,
    UnlogAllCommand,
    UnlogCommand,
    parse_command,
)
from sim_devices.gnss.constellation import Constellation, SatObservation, dops
from sim_devices.gnss.error_model import GnssErrorModel, GnssErrorParams, RtkState
from sim_devices.gnss.geodesy import EnuOrigin
from sim_devices.gnss.geoid import egm96_undulation_m
from sim_devices.gnss.pty import PtyPort
from sim_devices.gnss.rawlogs import rxstatus_ascii, rxstatus_binary
from sim_devices.gnss.solution import Solution
from sim_devices.gnss.timebase import SimTimeBase
from vsccore.clock import UNBOUNDED_NS, Clock, ClockGovernor, SystemClock, participant
from vsccore.errors import DeviceError, DeviceTimeoutError, SimulationError
from vsccore.gpstime import NS_PER_S, NS_PER_WEEK, gps_ns_to_unix_ns

__all__ = [
    "FACTORY_BAUD",
    "LATENCY_RANGE_S",
    "STANDARD_PORTS",
    "PortSettings",
    "ReceiverStatus",
    "SimReceiver",
    "Solution",
    "StartupTiming",
]

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
_T = TypeVar("_T")

_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3
_MAX_BACKLOG_NS = 2 * NS_PER_S
_MAX_LINE = 1024
_MAX_PORT_BACKLOG_S = 1.0
_RTCM_RX_MODES = frozenset({"RTCMV3", "AUTO"})
_COMMAND_RX_MODES = frozenset({"NOVATEL", "AUTO", "NOVATELBINARY", "NOVATELX", "GENERIC"})

STANDARD_PORTS = ("COM1", "COM2", "COM3", "USB1", "USB2", "USB3", "ICOM1")
"""Ports every simulated receiver has (an OEM729 / PwrPak7: three COM ports, USB1-3, ICOM1), wired or not."""
FACTORY_BAUD = 9600
"""A COM port's factory rate (SERIALCONFIG, Factory Defaults: ``SERIALCONFIG COM1 9600 N 8 1 N ON``)."""
_NO_BAUD_BPS = 12_000_000
"""USB and ICOM ports have no baud rate: their bytes leave at USB full speed (no SERIALCONFIG applies)."""
LATENCY_RANGE_S = (0.015, 0.050)
"""Range of a receiver's own output latency (MARK1TIME: logs leave typically 20-30 ms, 50 ms at most, after
their epoch), drawn per seed."""
_OVERRUN_HOLD_NS = 60 * NS_PER_S
"""How long (GPS time) a port's overrun flag stays set after its last dropped log. The OEM7 page does not
say; older NovAtel manuals clear it five minutes after the last overrun."""
_INTEGRITY_WARNING_M = 25.0
_INVALID_FIX_M = 50.0
"""FIX: "INTEGRITY_WARNING: ... off by approximately 25-50 metres; INVALID_FIX: ... off by a gross amount"."""
_MAX_BINARY_FRAME = 16384


class ReceiverStatus(IntFlag):
    """Bits of the receiver status word in every log header and in RXSTATUS (RXSTATUS, Receiver Status)."""

    COM_TX_BUFFER_OVERRUN = 0x0000_0100
    POSITION_SOLUTION_INVALID = 0x0008_0000
    POSITION_FIXED = 0x0010_0000


#: Port → (auxiliary status word 1-3, bit) of its buffer overrun (RXSTATUS, Auxiliary 1/2 Status).
_PORT_OVERRUN_BITS: dict[str, tuple[int, int]] = {
    "USB1": (1, 0x100), "USB2": (1, 0x200), "USB3": (1, 0x400), "ICOM1": (1, 0x8_0000), "ICOM2": (1, 0x10_0000),
    "ICOM3": (1, 0x20_0000), "COM4": (2, 0x4), "COM5": (2, 0x8), "COM1": (2, 0x200), "COM2": (2, 0x400),
    "COM3": (2, 0x800),
}


@dataclass(frozen=True, slots=True)
class StartupTiming:
    """What a receiver does after a reset (or a cold power-up), in seconds of simulated time.

    Silent (no output, input lost) for ``silent_s``; the time status is UNKNOWN (header week 0, seconds
    since the reset, no position) until ``coarse_s``, COARSE (a single-point solution, no RTK) until
    ``finesteering_s``, then FINESTEERING (OEM7 Commands and Logs Reference, GPS Reference Time Status).
    """

    silent_s: float = 1.0
    coarse_s: float = 2.0
    finesteering_s: float = 5.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.silent_s <= self.coarse_s <= self.finesteering_s:
            raise SimulationError(f"startup timing {self}: needs 0 <= silent_s <= coarse_s <= finesteering_s")


@dataclass(frozen=True, slots=True)
class PortSettings:
    """A port's settings now: baud rate (None for USB/ICOM), receive and transmit interface modes,
    whether it answers commands, and whether a pty is wired to it."""

    name: str
    baud: int | None
    rx_mode: str
    tx_mode: str
    responses: bool
    wired: bool


@dataclass(slots=True)
class _LogEntry:
    port: str
    name: str
    fmt: LogFormat
    trigger: Trigger
    period_ns: int
    offset_ns: int
    seq: int
    next_due_ns: int | None = None


@dataclass(slots=True)
class _PortState:
    name: str
    pty: PtyPort | None
    baud: int
    rx_mode: str = "NOVATEL"
    tx_mode: str = "NOVATEL"
    responses: bool = True
    free_at_ns: int = 0
    pending: deque[tuple[int, bytes]] = field(default_factory=deque)
    pending_bytes: int = 0
    """Sum of the lengths in ``pending`` (kept with it: summing per log cost the thread a tenth of its time)."""
    line: bytearray = field(default_factory=bytearray)
    last_cr: bool = False
    framer: Framer | None = None
    bytes_overrun: int = 0
    written: deque[tuple[int, int]] = field(default_factory=deque)
    """(bytes written on the pty after a write, clock time the write completed): what a reader may still owe."""
    consumed: int = 0
    read_seen: bool = False
    """Someone reads this port (only then does a governed clock wait for its reader)."""
    binary: bytearray = field(default_factory=bytearray)
    """A binary frame (NovAtel ``AA 44 12`` or RTCM3 ``D3``) arriving on a command port, until complete."""
    overrun_at_ns: int | None = None
    """GPS data time of the last log this port dropped for want of baud rate (its status bit)."""
    rtcm_ignored: int = 0
    """Raw RTCM3 frames this port received in a mode that does not take them (NOVATEL, NONE)."""

    @property
    def serial(self) -> bool:
        """A port with a baud rate (COM, AUX); USB and ICOM ports have none."""
        return self.name.startswith(("COM", "AUX"))

    @property
    def rate_bps(self) -> int:
        """Bits per second its bytes leave at (10 bits a byte on a serial port)."""
        return self.baud if self.serial else _NO_BAUD_BPS


_UNREAD_POLL_S = 0.0002
"""How often a governed receiver looks whether its reader has read what it wrote (wall seconds)."""
_PAUSED_LOOK_S = 0.02
"""Longest sleep (wall s) of a governed receiver on a clock that stands still for another participant
before it looks at its ports and requests again (input on them waits at most this long then)."""


class SimReceiver(abc.ABC):
    """Common engine of the simulated receivers (see module docstring).

    Args:
        name: device name for messages and the symlink file names.
        timebase: host clock ↔ GPS ↔ truth time of the session.
        clock: the injected host clock (default: the system clock).
        port_name: name of the main (command) port, e.g. ``COM1`` or ``USB1``.
        extra_ports: names of further ports wired to their own pty (a rover's correction port). Every
            port of :data:`STANDARD_PORTS` exists whether wired or not.
        link_dir: directory for the stable symlinks (default: a private temporary directory,
            removed by :meth:`stop`).
        baud: the rate the wired COM ports were set to (and saved) before the session; None leaves
            them at the factory 9600. Unwired COM ports are always at 9600; USB/ICOM have no rate.
        output_latency_s: delay from a message's data time to its first byte; None (default) draws
            the receiver's own in :data:`LATENCY_RANGE_S` from ``seed`` (the rig is never told it).
        latency_jitter_s: uniform jitter added to it per log.
        solution_rate_hz: rate of solution epochs (ONNEW/ONCHANGED of synchronous logs).
        startup_commands: the receiver's saved configuration, applied at power-up and by RESET
            (e.g. ``("LOG COM1 RTCM1006 ONTIME 1",)``).
        seed: seed of every random draw of this receiver.
        enforce_baud: when True, output is garbled and input ignored while the driver's side of a COM
            port is set to a baud rate other than the receiver's (for autobaud tests; USB ignores it).
        undulation_m: the geoid height the receiver's EGM96 table gives at its site; None (default)
            takes it from the EGM96 grid (:func:`~sim_devices.gnss.geoid.egm96_undulation_m`).
        error_params: the position/velocity error model.
        constellation: the synthetic satellites (shared, or one per receiver).
        serial_number: the product serial number (PSN) of VERSION; default derived from name and seed.
        lenient_corrections: the twin's old shortcut: wired ports other than the main one start in AUTO
            and take raw RTCM3 without an INTERFACEMODE command (no real receiver does this).
        startup: what a reset does (:class:`StartupTiming`).
        cold_start: run the reset sequence at :meth:`start` too (default: the receiver has long been on).
    """

    #: Logs whose ONNEW/ONCHANGED fire on an event instead of at every solution epoch.
    ASYNC_LOGS: frozenset[str] = frozenset(
        {"MARKPOS", "MARKTIME", "MARK1TIME", "MARK2POS", "MARK2TIME", "VERSION"}
    )
    #: VERSION's GPSCARD component: model, hardware, software and boot versions, compile date and time.
    MODEL = "FFNRNNCBN"
    VERSIONS = ("OEM7290-1.01", "OM7MR0810RN0000", "OM7BR0001RBG000", "2021/Apr/27", "13:20:06")

    def __init__(
        self,
        name: str,
        *,
        timebase: SimTimeBase,
        clock: Clock | None = None,
        port_name: str = "COM1",
        extra_ports: Sequence[str] = (),
        link_dir: Path | str | None = None,
        baud: int | None = 115200,
        output_latency_s: float | None = None,
        latency_jitter_s: float = 0.002,
        solution_rate_hz: float = 20.0,
        startup_commands: Sequence[str] = (),
        seed: int = 0,
        enforce_baud: bool = False,
        undulation_m: float | None = None,
        error_params: GnssErrorParams | None = None,
        constellation: Constellation | None = None,
        serial_number: str | None = None,
        lenient_corrections: bool = False,
        startup: StartupTiming | None = None,
        cold_start: bool = False,
    ) -> None:
        if not name.replace("_", "").replace("-", "").isalnum():
            raise SimulationError(f"sim receiver name {name!r} must be alphanumeric (with _ or -)")
        if output_latency_s is None:
            draw = np.random.default_rng(None if seed is None else (seed, 4049))
            output_latency_s = float(draw.uniform(*LATENCY_RANGE_S))
        if not (0.0 <= output_latency_s < 1.0 and 0.0 <= latency_jitter_s < 0.5):
            raise SimulationError(f"sim receiver {name}: output latency {output_latency_s} s / jitter out of range")
        if not (0.0 < solution_rate_hz <= 100.0):
            raise SimulationError(f"sim receiver {name}: solution_rate_hz {solution_rate_hz} out of (0, 100]")
        for pname in (port_name, *extra_ports):
            if pname not in _HEADER_PORTS:
                raise SimulationError(f"sim receiver {name}: {pname!r} is not a NovAtel port name (COM1, USB1 …)")
        if len({port_name, *extra_ports}) != 1 + len(extra_ports):
            raise SimulationError(f"sim receiver {name}: port names must differ, got {(port_name, *extra_ports)}")
        if baud is not None and baud <= 0:
            raise SimulationError(f"sim receiver {name}: baud {baud} must be positive")
        self.name = name
        self.timebase = timebase
        self.clock: Clock = clock if clock is not None else SystemClock()
        self.output_latency_s = output_latency_s
        self.latency_jitter_s = latency_jitter_s
        self.solution_period_ns = round(NS_PER_S / solution_rate_hz)
        self.enforce_baud = enforce_baud
        self._geoid_m = undulation_m
        self._undulation = UndulationCommand("EGM96")
        self.startup_commands = tuple(startup_commands)
        self.constellation = constellation if constellation is not None else Constellation()
        self.error_model = GnssErrorModel(error_params, seed)
        self._rng = np.random.default_rng(None if seed is None else seed + 7919)
        self.serial_number = serial_number if serial_number is not None else _default_psn(name, seed)
        self.lenient_corrections = lenient_corrections
        self.startup = startup if startup is not None else StartupTiming()
        self.cold_start = cold_start
        self._own_dir = link_dir is None
        self.link_dir = Path(tempfile.mkdtemp(prefix=f"vsc-sim-{name}-")) if link_dir is None else Path(link_dir)
        self.main_port = port_name
        self._wired_baud = baud
        self._ports: dict[str, _PortState] = {}
        self._governed = False
        wired = (port_name, *extra_ports)
        for pname in (*STANDARD_PORTS, *(p for p in wired if p not in STANDARD_PORTS)):
            pty = None
            if pname in wired:
                suffix = "" if pname == port_name else f"-{pname.lower()}"
                pty = PtyPort(pname, self.link_dir / f"{name}{suffix}")
            self._ports[pname] = _PortState(pname, pty, self._power_up_baud(pname, pty is not None))
        self._entries: dict[tuple[str, str], _LogEntry] = {}
        self._epoch_logs: bool | None = None
        """:meth:`_needs_epochs`, cached; None after any change of ``_entries``."""
        self._once: list[tuple[int, _LogEntry]] = []
        self._seq = 0
        self._next_epoch_ns: int | None = None
        self._fix: FixCommand | None = None
        self._events: dict[str, EventInCommand] = {"MARK1": EventInCommand("MARK1", True)}
        self._ecutoff_deg = 5.0
        self._config: list[tuple[Command, str]] = []
        self._saved: list[tuple[Command, str]] = []
        self._solutions: OrderedDict[int, Solution] = OrderedDict()
        self._geometry_cache: tuple[int, tuple[SatObservation, ...]] | None = None
        self._logs_paused = False
        #: True while :meth:`message` builds a log requested ONNEW/ONCHANGED (vs. ONTIME …).
        self.emitting_on_change = False
        self._unresponsive = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._requests: queue.SimpleQueue[tuple[Callable[[], object], list[object], threading.Event]] = (
            queue.SimpleQueue()
        )
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._started = False
        self.commands_received = 0
        self.errors_sent = 0
        self.logs_unrouted = 0
        self.resets = 0
        self.error: BaseException | None = None
        self._leap_seconds = timebase.leap_seconds
        self._event_cursor_ns = -1
        self._last_event_ns: int | None = None
        self._reset_at_ns: int | None = None
        """GPS time of the last reset (None: converged since before the session)."""
        self._rxstatus_sent: tuple[int, ...] | None = None

    # --- public API ---------------------------------------------------------------------------

    @property
    def port_path(self) -> str:
        """Stable path of the main port (a symlink to the current ``/dev/pts/N``) to open with pyserial."""
        return str(self._pty(self.main_port).path)

    @property
    def device_path(self) -> str | None:
        """Current ``/dev/pts/N`` of the main port (None while unplugged)."""
        return self._pty(self.main_port).device_path

    def port(self, name: str | None = None) -> PtyPort:
        """The pty of a port (main port by default)."""
        return self._pty(name or self.main_port)

    def start(self) -> None:
        """Power up: create the ptys, apply the saved configuration, start the thread."""
        if self._started:
            raise DeviceError(f"sim receiver {self.name}: already started")
        self._started = True
        try:
            for st in self._ports.values():
                if st.pty is not None:
                    st.pty.plug()
            self._wake_r, self._wake_w = os.pipe()
            os.set_blocking(self._wake_w, False)
            now = self.gps_now_ns()
            self._event_cursor_ns = now
            self._next_epoch_ns = self._grid_at_or_after(now, self.solution_period_ns, 0)
            self._saved = [(self._parse_startup(c), self.main_port) for c in self.startup_commands]
            self._restore(self._saved)
            if self.cold_start:
                self._reset_at_ns = now
        except BaseException:
            self._close_fds()
            raise
        self._thread = threading.Thread(target=self._run, name=f"sim-gnss-{self.name}", daemon=True)
        self._thread.start()
        log.info("sim receiver %s started on %s", self.name, self.port_path)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread, close every pty and remove the symlinks. Idempotent."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise DeviceTimeoutError(f"sim receiver {self.name}: thread did not stop within {timeout_s} s")
            self._thread = None
        self._close_fds()

    def __enter__(self) -> SimReceiver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self, port: str | None = None) -> None:
        """Pull the cable of a port (main port by default): the pty closes, the symlink goes."""
        self._call(lambda: self._pty(port or self.main_port).unplug())

    def replug(self, port: str | None = None) -> str:
        """Plug a port back in on a new pty; returns the new ``/dev/pts/N`` (``port_path`` stays)."""

        def do() -> str:
            pty = self._pty(port or self.main_port)
            pty.plug()
            st = self._ports[pty.name]
            st.line.clear()
            st.binary.clear()
            st.pending.clear()
            st.pending_bytes = 0
            st.framer = None
            return pty.device_path or ""

        return self._call(do)

    def reset(self) -> None:
        """Reset the receiver (the ``RESET`` command, or a power cycle): see :meth:`_do_reset`."""
        self._call(self._do_reset)

    def port_settings(self, name: str | None = None) -> PortSettings:
        """A port's settings now (main port by default), wired to a pty or not.

        Raises:
            DeviceError: the receiver has no such port.
        """

        def do() -> PortSettings:
            st = self._ports.get(name or self.main_port)
            if st is None:
                raise DeviceError(f"sim receiver {self.name}: no port {name!r} (has {sorted(self._ports)})")
            return PortSettings(st.name, st.baud if st.serial else None, st.rx_mode, st.tx_mode, st.responses,
                                st.pty is not None)

        return self._call(do)

    @property
    def undulation_m(self) -> float:
        """Geoid − ellipsoid separation the position logs report now: the EGM96 value of the site under the
        factory ``UNDULATION EGM96``, the user's value after ``UNDULATION USER x`` (UNDULATION)."""
        if self._undulation.option == "USER":
            return self._undulation.separation_m
        return self.geoid_m

    @undulation_m.setter
    def undulation_m(self, value: float) -> None:
        self._geoid_m = float(value)

    @property
    def geoid_m(self) -> float:
        """EGM96 geoid height at the receiver's site (where its antenna is at the start of the session)."""
        if self._geoid_m is None:
            ant = self.antenna_state(self.timebase.truth_start_gps_ns)
            self._geoid_m = egm96_undulation_m(ant.lat_deg, ant.lon_deg)
        return self._geoid_m

    def time_status_at(self, t_gps_ns: int) -> TimeStatus:
        """GPS reference time status at a GPS time: FINESTEERING, or the steps after a reset (StartupTiming)."""
        reset = self._reset_at_ns
        if reset is None:
            return TimeStatus.FINESTEERING
        since = t_gps_ns - reset
        if since >= round(self.startup.finesteering_s * NS_PER_S):
            return TimeStatus.FINESTEERING
        if since >= round(self.startup.coarse_s * NS_PER_S):
            return TimeStatus.COARSE
        return TimeStatus.UNKNOWN

    def silent_at(self, t_gps_ns: int) -> bool:
        """True while the receiver is restarting after a reset: nothing goes out, input is lost."""
        reset = self._reset_at_ns
        return reset is not None and t_gps_ns - reset < round(self.startup.silent_s * NS_PER_S)

    def status_words(self, t_gps_ns: int) -> tuple[int, int, int, int, int]:
        """Receiver status and auxiliary status words 1-4 at a GPS time (RXSTATUS): a port that dropped
        logs for want of baud rate in the last minute sets COM_TX_BUFFER_OVERRUN and its own bit."""
        rx = 0
        aux = [0, 0, 0, 0]
        for st in self._ports.values():
            at = st.overrun_at_ns
            if at is not None and t_gps_ns - at < _OVERRUN_HOLD_NS:
                rx |= ReceiverStatus.COM_TX_BUFFER_OVERRUN
                word, bit = _PORT_OVERRUN_BITS.get(st.name, (0, 0))
                if word:
                    aux[word - 1] |= bit
        fix = self._fix
        if fix is not None and fix.kind == "POSITION":
            rx |= ReceiverStatus.POSITION_FIXED
            if self.fix_status(t_gps_ns) is SolutionStatus.INVALID_FIX:
                rx |= ReceiverStatus.POSITION_SOLUTION_INVALID
        elif self.time_status_at(t_gps_ns) is TimeStatus.UNKNOWN:
            rx |= ReceiverStatus.POSITION_SOLUTION_INVALID
        return int(rx), aux[0], aux[1], aux[2], aux[3]

    def fix_status(self, t_gps_ns: int) -> SolutionStatus:
        """The integrity monitor's verdict on a ``FIX POSITION`` (FIX): SOL_COMPUTED when the fixed
        position (its height taken with the current undulation) is within 25 m of the antenna,
        INTEGRITY_WARNING up to 50 m, INVALID_FIX beyond; SOL_COMPUTED when nothing is fixed."""
        fix = self._fix
        if fix is None or fix.kind != "POSITION":
            return SolutionStatus.SOL_COMPUTED
        lat, lon, hgt = fix.values
        ant = self.antenna_state(t_gps_ns)
        off = EnuOrigin(ant.lat_deg, ant.lon_deg, ant.height_m).to_ecef(0.0, 0.0, 0.0)
        fixed = EnuOrigin(lat, lon, hgt + self.undulation_m).to_ecef(0.0, 0.0, 0.0)
        d = math.dist(off, fixed)
        if d > _INVALID_FIX_M:
            return SolutionStatus.INVALID_FIX
        if d > _INTEGRITY_WARNING_M:
            return SolutionStatus.INTEGRITY_WARNING
        return SolutionStatus.SOL_COMPUTED

    def inject(self, data: bytes, port: str | None = None) -> None:
        """Write raw bytes (garbage, truncated frames …) to a port now."""
        self._call(lambda: self._pty(port or self.main_port).write(bytes(data)))

    def pause_logs(self) -> None:
        """Stop streaming logs (commands are still answered)."""
        self._logs_paused = True

    def resume_logs(self) -> None:
        """Resume streaming logs."""
        self._logs_paused = False

    def set_unresponsive(self, flag: bool = True) -> None:
        """When True, commands are read and ignored (a hung receiver); logs go on unless paused."""
        self._unresponsive = flag

    def bytes_overrun(self, port: str | None = None) -> int:
        """Bytes of logs dropped because the port's baud rate could not carry them."""
        return self._ports[port or self.main_port].bytes_overrun

    def rtcm_ignored(self, port: str | None = None) -> int:
        """Raw RTCM3 frames a port received in a receive mode that does not take them (NOVATEL)."""
        return self._ports[port or self.main_port].rtcm_ignored

    def bytes_lost(self) -> dict[str, int]:
        """Bytes written to each port (by name) that its pty could not take while a reader had it
        open: the reader was behind and they are lost (:attr:`PtyPort.bytes_lost`). Readable from any
        thread."""
        return {name: st.pty.bytes_lost for name, st in list(self._ports.items()) if st.pty is not None}

    def logged(self) -> list[tuple[str, str, str, float]]:
        """The active log requests as (port, name + format suffix, trigger, period s)."""
        return self._call(
            lambda: [
                (e.port, e.name + e.fmt.value, e.trigger.value, e.period_ns / NS_PER_S) for e in self._entries.values()
            ]
        )

    # --- subclass hooks ------------------------------------------------------------------------

    def known_logs(self) -> frozenset[str]:
        """Log names the LOG command accepts."""
        return frozenset({"BESTPOS", "BESTVEL", "BESTXYZ", "TIME", "PSRDOP", "VERSION", "GPGGA", "RXSTATUS"})

    @abc.abstractmethod
    def antenna_state(self, t_gps_ns: int) -> AntennaState:
        """True antenna state at a GPS time (a rover follows the vehicle, a base stands still)."""

    def rtk_state(self, t_gps_ns: int) -> RtkState:
        """Solution type and differential age at a GPS time (no corrections: SINGLE)."""
        return RtkState(PositionType.SINGLE, 0.0, "")

    def message(
        self, entry_name: str, fmt: LogFormat, t_gps_ns: int, batch: Sequence[str]
    ) -> Body | bytes | list[Body] | None:
        """Body (or raw bytes written as they are, or one body per log) of a log at data time ``t_gps_ns``.

        None = nothing. :attr:`emitting_on_change` says whether the log fires ONNEW/ONCHANGED.
        """
        return self._common_message(entry_name, fmt, t_gps_ns)

    def next_event_ns(self, after_ns: int) -> int | None:
        """Time of the next asynchronous event (mark input …) after ``after_ns``; None if none."""
        return None

    def on_event(self, t_gps_ns: int) -> list[str]:
        """Process the event at ``t_gps_ns``; return the names of the asynchronous logs it renews."""
        return []

    def on_correction_frame(self, raw: bytes, rx_gps_ns: int) -> None:  # noqa: B027 - optional hook
        """A CRC-valid RTCM3 frame arrived on a port that accepts corrections (a base ignores them)."""

    def on_reset(self) -> None:  # noqa: B027 - optional hook
        """The receiver was reset: forget what a power cycle forgets (the RTK state …)."""

    def apply_simple(self, cmd: SimpleCommand) -> None:
        """Apply a simple configuration command (ECUTOFF …)."""
        if cmd.name == "ECUTOFF":
            self._ecutoff_deg = float(cmd.args[0])

    # --- time helpers ----------------------------------------------------------------------------

    def gps_now_ns(self) -> int:
        """True GPS time now (on the injected clock)."""
        return self.timebase.gps_ns(self.clock.now_ns())

    @staticmethod
    def _grid_at_or_after(t_ns: int, period_ns: int, offset_ns: int) -> int:
        k = -((offset_ns - t_ns) // period_ns)  # ceil((t - offset) / period)
        return k * period_ns + offset_ns

    # --- solution ------------------------------------------------------------------------------

    def geometry(self, t_gps_ns: int, ant: AntennaState) -> tuple[SatObservation, ...]:
        """Visible satellites (above 5°), recomputed once per GPS second."""
        sec = t_gps_ns // NS_PER_S
        if self._geometry_cache is None or self._geometry_cache[0] != sec:
            vis = self.constellation.visible(ant.lat_deg, ant.lon_deg, ant.height_m, float(sec), 5.0)
            self._geometry_cache = (sec, tuple(vis))
        return self._geometry_cache[1]

    def solution(self, t_gps_ns: int) -> Solution:
        """The solution at data time ``t_gps_ns`` (cached: every log of one epoch reports the same)."""
        cached = self._solutions.get(t_gps_ns)
        if cached is not None:
            return cached
        ant = self.antenna_state(t_gps_ns)
        sats = self.geometry(t_gps_ns, ant)
        in_soln = sum(1 for s in sats if s.elevation_deg >= self._ecutoff_deg)
        fix = self._fix
        time_status = self.time_status_at(t_gps_ns)
        if time_status is TimeStatus.UNKNOWN:  # restarting: no position yet
            sol = Solution(
                t_gps_ns, PositionType.NONE, 0.0, 0.0, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0,
                "", sats, 0, ant, SolutionStatus.INSUFFICIENT_OBS,
            )
        elif fix is not None and fix.kind == "POSITION":
            lat, lon, hgt = fix.values
            sol = Solution(
                t_gps_ns, PositionType.FIXEDPOS, lat, lon, hgt + self.undulation_m, (0.0, 0.0, 0.0),
                (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, "", sats, in_soln, ant, self.fix_status(t_gps_ns),
            )
        else:
            rtk = self.rtk_state(t_gps_ns)
            if time_status is not TimeStatus.FINESTEERING:  # no RTK (nor differential) before fine time
                rtk = RtkState(PositionType.SINGLE, 0.0, "")
            err = self.error_model.sample(t_gps_ns, rtk.pos_type)
            de, dn, du = (float(v) for v in err.position_enu_m)
            lat, lon, h = _offset_geodetic(ant.lat_deg, ant.lon_deg, ant.height_m, de, dn, du)
            dv = err.velocity_enu_mps
            sol = Solution(
                t_gps_ns,
                rtk.pos_type,
                lat,
                lon,
                h,
                _tuple3(err.position_sigma_enu_m),
                (ant.v_east_mps + float(dv[0]), ant.v_north_mps + float(dv[1]), ant.v_up_mps + float(dv[2])),
                _tuple3(err.velocity_sigma_enu_mps),
                rtk.diff_age_s,
                rtk.station_id,
                sats,
                in_soln,
                ant,
            )
        self._solutions[t_gps_ns] = sol
        while len(self._solutions) > 16:
            self._solutions.popitem(last=False)
        return sol

    # --- message bodies shared by all receivers -----------------------------------------------------

    def _common_message(self, name: str, fmt: LogFormat, t_ns: int) -> Body | bytes | None:
        if name == "BESTPOS":
            return bodies.bestpos(self.solution(t_ns), self.undulation_m)
        if name == "BESTVEL":
            return bodies.bestvel(self.solution(t_ns))
        if name == "BESTXYZ":
            return bodies.bestxyz(self.solution(t_ns))
        if name == "PSRDOP":
            sol = self.solution(t_ns)
            return bodies.psrdop(
                [s for s in sol.satellites if s.elevation_deg >= self._ecutoff_deg], self._ecutoff_deg
            )
        if name == "TIME":
            return self._time_body(t_ns)
        if name == "VERSION":
            return bodies.version(fmt, self.MODEL, self.serial_number, self.VERSIONS)
        if name == "RXSTATUS":
            words = self.status_words(t_ns)
            if self.emitting_on_change:  # ONCHANGED: only when a word changed
                if words == self._rxstatus_sent:
                    return None
                self._rxstatus_sent = words
            if fmt is LogFormat.BINARY:
                return RawBody(rxstatus_binary(0, words), BodyFormat.BINARY)
            return RawBody(rxstatus_ascii(0, words), BodyFormat.ASCII)
        if name == "GPGGA":
            sol = self.solution(t_ns)
            unix = gps_ns_to_unix_ns(t_ns, self._leap_seconds)
            utc = dt.datetime.fromtimestamp(unix // NS_PER_S, tz=dt.UTC)
            sec = utc.second + (unix % NS_PER_S) / NS_PER_S
            used = [s for s in sol.satellites if s.elevation_deg >= self._ecutoff_deg]
            return bodies.gpgga(sol, (utc.hour, utc.minute, sec), self.undulation_m, dops(used)[2])
        return None

    def _time_body(self, t_ns: int) -> Time:
        unix = gps_ns_to_unix_ns(t_ns, self._leap_seconds)
        utc = dt.datetime.fromtimestamp(unix // NS_PER_S, tz=dt.UTC)
        ms = utc.second * 1000 + (unix % NS_PER_S) // 1_000_000
        offset = float(self._rng.normal(0.0, 2e-10))
        status = self.time_status_at(t_ns)
        fine = status is TimeStatus.FINESTEERING
        clock = ClockModelStatus.VALID if fine else (
            ClockModelStatus.CONVERGING if status is TimeStatus.COARSE else ClockModelStatus.INVALID)
        return Time(
            clock, offset, 1.0e-9, -float(self._leap_seconds), utc.year, utc.month, utc.day,
            utc.hour, utc.minute, int(ms), UTCStatus.VALID if fine else UTCStatus.INVALID,
        )

    # --- command handling ------------------------------------------------------------------------

    def _parse_startup(self, line: str) -> Command:
        try:
            return parse_command(line, self.known_logs())
        except ReceiverCommandError as exc:
            raise SimulationError(
                f"sim receiver {self.name}: startup command {line!r} rejected: {exc.reason}"
            ) from None

    def _handle_line(self, st: _PortState, raw: bytes) -> None:
        if self._unresponsive:
            return
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            text = None
        if text is not None and not text.strip():
            self._reply(st, None)
            return
        if text is not None and text.startswith("#RTCM") and self._on_wrapped_ascii(text):
            return  # an RTCM log with a NovAtel ASCII header: a correction, not a command
        self.commands_received += 1
        if text is None or not text.isprintable():
            self._reply(st, "Invalid Message ID")
            return
        try:
            cmd = parse_command(text, self.known_logs())
            self._apply(cmd, st.name)
        except ReceiverCommandError as exc:
            log.debug("sim receiver %s: %r rejected: %s", self.name, text, exc.reason)
            self._reply(st, exc.reason)
            return
        self._reply(st, "")
        if isinstance(cmd, SerialConfigCommand):  # the new rate applies after the response
            self._set_baud(cmd, st.name)

    def _set_baud(self, cmd: SerialConfigCommand, this_port: str) -> None:
        target = self._ports.get(self._resolve_port(cmd.port, this_port))
        if target is not None:
            target.baud = cmd.baud  # kept on a USB/ICOM port too, where it changes nothing

    def _reply(self, st: _PortState, error: str | None) -> None:
        """``error`` "" → ``<OK``; text → ``<ERROR:text``; None → prompt only."""
        if not st.responses or st.pty is None:
            return
        data = b""
        if error == "":
            data = encode_ok()
        elif error is not None:
            data = encode_error(error)
            self.errors_sent += 1
        self._write(st, data + encode_prompt(st.name))

    def _resolve_port(self, port: str | None, this: str) -> str:
        return this if port is None or port == "THISPORT" else port

    def _apply(self, cmd: Command, this_port: str, *, record: bool = True) -> None:
        if isinstance(cmd, LogCommand):
            self._add_log(cmd, this_port)
        elif isinstance(cmd, UnlogCommand):
            key = (self._resolve_port(cmd.port, this_port), cmd.name)
            if key not in self._entries:
                raise ReceiverCommandError("Message Not Found")
            del self._entries[key]
            self._epoch_logs = None
            self._once = [(t, e) for t, e in self._once if (e.port, e.name) != key]
        elif isinstance(cmd, UnlogAllCommand):
            port = self._resolve_port(cmd.port, this_port)
            every = port in ("ALL", "ALL_PORTS")
            for key in [k for k in self._entries if every or k[0] == port]:
                del self._entries[key]
            self._epoch_logs = None
            self._once = [(t, e) for t, e in self._once if not (every or e.port == port)]
        elif isinstance(cmd, InterfaceModeCommand):
            st = self._ports.get(self._resolve_port(cmd.port, this_port))
            if st is not None:
                st.rx_mode, st.tx_mode, st.responses = cmd.rx_type, cmd.tx_type, cmd.responses
        elif isinstance(cmd, FixCommand):
            self._fix = None if cmd.kind in ("NONE", "AUTO") else cmd
            self._solutions.clear()
        elif isinstance(cmd, UndulationCommand):
            self._undulation = cmd
            self._solutions.clear()
        elif isinstance(cmd, EventInCommand):
            self._events[cmd.mark] = cmd
        elif isinstance(cmd, SerialConfigCommand):
            if not record:  # restoring saved settings: no response to wait for
                self._set_baud(cmd, this_port)
        elif isinstance(cmd, SimpleCommand):
            if cmd.name == "SAVECONFIG":
                self._saved = list(self._config)
                return
            if cmd.name == "RESET":
                self._do_reset()
                return
            if cmd.name == "FRESET":
                self._saved = []
                self._do_reset(factory=True)
                return
            self.apply_simple(cmd)
        if record:
            self._config.append((cmd, this_port))

    def _restore(self, config: Sequence[tuple[Command, str]], factory: bool = False) -> None:
        """Back to the factory settings (and the ports as installed, unless ``factory``), then ``config``."""
        self._entries.clear()
        self._epoch_logs = None
        self._once.clear()
        self._fix = None
        self._undulation = UndulationCommand("EGM96")
        self._events = {"MARK1": EventInCommand("MARK1", True)}
        self._ecutoff_deg = 5.0
        self._config = []
        self._solutions.clear()
        for st in self._ports.values():
            # INTERFACEMODE factory default: NOVATEL NOVATEL ON on every port (the lenient twin of old took
            # raw RTCM3 on every wired port but the main one)
            lenient = self.lenient_corrections and st.pty is not None and st.name != self.main_port
            st.rx_mode = "AUTO" if lenient else "NOVATEL"
            st.tx_mode = "NOVATEL"
            st.responses = True
            st.baud = FACTORY_BAUD if factory else self._power_up_baud(st.name, st.pty is not None)
        for cmd, port in config:
            if isinstance(cmd, SimpleCommand) and cmd.name in ("RESET", "FRESET", "SAVECONFIG"):
                continue
            try:
                self._apply(cmd, port, record=False)
            except ReceiverCommandError as exc:
                log.warning("sim receiver %s: saved command %s rejected: %s", self.name, cmd, exc.reason)
            self._config.append((cmd, port))

    def _do_reset(self, factory: bool = False) -> None:
        """RESET (FRESET with ``factory``): output buffers flushed, the saved configuration back (logs not
        saved with SAVECONFIG are gone), the RTK state lost; silent for a moment, then the time status runs
        UNKNOWN → COARSE → FINESTEERING (:class:`StartupTiming`)."""
        self.resets += 1
        self._reset_at_ns = self.gps_now_ns()
        for st in self._ports.values():
            st.pending.clear()
            st.pending_bytes = 0
            st.line.clear()
            st.binary.clear()
            st.framer = None
            st.overrun_at_ns = None
        self._rxstatus_sent = None
        self._restore(self._saved, factory=factory)
        self.on_reset()

    def _add_log(self, cmd: LogCommand, this_port: str) -> None:
        port = self._resolve_port(cmd.port, this_port)
        self._seq += 1
        entry = _LogEntry(
            port, cmd.name, cmd.fmt, cmd.trigger, round(cmd.period_s * NS_PER_S), round(cmd.offset_s * NS_PER_S),
            self._seq,
        )
        now = self.gps_now_ns()
        if cmd.trigger is Trigger.ONTIME:
            entry.next_due_ns = self._grid_at_or_after(now, entry.period_ns, entry.offset_ns)
        elif cmd.trigger is Trigger.ONCE:
            horizon = now - round(self.output_latency_s * NS_PER_S)
            if cmd.name in self.ASYNC_LOGS and cmd.name != "VERSION":
                t = self._last_event_ns
                if t is not None:
                    self._once.append((t, entry))
            else:
                t = (horizon // self.solution_period_ns) * self.solution_period_ns
                self._once.append((t, entry))
            return
        self._entries[(port, cmd.name)] = entry
        self._epoch_logs = None

    # --- production ------------------------------------------------------------------------------

    def _needs_epochs(self) -> bool:
        needs = self._epoch_logs  # asked several times per loop of the thread: cached until the logs change
        if needs is None:
            needs = self._epoch_logs = any(
                e.trigger in (Trigger.ONNEW, Trigger.ONCHANGED, Trigger.ONNEXT) and e.name not in self.ASYNC_LOGS
                for e in self._entries.values()
            )
        return needs

    def _next_data_time(self) -> int | None:
        times = [e.next_due_ns for e in self._entries.values() if e.next_due_ns is not None]
        times.extend(t for t, _ in self._once)
        if self._needs_epochs() and self._next_epoch_ns is not None:
            times.append(self._next_epoch_ns)
        ev = self.next_event_ns(self._event_cursor_ns)
        if ev is not None:
            times.append(ev)
        return min(times) if times else None

    def _produce(self, horizon_ns: int) -> None:
        floor = horizon_ns - _MAX_BACKLOG_NS
        if self._next_epoch_ns is None or self._next_epoch_ns < floor:
            self._next_epoch_ns = self._grid_at_or_after(max(floor, horizon_ns - self.solution_period_ns),
                                                         self.solution_period_ns, 0)
        for e in self._entries.values():
            if e.next_due_ns is not None and e.next_due_ns < floor:
                e.next_due_ns = self._grid_at_or_after(floor, e.period_ns, e.offset_ns)
        if self._event_cursor_ns < floor:
            self._event_cursor_ns = floor
        while True:
            t = self._next_data_time()
            if t is None or t > horizon_ns:
                break
            batch: list[_LogEntry] = []
            once_due = [item for item in self._once if item[0] <= t]
            if once_due:
                self._once = [item for item in self._once if item[0] > t]
                batch.extend(e for _, e in once_due)
            ev = self.next_event_ns(self._event_cursor_ns)
            if ev is not None and ev <= t:
                self._event_cursor_ns = ev
                self._last_event_ns = ev
                renewed = set(self.on_event(ev))
                batch.extend(e for e in self._entries.values() if self._fires_on_event(e, renewed))
                self._emit_batch(ev, batch)
                continue
            if self._next_epoch_ns is not None and self._next_epoch_ns <= t:
                if self._needs_epochs():
                    for e in list(self._entries.values()):
                        if e.name in self.ASYNC_LOGS:
                            continue
                        if e.trigger in (Trigger.ONNEW, Trigger.ONCHANGED):
                            batch.append(e)
                        elif e.trigger is Trigger.ONNEXT:
                            batch.append(e)
                            del self._entries[(e.port, e.name)]
                            self._epoch_logs = None
                self._next_epoch_ns += self.solution_period_ns
            for e in self._entries.values():
                if e.next_due_ns is not None and e.next_due_ns <= t:
                    batch.append(e)
                    e.next_due_ns += e.period_ns
            self._emit_batch(t, batch)

    def _fires_on_event(self, e: _LogEntry, renewed: set[str]) -> bool:
        if e.name in renewed:
            return e.trigger in (Trigger.ONNEW, Trigger.ONCHANGED)
        return e.trigger is Trigger.ONMARK and e.name not in self.ASYNC_LOGS

    def _emit_batch(self, t_ns: int, batch: list[_LogEntry]) -> None:
        if not batch:
            return
        batch.sort(key=lambda e: e.seq)
        names = [e.name for e in batch]
        for e in batch:
            self._emit(e, t_ns, names)

    def _emit(self, entry: _LogEntry, t_ns: int, batch: Sequence[str]) -> None:
        if self.silent_at(t_ns):
            return  # restarting after a reset: nothing goes out
        self.emitting_on_change = entry.trigger in (Trigger.ONNEW, Trigger.ONCHANGED)
        body = self.message(entry.name, entry.fmt, t_ns, batch)
        if body is None or self._logs_paused:
            return
        st = self._ports.get(entry.port)
        if st is None:  # a port this receiver does not have: its logs go nowhere
            self.logs_unrouted += 1
            return
        if isinstance(body, bytes):
            data = body if entry.fmt is LogFormat.ABBREVIATED or not entry.name.startswith("RTCM") else (
                self._wrap_rtcm(entry, body, t_ns))
        elif isinstance(body, list):  # one log per satellite (ephemerides)
            data = b"".join(self._encode(entry, b, t_ns) for b in body)
            if not data:
                return
        else:
            data = self._encode(entry, body, t_ns)
        rate = st.rate_bps
        if st.pty is None:
            # no cable: the port sends all the same (and overruns at its rate); the bytes go nowhere
            self.logs_unrouted += 1
            ready = self.timebase.clock_ns(t_ns) + round(self.output_latency_s * NS_PER_S)
            begin = max(ready, st.free_at_ns)
            busy = len(data) * 10 * NS_PER_S // rate
            if begin - ready + busy > _MAX_PORT_BACKLOG_S * NS_PER_S:
                self._overrun(st, t_ns, len(data))
            else:
                st.free_at_ns = begin + busy
            return
        backlog_s = (st.pending_bytes + len(data)) * 10 / rate
        if backlog_s > _MAX_PORT_BACKLOG_S:  # more logged than the baud rate carries: the port overruns
            self._overrun(st, t_ns, len(data))
            return
        jitter = float(self._rng.uniform(0.0, self.latency_jitter_s)) if self.latency_jitter_s > 0 else 0.0
        ready = self.timebase.clock_ns(t_ns) + round((self.output_latency_s + jitter) * NS_PER_S)
        st.pending.append((ready, data))
        st.pending_bytes += len(data)

    def _overrun(self, st: _PortState, t_ns: int, n: int) -> None:
        """A log the port's buffer cannot take is dropped whole and flagged in the status words (RXSTATUS)."""
        st.bytes_overrun += n
        st.overrun_at_ns = t_ns

    def _wrap_rtcm(self, entry: _LogEntry, frame: bytes, t_ns: int) -> bytes:
        """``RTCMnnnnB`` / ``RTCMnnnnA``: the RTCM3 message with a NovAtel header, for a NOVATEL port
        (Transmitting and receiving corrections, Configuration notes); the ASCII body is the message in hex.

        The message IDs of these logs are not in the codec's table (not verified against the reference),
        so the binary header carries ID 0; a receiver takes such a log by its body (:meth:`_on_wrapped_binary`).
        """
        if entry.fmt is LogFormat.BINARY:
            return self._encode(entry, RawBody(frame, BodyFormat.BINARY), t_ns)
        return self._encode(entry, RawBody(frame.hex().upper().encode("ascii"), BodyFormat.ASCII), t_ns)

    def _encode(self, entry: _LogEntry, body: Message | RawBody, t_ns: int) -> bytes:
        status = self.time_status_at(t_ns)
        if status is TimeStatus.UNKNOWN:  # no GPS time yet: week 0, seconds since the reset
            week, seconds = 0, (t_ns - (self._reset_at_ns or t_ns)) / NS_PER_S
        else:
            week, seconds = t_ns // NS_PER_WEEK, (t_ns % NS_PER_WEEK) / NS_PER_S
        header = Header(
            message_name=entry.name,
            message_id=LOG_IDS.get(entry.name, 0),
            port=entry.port,
            sequence=0,
            idle_time_pct=80.0,
            time_status=status,
            week=week,
            seconds=seconds,
            receiver_status=self.status_words(t_ns)[0],
            reserved=0xB1F6,
            sw_version=16809,
        )
        if entry.fmt is LogFormat.BINARY:
            if isinstance(body, RawBody) and body.fmt is not BodyFormat.BINARY:
                raise SimulationError(f"sim receiver {self.name}: {entry.name} has no binary body")
            return encode_binary(header, body)
        if entry.fmt is LogFormat.ASCII:
            return encode_ascii(header, body)
        if isinstance(body, RawBody):
            text = body.data.decode("latin-1").replace(",", " ")
            body = RawBody(f"<     {text}\r\n".encode("latin-1"), BodyFormat.ABBREVIATED)
        return encode_abbreviated(header, body)

    # --- output ----------------------------------------------------------------------------------

    def _write(self, st: _PortState, data: bytes) -> None:
        pty = st.pty
        if pty is None or not data:
            return
        if self.enforce_baud and st.serial:
            actual = pty.slave_baud()
            if actual is not None and actual != st.baud:
                data = bytes(b ^ 0xA5 for b in data[: max(1, len(data) * actual // max(st.baud, 1))])
        pty.write(data)

    def _flush(self, now_ns: int) -> int | None:
        """Write what is due; return the clock time of the next pending write (None if nothing)."""
        nxt: int | None = None
        for st in self._ports.values():
            while st.pending:
                ready, data = st.pending[0]
                start = max(ready, st.free_at_ns)
                done = start + len(data) * 10 * NS_PER_S // st.rate_bps
                if done > now_ns:
                    nxt = done if nxt is None else min(nxt, done)
                    break
                st.pending.popleft()
                st.pending_bytes -= len(data)
                st.free_at_ns = done
                self._write(st, data)
                if st.pty is not None and self._governed:
                    st.written.append((st.pty.bytes_written, done))
                    if not st.read_seen and len(st.written) > 64:
                        st.written.popleft()
        return nxt

    def _unread_since(self, closed: list[str]) -> int | None:
        """Clock time of the oldest write that a reader of one of the ports has not read yet; the ports
        whose reader closed its end (or that were unplugged) while it owed a write are added to
        ``closed`` (nothing is owed while nobody has a port open)."""
        oldest: int | None = None
        for st in self._ports.values():
            pty = st.pty
            if pty is None or not st.written:
                continue
            if pty.readers() == 0:
                if st.read_seen:
                    closed.append(f"port {st.name}" + ("" if pty.connected else " unplugged"))
                st.written.clear()
                st.read_seen = False
                st.consumed = pty.bytes_written - pty.unread()
                continue
            consumed = pty.bytes_written - pty.unread()
            if consumed > st.consumed:
                st.consumed = consumed
                st.read_seen = True
            written = st.written
            while written and written[0][0] <= consumed:
                written.popleft()
            if written and st.read_seen and (oldest is None or written[0][1] < oldest):
                oldest = written[0][1]
        return oldest

    # --- thread ------------------------------------------------------------------------------------

    def _run(self) -> None:
        speed = float(getattr(self.clock, "speed", 1.0))
        latency_ns = round(self.output_latency_s * NS_PER_S)
        me = participant(self.clock, f"gnss:{self.name}")
        self._governed = me.governed
        gov = getattr(self.clock, "governor", None)
        if not (me.governed and isinstance(gov, ClockGovernor)):
            gov = None
        hold_back = me.budget_ns
        try:
            while not self._stop.is_set():
                self._serve_requests()
                now = self.clock.now_ns()
                # an epoch's logs are made at its data time and written output_latency_s later: the
                # work is done while simulated time runs on towards the write
                self._produce(self.timebase.gps_ns(now))
                next_write = self._flush(now)
                wake: int | None = next_write
                due = next_write
                t_data = self._next_data_time()
                if t_data is not None:
                    c = self.timebase.clock_ns(t_data)
                    wake = c if wake is None else min(wake, c)
                    due = c + latency_ns if due is None else min(due, c + latency_ns)
                timeout = 0.1 if wake is None else min(0.1, max(0.0, (wake - self.clock.now_ns()) / speed / NS_PER_S))
                park_until: int | None = None
                if gov is not None:
                    # simulated time stands still at this receiver's next write until it has written (its
                    # first possible write, data time + output latency, until its logs are made), and at
                    # a write until it is read (not the budget past them): the readers' receive stamps of
                    # GNSS data are the session's host → GPS time base, and a clock that ran the budget
                    # past every late wake-up would put all of them the budget late
                    closed: list[str] = []
                    unread = self._unread_since(closed)
                    for port in closed:
                        me.reader_closed(port)
                    me.at(min(UNBOUNDED_NS if due is None else due - hold_back,
                              UNBOUNDED_NS if unread is None else unread - hold_back))
                    if unread is not None:
                        # the clock stands still until the reader has read: look again soon (a select
                        # timeout is the only way to see a pty's reader drain it)
                        timeout = min(timeout, _UNREAD_POLL_S)
                    elif wake is not None and timeout > 0:
                        # a clock that stands still for another participant cannot reach this receiver's
                        # next wake-up before a participant writes: sleep until one does (the wall-time
                        # timeout would look again and again while the clock stands: under a busy host,
                        # most of the session)
                        park_until = wake
                fds = [st.pty.master_fd for st in self._ports.values() if st.pty is not None and st.pty.connected]
                assert self._wake_r is not None
                watch = [self._wake_r, *(fd for fd in fds if fd is not None)]
                readable = None
                if gov is not None and park_until is not None:
                    readable = self._sleep_while_paused(gov, park_until, watch)
                if readable is None:
                    readable, _, _ = select.select(watch, [], [], timeout)
                for fd in readable:
                    if fd == self._wake_r:
                        with contextlib.suppress(BlockingIOError):
                            os.read(fd, 4096)
                        continue
                    for st in self._ports.values():
                        if st.pty is not None and st.pty.master_fd == fd:
                            data = st.pty.read()
                            if data:
                                self._on_input(st, data)
        except BaseException as exc:
            self.error = exc
            log.exception("sim receiver %s: thread failed", self.name)
            raise
        finally:
            me.close()
            self._serve_requests()

    def _sleep_while_paused(self, gov: ClockGovernor, wake_ns: int, watch: list[int]) -> list[int] | None:
        """Sleep while the governed clock stands still for another participant short of ``wake_ns``:
        until a write that can move it past, or input on ``watch`` (the ports, the wake-up pipe).
        Returns the readable descriptors (each look is a clock reading and a select, not a round of
        the receiver's loop); None when the clock did not stand or there is no futex to sleep on
        (look at the wall time)."""
        slept = False
        while True:
            seen = gov.change_count()  # before the look: no change is missed
            if not (self.clock.now_ns() < wake_ns and gov.paused_now()):
                return select.select(watch, [], [], 0.0)[0] if slept else None
            ready: list[int] = select.select(watch, [], [], 0.0)[0]
            if ready or not gov.wait_for_change(seen, _PAUSED_LOOK_S):
                return ready or None
            slept = True

    def _on_input(self, st: _PortState, data: bytes) -> None:
        if self.silent_at(self.gps_now_ns()):
            return  # restarting: what arrives now is lost
        if self.enforce_baud and st.serial and st.pty is not None:
            actual = st.pty.slave_baud()
            if actual is not None and actual != st.baud:
                return
        mode = st.rx_mode
        if self.lenient_corrections:
            # the old shortcut: AUTO on the command port means commands; on any other port, corrections
            if (mode in _RTCM_RX_MODES and st.name != self.main_port) or mode == "RTCMV3":
                self._on_rtcm_bytes(st, data)
                return
        elif mode == "RTCMV3":
            self._on_rtcm_bytes(st, data)
            return
        if mode not in _COMMAND_RX_MODES:
            return  # NONE (and modes the twin does not decode): the port interprets nothing (INTERFACEMODE)
        raw_rtcm = mode == "AUTO" and not self.lenient_corrections
        for byte in data:
            if st.binary or (not st.line and byte in (0xAA, 0xD3)):
                st.binary.append(byte)
                self._binary_byte(st, raw_rtcm)
            elif byte in (0x0D, 0x0A):
                if byte == 0x0A and st.last_cr:
                    st.last_cr = False
                    continue
                st.last_cr = byte == 0x0D
                line = bytes(st.line)
                st.line.clear()
                self._handle_line(st, line)
            else:
                st.last_cr = False
                if len(st.line) < _MAX_LINE:
                    st.line.append(byte)

    def _binary_byte(self, st: _PortState, raw_rtcm: bool) -> None:
        """One more byte of a binary frame on a command port: a NovAtel binary log or command
        (``AA 44 12``/``13``) or an RTCM3 frame (``D3``); a frame that cannot be one is dropped."""
        buf = st.binary
        n = len(buf)
        if buf[0] == 0xD3:
            if n == 2 and buf[1] & 0xFC:
                buf.clear()
                return
            if n < 3 or n < 6 + ((buf[1] & 0x03) << 8 | buf[2]):
                return
            frame = bytes(buf)
            buf.clear()
            if crc24q(frame[:-3]) != int.from_bytes(frame[-3:], "big"):
                return
            if raw_rtcm:  # AUTO receive: raw RTCM3 is taken as corrections
                self.on_correction_frame(frame, self.gps_now_ns())
            else:  # NOVATEL receive: raw RTCM3 is not a command and no correction (INTERFACEMODE)
                st.rtcm_ignored += 1
            return
        if (n == 2 and buf[1] != 0x44) or (n == 3 and buf[2] not in (0x12, 0x13)):
            buf.clear()
            return
        if n < 10:
            return
        total = 12 + buf[3] + 4 if buf[2] == 0x13 else buf[3] + (buf[8] | buf[9] << 8) + 4
        if total > _MAX_BINARY_FRAME:
            buf.clear()
            return
        if n < total:
            return
        frame = bytes(buf)
        buf.clear()
        if frame[2] == 0x12:  # a long-header log (short-header binary commands are not simulated)
            self._on_wrapped_binary(frame)

    def _on_wrapped_binary(self, frame: bytes) -> None:
        """A NovAtel binary log on a NOVATEL port: one whose body is an RTCM3 message (``RTCM1077B`` …)
        is a correction (Transmitting and receiving corrections, Configuration notes: "the rover
        ... uses the corrections it receives with a NovAtel header"); anything else is not simulated."""
        try:
            body = decode_binary(frame).body
        except ValueError:  # DecodeError: a bad CRC or a malformed header
            return
        if isinstance(body, RawBody) and _is_rtcm_frame(body.data):
            self.on_correction_frame(body.data, self.gps_now_ns())

    def _on_wrapped_ascii(self, text: str) -> bool:
        """``#RTCMnnnnA,…;<hex of the RTCM3 message>*crc``: True when it was a valid wrapped correction."""
        try:
            body = decode_ascii(text).body
            data = bytes.fromhex(body.data.decode("ascii")) if isinstance(body, RawBody) else b""
        except ValueError:
            return False
        if not _is_rtcm_frame(data):
            return False
        self.on_correction_frame(data, self.gps_now_ns())
        return True

    def _on_rtcm_bytes(self, st: _PortState, data: bytes) -> None:
        if st.framer is None:
            st.framer = Framer(decode_logs=False, decode_nmea=False, decode_rtcm=False)
        framer = st.framer
        rx = self.gps_now_ns()
        for frame in framer.feed(data):
            if frame.kind is FrameKind.RTCM3:
                self.on_correction_frame(frame.raw, rx)

    def _wake(self) -> None:
        if self._wake_w is not None:
            with contextlib.suppress(BlockingIOError, OSError):
                os.write(self._wake_w, b"x")

    def _serve_requests(self) -> None:
        while True:
            try:
                fn, result, done = self._requests.get_nowait()
            except queue.Empty:
                return
            try:
                result.append(fn())
            except BaseException as exc:
                result.append(exc)
            done.set()

    def _call(self, fn: Callable[[], _T], timeout_s: float = 5.0) -> _T:
        thread = self._thread
        if thread is None or not thread.is_alive() or threading.current_thread() is thread:
            return fn()
        result: list[object] = []
        done = threading.Event()
        self._requests.put((fn, result, done))
        self._wake()
        if not done.wait(timeout_s):
            raise DeviceTimeoutError(f"sim receiver {self.name}: request not served within {timeout_s} s")
        value = result[0]
        if isinstance(value, BaseException):
            raise value
        return value  # type: ignore[return-value]

    def _pty(self, name: str) -> PtyPort:
        st = self._ports.get(name)
        if st is None or st.pty is None:
            wired = sorted(n for n, p in self._ports.items() if p.pty is not None)
            raise DeviceError(f"sim receiver {self.name}: no port {name!r} wired to a pty (wired: {wired})")
        return st.pty

    def _power_up_baud(self, name: str, wired: bool) -> int:
        """A port's rate at power-up: the installer's saved ``baud`` on a wired port, else the factory 9600."""
        return self._wired_baud if wired and self._wired_baud is not None else FACTORY_BAUD

    def _close_fds(self) -> None:
        for st in self._ports.values():
            if st.pty is not None:
                st.pty.unplug()
        for fd in (self._wake_r, self._wake_w):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._wake_r = self._wake_w = None
        if self._own_dir:
            shutil.rmtree(self.link_dir, ignore_errors=True)


def _is_rtcm_frame(data: bytes) -> bool:
    """One whole CRC-valid RTCM3 transport frame (preamble, 10-bit length, message, CRC-24Q)."""
    return (len(data) >= 6 and data[0] == 0xD3 and not data[1] & 0xFC
            and len(data) == 6 + ((data[1] & 0x03) << 8 | data[2])
            and crc24q(data[:-3]) == int.from_bytes(data[-3:], "big"))


def _default_psn(name: str, seed: int | None) -> str:
    """A product serial number in NovAtel's form (``BMHR17090005E``), the same for the same name and seed."""
    h = zlib.crc32(f"{name}/{seed}".encode())
    return f"BMHR{15 + h % 9:02d}{(h >> 4) % 1_000_000:06d}E"


_HEADER_PORTS = frozenset(
    {"COM1", "COM2", "COM3", "COM4", "COM5", "COM6", "USB1", "USB2", "USB3", "ICOM1", "ICOM2", "ICOM3", "NCOM1",
     "NCOM2", "NCOM3", "XCOM1", "XCOM2", "XCOM3", "AUX", "ETH1", "FILE"}
)


def _tuple3(a: FloatArray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _offset_geodetic(lat_deg: float, lon_deg: float, h_m: float, de: float, dn: float, du: float
                     ) -> tuple[float, float, float]:
    """Geodetic position of a small ENU offset (m) from a point (WGS 84 radii of curvature)."""
    lat = math.radians(lat_deg)
    s = math.sin(lat)
    w = math.sqrt(1.0 - _WGS84_E2 * s * s)
    n_radius = _WGS84_A / w
    m_radius = _WGS84_A * (1.0 - _WGS84_E2) / (w * w * w)
    dlat = dn / (m_radius + h_m)
    dlon = de / ((n_radius + h_m) * math.cos(lat))
    return lat_deg + math.degrees(dlat), lon_deg + math.degrees(dlon), h_m + du
