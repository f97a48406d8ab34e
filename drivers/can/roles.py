"""Signal roles: which DBC signal carries yaw rate, steering-wheel angle, wheel speeds, ...

The rig understands a fixed set of *roles* (``yaw_rate``, ``lat_accel``, ``swa``, wheel
speeds, pressures, the VSC controller's own outputs) plus any extra role a test needs. A role
mapping ties each role to one DBC signal and says how to turn that signal's physical value into
the SI quantity in ISO 8855 axes:

    si = sign · (physical · unit.scale + unit.offset)

where ``physical`` is the DBC-scaled value of ``signal``, ``unit`` is the unit that value is
expressed in (``deg/s``, ``g``, ``km/h``, ``bar`` ...; see :data:`UNITS`), and ``sign`` is
−1 when the sign bit ``sign_signal`` holds ``sign_negative_when``, times −1 again when
``invert`` says the vehicle's convention is the opposite of ISO 8855. An optional quality bit
``valid_signal`` marks values whose raw value differs from ``valid_when`` as
:attr:`~drivers.can.checks.FrameFlag.INVALID` (the value is kept, only flagged).

Configuration (TOML). A roles file (``examples/roles/vw_mqb.toml``, named by ``roles_file``
in a ``[[can]]`` table of the session configuration) has top-level tables; the same tables may
also sit inline in the ``[[can]]`` table::

    [roles.yaw_rate]
    message = "ESP_02"
    signal = "ESP_Gierrate"
    unit = "deg/s"                    # unit of the DBC-scaled value; default: the DBC's unit
    sign_signal = "ESP_VZ_Gierrate"   # optional separate sign bit
    sign_negative_when = 1
    valid_signal = "ESP_QBit_Gierrate"  # optional quality bit
    valid_when = 0                    # or a list of raw values meaning "valid"
    invert = false                    # true: vehicle sign convention opposite to ISO 8855

    [checks.ESP_02]
    counter = "COUNTER"               # default: a COUNTER / *_BZ signal; "" disables
    checksum_signal = "CHECKSUM"      # default: a CHECKSUM / *_CRC signal
    algorithm = "vw_mqb_crc8"         # or "none" (default)
    max_counter_delta = 1             # optional: largest counter step that is not a jump

    checksum = "none"                 # optional default algorithm for role messages without [checks]

:meth:`RoleMap.from_mapping` validates all of it against the DBC and raises
:class:`~vsccore.errors.ConfigError` naming the key, the role, the message and the signal,
with "did you mean" suggestions.

:class:`RoleDecoder` is the live, per-frame decoder (cantools ``decode``); the vectorised,
offline equivalent is :class:`drivers.can.vector_decode.VectorRoleDecoder`. Both flag the same
frames and give the same values.
"""

from __future__ import annotations

import difflib
import logging
import math
import re
import struct
import tomllib
import types
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cantools.database.errors
import numpy as np
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import (
    IdentityConversion,
    LinearConversion,
    LinearIntegerConversion,
    NamedSignalConversion,
)

from drivers.can._records import positional_constructor
from drivers.can.checks import (
    CAN_EFF_FLAG,
    CHECKSUM_NONE,
    ChecksumAlgorithm,
    CounterTracker,
    FrameFlag,
    VwMqbCrc8,
    frame_key,
    get_checksum,
)
from vsccore.errors import ConfigError
from vsccore.roles import ROLE_SI_UNITS

__all__ = [
    "KNOWN_ROLES",
    "ROLE_KEYS",
    "ROLE_SI_UNITS",
    "UNITS",
    "DecodeStats",
    "DecodedFrame",
    "MessageCheck",
    "RoleDecoder",
    "RoleMap",
    "RoleSample",
    "RoleSpec",
    "UnitConversion",
    "encode_role_frame",
    "unit_conversion",
]

log = logging.getLogger(__name__)
_EFF = CAN_EFF_FLAG
_OK = FrameFlag.OK


# --------------------------------------------------------------------------------------------
# Units


@dataclass(frozen=True, slots=True)
class UnitConversion:
    """A unit and how to get to SI from it: ``si = value * scale + offset``."""

    name: str
    si_unit: str
    scale: float
    offset: float = 0.0

    def to_si(self, value: float) -> float:
        return value * self.scale + self.offset

    def from_si(self, value: float) -> float:
        return (value - self.offset) / self.scale


_DEG = math.pi / 180.0
_G0 = 9.80665  # standard gravity, m/s² (CGPM 1901)

UNITS: Mapping[str, UnitConversion] = types.MappingProxyType(
    {
        u.name: u
        for u in (
            UnitConversion("1", "1", 1.0),
            UnitConversion("%", "1", 0.01),
            UnitConversion("rad", "rad", 1.0),
            UnitConversion("deg", "rad", _DEG),
            UnitConversion("rad/s", "rad/s", 1.0),
            UnitConversion("deg/s", "rad/s", _DEG),
            UnitConversion("rpm", "rad/s", 2.0 * math.pi / 60.0),
            UnitConversion("m/s^2", "m/s^2", 1.0),
            UnitConversion("g", "m/s^2", _G0),
            UnitConversion("m/s", "m/s", 1.0),
            UnitConversion("km/h", "m/s", 1.0 / 3.6),
            UnitConversion("mph", "m/s", 0.44704),
            UnitConversion("Pa", "Pa", 1.0),
            UnitConversion("hPa", "Pa", 100.0),
            UnitConversion("kPa", "Pa", 1e3),
            UnitConversion("MPa", "Pa", 1e6),
            UnitConversion("bar", "Pa", 1e5),
            UnitConversion("mbar", "Pa", 100.0),
            UnitConversion("psi", "Pa", 6894.757293168361),
            UnitConversion("m", "m", 1.0),
            UnitConversion("mm", "m", 1e-3),
            UnitConversion("s", "s", 1.0),
            UnitConversion("ms", "s", 1e-3),
            UnitConversion("N", "N", 1.0),
            UnitConversion("Nm", "Nm", 1.0),
            UnitConversion("K", "K", 1.0),
            UnitConversion("degC", "K", 1.0, 273.15),
        )
    }
)

