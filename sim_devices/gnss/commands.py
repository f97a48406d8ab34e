"""Parser of the abbreviated-ASCII commands a simulated NovAtel receiver accepts.

Syntax and defaults follow the OEM7 Commands and Logs reference (OEMV accepts the same forms):

- ``LOG [port] message [trigger [period [offset [hold]]]]`` — message with ``A`` (ASCII), ``B``
  (binary) or no suffix (abbreviated ASCII); trigger ONNEW, ONCHANGED, ONTIME, ONNEXT, ONCE,
  ONMARK (default ONCE);
- ``UNLOG [port] message``, ``UNLOGALL [port] [held]``;
- ``INTERFACEMODE [port] rxtype txtype [responses]``;
- ``SERIALCONFIG [port] baud [parity [databits [stopbits [handshake [break]]]]]`` (OEMV: ``COM``);
- ``FIX NONE | FIX AUTO | FIX POSITION lat lon hgt | FIX HEIGHT hgt`` (height above MSL under the
  factory undulation, ellipsoidal after ``UNDULATION USER 0``: FIX);
- ``UNDULATION option [separation]``: EGM96 (factory), OSU89B, USER ±1000 m, and TABLE of older firmware
  (UNDULATION);
- ``EVENTINCONTROL mark switch [polarity [t_bias [t_guard]]]`` (OEM7) and
  ``MARKCONTROL signal switch [polarity [timebias [timeguard]]]`` (OEMV);
- ``SAVECONFIG``, ``RESET``, ``FRESET``, ``ECUTOFF``, ``RTKTIMEOUT``, ``PSRDIFFTIMEOUT``,
  ``RTKSOURCE``, ``PSRDIFFSOURCE``, ``DGPSTXID``, ``ANTENNAPOWER``.

A line that does not parse raises :class:`ReceiverCommandError` with the reason text a receiver puts
after ``<ERROR:`` (fields are numbered from 1 = the command word).
"""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from enum import Enum

from drivers.novatel.enums import PORT_ADDRESS

__all__ = [
    "Command",
    "EventInCommand",
    "FixCommand",
    "InterfaceModeCommand",
    "LogCommand",
    "LogFormat",
    "ReceiverCommandError",
    "SerialConfigCommand",
    "SimpleCommand",
    "Trigger",
    "UndulationCommand",
    "UnlogAllCommand",
    "UnlogCommand",
    "parse_command",
]

MAX_RATE_HZ = 50.0


