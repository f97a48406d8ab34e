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

import gc
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np
import numpy.typing as npt
from cantools.database.can import Database

from drivers.can.bus import CanBusConfig, open_bus
from drivers.can.roles import RoleMap
from rig.replay.faults import NS, Fault, IntArray
from rig.replay.plan import ReplayPlan, build_plan
from rig.replay.scheduling import check_rt_priority, fair_slice, let_threads_run, realtime_priority, timer_slack
from vsccore.clock import Clock
from vsccore.errors import ConfigError, DeviceError

__all__ = ["ReplayStats", "Replayer", "parse_bus_spec", "replay_session"]

log = logging.getLogger(__name__)


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
    (:func:`let_threads_run`), so that other threads of the process are not held up by it. The spin is
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
        self.rt_priority = check_rt_priority(rt_priority)
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
            with timer_slack(self.TIMER_SLACK_NS), realtime_priority(self.rt_priority), fair_slice(self.slice_ns):
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
            let_threads_run()
        return not stop.is_set()

    def _drain(self) -> None:
        for _ in range(64):
            try:
                if self.bus.recv(timeout=0.0) is None:
                    return
            except can.CanError:
                return


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

    check_rt_priority(rt_priority)
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
