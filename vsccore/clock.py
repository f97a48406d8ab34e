"""Injectable clocks: the host wall clock, and a scaled clock shared by a simulated session.

Everything that stamps host receive times takes a :class:`Clock`, so simulated sessions can run
faster than real time and tests never depend on the machine's wall clock.
"""

from __future__ import annotations

import contextlib
import ctypes
import enum
import fcntl
import logging
import mmap
import os
import platform
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Protocol

log = logging.getLogger(__name__)


class Clock(Protocol):
    """A source of host time in integer ns since the Unix epoch."""

    def now_ns(self) -> int:
        """Current host time (ns since the Unix epoch)."""
        ...

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        """Wait until ``now_ns() >= t_ns``; return False early if ``stop`` is set."""
        ...


class SystemClock:
    """The host's wall clock (``time.time_ns``)."""

    def now_ns(self) -> int:
        return time.time_ns()

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        delay = (t_ns - time.time_ns()) / 1e9
        if delay <= 0:
            return not (stop is not None and stop.is_set())
        if stop is None:
            time.sleep(delay)
            return True
        return not stop.wait(delay)


class ScaledClock:
    """A clock that runs ``speed`` times faster than the wall clock from a chosen start time.

    Shared by simulated devices and the recorder in a fast simulated session, so host receive
    times and device times stay consistent while the session takes less wall time. It pickles to
    another process as the same clock (CLOCK_MONOTONIC is system-wide).

    With a ``governor`` (:class:`ClockGovernor`) the clock is *governed*: simulated time never runs
    more than the governor's budget ahead of the slowest :class:`Participant`, so a busy host makes
    the session take longer instead of making every device and reader late in simulated time.
    Without one it runs freely and the host's scheduling delays show, ``speed`` times magnified.
    """

    def __init__(self, start_ns: int, speed: float = 1.0, governor: ClockGovernor | None = None) -> None:
        if speed <= 0:
            raise ValueError(f"clock speed must be > 0, got {speed}")
        self._start_ns = start_ns
        self._speed = speed
        self._mono0 = time.monotonic_ns()
        self.governor = governor
        self._last = start_ns
        self._last_lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:
        return {"start_ns": self._start_ns, "speed": self._speed, "mono0": self._mono0, "governor": self.governor}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self._start_ns = state["start_ns"]
        self._speed = state["speed"]
        self._mono0 = state["mono0"]
        self.governor = state["governor"]
        self._last = self._start_ns
        self._last_lock = threading.Lock()

    @property
    def speed(self) -> float:
        return self._speed

    @property
    def governed(self) -> bool:
        return self.governor is not None

    def wall_ns(self) -> int:
        """Wall time (ns) since this clock started."""
        return time.monotonic_ns() - self._mono0

    def now_ns(self) -> int:
        gov = self.governor
        if gov is not None and gov.enabled:
            return gov.now_ns(self._start_ns, self._speed, self._mono0)
        paused = gov.paused_ns() if gov is not None else 0
        t = self._start_ns + int((time.monotonic_ns() - self._mono0 - paused) * self._speed)
        if gov is None:
            return t
        with self._last_lock:  # released governor: never below what the governed clock handed out
            t = max(t, self._last, gov.high_ns())
            self._last = t
        return t

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        gov = self.governor
        while True:
            seen = gov.change_count() if gov is not None else 0  # before the look: no change is missed
            delay = (t_ns - self.now_ns()) / self._speed / 1e9
            if delay <= 0:
                return not (stop is not None and stop.is_set())
            if gov is not None and gov.paused_now():
                # a paused clock reaches t later than the wall clock says, and runs again only when a
                # participant changes something: wait for that (at most 20 ms: a stop is seen then)
                if stop is not None and stop.is_set():
                    return False
                if gov.wait_for_change(seen, _PAUSED_WAIT_S):
                    continue
                delay = max(min(delay, _PAUSED_WAIT_S), 0.0005)  # no futex here: look again soon
            if stop is None:
                time.sleep(delay)
            elif stop.wait(delay):
                return False
            if self.governor is None:
                return not (stop is not None and stop.is_set())


# ---------------------------------------------------------------------------------------------
# The governed scaled clock: simulated time that waits for whoever fell behind
# ---------------------------------------------------------------------------------------------

_PAUSED_WAIT_S = 0.02
"""Longest wait (wall s) of a sleeper on a paused clock before it looks again (and at its stop event)."""

UNBOUNDED_NS = (1 << 63) - 1
"""Progress of a participant that holds nothing back (idle, finished); also the value of a consumer
that reads nothing (see :meth:`Participant.feeds`)."""

