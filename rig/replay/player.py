"""HIL replay: play a recorded session's CAN frames back onto a live bus, with their recorded timing.

A VSC ECU on a bench can then be driven by a recorded road test. The frames of one recorded bus
(``/can/<bus>/frames``, read with :meth:`rig.data.Session.can_frames`) are sent on any python-can
interface (:func:`parse_bus_spec`: a session configuration's ``[[can]]`` table, or
``INTERFACE:CHANNEL[,KEY=VALUE...]``), optionally

- filtered by identifier or DBC message name (``ids``) and by the rig role they carry (``roles``);
- faster or slower (``speed``) and over and over (``passes``);
- with chosen signals rewritten (:class:`Fault`, ``TARGET:KIND[=VALUE][@T0[..T1]]``): an offset, a
  frozen value, a dropout. Only the chosen signal's bits change (and the quality bit, for a dropout);
  the checksum of every rewritten frame is recomputed with the message's algorithm from the role map.

Frames that are not rewritten go out byte-exact, counters and checksums as recorded, except from the
second pass of a loop on: there each protected message's rolling counter continues the sequence of the
previous pass (the recorded per-frame steps are kept) and its checksum is recomputed, so a bench ECU
sees no counter jump at the loop boundary.

Timing. Each frame is due at ``start + (t_i - t_0) / speed`` on an injected
:class:`~vsccore.clock.Clock`, where ``t_i`` is the frame's recorded time on the session's common
time base (interface clock mapped to the host clock when the interface stamps frames). The player
sleeps until each frame's absolute due time, so host scheduling delays never accumulate. python-can's
``MessageSync`` (4.6) also computes absolute wake-up times, but it reads ``time.perf_counter`` and
calls ``time.sleep`` directly (no clock to inject, so its schedule cannot be tested deterministically,
and it cannot be stopped between frames), has no speed factor and compresses pauses over 60 s; so
the schedule here is the same idea on the rig's clock, with a stop event. A host stall makes the
frames behind it go out late, in a burst, rather than be dropped; :class:`ReplayStats` counts them.

The recorded times of host-stamped frames (a virtual bus) can run back by a little scheduling
jitter; such a frame is sent right after its predecessor (never before it) and counted in
:attr:`ReplayPlan.clamped`.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import logging
import math
import os
import re
import select
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
import numpy as np
import numpy.typing as npt
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.can.bus import CanBusConfig, open_bus
from drivers.can.checks import CAN_EFF_FLAG, ChecksumAlgorithm
from drivers.can.roles import RoleMap, RoleSpec
from drivers.can.vector_encode import MessageEncoder, SignalLayout
from vsccore.clock import Clock
from vsccore.errors import AnalysisError, ConfigError, DeviceError, EncodeError

if TYPE_CHECKING:
    from rig.data import Session

__all__ = [
    "Fault",
    "FaultKind",
    "ReplayPlan",
    "ReplayStats",
    "Replayer",
    "build_plan",
    "describe_plan",
    "parse_bus_spec",
    "parse_fault",
    "parse_id",
    "realtime_priority",
    "replay_session",
]

log = logging.getLogger(__name__)

NS = 1_000_000_000
IntArray = npt.NDArray[np.int64]
_U64 = np.uint64


# ---------------------------------------------------------------------------------------------
# The bus to replay onto
# ---------------------------------------------------------------------------------------------

_BUS_KEYS = ("bitrate", "fd", "data_bitrate", "host", "port", "timestamp_source")


def _option_value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    try:
        return int(text, 0)
    except ValueError:
        return text


def parse_bus_spec(spec: str, *, bus: str | None = None) -> CanBusConfig:
    """The CAN bus to replay onto, from ``--bus``.

    - a session configuration file (``*.toml``): its ``[[can]]`` table named ``bus`` (or the only one;
      ``FILE.toml#NAME`` chooses one by name), opened the way ``rig record`` opens it;
    - ``INTERFACE:CHANNEL[,KEY=VALUE...]``: any python-can interface, e.g. ``socketcan:can0``,
      ``pcan:PCAN_USBBUS1,bitrate=250000``, ``socketcand:vsc0,host=127.0.0.1,port=29536``,
      ``virtual:bench``. ``bitrate``, ``fd``, ``data_bitrate``, ``host``, ``port`` are the ``[[can]]``
      keys; any other key is passed to ``can.Bus`` as it is.

    Raises:
        ConfigError: the spec is neither (the message says what was expected), the file has no such
            ``[[can]]`` table, or a value is invalid.
    """
    text = spec.strip()
    path_text, _, name = text.partition("#")
    if path_text.endswith(".toml") or Path(path_text).is_file():
        from rig.core.config import load_session

        cfg = load_session(Path(path_text))
        tables = {c.name: c for c in cfg.can}
        want = name or bus
        if not tables:
            raise ConfigError(f"--bus {spec}: no [[can]] table in {path_text}")
        if want and want in tables:
            chosen = tables[want]
        elif not name and len(tables) == 1:
            chosen = next(iter(tables.values()))
        else:
            raise ConfigError(f"--bus {spec}: no [[can]] table named {want!r} in {path_text} "
                              f"(have: {', '.join(tables)}); choose one with {path_text}#NAME")
        return CanBusConfig.from_mapping(chosen.model_dump(exclude={"dbc", "roles_file", "roles", "checks"}))
    interface, sep, rest = text.partition(":")
    if not sep or not interface or not rest:
        raise ConfigError(f"--bus {spec!r}: expected a session configuration FILE.toml[#NAME] or "
                          "INTERFACE:CHANNEL[,KEY=VALUE...] (e.g. socketcan:can0, virtual:bench)")
    channel, *pairs = rest.split(",")
    table: dict[str, Any] = {"interface": interface.strip(), "channel": channel.strip(), "name": "replay"}
    options: dict[str, Any] = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        key = key.strip()
        if not eq or not key:
            raise ConfigError(f"--bus {spec!r}: {pair!r} is not KEY=VALUE")
        (table if key in _BUS_KEYS else options)[key] = _option_value(value.strip())
    table["options"] = options
    return CanBusConfig.from_mapping(table)


# ---------------------------------------------------------------------------------------------
# Faults
# ---------------------------------------------------------------------------------------------


class FaultKind(StrEnum):
    """What a fault does to its signal (the values are the words of the ``--fault`` syntax)."""

    OFFSET = "offset"
    """Add ``value`` (SI for a role, the DBC's physical unit for ``MESSAGE.SIGNAL``)."""
    FREEZE = "freeze"
    """Hold the value of the last frame before the window (the sensor stuck)."""
    DROPOUT = "dropout"
    """Send ``value`` (default 0) and, when the role has a quality bit, mark it invalid (the sensor lost)."""


_TARGET = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)?$")


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


# ---------------------------------------------------------------------------------------------
# Signal bits (vectorised over the frames of one message)
# ---------------------------------------------------------------------------------------------


class _Bits:
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


class _MessageBits:
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

    def bits(self, signal: str) -> _Bits:
        return _Bits(self._layouts[signal], self.length)

    def present(self, signal: str, data: npt.NDArray[np.uint8]) -> npt.NDArray[np.bool_]:
        """Rows whose multiplexer selects ``signal`` (all rows for a plain signal)."""
        lay = self._layouts[signal]
        if lay.mux_ids is None or self._mux is None:
            return np.ones(data.shape[0], dtype=bool)
        return np.isin(self.bits(self._mux).get(data), list(lay.mux_ids))


# ---------------------------------------------------------------------------------------------
# The plan: which frames, with which payloads, at which recorded times
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Rewrite:
    """A protected message: where its counter and checksum sit, for rewritten frames and later loop passes."""

    message: DbcMessage
    rows: IntArray
    """Plan rows of this message with the DBC's length (others are never rewritten)."""
    counter: _Bits | None
    checksum: _Bits | None
    algorithm: ChecksumAlgorithm | None
    """None: no checksum to recompute."""

    def seal(self, data: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
        """Rows of this message with their checksum recomputed."""
        if self.checksum is None or self.algorithm is None:
            return data
        crc = self.algorithm.compute_many(int(self.message.frame_id), np.ascontiguousarray(data))
        return self.checksum.set(data, crc)


@dataclass(frozen=True, slots=True)
class ReplayPlan:
    """The frames to replay, in send order, with their payloads after the faults (build with :func:`build_plan`)."""

    bus: str
    """The recorded bus."""
    t_ns: IntArray
    """Recorded time of each frame, ns from the recorded bus's first frame; non-decreasing."""
    can_id: npt.NDArray[np.uint32]
    """11- or 29-bit identifier (without flag bits)."""
    flags: npt.NDArray[np.uint8]
    """:class:`rig.core.topics.CanFlag` bits as recorded."""
    dlc: npt.NDArray[np.uint8]
    length: npt.NDArray[np.int64]
    data: npt.NDArray[np.uint8]
    """(n, width) payloads as they will be sent in the first pass (zero padded)."""
    recorded: npt.NDArray[np.uint8]
    """(n, width) payloads as recorded."""
    faults: tuple[Fault, ...] = ()
    rewritten: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    """Rows whose payload a fault changed (their checksum recomputed)."""
    clamped: int = 0
    """Frames whose recorded time ran back behind their predecessor's (sent right after it)."""
    rewrites: tuple[_Rewrite, ...] = ()

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def duration_ns(self) -> int:
        return int(self.t_ns[-1]) if len(self) else 0

    def pass_length_ns(self) -> int:
        """Recorded time from a pass's first frame to the next pass's first frame in a loop.

        The recording's span plus the longest median cycle of its identifiers, so that every message
        has at least its own cycle time between its last frame of a pass and its first of the next.
        """
        if len(self) == 0:
            return 0
        longest = 0
        keys = self.can_id.astype(np.int64) | ((self.flags.astype(np.int64) & int(T.CanFlag.EXTENDED)) << 40)
        for key in np.unique(keys):
            t = self.t_ns[keys == key]
            if t.size > 1:
                longest = max(longest, int(np.median(np.diff(t))))
        return self.duration_ns + max(longest, 1_000_000)

    def payloads(self, pass_index: int) -> npt.NDArray[np.uint8]:
        """Payloads of pass ``pass_index`` (0 first): from pass 1 on, each protected message's counter
        continues from the previous pass and its checksum is recomputed."""
        if pass_index == 0:
            return self.data
        out = np.array(self.data, copy=True)
        for rw in self.rewrites:
            if rw.counter is None or rw.rows.size == 0:
                continue
            rows = self.data[rw.rows]
            counter = rw.counter.get(rows)
            modulus = 1 << rw.counter.lay.length
            step = (int(counter[-1]) - int(counter[0]) + 1) % modulus
            if step == 0:
                continue
            rows = rw.counter.set(rows, (counter + pass_index * step) % modulus)
            out[rw.rows] = rw.seal(rows)
        return out

    def message(self, row: int, data: npt.NDArray[np.uint8]) -> can.Message:
        """The python-can message of plan row ``row`` with payload row ``data``."""
        flags = int(self.flags[row])
        fd = bool(flags & T.CanFlag.FD)
        remote = bool(flags & T.CanFlag.REMOTE)
        n = int(self.length[row])
        return can.Message(
            arbitration_id=int(self.can_id[row]),
            is_extended_id=bool(flags & T.CanFlag.EXTENDED),
            is_remote_frame=remote,
            is_fd=fd,
            bitrate_switch=bool(flags & T.CanFlag.BRS),
            error_state_indicator=bool(flags & T.CanFlag.ESI),
            dlc=n if fd else int(self.dlc[row]),
            data=None if remote else bytes(data[:n]),
            check=False,
        )


def _frame_keys(can_id: npt.NDArray[np.uint32], flags: npt.NDArray[np.uint8]) -> IntArray:
    ext = (flags & int(T.CanFlag.EXTENDED)) != 0
    return np.where(ext, can_id.astype(np.int64) | CAN_EFF_FLAG, can_id.astype(np.int64))


def _message_of(db: Database, key: int) -> DbcMessage | None:
    ext = bool(key & CAN_EFF_FLAG)
    try:
        msg = db.get_message_by_frame_id(key & 0x1FFFFFFF)
    except KeyError:
        return None
    return msg if bool(msg.is_extended_frame) == ext else None


def build_plan(
    session: Session,
    *,
    bus: str | None = None,
    ids: Sequence[str] = (),
    roles: Sequence[str] = (),
    faults: Sequence[Fault] = (),
    db: Database | None = None,
    rolemap: RoleMap | None = None,
) -> ReplayPlan:
    """The frames of recorded bus ``bus`` (default: the session's only one) to replay.

    ``ids`` (identifiers or DBC message names) and ``roles`` (rig roles: the messages that carry them)
    keep only those frames (both empty: every frame). Error frames are never sent. ``db`` and
    ``rolemap`` default to the session's attached DBC and role map; they are needed for ``--id NAME``,
    ``roles`` and ``faults`` (and for the counters and checksums of loops), not for a plain replay.

    Raises:
        AnalysisError: the session has no (such) CAN bus, or the filters leave no frame.
        ConfigError: a filter or fault names an unknown role, message or signal, or a fault needs a
            checksum algorithm the role map does not give.
    """
    buses = session.can_buses()
    if bus is None:
        if len(buses) != 1:
            raise AnalysisError(f"{session.path}: {len(buses)} recorded CAN buses ({', '.join(buses) or 'none'}); "
                                "choose one with --recorded-bus")
        bus = buses[0]
    frames = session.can_frames(bus)
    rec = frames.records
    if rec.shape[0] == 0:
        raise AnalysisError(f"{session.path}: bus {bus!r} has no recorded frames")
    need_dbc = bool(roles or faults or any(not _is_number(i) for i in ids))
    if db is None and (need_dbc or _has_attachment(session, ".dbc")):
        try:
            db = session.dbc()
        except AnalysisError:
            if need_dbc:
                raise
    if rolemap is None and db is not None:
        try:
            rolemap = session.rolemap(db, bus)
        except AnalysisError:
            if roles or any(f.target.find(".") < 0 for f in faults):
                raise
    t = np.asarray(frames.time_ns, dtype=np.int64)
    flags = rec["flags"].astype(np.uint8)
    keep = (flags & int(T.CanFlag.ERROR)) == 0
    keys = _frame_keys(rec["can_id"].astype(np.uint32) & np.uint32(0x1FFFFFFF), flags)
    wanted: set[int] = {parse_id(i, db) for i in ids}
    for role in roles:
        assert rolemap is not None and db is not None
        spec = rolemap.role(role)
        msg = db.get_message_by_name(spec.message)
        wanted.add(int(msg.frame_id) | (CAN_EFF_FLAG if msg.is_extended_frame else 0))
    if wanted:
        keep &= np.isin(keys, sorted(wanted))
    if not keep.any():
        raise AnalysisError(f"{session.path}: bus {bus!r}: no frame left to replay after the filters "
                            f"(ids {sorted(hex(k & 0x1FFFFFFF) for k in wanted)})")
    t0 = int(t[0])  # windows and schedule count from the bus's first recorded frame
    t_rel = t[keep] - t0
    monotonic = np.maximum.accumulate(t_rel)
    clamped = int(np.count_nonzero(monotonic != t_rel))
    kept = rec[keep]
    data = np.ascontiguousarray(kept["data"]).astype(np.uint8)
    plan_keys = keys[keep]
    lengths = kept["len"].astype(np.int64)
    rewrites = _rewrites(db, rolemap, plan_keys, lengths)
    out = data.copy()
    changed = np.zeros(out.shape[0], dtype=bool)
    for fault in faults:
        assert db is not None
        _apply_fault(fault, db, rolemap, plan_keys, lengths, monotonic, out, changed)
    for rw in rewrites:  # reseal what the faults changed
        rows = rw.rows[changed[rw.rows]]
        if rows.size:
            out[rows] = rw.seal(out[rows])
    return ReplayPlan(
        bus=bus, t_ns=monotonic, can_id=kept["can_id"].astype(np.uint32) & np.uint32(0x1FFFFFFF), flags=kept["flags"],
        dlc=kept["dlc"].astype(np.uint8), length=lengths, data=out, recorded=data, faults=tuple(faults),
        rewritten=changed, clamped=clamped, rewrites=rewrites,
    )


def _is_number(text: str) -> bool:
    try:
        int(text.strip(), 0)
    except ValueError:
        return False
    return True


def _has_attachment(session: Session, suffix: str) -> bool:
    return any(n.lower().endswith(suffix) for n in session.attachments)


def _rewrites(db: Database | None, rolemap: RoleMap | None, keys: IntArray, lengths: IntArray) -> tuple[_Rewrite, ...]:
    """Protected messages (counter or checksum in the role map's checks) among the plan's frames."""
    if db is None or rolemap is None:
        return ()
    out = []
    for check in rolemap.checks:
        msg = db.get_message_by_name(check.message)
        key = int(msg.frame_id) | (CAN_EFF_FLAG if msg.is_extended_frame else 0)
        rows = np.flatnonzero((keys == key) & (lengths == int(msg.length))).astype(np.int64)
        if rows.size == 0 or (check.counter_signal is None and not check.verifies_checksum):
            continue
        try:
            bits = _MessageBits(msg)
        except ConfigError:
            log.warning("replay: %s is not rewritable; its counter will not continue across loop passes", msg.name)
            continue
        counter = bits.bits(check.counter_signal) if check.counter_signal is not None else None
        checksum = bits.bits(check.checksum_signal) if check.verifies_checksum and check.checksum_signal else None
        out.append(_Rewrite(msg, rows, counter, checksum, check.checksum if checksum is not None else None))
    return tuple(out)


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


def _apply_fault(
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
    bits = _MessageBits(msg)
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


# ---------------------------------------------------------------------------------------------
# Playing the plan
# ---------------------------------------------------------------------------------------------

_HIST_US = 1_000_000
"""Lateness histogram range (µs); later frames land in the last bin."""


@dataclass(frozen=True, slots=True)
class ReplayStats:
    """What a replay sent and how late, against its absolute schedule on the injected clock."""

    frames_sent: int
    passes: int
    """Passes begun (the last may be cut short by a stop)."""
    stopped: bool
    """True when the stop event ended the replay before its last frame."""
    late_frames: int
    """Frames sent more than 1 ms after their due time."""
    lateness_us: Mapping[str, float]
    """Lateness of the send call after each frame's due time (µs): ``p50``, ``p90``, ``p99``, ``p99.9``, ``max``."""
    start_ns: int
    """Clock time at which the first frame was due."""

    def summary(self) -> str:
        lat = self.lateness_us
        figures = ", ".join(f"{k} {v:.0f}" for k, v in lat.items())
        return (f"{self.frames_sent} frames in {self.passes} pass{'es' if self.passes != 1 else ''}"
                f"{' (stopped)' if self.stopped else ''}; send lateness µs: {figures}; "
                f"{self.late_frames} frames > 1 ms late")


class Replayer:
    """Sends a :class:`ReplayPlan` on a python-can bus at its recorded times (see the module docstring).

    ``passes``: how many times to play the recording (None: until ``stop`` is set). ``lead_s``: the
    first frame is due this long after :meth:`run` starts (time to build the first messages). The bus
    belongs to the caller; frames it receives meanwhile (a bench ECU's own traffic) are read and
    dropped while there is time to spare, so its receive queue does not grow.

    Precision. A sleep of the operating system ends some tens of µs after its deadline (the kernel's timer
    slack, 50 µs by default, is set to :attr:`TIMER_SLACK_NS` for the player thread during :meth:`run`) and
    later on a busy host, so the wait for each due time is in two steps: the clock's sleep until ``spin_s``
    before it, then a short spin on the clock that releases the interpreter lock between checks
    (:func:`_let_threads_run`), so that other threads of the process are not held up by it. The spin is
    bounded: when two readings of the clock are equal (a paused governed clock, a clock too coarse to spin on,
    a test's) the clock's own sleep finishes the wait. ``spin_s=0`` waits with the clock's sleep alone. The
    spin is short (0.3 ms) because it costs CPU time, and the fair scheduler lets a thread that used more of
    it wait longer when it wakes (a longer spin sent more frames late on a loaded host). For the same reason
    the player thread asks the kernel for a short time slice, ``slice_s`` (Linux >= 6.12, no privilege
    needed; None leaves the scheduler's default): a thread with a shorter slice gets an earlier deadline and
    takes the CPU from a busy process sooner when it wakes. On a heavily loaded host neither helps: the
    player waits for the CPU. The figures: ``benchmarks/bench_replay.py``.

    Real-time priority. ``rt_priority`` (1-99; ``rig replay --rt-priority``) puts the player thread on the
    kernel's ``SCHED_FIFO`` policy for :meth:`run`: it then takes a CPU from any ordinary process the moment
    its sleep ends, whatever the load (``benchmarks/bench_replay.py --rt-priority 50``). It needs root,
    ``CAP_SYS_NICE`` or an ``rtprio`` limit of at least that priority (``/etc/security/limits.conf``); without
    one, :meth:`run` refuses with that fix rather than play with ordinary timing. The kernel's real-time
    throttling (95 % of each second by default) still leaves ordinary processes CPU time, and the spin between
    frames is 0.3 ms, so the player cannot lock a core.

    Frames sharing a due time go out back to back after one wait. The python-can messages are built ahead
    (``build_ahead`` at a time, while there is time to spare), so nothing is encoded at a due time. The
    cyclic garbage collector is held off during the send loop (``hold_gc``) and run for the youngest
    generation only while there is time to spare; it is re-enabled at the end. None of this can stop
    another process or the hypervisor from taking the CPU at a due time: :class:`ReplayStats` reports the
    lateness that remains.
    """

    DRAIN_SLACK_NS = 2_000_000
    """Work between frames (draining the receive queue, building messages, a young-generation GC)
    happens only when the next frame is at least this far beyond the start of its spin."""
    SPIN_S = 0.0003
    """Default final approach to each due time (see the class docstring)."""
    SLICE_S = 0.0001
    """Default time slice the player thread asks the scheduler for (see the class docstring)."""
    TIMER_SLACK_NS = 1_000
    """The player thread's timer slack during :meth:`run` (Linux; the default is 50 µs, by which the kernel may
    defer a sleep's wake-up to batch timers)."""

    def __init__(
        self,
        plan: ReplayPlan,
        bus: can.BusABC,
        clock: Clock,
        *,
        speed: float = 1.0,
        passes: int | None = 1,
        stop: threading.Event | None = None,
        lead_s: float = 0.05,
        send_timeout_s: float = 0.1,
        spin_s: float = SPIN_S,
        build_ahead: int = 64,
        hold_gc: bool = True,
        slice_s: float | None = SLICE_S,
        rt_priority: int | None = None,
    ) -> None:
        if not speed > 0 or not math.isfinite(speed):
            raise ConfigError(f"replay: --speed must be a finite number > 0, got {speed}")
        if passes is not None and passes < 1:
            raise ConfigError(f"replay: passes must be >= 1, got {passes}")
        if not 0 <= spin_s < 1 or not math.isfinite(spin_s):
            raise ConfigError(f"replay: spin_s must be in [0, 1) s, got {spin_s}")
        if build_ahead < 1:
            raise ConfigError(f"replay: build_ahead must be >= 1, got {build_ahead}")
        if len(plan) == 0:
            raise ConfigError("replay: the plan has no frames")
        self.plan = plan
        self.bus = bus
        self.clock = clock
        self.speed = float(speed)
        self.passes = passes
        self.stop = stop or threading.Event()
        self.lead_ns = int(lead_s * NS)
        self.send_timeout_s = send_timeout_s
        self.spin_ns = int(spin_s * NS)
        self.build_ahead = int(build_ahead)
        self.hold_gc = hold_gc
        if slice_s is not None and not 0 < slice_s <= 0.1:
            raise ConfigError(f"replay: slice_s must be in (0, 0.1] s, got {slice_s}")
        self.slice_ns = None if slice_s is None else int(slice_s * NS)
        self.rt_priority = _check_rt_priority(rt_priority)
        self._offsets = np.round(plan.t_ns / self.speed).astype(np.int64)
        self._pass_ns = round(plan.pass_length_ns() / self.speed)
        # end (exclusive) of the run of rows sharing each row's due time
        starts = np.flatnonzero(np.diff(self._offsets) != 0) + 1
        bounds = np.append(starts, len(plan))
        self._group_end = np.repeat(bounds, np.diff(np.insert(bounds, 0, 0))).tolist()

    def due_times(self, start_ns: int, pass_index: int = 0) -> IntArray:
        """The absolute due time (clock ns) of every frame of pass ``pass_index`` when pass 0 starts at ``start_ns``."""
        return start_ns + pass_index * self._pass_ns + self._offsets

    def run(self) -> ReplayStats:
        """Play the plan (blocking) until its last pass ends or ``stop`` is set.

        Raises:
            DeviceError: the bus refused a frame (the message names the frame and its identifier).
        """
        gc_was_enabled = gc.isenabled()
        if self.hold_gc:
            gc.disable()
        try:
            # real-time first: the fair scheduler's slice applies to an ordinary thread only
            with _timer_slack(self.TIMER_SLACK_NS), realtime_priority(self.rt_priority), _fair_slice(self.slice_ns):
                return self._run()
        finally:
            if gc_was_enabled:
                gc.enable()

    def _run(self) -> ReplayStats:
        clock, bus, plan = self.clock, self.bus, self.plan
        n = len(plan)
        hist = np.zeros(_HIST_US + 1, dtype=np.int64)
        start_ns = clock.now_ns() + self.lead_ns
        sent = 0
        pass_index = 0
        stopped = False
        late_list: list[int] = []
        slack_ns = self.spin_ns + self.DRAIN_SLACK_NS
        group_end = self._group_end
        while self.passes is None or pass_index < self.passes:
            payloads = plan.payloads(pass_index)
            due = self.due_times(start_ns, pass_index).tolist()
            ahead: dict[int, can.Message] = {}
            built = 0  # rows [0, built) have their message built (and maybe sent already)
            row = 0
            while row < n:
                due_ns = due[row]
                end = group_end[row]
                if built < end:  # not built in time: build now what this due time needs
                    built = self._build(ahead, payloads, built, end)
                if due_ns - clock.now_ns() > slack_ns:
                    built = self._spare_time(ahead, payloads, built)
                if not self._wait(due_ns):
                    stopped = True
                    break
                for r in range(row, end):
                    msg = ahead.pop(r)
                    late_list.append(clock.now_ns() - due_ns)
                    try:
                        bus.send(msg, timeout=self.send_timeout_s)
                    except can.CanError as exc:
                        raise DeviceError(f"replay: {bus.channel_info}: sending frame {r} (pass {pass_index}, id "
                                          f"0x{msg.arbitration_id:X}) failed: {exc}") from exc
                    sent += 1
                if len(late_list) >= 4096:
                    _add(hist, late_list)
                row = end
            pass_index += 1
            if stopped:
                break
        _add(hist, late_list)
        return ReplayStats(sent, pass_index, stopped, int(hist[1001:].sum()), _percentiles(hist), start_ns)

    def _build(self, ahead: dict[int, can.Message], payloads: npt.NDArray[np.uint8], first: int, end: int) -> int:
        """Build the messages of rows ``[first, end)`` into ``ahead``; return ``end``."""
        plan = self.plan
        for r in range(first, end):
            ahead[r] = plan.message(r, payloads[r])
        return end

    def _spare_time(self, ahead: dict[int, can.Message], payloads: npt.NDArray[np.uint8], built: int) -> int:
        """Work that waits for time to spare: drain the receive queue, build messages ahead (returns how many
        rows are built), a young-generation GC."""
        self._drain()
        if len(ahead) < self.build_ahead:
            built = self._build(ahead, payloads, built, min(len(self.plan), built + self.build_ahead))
        if self.hold_gc and gc.get_count()[0] > _GC_YOUNG:
            gc.collect(0)
        return built

    def _wait(self, due_ns: int) -> bool:
        """Wait until the clock reaches ``due_ns`` (see the class docstring); False when ``stop`` is set."""
        clock, stop, spin = self.clock, self.stop, self.spin_ns
        if spin <= 0:
            return clock.sleep_until_ns(due_ns, stop)
        if due_ns - clock.now_ns() > spin and not clock.sleep_until_ns(due_ns - spin, stop):
            return False
        last = -1
        while (now := clock.now_ns()) < due_ns:
            if stop.is_set():
                return False
            if now == last:  # the clock stands still (paused, or too coarse to spin on): let it wait
                return clock.sleep_until_ns(due_ns, stop)
            last = now
            _let_threads_run()
        return not stop.is_set()

    def _drain(self) -> None:
        for _ in range(64):
            try:
                if self.bus.recv(timeout=0.0) is None:
                    return
            except can.CanError:
                return


def _let_threads_run() -> None:
    """Release the interpreter lock for a moment without giving up the CPU.

    A zero-timeout ``select`` releases the lock (a thread waiting for it gets it) and returns at once;
    ``time.sleep(0)`` would also release it but enters the scheduler, where other processes take the CPU.
    Windows' select needs a socket: it sleeps 0.
    """
    if os.name == "nt":
        time.sleep(0)
    else:
        select.select((), (), (), 0)


_PR_SET_TIMERSLACK = 29
_PR_GET_TIMERSLACK = 30


@contextlib.contextmanager
def _timer_slack(ns: int) -> Iterator[None]:
    """The calling thread's timer slack set to ``ns`` for the block, then restored (Linux ``prctl``; no privilege
    needed). Elsewhere, or when the call fails, nothing changes."""
    if sys.platform != "linux":
        yield
        return
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        yield
        return
    zero = ctypes.c_ulong(0)
    old = prctl(_PR_GET_TIMERSLACK, zero, zero, zero, zero)
    if old <= 0 or prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(ns), zero, zero, zero) != 0:
        yield
        return
    try:
        yield
    finally:
        prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(old), zero, zero, zero)


def _check_rt_priority(priority: int | None) -> int | None:
    if priority is None:
        return None
    if not hasattr(os, "sched_setscheduler") or not hasattr(os, "SCHED_FIFO"):
        raise ConfigError("replay: --rt-priority needs the SCHED_FIFO scheduling policy (Linux and other POSIX "
                          "systems); this system has none")
    top = os.sched_get_priority_max(os.SCHED_FIFO)
    low = os.sched_get_priority_min(os.SCHED_FIFO)
    if not low <= priority <= top:
        raise ConfigError(f"replay: --rt-priority must be in {low}..{top} (SCHED_FIFO), got {priority}")
    return priority


@contextlib.contextmanager
def realtime_priority(priority: int | None) -> Iterator[None]:
    """The calling thread on ``SCHED_FIFO`` at ``priority`` for the block, then back on its own policy
    (None: nothing changes). Threads it starts inside the block inherit the policy. A priority out of range,
    a system without the policy or a refusal by the kernel is a :class:`ConfigError` naming the fix."""
    checked = _check_rt_priority(priority)
    if checked is None:
        yield
        return
    old_policy, old_param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(checked))
    except PermissionError as exc:
        limit = _rtprio_limit()
        raise ConfigError(
            f"replay: --rt-priority {priority}: the kernel refused the SCHED_FIFO policy ({exc.strerror}); it "
            f"needs root, the CAP_SYS_NICE capability (sudo setcap cap_sys_nice+ep {os.path.realpath(sys.executable)})"
            f" or an rtprio limit >= {priority} for the user in /etc/security/limits.conf (this process's limit: "
            f"{limit}); or replay without --rt-priority (ordinary scheduling: frames may go out late on a busy host)"
        ) from exc
    try:
        yield
    finally:
        os.sched_setscheduler(0, old_policy, old_param)


