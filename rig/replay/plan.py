"""The replay plan: which recorded frames, with which payloads (faults applied, checksums resealed), at which
recorded times."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import can
import numpy as np
import numpy.typing as npt
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.can.checks import CAN_EFF_FLAG, ChecksumAlgorithm
from drivers.can.roles import RoleMap
from rig.replay.faults import NS, Fault, IntArray, MessageBits, SignalBits, apply_fault, parse_id
from vsccore.errors import AnalysisError, ConfigError

__all__ = ["ReplayPlan", "build_plan", "describe_plan"]

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from rig.data import Session


@dataclass(frozen=True, slots=True)
class _Rewrite:
    """A protected message: where its counter and checksum sit, for rewritten frames and later loop passes."""

    message: DbcMessage
    rows: IntArray
    """Plan rows of this message with the DBC's length (others are never rewritten)."""
    counter: SignalBits | None
    checksum: SignalBits | None
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
        apply_fault(fault, db, rolemap, plan_keys, lengths, monotonic, out, changed)
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
            bits = MessageBits(msg)
        except ConfigError:
            log.warning("replay: %s is not rewritable; its counter will not continue across loop passes", msg.name)
            continue
        counter = bits.bits(check.counter_signal) if check.counter_signal is not None else None
        checksum = bits.bits(check.checksum_signal) if check.verifies_checksum and check.checksum_signal else None
        out.append(_Rewrite(msg, rows, counter, checksum, check.checksum if checksum is not None else None))
    return tuple(out)


def describe_plan(plan: ReplayPlan) -> str:
    """One line: frames, identifiers, span, faults."""
    keys = np.unique(_frame_keys(plan.can_id, plan.flags))
    faults = "; faults: " + ", ".join(str(f) for f in plan.faults) if plan.faults else ""
    return (f"bus {plan.bus!r}: {len(plan)} frames of {keys.size} identifiers over {plan.duration_ns / NS:.3f} s"
            f"{faults}")

