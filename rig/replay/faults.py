"""Faults a replay injects: one signal rewritten through the DBC (offset, freeze, dropout) over a span;
every other bit as recorded."""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import numpy.typing as npt
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage

from drivers.can.checks import CAN_EFF_FLAG
from drivers.can.roles import RoleMap, RoleSpec
from drivers.can.vector_encode import MessageEncoder, SignalLayout
from vsccore.errors import ConfigError, EncodeError

__all__ = ["NS", "Fault", "FaultKind", "IntArray", "MessageBits", "SignalBits", "apply_fault", "parse_fault",
           "parse_id"]

log = logging.getLogger(__name__)


class FaultKind(StrEnum):
    """What a fault does to its signal (the values are the words of the ``--fault`` syntax)."""

    OFFSET = "offset"
    """Add ``value`` (SI for a role, the DBC's physical unit for ``MESSAGE.SIGNAL``)."""
    FREEZE = "freeze"
    """Hold the value of the last frame before the window (the sensor stuck)."""
    DROPOUT = "dropout"
    """Send ``value`` (default 0) and, when the role has a quality bit, mark it invalid (the sensor lost)."""


@dataclass(frozen=True, slots=True)
class Fault:
    """One signal rewrite (see :func:`parse_fault` for the syntax)."""

    target: str
    """A rig role (``yaw_rate``) or ``MESSAGE.SIGNAL``."""
    kind: FaultKind
    value: float = 0.0
    start_s: float = 0.0
    """Window start, seconds from the recorded bus's first frame."""
    end_s: float = math.inf
    """Window end (exclusive)."""

    def __str__(self) -> str:
        value = f"={self.value:g}" if self.kind != FaultKind.FREEZE else ""
        end = "" if math.isinf(self.end_s) else f"..{self.end_s:g}"
        return f"{self.target}:{self.kind.value}{value}@{self.start_s:g}{end}"


def parse_fault(text: str) -> Fault:
    """Parse ``TARGET:KIND[=VALUE][@T0[..T1]]``.

    ``TARGET`` is a role (``yaw_rate``; ``VALUE`` in SI: rad/s, m/s², rad, m/s, Pa) or
    ``MESSAGE.SIGNAL`` (``VALUE`` in the DBC's unit). ``KIND`` is ``offset=VALUE``, ``freeze`` or
    ``dropout[=VALUE]``. ``@T0..T1`` is the window in seconds from the recorded bus's first frame
    (``@T0``: to the end; none: the whole replay). Examples: ``yaw_rate:offset=0.05``,
    ``swa:freeze@12.0``, ``wheel_speed_fl:dropout@10..12``.

    Raises:
        ConfigError: naming the fault text and what is wrong with it.
    """
    where = f"--fault {text!r}"
    target, colon, rest = text.strip().partition(":")
    spec, at, window = rest.partition("@")
    kind, eq, value_text = spec.partition("=")
    if not colon or not _TARGET.match(target) or (at and not window) or (eq and not value_text):
        raise ConfigError(f"{where}: expected TARGET:KIND[=VALUE][@T0[..T1]], e.g. yaw_rate:offset=0.05@10..20")
    if kind not in {k.value for k in FaultKind}:
        raise ConfigError(f"{where}: unknown fault kind {kind!r} (known: {', '.join(k.value for k in FaultKind)})")
    value = 0.0
    if eq:
        if kind == FaultKind.FREEZE:
            raise ConfigError(f"{where}: freeze takes no value (it holds the value at the window start)")
        value = _float(value_text, f"{where}: value")
    elif kind == FaultKind.OFFSET:
        raise ConfigError(f"{where}: offset needs a value, e.g. {target}:offset=0.05")
    start, end = 0.0, math.inf
    if at:
        t0, dots, t1 = window.partition("..")
        start = _float(t0, f"{where}: window start")
        if dots:
            end = _float(t1, f"{where}: window end")
    if start < 0 or end <= start:
        raise ConfigError(f"{where}: window {start:g}..{end:g} s must have 0 <= start < end")
    return Fault(target, FaultKind(kind), value, start, end)