def _rtprio_limit() -> str:
    try:
        import resource
    except ImportError:  # not POSIX
        return "unknown"
    soft = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)


class _SchedAttr(ctypes.Structure):
    """Linux ``struct sched_attr`` (``SCHED_ATTR_SIZE_VER1``)."""

    _fields_ = [("size", ctypes.c_uint32), ("sched_policy", ctypes.c_uint32), ("sched_flags", ctypes.c_uint64),
                ("sched_nice", ctypes.c_int32), ("sched_priority", ctypes.c_uint32),
                ("sched_runtime", ctypes.c_uint64), ("sched_deadline", ctypes.c_uint64),
                ("sched_period", ctypes.c_uint64), ("sched_util_min", ctypes.c_uint32),
                ("sched_util_max", ctypes.c_uint32)]


_SCHED_OTHER = 0
_SYS_SCHED_ATTR = {"x86_64": (314, 315), "aarch64": (274, 275), "arm64": (274, 275), "riscv64": (274, 275)}
"""``(sched_setattr, sched_getattr)`` system call numbers per machine."""


@contextlib.contextmanager
def _fair_slice(ns: int | None) -> Iterator[None]:
    """The calling thread's requested time slice set to ``ns`` for the block, then restored (Linux >= 6.12,
    ``sched_attr.sched_runtime`` of a ``SCHED_OTHER`` thread; no privilege needed). The fair scheduler (EEVDF)
    gives a thread with a shorter slice an earlier deadline, so on waking it takes the CPU from a busy process
    sooner. Older kernels, other policies and other systems: nothing changes."""
    calls = _SYS_SCHED_ATTR.get(os.uname().machine) if ns is not None and sys.platform == "linux" else None
    if ns is None or calls is None:
        yield
        return
    try:
        syscall = ctypes.CDLL(None, use_errno=True).syscall
    except (OSError, AttributeError):
        yield
        return
    set_nr, get_nr = calls
    attr = _SchedAttr()
    size = ctypes.sizeof(attr)
    if syscall(get_nr, 0, ctypes.byref(attr), size, 0) != 0 or attr.sched_policy != _SCHED_OTHER:
        yield
        return
    old = int(attr.sched_runtime)
    attr.size, attr.sched_runtime = size, ns
    if syscall(set_nr, 0, ctypes.byref(attr), 0) != 0:
        yield
        return
    try:
        yield
    finally:
        attr.sched_runtime = old
        syscall(set_nr, 0, ctypes.byref(attr), 0)


