"""The replay schedule on an injected fake clock: absolute deadlines (lateness never accumulates), speed,
loop passes, stop, the lateness figures, and the final approach to each due time (the spin). Deterministic:
no wall clock involved (the schedule tests wait with the clock's sleep alone, ``spin_s=0``; the spin tests
run on a clock that advances at each reading)."""

from __future__ import annotations

import ctypes
import gc
import os
import sys
import threading
from typing import Any

import can
import numpy as np
import pytest

import rig.core.topics as T  # noqa: N812 - short alias
from rig.replay.plan import ReplayPlan
from rig.replay.player import Replayer
from tests.replay.conftest import fifo_allowed
from vsccore.errors import ConfigError

MS = 1_000_000


class FakeClock:
    """A clock whose sleeps end ``oversleep_ns[k % len]`` after the deadline asked for (a host that wakes late)."""

    def __init__(self, start_ns: int = 1_700_000_000 * 10**9, oversleep_ns: tuple[int, ...] = (0,)) -> None:
        self.t = start_ns
        self.oversleep = oversleep_ns
        self.sleeps = 0

    def now_ns(self) -> int:
        return self.t

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        if stop is not None and stop.is_set():
            return False
        if t_ns > self.t:
            self.t = t_ns + self.oversleep[self.sleeps % len(self.oversleep)]
            self.sleeps += 1
        return True


class TickingClock(FakeClock):
    """A fake clock that also advances ``tick_ns`` at every reading (a host clock read in a spin); its sleeps
    end ``oversleep_ns`` late and are kept in ``targets``."""

    def __init__(self, tick_ns: int, oversleep_ns: tuple[int, ...] = (0,)) -> None:
        super().__init__(oversleep_ns=oversleep_ns)
        self.tick = tick_ns
        self.targets: list[int] = []

    def now_ns(self) -> int:
        t = self.t
        self.t += self.tick
        return t

    def sleep_until_ns(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        self.targets.append(t_ns)
        return super().sleep_until_ns(t_ns, stop)


class RecordingBus(can.BusABC):
    """Keeps every frame sent with the fake clock's time; receives nothing."""

    def __init__(self, clock: FakeClock, stop_after: int | None = None, stop: threading.Event | None = None,
                 incoming: int = 0) -> None:
        super().__init__(channel="fake")
        self.clock = clock
        self.incoming = [can.Message(arbitration_id=0x700, data=b"\x01") for _ in range(incoming)]
        self.sent: list[tuple[int, can.Message]] = []
        self.gc_enabled: list[bool] = []
        self._stop_after = stop_after
        self._stop = stop
        self.channel_info = "fake bus"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append((self.clock.t, msg))  # the clock's time without reading it (a TickingClock advances)
        self.gc_enabled.append(gc.isenabled())
        if self._stop is not None and len(self.sent) == self._stop_after:
            self._stop.set()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self.incoming.pop() if self.incoming else None), False


def plan_of(t_ms: list[float], ids: list[int]) -> ReplayPlan:
    n = len(t_ms)
    data = np.zeros((n, 8), dtype=np.uint8)
    data[:, 0] = np.arange(n) % 256
    return ReplayPlan(
        bus="test", t_ns=np.round(np.asarray(t_ms) * MS).astype(np.int64),
        can_id=np.asarray(ids, dtype=np.uint32), flags=np.full(n, int(T.CanFlag.RX), dtype=np.uint8),
        dlc=np.full(n, 8, dtype=np.uint8), length=np.full(n, 8, dtype=np.int64), data=data, recorded=data,
        rewritten=np.zeros(n, dtype=bool),
    )


def periodic(n: int, period_ms: float = 10.0, ident: int = 0x101) -> ReplayPlan:
    return plan_of([k * period_ms for k in range(n)], [ident] * n)


def run(plan: ReplayPlan, clock: FakeClock, **kw: Any) -> tuple[RecordingBus, Any]:
    kw.setdefault("spin_s", 0.0)
    bus = RecordingBus(clock)
    try:
        stats = Replayer(plan, bus, clock, **kw).run()
    finally:
        bus.shutdown()
    return bus, stats


def test_each_frame_is_sent_at_its_absolute_due_time_and_lateness_does_not_accumulate() -> None:
    """Every wake-up is 0.4 ms late: with absolute deadlines each frame is 0.4 ms late, never more. A player
    that slept the recorded gap after each send (relative sleeps) would be 1000 x 0.4 ms = 400 ms late at the end."""
    clock = FakeClock(oversleep_ns=(400_000,))
    plan = periodic(1000)
    bus, stats = run(plan, clock, lead_s=0.01)
    sent = np.asarray([t for t, _m in bus.sent])
    due = stats.start_ns + plan.t_ns
    assert sent.size == 1000
    assert np.all(sent - due == 400_000)
    assert stats.late_frames == 0 and stats.lateness_us["max"] == 400
    assert [int(m.data[0]) for _t, m in bus.sent] == [k % 256 for k in range(1000)]