_HDR = 16
"""int64 words of the shared header (see :class:`ClockGovernor`)."""
_SLOT = 14
"""int64 words per participant slot: progress, ignored value, blamed wall ns, a free value (a consumer's
last taken stamp, a producer's newest sent stamp), the consumer slot + 1 (0: none), the producer's
previous sent stamp, the frames with the newest stamp (sent or taken), those with the previous stamp
(sent), the pid of its process, the native id of the thread that does its work (0: not known yet),
then the name."""
(_S_PROGRESS, _S_IGNORED, _S_BLAMED, _S_VALUE, _S_PEER, _S_PREV, _S_COUNT, _S_PREV_COUNT, _S_PID, _S_TID) = range(10)
_S_NAME = 10
ALL_FRAMES = 1 << 62
"""Count of a consumer's first stamp after it (re)connected: what was sent before is not owed."""
_MAX_SLOTS = 64
_NAME_BYTES = (_SLOT - _S_NAME) * 8
_MAGIC = 0x56534349  # "VSCI": slot layout 3 (pid, thread, release records)
(_H_MAGIC, _H_SLOTS, _H_PAUSED, _H_HIGH, _H_CLAMP_SINCE, _H_OFF, _H_PAUSES, _H_IGNORED, _H_RELEASES,
 _H_SAFETY, _H_EPOCH) = range(11)
_REC = 8
"""int64 words per release record: slot, reason, monotonic ns, clock ns, held wall ns, then the detail."""
_R_DETAIL = 5
_DETAIL_BYTES = (_REC - _R_DETAIL) * 8
_MAX_RECS = 64
"""Release records kept (a ring): more than the readers of :meth:`ClockGovernor.releases` fall behind by."""
_REC0 = _HDR + _MAX_SLOTS * _SLOT
_NEVER = -(1 << 63)
STAMP_TOLERANCE_NS = 2_000
"""A consumer's stamp comes back through float seconds (and socketcand's µs): frames this close count as taken."""
SAFETY_LIMIT_S = 60.0
"""Default last-resort limit (s of wall time) on one continuous hold of a participant that is alive."""
_CHECK_AFTER_NS = 50_000_000
"""A hold this long (wall ns) makes the clock look whether the participant holding it is still there."""
_CHECK_EVERY_NS = 100_000_000
"""Wall ns between two such looks (per copy of the governor)."""


class ReleaseReason(enum.IntEnum):
    """Why the governed clock stopped waiting for a participant (see :class:`GovernorRelease`)."""

    PROCESS_ENDED = 1
    """The participant's process has ended (or is a zombie)."""
    THREAD_ENDED = 2
    """The thread that did the participant's work has ended."""
    READER_CLOSED = 3
    """The reader closed its end (port closed, adapter unplugged, bus shut down): nothing is owed."""
    SAFETY_LIMIT = 4
    """Alive, but held simulated time for the governor's safety limit of wall time: the last resort."""

    @property
    def text(self) -> str:
        return {
            ReleaseReason.PROCESS_ENDED: "its process has ended",
            ReleaseReason.THREAD_ENDED: "its thread has ended",
            ReleaseReason.READER_CLOSED: "its reader closed its end",
            ReleaseReason.SAFETY_LIMIT: "it held simulated time for the safety limit (alive but stalled)",
        }[self]


@dataclass(frozen=True, slots=True)
class GovernorRelease:
    """One participant the governed clock stopped waiting for, and why (written to ``/rig/events``)."""

    participant: str
    reason: ReleaseReason
    detail: str
    """What the participant said (a port name …) or what the governor saw (pid, thread id)."""
    clock_ns: int
    """Simulated time at the release."""
    held_wall_ns: int
    """Wall time (ns) the clock had been standing still when it let go (0: nothing was held)."""

    @property
    def text(self) -> str:
        detail = f" ({self.detail})" if self.detail else ""
        held = (f" after holding simulated time for {self.held_wall_ns / 1e9:.1f} s of wall time"
                if self.held_wall_ns else "")
        return f"governed clock: no longer waits for {self.participant}: {self.reason.text}{detail}{held}"


@dataclass(frozen=True, slots=True)
class GovernorStats:
    """How much a governed clock had to hold simulated time back."""

    budget_ns: int
    paused_wall_ns: int
    """Wall time (ns) during which simulated time stood still waiting for a participant."""
    pauses: int
    """Number of times the clock started holding back."""
    ignored: int
    """Participants that held the clock and were released: gone (process or thread ended) or, alive, at
    the safety limit."""
    blamed_wall_ns: dict[str, int]
    """Paused wall time per participant that was the furthest behind."""
    safety_releases: int = 0
    """Of ``ignored``: alive participants released at the safety limit (the run's figures may suffer)."""

    def effective_speed(self, speed: float, wall_ns: int) -> float:
        """The speed actually achieved over ``wall_ns`` of wall time at nominal ``speed``."""
        if wall_ns <= 0:
            return speed
        return speed * max(0, wall_ns - self.paused_wall_ns) / wall_ns

    def as_dict(self) -> dict[str, object]:
        return {"budget_ns": self.budget_ns, "paused_wall_ns": self.paused_wall_ns, "pauses": self.pauses,
                "ignored": self.ignored, "safety_releases": self.safety_releases,
                "blamed_wall_ns": dict(self.blamed_wall_ns)}


_FUTEX_WAIT_BITSET, _FUTEX_WAKE_BITSET = 9, 10
_WAKE_ALL = 0x7FFFFFFF
"""Futex bits of a write every sleeper must see (one that can move any participant's place)."""
_WAKE_GLOBAL = 1 << 30
"""The bit every sleeper waits on besides those of the participants that hold the clock."""