# Other spellings, including the unit strings of common production DBCs (VW writes
# "Unit_DegreOfArcPerSecon"), so a role may omit `unit` when the DBC's unit is recognisable.
_UNIT_ALIASES: Mapping[str, str] = types.MappingProxyType(
    {
        "": "1",
        "-": "1",
        "°": "deg",
        "degree": "deg",
        "degrees": "deg",
        "°/s": "deg/s",
        "deg/sec": "deg/s",
        "m/s2": "m/s^2",
        "m/s²": "m/s^2",
        "m/s**2": "m/s^2",
        "kph": "km/h",
        "kmh": "km/h",
        "Bar": "bar",
        "°C": "degC",
        "Unit_DegreOfArc": "deg",
        "Unit_DegreOfArcPerSecon": "deg/s",
        "Unit_ForceOfGravi": "g",
        "Unit_MeterPerSeconSquar": "m/s^2",
        "Unit_KiloMeterPerHour": "km/h",
        "Unit_MeterPerSecond": "m/s",
        "Unit_Bar": "bar",
        "Unit_MilliBar": "mbar",
        "Unit_PerCent": "%",
        "Unit_NewtoMeter": "Nm",
        "Unit_DegreCelsi": "degC",
        "Unit_MinutInver": "rpm",
    }
)


def unit_conversion(name: str, *, where: str = "unit") -> UnitConversion:
    """The conversion for a unit name or alias.

    Raises:
        ConfigError: unknown unit; names ``where`` and suggests close matches.
    """
    canonical = _UNIT_ALIASES.get(name, name)
    try:
        return UNITS[canonical]
    except KeyError:
        raise ConfigError(f"{where}: unknown unit {name!r}{_did_you_mean(name, list(UNITS))}") from None


# --------------------------------------------------------------------------------------------
# Roles

# the table lives in vsccore so that rig.core.topics can name the roles without importing cantools

KNOWN_ROLES = frozenset(ROLE_SI_UNITS)

ROLE_KEYS = (
    "message",
    "signal",
    "unit",
    "invert",
    "sign_signal",
    "sign_negative_when",
    "valid_signal",
    "valid_when",
)
"""Keys accepted in a ``[can.roles.<role>]`` table."""

CHECK_KEYS = ("counter", "checksum_signal", "algorithm", "max_counter_delta")
"""Keys accepted in a ``[can.checks.<MESSAGE>]`` table."""

_ROLE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
_COUNTER_NAME = re.compile(r"^(COUNTER|.*_BZ)$")
_CHECKSUM_NAME = re.compile(r"^(CHECKSUM|CRC|.*_CRC)$")


@dataclass(frozen=True, slots=True)
class RoleSpec:
    """How one role is read from one DBC signal (see the module docstring for the formula).

    ``unit`` is a key of :data:`UNITS` (aliases are resolved when the map is built).
    ``sign_negative_when`` and ``valid_when`` compare against *raw* values of their signals.
    """

    role: str
    message: str
    signal: str
    unit: str = "1"
    invert: bool = False
    sign_signal: str | None = None
    sign_negative_when: int = 1
    valid_signal: str | None = None
    valid_when: int | tuple[int, ...] = 1

    @property
    def valid_values(self) -> tuple[int, ...]:
        """Raw values of ``valid_signal`` that mean "valid"."""
        return self.valid_when if isinstance(self.valid_when, tuple) else (self.valid_when,)

    @property
    def conversion(self) -> UnitConversion:
        return UNITS[self.unit]

    @property
    def si_unit(self) -> str:
        return UNITS[self.unit].si_unit

    def to_si(self, physical: float, sign_raw: int | None = None) -> float:
        """SI value from the signal's physical value and the raw sign bit (if the role has one)."""
        value = self.conversion.to_si(physical)
        if self.sign_signal is not None and sign_raw == self.sign_negative_when:
            value = -value
        return -value if self.invert else value

    def signal_values(self, value_si: float) -> dict[str, float]:
        """Physical signal values that encode ``value_si`` (the inverse of :meth:`to_si`).

        For simulators and tests that build frames: returns the magnitude signal and, when the
        role has one, the sign bit (a separate sign bit cannot express −0, which encodes as +0).
        """
        value = -value_si if self.invert else value_si
        out: dict[str, float] = {}
        if self.sign_signal is not None:
            negative = value < 0
            out[self.sign_signal] = self.sign_negative_when if negative else 1 - self.sign_negative_when
            value = abs(value)
        out[self.signal] = self.conversion.from_si(value)
        return out

    def to_mapping(self) -> dict[str, Any]:
        """The ``[can.roles.<role>]`` table for this role (optional keys left out when unset)."""
        out: dict[str, Any] = {"message": self.message, "signal": self.signal, "unit": self.unit}
        if self.invert:
            out["invert"] = True
        if self.sign_signal is not None:
            out["sign_signal"] = self.sign_signal
            out["sign_negative_when"] = self.sign_negative_when
        if self.valid_signal is not None:
            out["valid_signal"] = self.valid_signal
            out["valid_when"] = list(self.valid_values) if isinstance(self.valid_when, tuple) else self.valid_when
        return out


@dataclass(frozen=True, slots=True)
class MessageCheck:
    """End-to-end checks of one message: a rolling counter and/or a checksum."""

    message: str
    counter_signal: str | None = None
    checksum_signal: str | None = None
    algorithm: str = CHECKSUM_NONE
    max_counter_delta: int = 1

    @property
    def checksum(self) -> ChecksumAlgorithm:
        return get_checksum(self.algorithm)

    @property
    def verifies_checksum(self) -> bool:
        return self.algorithm != CHECKSUM_NONE and self.checksum_signal is not None

    def to_mapping(self) -> dict[str, Any]:
        """The ``[can.checks.<MESSAGE>]`` table for this check."""
        out: dict[str, Any] = {"counter": self.counter_signal or "", "algorithm": self.algorithm}
        if self.checksum_signal is not None:
            out["checksum_signal"] = self.checksum_signal
        out["max_counter_delta"] = self.max_counter_delta
        return out