def _float(text: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"{where} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ConfigError(f"{where} {text!r} is not finite")
    return value


def parse_id(text: str, db: Database | None) -> int:
    """A frame key (:func:`drivers.can.checks.frame_key` form) from ``0x101``, ``257`` or a DBC message name.

    An identifier above 0x7FF is taken as extended (29-bit), as is one given with 8 hex digits.

    Raises:
        ConfigError: neither a number nor a message of the DBC.
    """
    t = text.strip()
    try:
        ident = int(t, 0)
    except ValueError:
        if db is None:
            raise ConfigError(f"--id {text!r}: not a number and no DBC to look a message name up in") from None
        try:
            msg = db.get_message_by_name(t)
        except KeyError:
            raise ConfigError(f"--id {text!r}: not a number nor a message of the DBC") from None
        return int(msg.frame_id) | (CAN_EFF_FLAG if msg.is_extended_frame else 0)
    if not 0 <= ident <= 0x1FFFFFFF:
        raise ConfigError(f"--id {text!r}: outside 0..0x1FFFFFFF")
    extended = ident > 0x7FF or (t.lower().startswith("0x") and len(t) == 10)
    return ident | (CAN_EFF_FLAG if extended else 0)


class SignalBits:
    """Read and write one signal's raw value in ``(n, length)`` payload rows (messages up to 8 bytes)."""

    def __init__(self, lay: SignalLayout, length: int) -> None:
        self.lay = lay
        self.length = length
        self.mask = _U64((1 << lay.length) - 1)

    def _word(self, data: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint64]:
        padded = np.zeros((data.shape[0], 8), dtype=np.uint8)
        padded[:, : self.length] = data[:, : self.length]
        if self.lay.big_endian:
            return padded.view(">u8").reshape(-1).astype(_U64) >> _U64(8 * (8 - self.length))
        return padded.view("<u8").reshape(-1).astype(_U64)

    def _bytes(self, word: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint8]:
        if self.lay.big_endian:
            full = (word << _U64(8 * (8 - self.length))).astype(">u8")
        else:
            full = word.astype("<u8")
        return full.view(np.uint8).reshape(-1, 8)[:, : self.length]

    def get(self, data: npt.NDArray[np.uint8]) -> IntArray:
        raw = ((self._word(data) >> _U64(self.lay.shift)) & self.mask).astype(np.int64)
        if self.lay.signed:
            top = 1 << (self.lay.length - 1)
            raw = np.where(raw & top, raw - (1 << self.lay.length), raw)
        return raw

    def set(self, data: npt.NDArray[np.uint8], raw: npt.ArrayLike) -> npt.NDArray[np.uint8]:
        """``data`` with this signal's bits replaced by ``raw`` (other bits untouched)."""
        word = self._word(data)
        bits = (np.asarray(raw, dtype=np.int64).astype(_U64) & self.mask) << _U64(self.lay.shift)
        word = (word & ~(self.mask << _U64(self.lay.shift))) | bits
        out = np.array(data, dtype=np.uint8, copy=True)
        out[:, : self.length] = self._bytes(word)
        return out

    def raw_limits(self) -> tuple[int, int]:
        lay = self.lay
        lo, hi = (-(1 << (lay.length - 1)), (1 << (lay.length - 1)) - 1) if lay.signed else (0, (1 << lay.length) - 1)
        if lay.minimum is not None:
            lo = max(lo, math.ceil((lay.minimum - lay.offset) / lay.scale - 1e-9)) if lay.scale > 0 else lo
        if lay.maximum is not None:
            hi = min(hi, math.floor((lay.maximum - lay.offset) / lay.scale + 1e-9)) if lay.scale > 0 else hi
        return lo, hi


class MessageBits:
    """The bit layouts of one DBC message, for rewriting its frames."""

    def __init__(self, message: DbcMessage) -> None:
        self.message = message
        try:
            layouts = MessageEncoder(message).layouts
        except EncodeError as exc:
            raise ConfigError(f"replay: cannot rewrite {message.name}: {exc}") from exc
        if layouts is None:
            raise ConfigError(
                f"replay: cannot rewrite signals of {message.name} (longer than 8 bytes, float signals or nested "
                "multiplexing); replay it without faults on it"
            )
        self.length = int(message.length)
        self._layouts = {lay.name: lay for lay in layouts}
        self._mux = next((s.name for s in message.signals if s.is_multiplexer), None)

    def bits(self, signal: str) -> SignalBits:
        return SignalBits(self._layouts[signal], self.length)

    def present(self, signal: str, data: npt.NDArray[np.uint8]) -> npt.NDArray[np.bool_]:
        """Rows whose multiplexer selects ``signal`` (all rows for a plain signal)."""
        lay = self._layouts[signal]
        if lay.mux_ids is None or self._mux is None:
            return np.ones(data.shape[0], dtype=bool)
        return np.isin(self.bits(self._mux).get(data), list(lay.mux_ids))


def _fault_target(fault: Fault, db: Database, rolemap: RoleMap | None) -> tuple[str, str, RoleSpec | None]:
    """(message, signal, role spec or None) of a fault's target."""
    where = f"--fault {fault}"
    if "." in fault.target:
        message, signal = fault.target.split(".", 1)
        try:
            msg = db.get_message_by_name(message)
        except KeyError:
            raise ConfigError(f"{where}: message {message!r} is not in the DBC") from None
        if signal not in {s.name for s in msg.signals}:
            raise ConfigError(f"{where}: signal {signal!r} is not in message {message}")
        return message, signal, None
    if rolemap is None:
        raise ConfigError(f"{where}: no role map (attach one to the session or give --roles) to find role "
                          f"{fault.target!r}; or name the signal as MESSAGE.SIGNAL")
    try:
        spec = rolemap.role(fault.target)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return spec.message, spec.signal, spec


def apply_fault(
    fault: Fault, db: Database, rolemap: RoleMap | None, keys: IntArray, lengths: IntArray, t_rel: IntArray,
    out: npt.NDArray[np.uint8], changed: npt.NDArray[np.bool_],
) -> None:
    """Rewrite ``fault``'s signal in ``out`` (in place) and mark the rows it changed."""
    name, signal, spec = _fault_target(fault, db, rolemap)
    msg = db.get_message_by_name(name)
    check = rolemap.check_for(name) if rolemap is not None else None
    checksum_name = next((s.name for s in msg.signals if re.match(r"^(CHECKSUM|CRC|.*_CRC)$", s.name)), None)
    if checksum_name is not None and (check is None or not check.verifies_checksum):
        raise ConfigError(f"--fault {fault}: {name} has a checksum signal {checksum_name} but the role map gives no "
                          f"algorithm for it ([checks.{name}] algorithm = ...); its frames cannot be resealed")
    bits = MessageBits(msg)
    key = int(msg.frame_id) | (CAN_EFF_FLAG if msg.is_extended_frame else 0)
    rows = np.flatnonzero((keys == key) & (lengths == int(msg.length)))
    if rows.size == 0:
        raise ConfigError(f"--fault {fault}: no frame of {name} (0x{msg.frame_id:X}) among the replayed frames")
    data = out[rows]
    present = bits.present(signal, data)
    lo, hi = int(round(fault.start_s * NS)), (math.inf if math.isinf(fault.end_s) else int(round(fault.end_s * NS)))
    t = t_rel[rows]
    window = present & (t >= lo) & (t < hi)
    if not window.any():
        log.warning("replay: fault %s: no frame of %s in its window", fault, name)
        return
    sig = bits.bits(signal)
    raw = sig.get(data)
    lay = sig.lay
    sign_bits = bits.bits(spec.sign_signal) if spec is not None and spec.sign_signal is not None else None
    sign_raw = sign_bits.get(data) if sign_bits is not None else None
    new_raw = raw.copy()
    new_sign = None if sign_raw is None else sign_raw.copy()
    if fault.kind == FaultKind.FREEZE:
        first = int(np.flatnonzero(window)[0])
        before = np.flatnonzero(present[:first])
        src = int(before[-1]) if before.size else first
        new_raw[window] = raw[src]
        if new_sign is not None and sign_raw is not None:
            new_sign[window] = sign_raw[src]
    else:
        phys = raw.astype(np.float64) * lay.scale + lay.offset
        if spec is not None:
            si = _to_si(spec, phys, sign_raw)
            target_si = si + fault.value if fault.kind == FaultKind.OFFSET else np.full_like(si, fault.value)
            phys_new, sign_new = _from_si(spec, target_si)
            if new_sign is not None and sign_new is not None:
                new_sign[window] = sign_new[window]
        else:
            phys_new = phys + fault.value if fault.kind == FaultKind.OFFSET else np.full_like(phys, fault.value)
        lo_raw, hi_raw = sig.raw_limits()
        wanted = np.round((phys_new - lay.offset) / lay.scale).astype(np.int64)
        clipped = np.clip(wanted, lo_raw, hi_raw)
        n_clip = int(np.count_nonzero((clipped != wanted) & window))
        if n_clip:
            log.warning("replay: fault %s: %d values clipped to the DBC range of %s.%s", fault, n_clip, name, signal)
        new_raw[window] = clipped[window]
    data = sig.set(data, np.where(window, new_raw, raw))
    if sign_bits is not None and new_sign is not None and sign_raw is not None:
        data = sign_bits.set(data, np.where(window, new_sign, sign_raw))
    if fault.kind == FaultKind.DROPOUT and spec is not None and spec.valid_signal is not None:
        q = bits.bits(spec.valid_signal)
        invalid = next(v for v in range(1 << q.lay.length) if v not in spec.valid_values)
        data = q.set(data, np.where(window, invalid, q.get(data)))
    diff = (data != out[rows]).any(axis=1)
    out[rows] = data
    changed[rows[diff]] = True


def _to_si(spec: RoleSpec, phys: npt.NDArray[np.float64], sign_raw: IntArray | None) -> npt.NDArray[np.float64]:
    conv = spec.conversion
    si = phys * conv.scale + conv.offset
    if sign_raw is not None:
        si = np.where(sign_raw == spec.sign_negative_when, -si, si)
    return -si if spec.invert else si


def _from_si(spec: RoleSpec, si: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.float64], IntArray | None]:
    """Physical values of the role's signal (and its raw sign bit) for SI values (inverse of :func:`_to_si`)."""
    value = -si if spec.invert else si
    sign: IntArray | None = None
    if spec.sign_signal is not None:
        neg = value < 0
        sign = np.where(neg, spec.sign_negative_when, 1 - spec.sign_negative_when).astype(np.int64)
        value = np.abs(value)
    conv = spec.conversion
    return (value - conv.offset) / conv.scale, sign


NS = 1_000_000_000


IntArray = npt.NDArray[np.int64]


_U64 = np.uint64


_TARGET = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)?$")
