"""NovAtel configuration commands as text (OEMV / OEM7 abbreviated-ASCII command syntax).

Builders for the commands a session sends at connect, and :func:`standard_configuration` that puts
them in the order a receiver needs (stop old logs, port modes, position fix, event input, logs):

- ``UNLOGALL [port]``
- ``INTERFACEMODE port rxtype txtype [responses]``
- ``SERIALCONFIG port baud parity databits stopbits handshake break``
- ``FIX POSITION lat lon hgt`` / ``FIX NONE``
- ``MARKCONTROL MARK1 ENABLE POSITIVE``
- ``LOG port message trigger [period [offset]]``

Each builder checks its values and raises :class:`vsccore.errors.EncodeError` naming the command
and the value that cannot be sent. Pure text, no I/O.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from drivers.novatel.enums import PORT_ADDRESS
from vsccore.errors import EncodeError

__all__ = [
    "LogRequest",
    "LogTrigger",
    "fix_none_command",
    "fix_position_command",
    "interfacemode_command",
    "log_command",
    "markcontrol_command",
    "serialconfig_command",
    "standard_configuration",
    "undulation_command",
    "unlogall_command",
]

_LOG_NAME = re.compile(r"[A-Z][A-Z0-9]*[ABS]?")
_TOKEN = re.compile(r"[A-Z0-9_]+")


class LogTrigger(Enum):
    """When a receiver sends a requested log."""

    ONTIME = "ONTIME"
    ONNEW = "ONNEW"
    ONCHANGED = "ONCHANGED"
    ONCE = "ONCE"
    ONMARK = "ONMARK"


@dataclass(frozen=True, slots=True)
class LogRequest:
    """One log to request: name with its format suffix (``BESTPOSB``, ``RANGECMPB``), trigger, period."""

    name: str
    trigger: LogTrigger = LogTrigger.ONTIME
    period_s: float | None = None
    offset_s: float | None = None


def _number(value: float, what: str, command: str) -> str:
    if not math.isfinite(value):
        raise EncodeError(f"NovAtel {command}: {what} {value} is not a finite number")
    return format(value, ".10g")


def _port(port: str, command: str) -> str:
    if port not in PORT_ADDRESS:
        raise EncodeError(f"NovAtel {command}: {port!r} is not a NovAtel port name (e.g. COM1, USB1, ICOM1)")
    return port


def _token(value: str, what: str, command: str) -> str:
    if not _TOKEN.fullmatch(value):
        raise EncodeError(f"NovAtel {command}: {what} {value!r} is not a command token")
    return value


def log_command(port: str, request: LogRequest) -> str:
    """``LOG port NAME TRIGGER [period [offset]]``.

    Raises:
        EncodeError: unknown port, bad log name, ONTIME without a positive period.
    """
    name = request.name
    if not _LOG_NAME.fullmatch(name):
        raise EncodeError(f"NovAtel LOG: {name!r} is not a log name (e.g. BESTPOSB)")
    parts = ["LOG", _port(port, "LOG"), name, request.trigger.value]
    if request.trigger is LogTrigger.ONTIME and (request.period_s is None or not request.period_s > 0):
        raise EncodeError(f"NovAtel LOG {name}: ONTIME needs a period > 0 s, got {request.period_s}")
    if request.period_s is not None:
        if request.trigger is not LogTrigger.ONTIME:
            raise EncodeError(f"NovAtel LOG {name}: a period is only valid with ONTIME")
        parts.append(_number(request.period_s, "period", f"LOG {name}"))
        if request.offset_s is not None:
            parts.append(_number(request.offset_s, "offset", f"LOG {name}"))
    return " ".join(parts)


def unlogall_command(port: str | None = None) -> str:
    """``UNLOGALL`` (every port) or ``UNLOGALL port``."""
    return "UNLOGALL" if port is None else f"UNLOGALL {_port(port, 'UNLOGALL')}"


def interfacemode_command(port: str, rx: str, tx: str, responses: bool = True) -> str:
    """``INTERFACEMODE port rx tx ON|OFF`` (rx/tx e.g. NOVATEL, RTCMV3, RTCA, CMR, NONE)."""
    return (
        f"INTERFACEMODE {_port(port, 'INTERFACEMODE')} {_token(rx, 'rx type', 'INTERFACEMODE')} "
        f"{_token(tx, 'tx type', 'INTERFACEMODE')} {'ON' if responses else 'OFF'}"
    )


def serialconfig_command(
    port: str, baud: int, parity: str = "N", databits: int = 8, stopbits: int = 1, handshake: str = "N",
    break_detect: bool = True,
) -> str:
    """``SERIALCONFIG port baud parity databits stopbits handshake ON|OFF``."""
    if baud <= 0:
        raise EncodeError(f"NovAtel SERIALCONFIG {port}: baud {baud} must be > 0")
    if parity not in ("N", "E", "O") or handshake not in ("N", "XON", "CTS") or databits not in (7, 8):
        raise EncodeError(f"NovAtel SERIALCONFIG {port}: bad framing {parity}{databits}{stopbits} {handshake}")
    if stopbits not in (1, 2):
        raise EncodeError(f"NovAtel SERIALCONFIG {port}: stop bits {stopbits} must be 1 or 2")
    return (
        f"SERIALCONFIG {_port(port, 'SERIALCONFIG')} {baud} {parity} {databits} {stopbits} {handshake} "
        f"{'ON' if break_detect else 'OFF'}"
    )


def undulation_command(ellipsoidal: bool) -> str:
    """``UNDULATION USER 0`` (heights are ellipsoidal) or ``UNDULATION EGM96`` (mean sea level, the factory
    setting): how the receiver reads a FIX POSITION height (OEM7 Commands and Logs Reference, UNDULATION, FIX)."""
    return "UNDULATION USER 0.0" if ellipsoidal else "UNDULATION EGM96"


def fix_position_command(lat_deg: float, lon_deg: float, hgt_m: float) -> str:
    """``FIX POSITION lat lon hgt`` (WGS84 degrees, height in m on the receiver's UNDULATION setting: mean sea
    level under the factory EGM96, ellipsoidal after ``UNDULATION USER 0``)."""
    if not -90 <= lat_deg <= 90 or not -180 <= lon_deg <= 360:
        raise EncodeError(f"NovAtel FIX POSITION: latitude {lat_deg} / longitude {lon_deg} out of range")
    if not -1000 <= hgt_m <= 20000:
        raise EncodeError(f"NovAtel FIX POSITION: height {hgt_m} m out of range")
    return f"FIX POSITION {lat_deg:.10f} {lon_deg:.10f} {hgt_m:.4f}"


def fix_none_command() -> str:
    """``FIX NONE``: release a fixed position."""
    return "FIX NONE"


def markcontrol_command(mark: str = "MARK1", enable: bool = True, positive: bool = True) -> str:
    """``MARKCONTROL MARKn ENABLE|DISABLE POSITIVE|NEGATIVE``."""
    if mark not in ("MARK1", "MARK2", "MARK3", "MARK4"):
        raise EncodeError(f"NovAtel MARKCONTROL: {mark!r} is not MARK1..MARK4")
    return f"MARKCONTROL {mark} {'ENABLE' if enable else 'DISABLE'} {'POSITIVE' if positive else 'NEGATIVE'}"


def standard_configuration(
    port: str,
    logs: Sequence[LogRequest],
    *,
    unlogall: bool = True,
    interface_modes: Sequence[tuple[str, str, str]] = (),
    serial_configs: Sequence[tuple[str, int]] = (),
    fix_position: tuple[float, float, float] | None = None,
    fix_height_ellipsoidal: bool = True,
    mark_inputs: Sequence[str] = (),
    extra: Sequence[str] = (),
) -> tuple[str, ...]:
    """The command list of a session, in the order a receiver needs it.

    Args:
        port: the receiver port the host is connected to (logs are requested there).
        logs: the logs to request on ``port``.
        unlogall: start with ``UNLOGALL`` (stop every log on every port).
        interface_modes: ``(port, rx, tx)`` triples, e.g. ``("COM2", "RTCMV3", "NONE")`` on a rover.
        serial_configs: ``(port, baud)`` pairs for other ports (e.g. the correction port), break detection off.
        fix_position: ``(lat_deg, lon_deg, hgt_m)`` for a base receiver, sent after the UNDULATION command
            that says how its height reads (``fix_height_ellipsoidal``: ellipsoidal, else mean sea level).
        mark_inputs: event inputs to enable (``"MARK1"``), positive edge.
        extra: further commands, sent last as given.

    Raises:
        EncodeError: a value cannot be sent (the message names the command).
    """
    commands: list[str] = []
    if unlogall:
        commands.append(unlogall_command())
    # break detection off: a correction link (radio, cable) must not reset the port on a line break
    commands += [serialconfig_command(p, baud, break_detect=False) for p, baud in serial_configs]
    commands += [interfacemode_command(p, rx, tx) for p, rx, tx in interface_modes]
    if fix_position is not None:
        commands.append(undulation_command(fix_height_ellipsoidal))
        commands.append(fix_position_command(*fix_position))
    commands += [markcontrol_command(mark) for mark in mark_inputs]
    commands += [log_command(port, request) for request in logs]
    for command in extra:
        if not command.strip() or "\r" in command or "\n" in command:
            raise EncodeError(f"NovAtel extra command {command!r} is empty or holds a line break")
        commands.append(command.strip())
    return tuple(commands)