@dataclass(frozen=True, slots=True)
class RoleMap:
    """A validated set of roles and message checks; build it with :meth:`from_mapping`."""

    roles: tuple[RoleSpec, ...]
    checks: tuple[MessageCheck, ...] = ()
    _by_role: Mapping[str, RoleSpec] = field(init=False, repr=False, compare=False)
    _by_message: Mapping[str, tuple[RoleSpec, ...]] = field(init=False, repr=False, compare=False)
    _checks: Mapping[str, MessageCheck] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        by_message: dict[str, list[RoleSpec]] = {}
        for spec in self.roles:
            by_message.setdefault(spec.message, []).append(spec)
        object.__setattr__(self, "_by_role", types.MappingProxyType({s.role: s for s in self.roles}))
        object.__setattr__(self, "_by_message", types.MappingProxyType({k: tuple(v) for k, v in by_message.items()}))
        object.__setattr__(self, "_checks", types.MappingProxyType({c.message: c for c in self.checks}))

    # -- queries ---------------------------------------------------------------------------

    @property
    def role_names(self) -> tuple[str, ...]:
        return tuple(s.role for s in self.roles)

    @property
    def messages(self) -> tuple[str, ...]:
        """Names of the messages that carry at least one role or have a check, in first-use order."""
        names = dict.fromkeys([s.message for s in self.roles] + [c.message for c in self.checks])
        return tuple(names)

    def role(self, name: str) -> RoleSpec:
        """The spec of role ``name``. Raises ConfigError (with suggestions) if not mapped."""
        try:
            return self._by_role[name]
        except KeyError:
            raise ConfigError(f"role {name!r} is not mapped{_did_you_mean(name, list(self._by_role))}") from None

    def roles_for_message(self, message: str) -> tuple[RoleSpec, ...]:
        return self._by_message.get(message, ())

    def check_for(self, message: str) -> MessageCheck | None:
        return self._checks.get(message)

    def to_mapping(self) -> dict[str, Any]:
        """The ``[can]`` sub-tables (``roles``, ``checks``) that rebuild this map."""
        return {
            "roles": {s.role: s.to_mapping() for s in self.roles},
            "checks": {c.message: c.to_mapping() for c in self.checks},
        }

    # -- construction ----------------------------------------------------------------------

    @classmethod
    def from_toml(cls, path: str | Path, db: Database) -> RoleMap:
        """Read a roles file (top-level ``[roles.*]`` / ``[checks.*]``) or the single ``[can]``
        table of a configuration file (see :meth:`from_mapping`).

        Raises:
            ConfigError: unreadable file, TOML syntax error, or an invalid mapping.
        """
        p = Path(path)
        try:
            with p.open("rb") as fh:
                doc = tomllib.load(fh)
        except FileNotFoundError:
            raise ConfigError(f"{p}: role configuration not found") from None
        except OSError as exc:
            raise ConfigError(f"{p}: cannot read role configuration: {exc.strerror or exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: TOML syntax error: {exc}") from None
        if "roles" in doc or "checks" in doc:
            return cls.from_mapping(doc, db, source=str(p))
        can_table = doc.get("can")
        if isinstance(can_table, Mapping):
            return cls.from_mapping(can_table, db, source=str(p), key_prefix="can.")
        raise ConfigError(f"{p}: no [roles.<role>] tables (nor a [can] table holding them)")

    @classmethod
    def from_mapping(
        cls, can_table: Mapping[str, Any], db: Database, *, source: str = "config", key_prefix: str = ""
    ) -> RoleMap:
        """Build and validate a role map from a roles table or a ``[[can]]`` table.

        Reads ``can_table["roles"]`` (one table per role, keys :data:`ROLE_KEYS`),
        ``can_table["checks"]`` (one table per message, keys :data:`CHECK_KEYS`) and
        ``can_table["checksum"]`` (default algorithm, ``"none"`` if absent). Other keys (dbc,
        interface, channel ...) are ignored here, so a pydantic ``model_dump()`` of the session's
        CAN configuration can be passed as is (``None`` means "not given").

        Every message used by a role gets a check: the explicit ``checks.<MESSAGE>`` one,
        or else a counter check on a signal named ``COUNTER`` or ``*_BZ`` and, when the default
        algorithm is not ``"none"``, a checksum check on a signal named ``CHECKSUM``/``*_CRC``.

        Raises:
            ConfigError: unknown key, message, signal, unit or algorithm; a unit of the wrong
                dimension for a known role; a checksum algorithm that does not support the
                message. Messages start with ``source`` and the key path
                (``{key_prefix}roles.yaw_rate.signal``) and carry "did you mean" suggestions.
        """
        base = f"{source}: {key_prefix}"
        roles_table = can_table.get("roles", {})
        if not isinstance(roles_table, Mapping):
            raise ConfigError(f"{base}roles must be a table of role tables")
        checks_table = can_table.get("checks", {})
        if not isinstance(checks_table, Mapping):
            raise ConfigError(f"{base}checks must be a table of message tables")
        default_algo = can_table.get("checksum") or CHECKSUM_NONE
        if not isinstance(default_algo, str):
            raise ConfigError(f"{base}checksum must be a string, got {default_algo!r}")
        get_checksum(default_algo, where=f"{base}checksum")

        specs = tuple(_role_from_table(str(name), table, db, base) for name, table in roles_table.items())
        checks: dict[str, MessageCheck] = {}
        for msg_name, table in checks_table.items():
            checks[str(msg_name)] = _check_from_table(str(msg_name), table, db, base)
        for spec in specs:
            if spec.message not in checks:
                auto = _auto_check(db.get_message_by_name(spec.message), default_algo, base)
                if auto is not None:
                    checks[spec.message] = auto
        return cls(roles=specs, checks=tuple(checks.values()))