class ReceiverCommandError(Exception):
    """The receiver answers ``<ERROR:reason``."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class LogFormat(Enum):
    """Output form requested by the message-name suffix."""

    BINARY = "B"
    ASCII = "A"
    ABBREVIATED = ""


class Trigger(Enum):
    """LOG trigger."""

    ONNEW = "ONNEW"
    ONCHANGED = "ONCHANGED"
    ONTIME = "ONTIME"
    ONNEXT = "ONNEXT"
    ONCE = "ONCE"
    ONMARK = "ONMARK"


@dataclass(frozen=True, slots=True)
class LogCommand:
    """``LOG``: ``port`` None means the port the command came in on."""

    port: str | None
    name: str
    fmt: LogFormat
    trigger: Trigger = Trigger.ONCE
    period_s: float = 0.0
    offset_s: float = 0.0


@dataclass(frozen=True, slots=True)
class UnlogCommand:
    port: str | None
    name: str


@dataclass(frozen=True, slots=True)
class UnlogAllCommand:
    port: str | None
    held: bool = False


@dataclass(frozen=True, slots=True)
class InterfaceModeCommand:
    port: str | None
    rx_type: str
    tx_type: str
    responses: bool = True


@dataclass(frozen=True, slots=True)
class SerialConfigCommand:
    port: str | None
    baud: int
    parity: str = "N"
    data_bits: int = 8
    stop_bits: int = 1
    handshake: str = "N"


@dataclass(frozen=True, slots=True)
class FixCommand:
    """``FIX``: kind NONE, AUTO, POSITION (lat deg, lon deg, height m above MSL) or HEIGHT."""

    kind: str
    values: tuple[float, ...] = ()


@dataclass(frozen=True, slots=True)
class UndulationCommand:
    """``UNDULATION``: the geoid model (EGM96, OSU89B, TABLE) or USER with a separation (m)."""

    option: str
    separation_m: float = 0.0


@dataclass(frozen=True, slots=True)
class EventInCommand:
    """``EVENTINCONTROL``/``MARKCONTROL`` for one event input."""

    mark: str
    enabled: bool
    positive: bool = False
    t_bias_ns: int = 0
    t_guard_ms: int = 4


@dataclass(frozen=True, slots=True)
class SimpleCommand:
    """A configuration command the simulator only acknowledges (or applies one value of)."""

    name: str
    args: tuple[str, ...]


Command = (
    LogCommand
    | UnlogCommand
    | UnlogAllCommand
    | InterfaceModeCommand
    | SerialConfigCommand
    | FixCommand
    | UndulationCommand
    | EventInCommand
    | SimpleCommand
)

INTERFACE_MODES = frozenset(
    {"NONE", "NOVATEL", "RTCM", "RTCA", "CMR", "OMNISTAR", "RTCMNOCR", "CDGPS", "TCOM1", "TCOM2", "TCOM3",
     "TAUX", "NOVATELBINARY", "RTCMV3", "NOVATELX", "AUTO", "GENERIC", "MRTCA", "LUA", "TUSB1", "TUSB2", "TUSB3",
     "TETH1", "TNCOM1", "TICOM1", "IMU", "INTERNAL", "KVH", "NMEA"}
)
BAUD_RATES = frozenset({300, 600, 900, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600})
_PORT_NAMES = frozenset(PORT_ADDRESS) | {"THISPORT", "ALL"}


def _is_port(token: str) -> bool:
    return token in _PORT_NAMES


def _float(token: str, field: int, lo: float, hi: float) -> float:
    try:
        value = float(token)
    except ValueError:
        raise ReceiverCommandError(f"Invalid Message. Field = {field}") from None
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ReceiverCommandError(f"Parameter {field} Out Of Range")
    return value


def _int(token: str, field: int, lo: int, hi: int) -> int:
    try:
        value = int(token)
    except ValueError:
        raise ReceiverCommandError(f"Invalid Message. Field = {field}") from None
    if not lo <= value <= hi:
        raise ReceiverCommandError(f"Parameter {field} Out Of Range")
    return value


def _choice(token: str, field: int, choices: Collection[str]) -> str:
    if token not in choices:
        raise ReceiverCommandError(f"Invalid Message. Field = {field}")
    return token


def _split_port(args: list[str]) -> tuple[str | None, list[str], int]:
    """Optional leading port: (port, remaining args, field number of the first remaining arg)."""
    if args and _is_port(args[0]):
        return args[0], args[1:], 3
    return None, args, 2


def _log_name(token: str, known: Collection[str], field: int) -> tuple[str, LogFormat]:
    if token in known:
        return token, LogFormat.ABBREVIATED
    if token[-1:] in ("A", "B") and token[:-1] in known:
        return token[:-1], LogFormat(token[-1])
    raise ReceiverCommandError(f"Invalid Message. Field = {field}")


def _valid_period(period: float) -> bool:
    if period == 0.0:
        return True
    if period < 1.0 / MAX_RATE_HZ - 1e-9:
        return False
    if period < 1.0:  # sub-second periods must divide a second (0.02, 0.05, 0.1, 0.2, 0.25, 0.5)
        n = round(1.0 / period)
        return abs(n * period - 1.0) < 1e-6
    return abs(period * 1000 - round(period * 1000)) < 1e-6


def _parse_log(args: list[str], known: Collection[str]) -> LogCommand:
    port, rest, f = _split_port(args)
    if not rest:
        raise ReceiverCommandError("Message Missing Field")
    name, fmt = _log_name(rest[0], known, f)
    trigger = Trigger.ONCE
    period = offset = 0.0
    if len(rest) > 1:
        try:
            trigger = Trigger(rest[1])
        except ValueError:
            raise ReceiverCommandError(f"Invalid Message. Field = {f + 1}") from None
    if len(rest) > 2:
        period = _float(rest[2], f + 2, 0.0, 3600.0 * 24)
        if not _valid_period(period):
            raise ReceiverCommandError(f"Parameter {f + 2} Out Of Range")
    if len(rest) > 3:
        offset = _float(rest[3], f + 3, 0.0, max(period, 0.0))
        if period > 0 and offset >= period:
            raise ReceiverCommandError(f"Parameter {f + 3} Out Of Range")
    if len(rest) > 4:
        _choice(rest[4], f + 4, ("HOLD", "NOHOLD"))
    if len(rest) > 5:
        raise ReceiverCommandError(f"Invalid Message. Field = {f + 5}")
    if trigger is Trigger.ONTIME and period <= 0.0:
        raise ReceiverCommandError(f"Parameter {f + 2} Out Of Range")
    return LogCommand(port, name, fmt, trigger, period, offset)


def _parse_unlog(args: list[str], known: Collection[str]) -> UnlogCommand:
    port, rest, f = _split_port(args)
    if not rest:
        raise ReceiverCommandError("Message Missing Field")
    if len(rest) > 1:
        raise ReceiverCommandError(f"Invalid Message. Field = {f + 1}")
    name, _ = _log_name(rest[0], known, f)
    return UnlogCommand(port, name)


def _parse_unlogall(args: list[str]) -> UnlogAllCommand:
    port, rest, f = _split_port(args)
    held = False
    if rest:
        held = _choice(rest[0], f, ("TRUE", "FALSE")) == "TRUE"
    if len(rest) > 1:
        raise ReceiverCommandError(f"Invalid Message. Field = {f + 1}")
    return UnlogAllCommand(port, held)


def _parse_interfacemode(args: list[str]) -> InterfaceModeCommand:
    port, rest, f = _split_port(args)
    if len(rest) < 2:
        raise ReceiverCommandError("Message Missing Field")
    rx = _choice(rest[0], f, INTERFACE_MODES)
    tx = _choice(rest[1], f + 1, INTERFACE_MODES)
    responses = True
    if len(rest) > 2:
        responses = _choice(rest[2], f + 2, ("ON", "OFF")) == "ON"
    if len(rest) > 3:
        raise ReceiverCommandError(f"Invalid Message. Field = {f + 3}")
    return InterfaceModeCommand(port, rx, tx, responses)


def _parse_serialconfig(args: list[str]) -> SerialConfigCommand:
    port, rest, f = _split_port(args)
    if not rest:
        raise ReceiverCommandError("Message Missing Field")
    baud = _int(rest[0], f, 0, 10_000_000)
    if baud not in BAUD_RATES:
        raise ReceiverCommandError(f"Parameter {f} Out Of Range")
    parity = _choice(rest[1], f + 1, ("N", "E", "O")) if len(rest) > 1 else "N"
    data_bits = int(_choice(rest[2], f + 2, ("7", "8"))) if len(rest) > 2 else 8
    stop_bits = int(_choice(rest[3], f + 3, ("1", "2"))) if len(rest) > 3 else 1
    handshake = _choice(rest[4], f + 4, ("N", "XON", "CTS")) if len(rest) > 4 else "N"
    if len(rest) > 5:
        _choice(rest[5], f + 5, ("ON", "OFF"))
    if len(rest) > 6:
        raise ReceiverCommandError(f"Invalid Message. Field = {f + 6}")
    return SerialConfigCommand(port, baud, parity, data_bits, stop_bits, handshake)


def _parse_fix(args: list[str]) -> FixCommand:
    if not args:
        raise ReceiverCommandError("Message Missing Field")
    kind = _choice(args[0], 2, ("NONE", "AUTO", "POSITION", "HEIGHT"))
    want = {"NONE": 0, "AUTO": 0, "POSITION": 3, "HEIGHT": 1}[kind]
    if len(args) - 1 < want:
        raise ReceiverCommandError("Message Missing Field")
    if len(args) - 1 > want:
        raise ReceiverCommandError(f"Invalid Message. Field = {want + 3}")
    if kind == "POSITION":
        lat = _float(args[1], 3, -90.0, 90.0)
        lon = _float(args[2], 4, -360.0, 360.0)
        hgt = _float(args[3], 5, -1000.0, 20_000_000.0)
        return FixCommand(kind, (lat, lon, hgt))
    if kind == "HEIGHT":
        return FixCommand(kind, (_float(args[1], 3, -1000.0, 20_000_000.0),))
    return FixCommand(kind)


def _parse_undulation(args: list[str]) -> UndulationCommand:
    if not args:
        raise ReceiverCommandError("Message Missing Field")
    option = _choice(args[0], 2, ("USER", "OSU89B", "EGM96", "TABLE"))
    separation = _float(args[1], 3, -1000.0, 1000.0) if len(args) > 1 else 0.0
    if len(args) > 2:
        raise ReceiverCommandError("Invalid Message. Field = 4")
    return UndulationCommand(option, separation)


def _parse_event(name: str, args: list[str]) -> EventInCommand:
    if len(args) < 2:
        raise ReceiverCommandError("Message Missing Field")
    mark = _choice(args[0], 2, ("MARK1", "MARK2", "MARK3", "MARK4"))
    switches = ("DISABLE", "ENABLE") if name == "MARKCONTROL" else ("DISABLE", "EVENT", "COUNT", "ENABLE")
    enabled = _choice(args[1], 3, switches) != "DISABLE"
    positive = _choice(args[2], 4, ("NEGATIVE", "POSITIVE")) == "POSITIVE" if len(args) > 2 else False
    t_bias = _int(args[3], 5, -999_999_999, 999_999_999) if len(args) > 3 else 0
    t_guard = _int(args[4], 6, 2, 3_599_999) if len(args) > 4 else 4
    if len(args) > 5:
        raise ReceiverCommandError("Invalid Message. Field = 7")
    return EventInCommand(mark, enabled, positive, t_bias, t_guard)


#: Commands acknowledged with their argument count range (min, max).
_SIMPLE: dict[str, tuple[int, int]] = {
    "SAVECONFIG": (0, 0),
    "RESET": (0, 1),
    "FRESET": (0, 1),
    "ECUTOFF": (1, 1),
    "RTKTIMEOUT": (1, 1),
    "PSRDIFFTIMEOUT": (1, 1),
    "RTKSOURCE": (1, 2),
    "PSRDIFFSOURCE": (1, 2),
    "DGPSTXID": (1, 2),
    "ANTENNAPOWER": (1, 1),
}


def parse_command(line: str, known_logs: Collection[str]) -> Command:
    """Parse one command line (without its line end). Command words are case-insensitive.

    Raises:
        ReceiverCommandError: unknown command or a field that does not parse (reason as the receiver says it).
    """
    tokens = line.strip().upper().replace(",", " ").split()
    if not tokens:
        raise ReceiverCommandError("Invalid Message ID")
    name, args = tokens[0], tokens[1:]
    if name == "LOG":
        return _parse_log(args, known_logs)
    if name == "UNLOG":
        return _parse_unlog(args, known_logs)
    if name == "UNLOGALL":
        return _parse_unlogall(args)
    if name == "INTERFACEMODE":
        return _parse_interfacemode(args)
    if name in ("SERIALCONFIG", "COM"):
        return _parse_serialconfig(args)
    if name == "FIX":
        return _parse_fix(args)
    if name == "UNDULATION":
        return _parse_undulation(args)
    if name in ("EVENTINCONTROL", "MARKCONTROL"):
        return _parse_event(name, args)
    limits = _SIMPLE.get(name)
    if limits is None:
        raise ReceiverCommandError("Invalid Message ID")
    if len(args) < limits[0]:
        raise ReceiverCommandError("Message Missing Field")
    if len(args) > limits[1]:
        raise ReceiverCommandError(f"Invalid Message. Field = {limits[1] + 2}")
    if name == "ECUTOFF":
        _float(args[0], 2, -90.0, 90.0)
    elif name in ("RTKTIMEOUT", "PSRDIFFTIMEOUT"):
        _float(args[0], 2, 5.0, 1200.0)
    elif name == "ANTENNAPOWER":
        _choice(args[0], 2, ("ON", "OFF", "ON1", "OFF1"))
    return SimpleCommand(name, tuple(args))