def _wake_bit(slot: int) -> int:
    """The futex bit of participant ``slot`` (slots 30 apart share one: a spurious wake-up at worst)."""
    return 1 << (slot % 30)
_SYS_FUTEX = {"x86_64": 202, "amd64": 202, "aarch64": 98, "arm64": 98, "riscv64": 98, "i386": 240, "i686": 240,
              "armv7l": 240, "armv6l": 240, "ppc64le": 221, "s390x": 238}


class _Timespec(ctypes.Structure):
    _fields_ = (("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long))


def _futex_syscall() -> Any:
    """libc's ``syscall`` set up for futex(2), or None (not Linux, an unknown machine, no libc)."""
    number = _SYS_FUTEX.get(platform.machine().lower()) if sys.platform.startswith("linux") else None
    if number is None:
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).syscall
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_long
    fn.argtypes = (ctypes.c_long, ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p,
                   ctypes.c_int)

    def futex(addr: int, op: int, val: int, timeout: _Timespec | None, bits: int) -> int:
        return int(fn(number, addr, op, val, ctypes.byref(timeout) if timeout is not None else None, None, bits))

    return futex


_FUTEX = _futex_syscall()
"""futex(addr, op, val, timeout, bitset) (a shared futex: the governor's file is mapped in several processes),
or None."""


class ClockGovernor:
    """State shared by every copy of a governed :class:`ScaledClock`, in every process.

    A small file in shared memory (``/dev/shm`` where it exists), mapped by each copy and locked with
    ``flock`` (plus a thread lock, as ``flock`` does not exclude threads sharing a descriptor). It
    holds the wall time the clock has spent paused, the highest time handed out (so the clock never
    runs backwards, in any process) and one slot per *participant*: a device or reader that
    publishes its *progress*, the simulated time up to which it has done its work. Simulated time
    never runs more than ``budget_ns`` past the smallest progress: when it would, the clock stands
    still (the paused wall time grows) until that participant catches up.

    A *producer* (a simulated ECU) may name the *consumer* that reads what it sends (its CAN reader,
    :meth:`Participant.feeds`): the producer publishes the stamp of every frame as it sends it, the
    consumer the stamp of every frame it takes, and while the consumer owes frames its producer's
    progress counts as no later than the oldest frame owed. Every copy evaluates that on every
    :meth:`now_ns`, so the clock runs again the moment the consumer has taken its frames — nobody
    polls for it.

    Only a participant that is really gone is released (until its progress, or what it owes,
    changes): while the clock stands still for a participant, every copy looks (every 0.1 s, from
    0.05 s of standing still on) whether the process of the one to blame, or the thread that did its
    work, has ended. A reader that closes its end (a port closed, an adapter unplugged) says so itself
    (:meth:`Participant.not_reading`, :meth:`Participant.reader_closed`) and owes nothing. A
    participant that is alive but slow holds the clock however long it takes: the session takes
    longer, its figures do not get worse. Only as a last resort, after ``stall_limit_s`` of wall
    time on end (default :data:`SAFETY_LIMIT_S`), is a live participant released, with a log error.
    Every release is kept as a :class:`GovernorRelease` (:meth:`releases`) for the session's events.

    Every write bumps a shared change counter and wakes (Linux futex) whoever sleeps on it: a device
    whose time is after a pause sleeps until a participant changes something
    (:meth:`wait_for_change`) instead of polling, so it acts the moment the clock runs again.
    """

    def __init__(self, path: str, budget_ns: int, stall_limit_s: float, *, create: bool) -> None:
        if budget_ns <= 0:
            raise ValueError(f"clock governor budget must be > 0 ns, got {budget_ns}")
        self.path = path
        self.budget_ns = int(budget_ns)
        self.stall_limit_ns = int(stall_limit_s * 1e9)
        self._owner = create
        size = (_REC0 + _MAX_RECS * _REC) * 8
        flags = os.O_RDWR | (os.O_CREAT | os.O_EXCL if create else 0)
        self._fd = os.open(path, flags, 0o600)
        try:
            if create:
                os.ftruncate(self._fd, size)
            self._mm = mmap.mmap(self._fd, size)
        except BaseException:
            os.close(self._fd)
            raise
        # int64 words; a memoryview indexes a handful of words far faster than numpy does
        self._w = memoryview(self._mm).cast("q")
        if create:
            self._w[_H_MAGIC] = _MAGIC
        elif int(self._w[_H_MAGIC]) != _MAGIC:
            self._w.release()
            self._mm.close()
            os.close(self._fd)
            raise ValueError(f"clock governor {path}: not a governor state file (of this version)")
        # the change counter's low 32 bits are the futex word every write wakes (see wait_for_change)
        self._futex_word: ctypes.c_int32 | None = None
        self._futex_addr = 0
        if _FUTEX is not None:
            low = 0 if sys.byteorder == "little" else 4
            self._futex_word = ctypes.c_int32.from_buffer(self._mm, _H_EPOCH * 8 + low)
            self._futex_addr = ctypes.addressof(self._futex_word)
        self._tlock = threading.Lock()
        self._final = (0, 0)
        self._stats: GovernorStats | None = None
        self._next_check_ns = 0
        self._epoch = -1
        self._local_high = _NEVER
        self._slow = (UNBOUNDED_NS, -1, -1)

    @classmethod
    def create(cls, budget_ns: int, stall_limit_s: float = SAFETY_LIMIT_S) -> ClockGovernor:
        """A new shared state (removed again by :meth:`close` of this copy)."""
        folder = "/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir()
        path = os.path.join(folder, f"vsc-clock-{os.getpid()}-{uuid.uuid4().hex[:12]}")
        return cls(path, budget_ns, stall_limit_s, create=True)

    def __reduce__(self) -> tuple[Any, ...]:
        return (_attach_governor, (self.path, self.budget_ns, self.stall_limit_ns / 1e9))

    def close(self) -> None:
        """Unmap (and, for the copy that created it, remove) the shared state."""
        with self._tlock:
            if self._fd < 0:
                return
            self._stats = self.stats()
            self._final = (int(self._w[_H_PAUSED]), int(self._w[_H_HIGH]))
            self._futex_addr = 0
            self._futex_word = None  # the mapping cannot close while a ctypes view of it lives
            self._w.release()
            with contextlib.suppress(BufferError):
                self._mm.close()
            os.close(self._fd)
            self._fd = -1
        if self._owner:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)

    @contextlib.contextmanager
    def _locked(self) -> Iterator[memoryview]:
        with self._tlock:
            if self._fd < 0:
                raise ValueError(f"clock governor {self.path}: closed")
            fcntl.flock(self._fd, fcntl.LOCK_EX)
            try:
                yield self._w
            finally:
                fcntl.flock(self._fd, fcntl.LOCK_UN)

    # --- participants ---------------------------------------------------------------------------

    def register(self, name: str, progress_ns: int, *, reuse: bool = False, value: int = 0) -> int:
        """A new slot for participant ``name`` starting at ``progress_ns`` with free value ``value``
        (``reuse``: the slot of that name if there is one); its index."""
        raw = name.encode("utf-8")[:_NAME_BYTES].ljust(_NAME_BYTES, b"\0")
        with self._locked() as w:
            n = int(w[_H_SLOTS])
            names = self.names()
            if reuse and name in names:
                base = _HDR + names.index(name) * _SLOT
                w[base + _S_PID] = os.getpid()
                w[base + _S_TID] = 0
                w[base + _S_COUNT] = ALL_FRAMES
                w[base + _S_VALUE] = value
                w[base + _S_PROGRESS] = progress_ns
                self._changed(w)
                return names.index(name)
            if n >= _MAX_SLOTS:
                raise ValueError(f"clock governor: no slot left for participant {name!r} ({_MAX_SLOTS} in use)")
            base = _HDR + n * _SLOT
            w[base + _S_PROGRESS] = progress_ns
            w[base + _S_IGNORED] = _NEVER  # no progress equals it: not released
            w[base + _S_BLAMED] = 0
            w[base + _S_VALUE] = value
            w[base + _S_PEER] = 0
            w[base + _S_PREV] = value
            w[base + _S_COUNT] = ALL_FRAMES
            w[base + _S_PREV_COUNT] = 0
            w[base + _S_PID] = os.getpid()
            w[base + _S_TID] = 0
            for i in range(_SLOT - _S_NAME):
                w[base + _S_NAME + i] = int.from_bytes(raw[8 * i: 8 * i + 8], "little", signed=True)
            w[_H_SLOTS] = n + 1
            self._changed(w)
            return n

    def _changed(self, w: memoryview, slot: int = -1) -> None:
        """Bump the change counter (after the write it announces) and wake the sleepers on it that the
        write concerns: those waiting for participant ``slot`` (see :meth:`wait_for_change`), or
        every sleeper (``slot`` -1: a write that can move anyone's place)."""
        w[_H_EPOCH] += 1
        if self._futex_addr:  # set only where there is a futex
            _FUTEX(self._futex_addr, _FUTEX_WAKE_BITSET, 0x7FFFFFFF, None,
                   _WAKE_ALL if slot < 0 else _wake_bit(slot))

    def change_count(self) -> int:
        """The shared change counter (read it before looking at the clock; see :meth:`wait_for_change`)."""
        return int(self._w[_H_EPOCH]) if self._fd >= 0 else 0

    def wait_for_change(self, seen: int, timeout_s: float) -> bool:
        """Sleep while the clock stands still: until a write that can move it (by the participant that
        holds it or the reader that participant waits for, as this copy last looked; or a write that
        concerns every participant), at most ``timeout_s``. Returns at once when the change counter
        is no longer ``seen`` (read it before looking at the clock: what was written since is looked
        at again). True when it waited (or saw a change), False when this system has no futex (the
        caller polls instead).

        Writes by the other participants bump the counter without waking the sleeper: they cannot
        move a clock that stands for someone else (a write that changes who holds it is one by the
        holder), and under a busy host waking every sleeper at every write costs more CPU than the
        session's own work.
        """
        addr = self._futex_addr
        if not addr:
            return False
        if timeout_s > 0:
            _prog, who, blame = self._slow
            bits = _WAKE_GLOBAL
            for k in (who, blame):
                if k >= 0:
                    bits |= _wake_bit(k)
            end = time.monotonic_ns() + int(timeout_s * 1e9)  # FUTEX_WAIT_BITSET: absolute CLOCK_MONOTONIC
            ts = _Timespec(end // 1_000_000_000, end % 1_000_000_000)
            low = seen & 0xFFFFFFFF
            _FUTEX(addr, _FUTEX_WAIT_BITSET, low - (1 << 32) if low >= 1 << 31 else low, ts, bits)
        return True

    def publish(self, slot: int, progress_ns: int) -> None:
        """Set a slot's progress (one writer per slot: an aligned 8-byte store needs no lock)."""
        if self._fd >= 0:
            w = self._w
            w[_HDR + slot * _SLOT + _S_PROGRESS] = progress_ns
            self._changed(w, slot)

    def set_thread(self, slot: int, tid: int) -> None:
        """Name the thread (native id) that does slot ``slot``'s work: its end releases the slot."""
        if self._fd >= 0:
            self._w[_HDR + slot * _SLOT + _S_TID] = tid

    def set_value(self, slot: int, value: int) -> None:
        """Set a slot's free value (a consumer's last taken stamp, for its producer to see)."""
        if self._fd >= 0:
            w = self._w
            w[_HDR + slot * _SLOT + _S_VALUE] = value
            self._changed(w, slot)

    def link(self, producer: int, consumer: int) -> None:
        """Make ``consumer`` the reader of what ``producer`` sends (see :meth:`sent`)."""
        if self._fd >= 0:
            w = self._w
            w[_HDR + producer * _SLOT + _S_PEER] = consumer + 1
            self._changed(w)

    def sent(self, slot: int, stamp_ns: int) -> None:
        """Producer ``slot`` sends a frame stamped ``stamp_ns`` now (stamps never decrease)."""
        if self._fd >= 0:
            base = _HDR + slot * _SLOT
            w = self._w
            last = w[base + _S_VALUE]
            if stamp_ns != last:
                # the previous burst first, the new stamp last: a concurrent look sees at worst the
                # previous state, never more frames taken than there were
                w[base + _S_PREV_COUNT] = w[base + _S_COUNT]
                w[base + _S_PREV] = last
                w[base + _S_COUNT] = 1
                w[base + _S_VALUE] = stamp_ns
            else:
                w[base + _S_COUNT] += 1
            self._changed(w, slot)

    def took(self, slot: int, stamp_ns: int, count: int) -> None:
        """Consumer ``slot`` has taken ``count`` frames stamped ``stamp_ns`` (and all before them)."""
        if self._fd >= 0:
            base = _HDR + slot * _SLOT
            w = self._w
            w[base + _S_COUNT] = count  # the count first: seen early it only means fewer taken
            w[base + _S_VALUE] = stamp_ns
            self._changed(w, slot)

    def find(self, name: str) -> int | None:
        """The slot index of participant ``name`` (None: not registered)."""
        if self._fd < 0:
            return None
        names = self.names()
        return names.index(name) if name in names else None

    def value_at(self, slot: int) -> int:
        """The free value of slot ``slot``."""
        return int(self._w[_HDR + slot * _SLOT + _S_VALUE]) if self._fd >= 0 else 0

    def names(self) -> list[str]:
        n = int(self._w[_H_SLOTS])
        out = []
        for i in range(n):
            base = (_HDR + i * _SLOT + _S_NAME) * 8
            out.append(bytes(self._mm[base: base + _NAME_BYTES]).rstrip(b"\0").decode("utf-8", "replace"))
        return out

    def progress(self) -> dict[str, int]:
        """Every participant's current progress (ns of simulated time; UNBOUNDED_NS when idle)."""
        return {name: int(self._w[_HDR + i * _SLOT]) for i, name in enumerate(self.names())}

    # --- the clock --------------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        return self._fd >= 0 and int(self._w[_H_OFF]) == 0

    def release(self) -> None:
        """Stop governing: from now on the clock runs freely (the end of a recording)."""
        with self._locked() as w:
            w[_H_OFF] = 1
            self._changed(w)

    def _slowest(self, w: memoryview) -> tuple[int, int, int]:
        """(effective progress, slot holding it, slot to blame) of the slowest live participant;
        (UNBOUNDED_NS, -1, -1) when nobody holds the clock."""
        best, who, blame = UNBOUNDED_NS, -1, -1
        for k in range(int(w[_H_SLOTS])):
            base = _HDR + k * _SLOT
            p = w[base + _S_PROGRESS]
            culprit = k
            peer = w[base + _S_PEER]
            if peer:
                # frames sent that the consumer has not taken hold the producer back to the oldest owed
                cbase = _HDR + (peer - 1) * _SLOT
                taken = w[cbase + _S_VALUE]
                n_taken = w[cbase + _S_COUNT]
                sent = w[base + _S_VALUE]
                owed = UNBOUNDED_NS
                if taken == UNBOUNDED_NS:
                    pass  # not reading: owes nothing
                elif abs(sent - taken) <= STAMP_TOLERANCE_NS:
                    if n_taken < w[base + _S_COUNT]:
                        owed = sent  # the rest of the newest burst
                elif sent > taken:
                    prev = w[base + _S_PREV]
                    if abs(prev - taken) <= STAMP_TOLERANCE_NS:
                        owed = prev if n_taken < w[base + _S_PREV_COUNT] else sent
                    else:
                        owed = taken if prev > taken else sent  # behind by more than a burst: at least
                if owed < p:
                    p, culprit = owed, peer - 1
            if p < best and p != w[base + _S_IGNORED]:
                best, who, blame = p, k, culprit
        return best, who, blame

    def now_ns(self, start_ns: int, speed: float, mono0: int) -> int:
        """Current governed time (see the class docstring).

        The common case, a clock that runs, takes no file lock: the slowest participant is looked up
        again only when a participant has written since (every write bumps a shared epoch word after
        its own: an aligned 8-byte word is never torn, and a write not seen yet is one that happens
        just after this call), and the paused time only grows, so a stale value can only make the
        clock look further ahead, i.e. take the locked path. The highest time handed out is raised
        without the file lock: two processes raising it in the same microsecond may leave the
        lower of their two values (never below what either process handed out to itself, as each
        copy keeps its own; the next clamp stands at the shared value).
        """
        with self._tlock:
            if self._fd < 0:
                raise ValueError(f"clock governor {self.path}: closed")
            w = self._w
            limit = UNBOUNDED_NS
            if w[_H_OFF] == 0:
                epoch = w[_H_EPOCH]
                if epoch != self._epoch:
                    self._epoch = epoch  # the epoch read before the look: a write during it bumps it again
                    self._slow = self._slowest(w)
                prog, who, _blame = self._slow
                if who >= 0 and prog < UNBOUNDED_NS - self.budget_ns:
                    limit = prog + self.budget_ns
            if w[_H_CLAMP_SINCE] == 0:
                free = start_ns + int((time.monotonic_ns() - mono0 - w[_H_PAUSED]) * speed)
                if free <= limit:
                    t = max(free, w[_H_HIGH], self._local_high)
                    w[_H_HIGH] = t
                    self._local_high = t
                    return t
        return self._now_locked(start_ns, speed, mono0)

    def _now_locked(self, start_ns: int, speed: float, mono0: int) -> int:
        """:meth:`now_ns` while the clock stands still (or is about to), under the file lock."""
        with self._locked() as w:
            mono = time.monotonic_ns()
            free = start_ns + int((mono - mono0 - w[_H_PAUSED]) * speed)
            high = w[_H_HIGH]
            limit = UNBOUNDED_NS
            who = blame = -1
            if w[_H_OFF] == 0:
                prog, who, blame = self._slowest(w)
                if who >= 0 and prog < UNBOUNDED_NS - self.budget_ns:
                    limit = prog + self.budget_ns
            t = free
            if free > limit:
                t = max(limit, high)
                paused = int((free - t) / speed)
                if paused > 0:
                    w[_H_PAUSED] += paused
                    w[_HDR + blame * _SLOT + _S_BLAMED] += paused
                    since = w[_H_CLAMP_SINCE]
                    if since == 0:
                        w[_H_CLAMP_SINCE] = mono
                        w[_H_PAUSES] += 1
                    elif mono - since > _CHECK_AFTER_NS and mono >= self._next_check_ns:
                        self._next_check_ns = mono + _CHECK_EVERY_NS
                        self._release_if_gone(w, who, blame, limit - self.budget_ns, t, mono - since)
            else:
                w[_H_CLAMP_SINCE] = 0
            t = max(t, high, self._local_high)
            w[_H_HIGH] = t
            self._local_high = t
            return t

    def _release_if_gone(self, w: memoryview, who: int, blame: int, progress: int, t: int, held: int) -> None:
        """Release slot ``who`` (held back at ``progress`` by slot ``blame``) if ``blame`` is gone, or at
        the safety limit; with the lock held."""
        reason, detail = _gone(int(w[_HDR + blame * _SLOT + _S_PID]), int(w[_HDR + blame * _SLOT + _S_TID]))
        if reason is None and held > self.stall_limit_ns:
            reason, detail = ReleaseReason.SAFETY_LIMIT, f"limit {self.stall_limit_ns / 1e9:g} s"
            w[_H_SAFETY] += 1
        if reason is None:
            return
        w[_HDR + who * _SLOT + _S_IGNORED] = progress
        self._changed(w)
        w[_H_IGNORED] += 1
        w[_H_CLAMP_SINCE] = 0
        rel = self._record(w, blame, reason, detail, t, held)
        if reason is ReleaseReason.SAFETY_LIMIT:
            log.error("%s: the run's timing may suffer", rel.text)
        else:
            log.warning("%s", rel.text)

    def _record(self, w: memoryview, slot: int, reason: ReleaseReason, detail: str, t: int,
                held: int) -> GovernorRelease:
        k = int(w[_H_RELEASES])
        base = _REC0 + (k % _MAX_RECS) * _REC
        w[base] = slot
        w[base + 1] = int(reason)
        w[base + 2] = time.monotonic_ns()
        w[base + 3] = t
        w[base + 4] = held
        raw = detail.encode("utf-8")[:_DETAIL_BYTES].ljust(_DETAIL_BYTES, b"\0")
        for i in range(_REC - _R_DETAIL):
            w[base + _R_DETAIL + i] = int.from_bytes(raw[8 * i: 8 * i + 8], "little", signed=True)
        w[_H_RELEASES] = k + 1
        return self._release_at(w, k)

    def _release_at(self, w: memoryview, k: int) -> GovernorRelease:
        base = _REC0 + (k % _MAX_RECS) * _REC
        slot = int(w[base])
        raw = b"".join(int(w[base + _R_DETAIL + i]).to_bytes(8, "little", signed=True) for i in range(_REC - _R_DETAIL))
        names = self.names()
        return GovernorRelease(
            participant=names[slot] if 0 <= slot < len(names) else f"slot {slot}",
            reason=ReleaseReason(int(w[base + 1])),
            detail=raw.rstrip(b"\0").decode("utf-8", "replace"),
            clock_ns=int(w[base + 3]),
            held_wall_ns=int(w[base + 4]),
        )

    def note_release(self, slot: int, reason: ReleaseReason, detail: str = "") -> None:
        """Record that participant ``slot`` no longer holds the clock for ``reason`` (it said so itself,
        e.g. its reader closed its end); nothing is released by this call."""
        with contextlib.suppress(ValueError), self._locked() as w:
            rel = self._record(w, slot, reason, detail, int(w[_H_HIGH]), 0)
            log.info("%s", rel.text)

    def releases(self, start: int = 0) -> tuple[list[GovernorRelease], int]:
        """Release records from number ``start`` on, and the number to ask from next time (records
        more than the ring holds behind are lost; the count says how many were made)."""
        if self._fd < 0:
            return [], start
        with self._locked() as w:
            end = int(w[_H_RELEASES])
            first = max(start, end - _MAX_RECS)
            return [self._release_at(w, k) for k in range(first, end)], end

    def high_ns(self) -> int:
        """The highest time the governed clock has handed out."""
        if self._fd >= 0:
            self._final = (int(self._w[_H_PAUSED]), int(self._w[_H_HIGH]))
        return self._final[1]

    def paused_ns(self) -> int:
        """Wall time (ns) the clock has stood still so far."""
        if self._fd >= 0:
            self._final = (int(self._w[_H_PAUSED]), int(self._w[_H_HIGH]))
        return self._final[0]

    def paused_now(self) -> bool:
        """True while the clock is standing still for a participant."""
        return self._fd >= 0 and int(self._w[_H_CLAMP_SINCE]) != 0

    def stats(self) -> GovernorStats:
        """What the clock has held back so far (kept after :meth:`close`)."""
        if self._fd < 0:
            if self._stats is None:
                raise ValueError(f"clock governor {self.path}: closed before any statistics")
            return self._stats
        names = self.names()
        w = self._w
        return GovernorStats(
            budget_ns=self.budget_ns,
            paused_wall_ns=int(w[_H_PAUSED]),
            pauses=int(w[_H_PAUSES]),
            ignored=int(w[_H_IGNORED]),
            safety_releases=int(w[_H_SAFETY]),
            blamed_wall_ns={nm: int(w[_HDR + i * _SLOT + _S_BLAMED]) for i, nm in enumerate(names)
                            if int(w[_HDR + i * _SLOT + _S_BLAMED]) > 0},
        )


def _gone(pid: int, tid: int) -> tuple[ReleaseReason | None, str]:
    """Whether process ``pid`` (thread ``tid``, 0: not known) has ended: (reason, detail) or (None, "")."""
    if pid <= 0:
        return None, ""
    state = _task_state(pid, pid)
    if state is None or state in "ZXx":
        return ReleaseReason.PROCESS_ENDED, f"pid {pid}"
    if tid > 0 and tid != pid:
        state = _task_state(pid, tid)
        if state is None or state in "ZXx":
            return ReleaseReason.THREAD_ENDED, f"pid {pid} thread {tid}"
    return None, ""


def _task_state(pid: int, tid: int) -> str | None:
    """The scheduler state letter of a task (``/proc``), None when it does not exist."""
    try:
        with open(f"/proc/{pid}/task/{tid}/stat", "rb") as f:
            text = f.read()
    except FileNotFoundError:
        return None
    except OSError:  # no /proc here: only the process can be asked about
        if tid != pid:
            return "?"
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass
        return "?"
    # "pid (comm) S ...": comm may hold spaces and parentheses, the state follows the last ')'
    return text[text.rfind(b")") + 2: text.rfind(b")") + 3].decode("ascii", "replace") or "?"


def _attach_governor(path: str, budget_ns: int, stall_limit_s: float) -> ClockGovernor:
    return ClockGovernor(path, budget_ns, stall_limit_s, create=False)


class Participant:
    """A device or reader that a governed clock waits for (see :class:`ClockGovernor`).

    :meth:`at` publishes the simulated time up to which it has done its work; :meth:`idle` says it
    holds nothing back; :meth:`close` (or leaving the ``with`` block) ends its part. A producer
    names its consumer with :meth:`feeds` and announces every frame with :meth:`sent`; the consumer
    reports every frame it takes with :meth:`took` and :meth:`not_reading` when it stops (a consumer
    registered with value ``UNBOUNDED_NS`` owes nothing until its first frame). On a clock that is
    not governed the calls change nothing.

    The thread that calls :meth:`at`, :meth:`took` or :meth:`sent` is the one that does the work:
    when it ends (or the process does) while the clock waits for this participant, the clock stops
    waiting for it (see :class:`ClockGovernor`).
    """

    def __init__(self, governor: ClockGovernor | None, name: str, progress_ns: int, *, reuse: bool = False,
                 value: int = 0) -> None:
        self.name = name
        self._gov = governor
        self._slot = (governor.register(name, progress_ns, reuse=reuse, value=value)
                      if governor is not None else -1)
        self._peers: dict[str, int] = {}
        self._consumer: str | None = None
        self._linked = False
        self._taken_stamp = value
        self._taken_count = ALL_FRAMES
        self._tid = 0
        self.progress_ns = progress_ns

    @property
    def governed(self) -> bool:
        return self._gov is not None

    @property
    def budget_ns(self) -> int:
        """How far the governed clock may run past this participant's progress (0: not governed)."""
        return self._gov.budget_ns if self._gov is not None else 0

    def _worker(self, gov: ClockGovernor) -> None:
        tid = threading.get_native_id()
        if tid != self._tid:
            self._tid = tid
            gov.set_thread(self._slot, tid)

    def at(self, progress_ns: int) -> None:
        if progress_ns != self.progress_ns:
            self.progress_ns = progress_ns
            gov = self._gov
            if gov is not None:
                if progress_ns != UNBOUNDED_NS:
                    self._worker(gov)
                gov.publish(self._slot, progress_ns)

    def idle(self) -> None:
        self.at(UNBOUNDED_NS)

    def set_value(self, value: int) -> None:
        """Publish a free value for another participant (e.g. a reader's last consumed stamp)."""
        if self._gov is not None:
            self._gov.set_value(self._slot, value)

    def took(self, stamp_ns: int) -> None:
        """A consumer took a frame stamped ``stamp_ns`` (frames arrive in stamp order)."""
        if self._gov is None:
            return
        self._worker(self._gov)
        if stamp_ns == self._taken_stamp:
            self._taken_count += 1
        else:
            # the first frame after (re)connecting: what was sent before with its stamp is not owed
            self._taken_count = ALL_FRAMES if self._taken_stamp == UNBOUNDED_NS else 1
            self._taken_stamp = stamp_ns
        self._gov.took(self._slot, stamp_ns, self._taken_count)

    def not_reading(self) -> None:
        """A consumer stopped reading (unplugged, closed): it owes nothing until its next :meth:`took`
        (a release record says so when it was reading)."""
        was_reading = self._taken_stamp != UNBOUNDED_NS
        self._taken_stamp = UNBOUNDED_NS
        self.set_value(UNBOUNDED_NS)
        if was_reading and self._gov is not None:
            self._gov.note_release(self._slot, ReleaseReason.READER_CLOSED)

    def reader_closed(self, detail: str) -> None:
        """What this participant holds the clock for is no longer owed: its reader closed its end
        (``detail``: which, e.g. a port); recorded as a release."""
        if self._gov is not None:
            self._gov.note_release(self._slot, ReleaseReason.READER_CLOSED, detail)

    def feeds(self, consumer: str) -> None:
        """What this participant sends is read by participant ``consumer`` (linked once it registers)."""
        self._consumer = consumer
        self._linked = False
        self._link()

    def _link(self) -> bool:
        if self._linked or self._gov is None or self._consumer is None:
            return self._linked
        slot = self._gov.find(self._consumer)
        if slot is not None:
            self._gov.link(self._slot, slot)
            self._linked = True
        return self._linked

    @property
    def linked(self) -> bool:
        """The consumer named by :meth:`feeds` has registered (the clock waits for it)."""
        return self._link()

    def sent(self, stamp_ns: int) -> None:
        """A frame stamped ``stamp_ns`` goes out now; call it before the frame can reach the consumer."""
        if self._gov is not None:
            self._link()
            self._worker(self._gov)
            self._gov.sent(self._slot, stamp_ns)

    def peer_value(self, name: str) -> int | None:
        """The free value published by participant ``name`` (None: it has not registered yet)."""
        if self._gov is None:
            return None
        slot = self._peers.get(name)
        if slot is None:
            slot = self._gov.find(name)
            if slot is None:
                return None
            self._peers[name] = slot
        return self._gov.value_at(slot)

    def close(self) -> None:
        self.idle()

    def __enter__(self) -> Participant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def participant(clock: Clock, name: str, *, progress_ns: int | None = None, reuse: bool = False,
                value: int = 0) -> Participant:
    """A :class:`Participant` of ``clock`` (one that changes nothing unless the clock is governed),
    starting at ``progress_ns`` (default: the clock's current time) with free value ``value``."""
    gov = getattr(clock, "governor", None)
    start = clock.now_ns() if progress_ns is None else progress_ns
    return Participant(gov if isinstance(gov, ClockGovernor) else None, name, start, reuse=reuse, value=value)