def _did_you_mean(name: str, candidates: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(candidates), n=3, cutoff=0.6)
    return f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""


def _message(db: Database, name: Any, where: str) -> Message:
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}: message must be a non-empty string, got {name!r}")
    try:
        return db.get_message_by_name(name)
    except KeyError:
        names = [m.name for m in db.messages]
        raise ConfigError(f"{where}: message {name!r} is not in the DBC{_did_you_mean(name, names)}") from None


def _signal_in(db: Database, message: Message, name: Any, where: str, role: str) -> str:
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}: signal name must be a non-empty string, got {name!r}")
    names = [s.name for s in message.signals]
    if name in names:
        return name
    elsewhere = [m.name for m in db.messages if any(s.name == name for s in m.signals)]
    hint = f"; {name!r} is in message(s) {', '.join(elsewhere)}" if elsewhere else _did_you_mean(name, names)
    raise ConfigError(f"{where}: role {role!r}: signal {name!r} is not in message {message.name!r}{hint}")


def _check_keys(table: Mapping[str, Any], allowed: tuple[str, ...], where: str) -> None:
    for key in table:
        if key not in allowed:
            hint = _did_you_mean(str(key), allowed)
            raise ConfigError(f"{where}.{key}: unknown key{hint} (allowed: {', '.join(allowed)})")


def _int(table: Mapping[str, Any], key: str, default: int, where: str) -> int:
    value = table.get(key)
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}.{key}: must be an integer, got {value!r}")
    return value


def _valid_when(table: Mapping[str, Any], where: str) -> int | tuple[int, ...]:
    value = table.get("valid_when")
    if isinstance(value, list | tuple):
        if not value or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ConfigError(f"{where}.valid_when: must be an integer or a non-empty list of integers, got {value!r}")
        return tuple(int(v) for v in value)
    return _int(table, "valid_when", 1, where)


def _role_from_table(role: str, table: Any, db: Database, base: str) -> RoleSpec:
    where = f"{base}roles.{role}"
    if not _ROLE_NAME.match(role):
        raise ConfigError(f"{where}: role names are lower-case identifiers (a-z, 0-9, _)")
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: must be a table with keys {', '.join(ROLE_KEYS)}")
    _check_keys(table, ROLE_KEYS, where)
    for key in ("message", "signal"):
        if key not in table:
            raise ConfigError(f"{where}.{key}: missing (required)")
    message = _message(db, table["message"], f"{where}.message")
    signal_name = _signal_in(db, message, table["signal"], f"{where}.signal", role)
    signal = message.get_signal_by_name(signal_name)

    unit_raw = table.get("unit")
    inferred = unit_raw is None
    if unit_raw is None:
        dbc_unit = signal.unit or ""
        if dbc_unit not in UNITS and dbc_unit not in _UNIT_ALIASES:
            raise ConfigError(
                f"{where}.unit: missing, and the DBC unit {dbc_unit!r} of {message.name}.{signal_name} "
                "is not recognised; give the unit of the signal's physical value"
            )
        unit_raw = dbc_unit
    if not isinstance(unit_raw, str):
        raise ConfigError(f"{where}.unit: must be a string, got {unit_raw!r}")
    conversion = unit_conversion(unit_raw, where=f"{where}.unit")
    expected = ROLE_SI_UNITS.get(role)
    if expected is not None and conversion.si_unit != expected:
        what = f"missing; the DBC unit {unit_raw!r} of {message.name}.{signal_name}" if inferred else repr(unit_raw)
        raise ConfigError(f"{where}.unit: {what} converts to {conversion.si_unit}, but role {role!r} is in {expected}")

    invert = table.get("invert") or False
    if not isinstance(invert, bool):
        raise ConfigError(f"{where}.invert: must be true or false, got {invert!r}")
    sign_signal = table.get("sign_signal")
    if sign_signal is not None:
        sign_signal = _signal_in(db, message, sign_signal, f"{where}.sign_signal", role)
    valid_signal = table.get("valid_signal")
    if valid_signal is not None:
        valid_signal = _signal_in(db, message, valid_signal, f"{where}.valid_signal", role)
    if (invert or sign_signal is not None) and conversion.offset != 0.0:
        raise ConfigError(f"{where}: a sign flip cannot apply to unit {unit_raw!r}, which has an offset")
    return RoleSpec(
        role=role,
        message=message.name,
        signal=signal_name,
        unit=conversion.name,
        invert=invert,
        sign_signal=sign_signal,
        sign_negative_when=_int(table, "sign_negative_when", 1, where),
        valid_signal=valid_signal,
        valid_when=_valid_when(table, where),
    )


def _check_from_table(msg_name: str, table: Any, db: Database, base: str) -> MessageCheck:
    where = f"{base}checks.{msg_name}"
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: must be a table with keys {', '.join(CHECK_KEYS)}")
    _check_keys(table, CHECK_KEYS, where)
    message = _message(db, msg_name, where)
    counter = table.get("counter")
    if counter is None:
        counter = _detect(message, _COUNTER_NAME)
    elif counter == "":
        counter = None
    else:
        counter = _signal_in(db, message, counter, f"{where}.counter", "(counter)")
    algorithm = table.get("algorithm") or CHECKSUM_NONE
    if not isinstance(algorithm, str):
        raise ConfigError(f"{where}.algorithm: must be a string, got {algorithm!r}")
    algo = get_checksum(algorithm, where=f"{where}.algorithm")
    checksum_signal = table.get("checksum_signal")
    if checksum_signal is not None:
        checksum_signal = _signal_in(db, message, checksum_signal, f"{where}.checksum_signal", "(checksum)")
    elif algorithm != CHECKSUM_NONE:
        checksum_signal = _detect(message, _CHECKSUM_NAME)
        if checksum_signal is None:
            raise ConfigError(f"{where}.checksum_signal: missing, and no CHECKSUM/*_CRC signal in {message.name}")
    if not algo.supports(message.frame_id):
        raise ConfigError(
            f"{where}.algorithm: {algorithm!r} has no parameters for {message.name} (0x{message.frame_id:X})"
        )
    max_delta = _int(table, "max_counter_delta", 1, where)
    if counter is not None:
        modulus = 1 << message.get_signal_by_name(counter).length
        if not 1 <= max_delta < modulus:
            raise ConfigError(f"{where}.max_counter_delta: must be in 1..{modulus - 1}, got {max_delta}")
    return MessageCheck(message.name, counter, checksum_signal, algorithm, max_delta)