def test_a_stall_delays_only_the_frames_behind_it() -> None:
    """One wake-up 25 ms late (a host stall): the frames due meanwhile go out at once, later ones on time."""
    clock = FakeClock(oversleep_ns=(0,) * 9 + (25 * MS,) + (0,) * 1000)  # frame 0 needs no sleep
    plan = periodic(50)
    bus, stats = run(plan, clock, lead_s=0.0)
    late = np.asarray([t for t, _m in bus.sent]) - (stats.start_ns + plan.t_ns)
    assert late[:10].max() == 0
    assert late[10] == 25 * MS and late[11] == 15 * MS and late[12] == 5 * MS
    assert np.all(late[13:] == 0)
    assert stats.late_frames == 3 and stats.frames_sent == 50


def test_speed_scales_the_recorded_spacing() -> None:
    clock = FakeClock()
    plan = plan_of([0.0, 10.0, 15.0, 40.0], [1, 2, 3, 4])
    bus, stats = run(plan, clock, speed=2.5, lead_s=0.0)
    sent = np.asarray([t for t, _m in bus.sent]) - stats.start_ns
    assert sent.tolist() == [0, 4 * MS, 6 * MS, 16 * MS]


def test_loop_passes_follow_each_other_with_the_longest_cycle_between() -> None:
    # two messages: 0x101 every 10 ms, 0x5A0 every 100 ms; span 290 ms
    t = [k * 10.0 for k in range(30)] + [5.0 + 100.0 * k for k in range(3)]
    ids = [0x101] * 30 + [0x5A0] * 3
    order = np.argsort(t, kind="stable")
    plan = plan_of([t[k] for k in order], [ids[k] for k in order])
    assert plan.pass_length_ns() == 290 * MS + 100 * MS
    clock = FakeClock()
    bus, stats = run(plan, clock, passes=3, lead_s=0.0)
    assert stats.passes == 3 and stats.frames_sent == 3 * 33
    sent = np.asarray([t for t, _m in bus.sent]) - stats.start_ns
    for p in range(3):
        assert np.array_equal(sent[33 * p: 33 * (p + 1)], plan.t_ns + p * 390 * MS)
    # the slow message keeps at least its own cycle across the loop boundary
    slow = sent[[k for k, (_t, m) in enumerate(bus.sent) if m.arbitration_id == 0x5A0]]
    assert np.diff(slow).min() >= 100 * MS


def test_stop_ends_the_replay_between_frames() -> None:
    clock = FakeClock()
    stop = threading.Event()
    bus = RecordingBus(clock, stop_after=7, stop=stop)
    try:
        stats = Replayer(periodic(100), bus, clock, passes=None, stop=stop, lead_s=0.0, spin_s=0.0).run()
    finally:
        bus.shutdown()
    assert stats.stopped and stats.frames_sent == 7 and len(bus.sent) == 7


def test_frames_keep_id_length_flags_and_bytes() -> None:
    plan = plan_of([0.0, 1.0], [0x101, 0x18FF0001])
    flags = plan.flags.copy()
    flags[1] |= int(T.CanFlag.EXTENDED)
    plan = ReplayPlan(**{**{f: getattr(plan, f) for f in plan.__dataclass_fields__}, "flags": flags})
    bus, _stats = run(plan, FakeClock(), lead_s=0.0)
    (_t0, a), (_t1, b) = bus.sent
    assert (a.arbitration_id, a.is_extended_id, bytes(a.data)) == (0x101, False, bytes(plan.data[0]))
    assert (b.arbitration_id, b.is_extended_id, b.dlc) == (0x18FF0001, True, 8)


@pytest.mark.parametrize(("kw", "match"), [({"speed": 0.0}, "speed"), ({"speed": float("nan")}, "speed"),
                                           ({"passes": 0}, "passes"), ({"slice_s": 0.0}, "slice_s"),
                                           ({"slice_s": 0.5}, "slice_s"), ({"rt_priority": 0}, "rt-priority"),
                                           ({"rt_priority": 100}, "rt-priority")])
def test_bad_options_are_config_errors(kw: dict[str, Any], match: str) -> None:
    clock = FakeClock()
    bus = RecordingBus(clock)
    try:
        with pytest.raises(ConfigError, match=match):
            Replayer(periodic(3), bus, clock, **kw)
    finally:
        bus.shutdown()