_GC_YOUNG = 700
"""Young objects above which the held-off collector runs its youngest generation when there is time to spare
(CPython's default generation-0 threshold)."""


def _add(hist: npt.NDArray[np.int64], late_ns: list[int]) -> None:
    if late_ns:
        us = np.clip(np.asarray(late_ns, dtype=np.int64) // 1000, 0, _HIST_US)
        hist += np.bincount(us, minlength=_HIST_US + 1)
        late_ns.clear()


def _percentiles(hist: npt.NDArray[np.int64]) -> dict[str, float]:
    total = int(hist.sum())
    if total == 0:
        return {}
    cum = np.cumsum(hist)
    out = {}
    for name, q in (("p50", 0.5), ("p90", 0.9), ("p99", 0.99), ("p99.9", 0.999)):
        out[name] = float(np.searchsorted(cum, math.ceil(q * total)))
    out["max"] = float(np.flatnonzero(hist)[-1])
    return out


def describe_plan(plan: ReplayPlan) -> str:
    """One line: frames, identifiers, span, faults."""
    keys = np.unique(_frame_keys(plan.can_id, plan.flags))
    faults = "; faults: " + ", ".join(str(f) for f in plan.faults) if plan.faults else ""
    return (f"bus {plan.bus!r}: {len(plan)} frames of {keys.size} identifiers over {plan.duration_ns / NS:.3f} s"
            f"{faults}")


def replay_session(
    path: Path | str,
    bus_config: CanBusConfig,
    *,
    recorded_bus: str | None = None,
    ids: Sequence[str] = (),
    roles: Sequence[str] = (),
    faults: Sequence[Fault] = (),
    speed: float = 1.0,
    passes: int | None = 1,
    clock: Clock | None = None,
    stop: threading.Event | None = None,
    db: Database | None = None,
    rolemap: RoleMap | None = None,
    on_plan: Callable[[ReplayPlan], None] | None = None,
    rt_priority: int | None = None,
) -> ReplayStats:
    """Replay the session at ``path`` onto the bus of ``bus_config`` (opened here and closed at the end).

    ``on_plan`` sees the plan before the bus is opened (the CLI prints it). ``rt_priority``: see
    :class:`Replayer` (checked before the session is read). ``clock`` defaults to a
    monotonic clock on the Unix epoch (:class:`~vsccore.clock.ScaledClock` at 1x): a wall-clock step
    during a replay would move every later frame.

    Raises:
        SessionFileError: the session cannot be read. AnalysisError, ConfigError: see :func:`build_plan`.
        DeviceError: the bus cannot be opened or refuses a frame.
    """

    from rig.data import load_session
    from vsccore.clock import ScaledClock

    _check_rt_priority(rt_priority)
    session = load_session(path, include=lambda topic: topic.startswith("/can/") and topic.endswith("/frames"))
    plan = build_plan(session, bus=recorded_bus, ids=ids, roles=roles, faults=faults, db=db, rolemap=rolemap)
    if on_plan is not None:
        on_plan(plan)
    bus = open_bus(bus_config)
    try:
        player = Replayer(plan, bus, clock or ScaledClock(time.time_ns()), speed=speed, passes=passes, stop=stop,
                          rt_priority=rt_priority)
        return player.run()
    finally:
        bus.shutdown()