def _auto_check(message: Message, default_algo: str, base: str) -> MessageCheck | None:
    counter = _detect(message, _COUNTER_NAME)
    checksum_signal = _detect(message, _CHECKSUM_NAME) if default_algo != CHECKSUM_NONE else None
    if checksum_signal is not None and not get_checksum(default_algo).supports(message.frame_id):
        raise ConfigError(
            f"{base}checksum: {default_algo!r} has no parameters for {message.name} "
            f'(0x{message.frame_id:X}); add [checks.{message.name}] with algorithm = "none"'
        )
    if counter is None and checksum_signal is None:
        return None
    algorithm = default_algo if checksum_signal is not None else CHECKSUM_NONE
    return MessageCheck(message.name, counter, checksum_signal, algorithm)


def _detect(message: Message, pattern: re.Pattern[str]) -> str | None:
    for s in message.signals:
        if pattern.match(s.name):
            return s.name
    return None


# --------------------------------------------------------------------------------------------
# Live decoding


@dataclass(frozen=True, slots=True)
class RoleSample:
    """One role value from one frame.

    ``value`` is SI (``unit``) in ISO 8855 axes; ``raw`` is the raw integer (or float) of the
    role's signal and ``label`` its DBC choice name, if it has one (enums keep both).
    ``flags`` is ``OK`` or ``INVALID`` (quality bit says substitute value).
    """

    role: str
    timestamp_ns: int
    value: float
    unit: str
    raw: int | float
    label: str | None = None
    flags: FrameFlag = FrameFlag.OK


@dataclass(frozen=True, slots=True)
class DecodedFrame:
    """What :meth:`RoleDecoder.decode` made of one frame.

    ``message`` is None for identifiers not in the DBC. A frame with a frame-level flag
    (wrong length, checksum, counter, decode error, unknown id) has no samples.
    """

    timestamp_ns: int
    arbitration_id: int
    message: str | None
    flags: FrameFlag
    samples: tuple[RoleSample, ...] = ()


@dataclass(frozen=True, slots=True)
class DecodeStats:
    """Counts since the decoder was made: frames seen, frames with role values, flags, unknown ids."""

    frames: int
    decoded: int
    unknown_ids: Mapping[int, int]
    flagged: Mapping[str, int]


@dataclass(slots=True)
class _LiveMessage:
    message: Message
    specs: tuple[RoleSpec, ...]
    check: MessageCheck | None
    algorithm: ChecksumAlgorithm | None
    counter: CounterTracker | None
    fast: Callable[[bytes, int], DecodedFrame | FrameFlag] | None = None
    """The compiled decoder (None: the generic cantools path)."""
    name: str = ""
    frame_id: int = 0
    length: int = 0


# --------------------------------------------------------------------------------------------
# Live decoding, compiled: per message, straight-line Python made once from the DBC
#
# The generic path (cantools ``Message.decode`` of every signal, then a walk over the specs) costs
# ~40 µs a frame; a 1 Mbit/s bus at full load carries ~8000 frames/s. For each message the signals
# the roles and checks need (and the multiplexers that select them) are turned into shift-and-mask
# expressions on the payload read as one integer, the conversions into inline arithmetic with the
# DBC's own scale/offset objects (so every float is computed by the same operations as cantools
# and :meth:`RoleSpec.to_si`), and the code is compiled into one function. Messages the generator
# does not handle (container messages, signals beyond the payload, float multiplexers) keep the
# generic path. Tests compare both paths frame by frame.

_F32 = struct.Struct("<f").unpack
_F64 = struct.Struct("<d").unpack


_new_sample = positional_constructor(RoleSample)
_new_decoded = positional_constructor(DecodedFrame)


class _UncompilableError(Exception):
    """The message needs the generic path."""