def test_frames_the_bus_receives_meanwhile_are_drained_when_there_is_time() -> None:
    """A bench ECU's own traffic lands in the replaying bus's receive queue: it is read and dropped between
    frames (only when the next frame is >= 2 ms away), so the queue does not grow over a long replay."""
    clock = FakeClock()
    bus = RecordingBus(clock, incoming=500)
    try:
        Replayer(periodic(20), bus, clock, lead_s=0.0, spin_s=0.0).run()
    finally:
        bus.shutdown()
    assert not bus.incoming and len(bus.sent) == 20
    dense = RecordingBus(clock, incoming=500)
    try:
        Replayer(periodic(20, period_ms=1.0), dense, clock, lead_s=0.0, spin_s=0.0).run()
    finally:
        dense.shutdown()
    assert len(dense.incoming) == 500  # 1 ms apart: no time to spare, nothing read


# --- the final approach: coarse sleep, then a bounded spin on the clock ---------------------------------


def test_the_spin_sends_on_time_when_the_sleep_wakes_late() -> None:
    """Every sleep ends 0.9 ms late (a busy host): the player sleeps until 1.5 ms before each due time and spins
    on the clock from there, so each frame goes out within two clock readings (10 µs each) of its due time.
    Waiting with the sleep alone (``spin_s=0``, the player before the spin) sends every frame 0.9 ms late."""
    plan = periodic(100)
    clock = TickingClock(10_000, oversleep_ns=(900_000,))
    bus, stats = run(plan, clock, lead_s=0.01, spin_s=0.0015)
    due = stats.start_ns + plan.t_ns
    late = np.asarray([t for t, _m in bus.sent]) - due
    assert late.min() >= 0 and late.max() <= 20_000, late  # the reading that reached it, the lateness reading
    assert stats.late_frames == 0 and stats.lateness_us["max"] < 20
    assert clock.targets == (due - 1_500_000).tolist()  # one coarse sleep per frame, ending where the spin starts

    plain = TickingClock(10_000, oversleep_ns=(900_000,))
    bus, stats = run(plan, plain, lead_s=0.01, spin_s=0.0)
    late = np.asarray([t for t, _m in bus.sent]) - (stats.start_ns + plan.t_ns)
    assert late.min() >= 900_000 and stats.lateness_us["p50"] >= 900


def test_a_sleep_that_ends_past_the_due_time_sends_at_once() -> None:
    """A stall longer than the spin: no spin, the frame goes out right away, 1 ms late (2.5 - 1.5)."""
    plan = periodic(20)
    clock = TickingClock(10_000, oversleep_ns=(2_500_000,))
    bus, stats = run(plan, clock, lead_s=0.01, spin_s=0.0015)
    late = np.asarray([t for t, _m in bus.sent]) - (stats.start_ns + plan.t_ns)
    assert np.all((late >= 1_000_000) & (late < 1_000_000 + 30_000)), late


def test_the_spin_gives_up_on_a_clock_that_does_not_advance() -> None:
    """A clock that stands still between sleeps (paused, governed, a test's): the spin ends at the first
    repeated reading and the clock's sleep finishes the wait, so the replay neither hangs nor sends early."""
    plan = periodic(3)
    clock = FakeClock(oversleep_ns=(300_000,))
    bus, stats = run(plan, clock, lead_s=0.01, spin_s=0.001)
    late = np.asarray([t for t, _m in bus.sent]) - (stats.start_ns + plan.t_ns)
    assert late.tolist() == [300_000] * 3


def test_stop_ends_a_spin() -> None:
    clock = TickingClock(10_000)
    stop = threading.Event()
    bus = RecordingBus(clock, stop_after=7, stop=stop)
    try:
        stats = Replayer(periodic(100), bus, clock, passes=None, stop=stop, lead_s=0.0, spin_s=0.0015).run()
    finally:
        bus.shutdown()
    assert stats.stopped and stats.frames_sent == 7


def test_frames_sharing_a_due_time_go_out_together_after_one_wait() -> None:
    """Frames recorded with one timestamp (a hardware-stamped burst): one coarse sleep for the group, then every
    frame of it at its due time, in recorded order."""
    plan = plan_of([0.0, 0.0, 0.0, 10.0, 10.0, 20.0], [1, 2, 3, 4, 5, 6])
    clock = TickingClock(10_000)
    bus, stats = run(plan, clock, lead_s=0.01, spin_s=0.0015)
    late = np.asarray([t for t, _m in bus.sent]) - (stats.start_ns + plan.t_ns)
    assert [m.arbitration_id for _t, m in bus.sent] == [1, 2, 3, 4, 5, 6]
    assert late.min() >= 0 and late.max() < 60_000, late
    assert len(clock.targets) == 3