def _extract_expr(signal: Signal, length: int) -> tuple[str, bool]:
    """Expression of the raw value of ``signal`` from ``le``/``be`` (the payload as a little/big-endian
    int) as cantools gives it with ``scaling=False``, and whether it reads ``be``."""
    n = signal.length
    if n < 1:
        raise _UncompilableError(f"signal {signal.name} has length {n}")
    mask = (1 << n) - 1
    if signal.byte_order == "big_endian":
        msb_lin = 8 * (signal.start // 8) + 7 - signal.start % 8
        shift = 8 * length - 1 - (msb_lin + n - 1)
        bits, big = f"((be >> {shift}) & {mask})", True
    else:
        shift = signal.start
        bits, big = f"((le >> {shift}) & {mask})", False
    if shift < 0 or shift + n > 8 * length:
        raise _UncompilableError(f"signal {signal.name} reaches beyond the {length}-byte payload")
    if signal.is_float:
        if n == 32:
            return f"_F32(({bits}).to_bytes(4, 'little'))[0]", big
        if n == 64:
            return f"_F64(({bits}).to_bytes(8, 'little'))[0]", big
        raise _UncompilableError(f"float signal {signal.name} of {n} bits")
    if signal.is_signed:
        return f"(({bits} ^ {1 << (n - 1)}) - {1 << (n - 1)})", big
    return bits, big


def _scaled_expr(signal: Signal, raw: str, ns: dict[str, Any], tag: str) -> str:
    """``float(signal.conversion.raw_to_scaled(raw, decode_choices=False))`` as an expression."""
    conv = signal.conversion
    inner = getattr(conv, "_conversion", None) if isinstance(conv, NamedSignalConversion) else conv
    # float() of a float is the same float: left out where the value is a float already
    if isinstance(inner, IdentityConversion):
        return raw if signal.is_float else f"float({raw})"
    if isinstance(inner, LinearIntegerConversion | LinearConversion):
        ns[f"_S{tag}"], ns[f"_O{tag}"] = inner.scale, inner.offset
        expr = f"{raw} * _S{tag} + _O{tag}"
        floats = signal.is_float or isinstance(inner.scale, float) or isinstance(inner.offset, float)
        return f"({expr})" if floats else f"float({expr})"
    ns[f"_RT{tag}"] = conv.raw_to_scaled
    return f"float(_RT{tag}({raw}, decode_choices=False))"


def _fast_checksum(algorithm: ChecksumAlgorithm, frame_id: int) -> Callable[[bytes], int] | None:
    """``algorithm.compute(frame_id, ·)`` without numpy per byte for the VW MQB CRC (None: use ``compute``)."""
    if not isinstance(algorithm, VwMqbCrc8) or frame_id not in algorithm.data_ids:
        return None
    table = tuple(int(v) for v in np.asarray(algorithm._table).tolist())  # the algorithm's own CRC table
    ids = tuple(int(v) for v in algorithm.data_ids[frame_id])
    if len(table) != 256 or len(ids) != 16:
        return None

    def compute(data: bytes) -> int:
        if len(data) < 2:
            return algorithm.compute(frame_id, data)  # raises as the generic path does
        crc = 0xFF
        for byte in data[1:]:
            crc = table[crc ^ byte]
        return table[crc ^ ids[data[1] & 0x0F]] ^ 0xFF

    return compute


def _compile_message(live: _LiveMessage) -> Callable[[bytes, int], DecodedFrame | FrameFlag]:
    """The straight-line decoder of one message: ``(payload, timestamp_ns) ->`` the decoded frame, or the
    frame-level flag that stops it (``DECODE_ERROR``, ``CHECKSUM``, ``COUNTER``).

    The payload has the message's length (checked by the caller). Raises :class:`_UncompilableError`.
    """
    message = live.message
    if message.is_container:
        raise _UncompilableError("container message")
    length = message.length
    by_name = {s.name: s for s in message.signals}
    children: dict[str, set[int]] = {}
    for s in message.signals:
        if s.multiplexer_signal is not None and s.multiplexer_ids:
            children.setdefault(s.multiplexer_signal, set()).update(int(i) for i in s.multiplexer_ids)
    check = live.check
    wanted: list[str] = list(children)
    for spec in live.specs:
        wanted += [n for n in (spec.signal, spec.sign_signal, spec.valid_signal) if n is not None]
    if check is not None:
        wanted += [n for n in (check.counter_signal, check.checksum_signal) if n is not None]
    # multiplexers before what they select (the ancestors of every wanted signal)
    order: list[str] = []

    def visit(name: str, depth: int = 0) -> None:
        if name in order:
            return
        if name not in by_name or depth > len(by_name):
            raise _UncompilableError(f"signal {name} (or a multiplexer cycle)")
        parent = by_name[name].multiplexer_signal
        if parent is not None:
            visit(parent, depth + 1)
        order.append(name)

    for name in wanted:
        visit(name)
    var = {name: f"r{i}" for i, name in enumerate(order)}
    ns: dict[str, Any] = {"_F32": _F32, "_F64": _F64, "_new_sample": _new_sample, "_from": int.from_bytes,
                          "_DECODE_ERROR": FrameFlag.DECODE_ERROR, "_CHECKSUM": FrameFlag.CHECKSUM,
                          "_COUNTER": FrameFlag.COUNTER, "_OK": FrameFlag.OK, "_INVALID": FrameFlag.INVALID}
    body: list[str] = []
    present: dict[str, str] = {}  # name -> condition ("" when always present)
    uses = {"le": False, "be": False}
    for name in order:
        s = by_name[name]
        expr, big = _extract_expr(s, length)
        uses["be" if big else "le"] = True
        parent = s.multiplexer_signal
        if parent is None:
            present[name] = ""
            body.append(f"{var[name]} = {expr}")
        else:
            if by_name[parent].is_float:
                raise _UncompilableError(f"float multiplexer {parent}")
            ns[f"_ids_{var[name]}"] = frozenset(int(i) for i in s.multiplexer_ids or ())
            cond = f"{var[parent]} in _ids_{var[name]}"
            if present[parent]:
                cond = f"{present[parent]} and {cond}"
            present[name] = f"p_{var[name]}"
            body.append(f"p_{var[name]} = {cond}")
            body.append(f"{var[name]} = {expr} if p_{var[name]} else None")
        if name in children:  # cantools: a multiplexer value no signal is defined for fails the frame
            ns[f"_kids_{var[name]}"] = frozenset(children[name])
            guard = f"{present[name]} and " if present[name] else ""
            body.append(f"if {guard}{var[name]} not in _kids_{var[name]}:")
            body.append("    return _DECODE_ERROR")
    def as_int(name: str) -> str:  # int() of an int signal's raw value is the value itself
        return f"int({var[name]})" if by_name[name].is_float else var[name]

    def absent(name: str) -> str:  # "... is None or " for a multiplexed signal, else nothing
        return f"{var[name]} is None or " if present[name] else ""

    def there(name: str) -> str:
        return f"{var[name]} is not None and " if present[name] else ""

    head = []
    if uses["le"]:
        head.append("le = _from(data, 'little')")
    if uses["be"]:
        head.append("be = _from(data, 'big')")
    lines = ["def decode(data, ts):", *("    " + x for x in head + body)]
    if check is not None and live.algorithm is not None and check.checksum_signal is not None:
        fast = _fast_checksum(live.algorithm, message.frame_id)
        if fast is not None:
            ns["_crc"] = fast
            call = "_crc(data)"
        else:
            ns["_algorithm"] = live.algorithm
            call = f"_algorithm.compute({message.frame_id}, data)"
        cs = check.checksum_signal
        lines.append(f"    if {absent(cs)}{as_int(cs)} != {call}:")
        lines.append("        return _CHECKSUM")
    if live.counter is not None and check is not None and check.counter_signal is not None:
        ns["_counter_check"] = live.counter.check
        cnt = check.counter_signal
        lines.append(f"    if {there(cnt)}_counter_check({as_int(cnt)}):")
        lines.append("        return _COUNTER")
    ns["_new_decoded"], ns["_FID"], ns["_NAME"] = _new_decoded, message.frame_id, message.name
    # samples of roles whose signal is always present are locals; multiplexed ones are collected
    collect = any(present[spec.signal] for spec in live.specs)
    if collect:
        lines.append("    out = []")
    for k, spec in enumerate(live.specs):
        s = by_name[spec.signal]
        r = var[spec.signal]
        conv = spec.conversion
        ns[f"_role{k}"], ns[f"_unit{k}"] = spec.role, spec.si_unit
        ns[f"_US{k}"], ns[f"_UO{k}"] = conv.scale, conv.offset
        ind = "    "
        if present[spec.signal]:
            lines.append(f"    if {r} is not None:")
            ind = "        "
        lines.append(f"{ind}v = {_scaled_expr(s, r, ns, str(k))} * _US{k} + _UO{k}")
        if spec.sign_signal is not None:
            ns[f"_NEG{k}"] = spec.sign_negative_when
            sg = spec.sign_signal
            lines.append(f"{ind}if {there(sg)}{as_int(sg)} == _NEG{k}:")
            lines.append(f"{ind}    v = -v")
        if spec.invert:
            lines.append(f"{ind}v = -v")
        if spec.valid_signal is not None:
            ns[f"_VALID{k}"] = spec.valid_values
            vs = spec.valid_signal
            lines.append(f"{ind}fl = _INVALID if {absent(vs)}{as_int(vs)} not in _VALID{k} else _OK")
        else:
            lines.append(f"{ind}fl = _OK")
        if s.choices:
            ns[f"_CH{k}"] = {key: str(val) for key, val in s.choices.items()}
            label = f"_CH{k}.get({r})"
        else:
            label = "None"
        new = f"_new_sample(_role{k}, ts, v, _unit{k}, {r}, {label}, fl)"
        lines.append(f"{ind}out.append({new})" if collect else f"{ind}s{k} = {new}")
    if collect:
        lines.append("    return _new_decoded(ts, _FID, _NAME, _OK, tuple(out))")
    else:
        samples = "".join(f"s{k}, " for k in range(len(live.specs)))
        lines.append(f"    return _new_decoded(ts, _FID, _NAME, _OK, ({samples}))")
    exec(compile("\n".join(lines), f"<role decoder {message.name}>", "exec"), ns)  # numbers and ns names only
    decode: Callable[[bytes, int], DecodedFrame | FrameFlag] = ns["decode"]
    return decode



class RoleDecoder:
    """Per-frame decoder from CAN frames to role samples (the live path).

    Each message with roles or checks gets a decoder compiled from the DBC (only the signals it
    needs, shift-and-mask on the payload as one integer, conversions inline); with
    ``compiled=False``, or for a message the compiler does not handle, cantools
    ``Message.decode`` does the bit work. Either way it then applies checks, units, sign bits and
    quality bits, with the same results. Not thread-safe: call :meth:`decode` from one thread (the
    counter state is per message).
    """

    def __init__(self, db: Database, rolemap: RoleMap, *, compiled: bool = True) -> None:
        self._db = db
        self._rolemap = rolemap
        self._by_id: dict[int, _LiveMessage] = {}
        for message in db.messages:
            specs = rolemap.roles_for_message(message.name)
            check = rolemap.check_for(message.name)
            algorithm = check.checksum if check is not None and check.verifies_checksum else None
            counter = None
            if check is not None and check.counter_signal is not None:
                modulus = 1 << message.get_signal_by_name(check.counter_signal).length
                counter = CounterTracker(modulus, check.max_counter_delta)
            live = _LiveMessage(message, specs, check, algorithm, counter, None, message.name, message.frame_id,
                                message.length)
            if compiled and (specs or check is not None):
                try:
                    live.fast = _compile_message(live)
                except _UncompilableError as exc:
                    log.info("CAN message %s decoded by cantools (not compiled: %s)", message.name, exc)
            self._by_id[frame_key(message.frame_id, message.is_extended_frame)] = live
        self._frames = 0
        self._decoded = 0
        self._unknown: dict[int, int] = {}
        self._flagged: dict[str, int] = {}

    @property
    def rolemap(self) -> RoleMap:
        return self._rolemap

    @property
    def compiled_messages(self) -> tuple[str, ...]:
        """Messages decoded by their compiled decoder (the others with roles or checks go through cantools)."""
        return tuple(live.message.name for live in self._by_id.values() if live.fast is not None)

    def stats(self) -> DecodeStats:
        """A snapshot of the counters."""
        return DecodeStats(
            frames=self._frames,
            decoded=self._decoded,
            unknown_ids=types.MappingProxyType(dict(self._unknown)),
            flagged=types.MappingProxyType(dict(self._flagged)),
        )

    def reset(self) -> None:
        """Forget counter history (call after the bus was reopened: the next frame is not a jump)."""
        for live in self._by_id.values():
            if live.counter is not None:
                live.counter.reset()

    def decode(self, arbitration_id: int, data: bytes, timestamp_ns: int, is_extended: bool = False) -> DecodedFrame:
        """Decode one frame into role samples; never raises on bad frames, flags them instead.

        ``is_extended`` tells a 29-bit identifier (or pass ``arbitration_id`` with
        :data:`~drivers.can.checks.CAN_EFF_FLAG` set); unknown identifiers are counted by that key.
        """
        self._frames += 1
        if is_extended or arbitration_id & _EFF:  # frame_key, inline
            key = (arbitration_id & 0x1FFF_FFFF) | _EFF
        else:
            key = arbitration_id & 0x1FFF_FFFF
        live = self._by_id.get(key)
        if live is None:
            self._unknown[key] = self._unknown.get(key, 0) + 1
            return self._flag(timestamp_ns, arbitration_id, None, FrameFlag.UNKNOWN_ID)
        fast = live.fast
        if fast is not None:  # (compiled only for messages with roles or checks)
            if type(data) is not bytes:
                data = bytes(data)
            if len(data) != live.length:
                return self._flag(timestamp_ns, live.frame_id, live.name, FrameFlag.WRONG_LENGTH)
            res = fast(data, timestamp_ns)
            if isinstance(res, DecodedFrame):
                if res.samples:
                    self._decoded += 1
                return res
            return self._flag(timestamp_ns, live.frame_id, live.name, res)
        message = live.message
        arbitration_id = message.frame_id
        if not live.specs and live.check is None:
            return _new_decoded(timestamp_ns, arbitration_id, message.name, _OK, ())
        data = bytes(data)
        if len(data) != message.length:
            return self._flag(timestamp_ns, arbitration_id, message.name, FrameFlag.WRONG_LENGTH)
        try:
            decoded = message.decode(data, decode_choices=False, scaling=False)
        except (cantools.database.errors.DecodeError, ValueError, KeyError):
            return self._flag(timestamp_ns, arbitration_id, message.name, FrameFlag.DECODE_ERROR)
        if not isinstance(decoded, dict):  # container messages; the rig does not use them
            return self._flag(timestamp_ns, arbitration_id, message.name, FrameFlag.DECODE_ERROR)
        raw: dict[str, Any] = decoded
        check = live.check
        if live.algorithm is not None and check is not None and check.checksum_signal is not None:
            actual = raw.get(check.checksum_signal)
            if actual is None or int(actual) != live.algorithm.compute(arbitration_id, data):
                return self._flag(timestamp_ns, arbitration_id, message.name, FrameFlag.CHECKSUM)
        if live.counter is not None and check is not None and check.counter_signal is not None:
            counter_value = raw.get(check.counter_signal)
            if counter_value is not None and live.counter.check(int(counter_value)):
                return self._flag(timestamp_ns, arbitration_id, message.name, FrameFlag.COUNTER)
        samples = []
        for spec in live.specs:
            sample = self._sample(message, spec, raw, timestamp_ns)
            if sample is not None:
                samples.append(sample)
        if samples:
            self._decoded += 1
        return DecodedFrame(timestamp_ns, arbitration_id, message.name, FrameFlag.OK, tuple(samples))

    def _flag(self, timestamp_ns: int, arbitration_id: int, message: str | None, flag: FrameFlag) -> DecodedFrame:
        name = flag.name or str(int(flag))
        self._flagged[name] = self._flagged.get(name, 0) + 1
        return _new_decoded(timestamp_ns, arbitration_id, message, flag, ())

    @staticmethod
    def _sample(message: Message, spec: RoleSpec, raw: Mapping[str, Any], timestamp_ns: int) -> RoleSample | None:
        raw_value = raw.get(spec.signal)
        if raw_value is None:  # multiplexed out of this frame
            return None
        signal = message.get_signal_by_name(spec.signal)
        physical = float(signal.conversion.raw_to_scaled(raw_value, decode_choices=False))  # type: ignore[arg-type]
        sign_raw = None
        if spec.sign_signal is not None:
            sign_value = raw.get(spec.sign_signal)
            sign_raw = None if sign_value is None else int(sign_value)
        flags = FrameFlag.OK
        if spec.valid_signal is not None:
            valid_value = raw.get(spec.valid_signal)
            if valid_value is None or int(valid_value) not in spec.valid_values:
                flags = FrameFlag.INVALID
        label = None
        if signal.choices is not None and raw_value in signal.choices:
            label = str(signal.choices[raw_value])
        return RoleSample(
            role=spec.role,
            timestamp_ns=timestamp_ns,
            value=spec.to_si(physical, sign_raw),
            unit=spec.si_unit,
            raw=raw_value,
            label=label,
            flags=flags,
        )


def encode_role_frame(
    db: Database,
    rolemap: RoleMap,
    message: str,
    role_values: Mapping[str, float],
    *,
    counter: int = 0,
    signals: Mapping[str, float] | None = None,
) -> bytes:
    """Build the payload of ``message`` carrying SI role values (for simulators and tests).

    Signals not given default to 0, except quality bits, which are set to their role's
    first ``valid_when`` value. ``signals`` (physical values by signal name) override everything; the
    counter signal gets ``counter`` and the checksum signal is computed last.

    Raises:
        ConfigError: ``message`` is not in the DBC or a role is not mapped onto it.
    """
    msg = _message(db, message, "encode_role_frame")
    values: dict[str, float] = {s.name: 0.0 for s in msg.signals}
    for spec in rolemap.roles_for_message(message):
        if spec.valid_signal is not None:
            values[spec.valid_signal] = spec.valid_values[0]
    for role, value in role_values.items():
        spec = rolemap.role(role)
        if spec.message != message:
            raise ConfigError(f"encode_role_frame: role {role!r} is carried by {spec.message}, not {message}")
        values.update(spec.signal_values(value))
    check = rolemap.check_for(message)
    if check is not None and check.counter_signal is not None:
        values[check.counter_signal] = counter % (1 << msg.get_signal_by_name(check.counter_signal).length)
    if signals:
        values.update(signals)
    for s in msg.signals:  # round to the raw grid so encode does not reject values between steps
        if not s.is_float and s.name in values and not (s.is_multiplexer is False and s.multiplexer_ids):
            raw = round((values[s.name] - s.offset) / s.scale)
            raw = max(raw, 0 if not s.is_signed else -(1 << (s.length - 1)))
            raw = min(raw, (1 << s.length) - 1 if not s.is_signed else (1 << (s.length - 1)) - 1)
            values[s.name] = raw * s.scale + s.offset
    data = bytearray(msg.encode(values, scaling=True, strict=False))
    if check is not None and check.verifies_checksum and check.checksum_signal is not None:
        crc = check.checksum.compute(msg.frame_id, bytes(data))
        values[check.checksum_signal] = crc
        data = bytearray(msg.encode(values, scaling=True, strict=False))
    return bytes(data)