@pytest.mark.parametrize("enabled_before", [True, False])
def test_the_collector_is_held_off_while_sending_and_restored(enabled_before: bool) -> None:
    """No cyclic-GC pause at a due time: the collector is off during every send and back as it was afterwards."""
    was = gc.isenabled()
    (gc.enable if enabled_before else gc.disable)()
    try:
        bus, _stats = run(periodic(10), FakeClock(), lead_s=0.0)
        assert gc.isenabled() == enabled_before
    finally:
        (gc.enable if was else gc.disable)()
    assert bus.gc_enabled == [False] * 10


@pytest.mark.skipif(sys.platform != "linux", reason="the timer slack is a Linux thread attribute (prctl)")
def test_the_player_thread_sleeps_with_a_fine_timer_slack_and_restores_it() -> None:
    """While playing, the thread's timer slack is 1 µs (Linux's default 50 µs lets a sleep's wake-up be deferred
    by that much); afterwards it is what it was."""
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    zero = ctypes.c_ulong(0)

    def slack() -> int:
        return int(prctl(30, zero, zero, zero, zero))  # PR_GET_TIMERSLACK

    before = slack()
    assert before > Replayer.TIMER_SLACK_NS  # the test means something only from a coarser slack
    seen: list[int] = []

    class SlackBus(RecordingBus):
        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            seen.append(slack())
            super().send(msg, timeout)

    clock = FakeClock()
    bus = SlackBus(clock)
    try:
        Replayer(periodic(5), bus, clock, spin_s=0.0).run()
    finally:
        bus.shutdown()
    assert seen == [Replayer.TIMER_SLACK_NS] * 5
    assert slack() == before


def _slice_ns() -> int | None:
    """The calling thread's scheduler time slice (``sched_getattr``), None where it cannot be read."""
    from rig.replay.scheduling import _SYS_SCHED_ATTR, _SchedAttr

    calls = _SYS_SCHED_ATTR.get(os.uname().machine) if sys.platform == "linux" else None
    if calls is None:
        return None
    attr = _SchedAttr()
    if ctypes.CDLL(None).syscall(calls[1], 0, ctypes.byref(attr), ctypes.sizeof(attr), 0) != 0:
        return None
    return int(attr.sched_runtime)


@pytest.mark.skipif(_slice_ns() in (None, 0), reason="no fair-scheduler time slice to read (Linux >= 6.12)")
def test_the_player_thread_asks_for_a_short_time_slice_and_restores_it() -> None:
    """While playing, the thread's time slice is ``slice_s`` (so it takes the CPU sooner when it wakes on a busy
    host); afterwards it is what it was; ``slice_s=None`` leaves it alone."""
    before = _slice_ns()
    assert before is not None and before > Replayer.SLICE_S * 1e9
    for slice_s, expected in ((Replayer.SLICE_S, round(Replayer.SLICE_S * 1e9)), (0.0005, 500_000), (None, before)):
        assert _read_at_each_send(_slice_ns, slice_s=slice_s) == [expected] * 3, slice_s
        assert _slice_ns() == before


def _read_at_each_send(read: Any, **kw: Any) -> list[Any]:
    """Play 3 frames (fake clock, no spin) with the Replayer options ``kw``; ``read()`` taken at each send, on
    the player's thread."""
    seen: list[Any] = []

    class ReadingBus(RecordingBus):
        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            seen.append(read())
            super().send(msg, timeout)

    clock = FakeClock()
    bus = ReadingBus(clock)
    try:
        Replayer(periodic(3), bus, clock, spin_s=0.0, **kw).run()
    finally:
        bus.shutdown()
    return seen


@pytest.mark.skipif(not fifo_allowed(), reason="SCHED_FIFO needs root, CAP_SYS_NICE or an rtprio limit")
def test_rt_priority_plays_on_sched_fifo_and_restores_the_policy() -> None:
    """``rt_priority``: every frame goes out from a SCHED_FIFO thread at that priority; afterwards the thread is
    back on its own policy (and without it nothing changes)."""
    def policy() -> tuple[int, int]:
        return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority

    before = policy()
    for prio, expected in ((20, (os.SCHED_FIFO, 20)), (None, before)):
        assert _read_at_each_send(policy, rt_priority=prio) == [expected] * 3, prio
        assert policy() == before


@pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="no SCHED_FIFO on this system")
def test_rt_priority_refused_by_the_kernel_names_the_fix_and_sends_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(pid: int, policy: int, param: Any) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    clock = FakeClock()
    bus = RecordingBus(clock)
    try:
        with pytest.raises(ConfigError, match=r"--rt-priority 30: the kernel refused the SCHED_FIFO policy "
                                              r"\(Operation not permitted\); it needs root, the CAP_SYS_NICE "
                                              r"capability .* or an rtprio limit >= 30"):
            Replayer(periodic(3), bus, clock, spin_s=0.0, rt_priority=30).run()
    finally:
        bus.shutdown()
    assert bus.sent == []
