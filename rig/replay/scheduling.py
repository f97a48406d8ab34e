"""Real-time scheduling of the player thread: timer slack, a short fair-scheduler slice, SCHED_FIFO priority,
letting other threads run."""

from __future__ import annotations

import contextlib
import ctypes
import os
import select
import sys
import time
from collections.abc import Iterator

from vsccore.errors import ConfigError

__all__ = ["check_rt_priority", "fair_slice", "let_threads_run", "realtime_priority", "timer_slack"]


def let_threads_run() -> None:
    """Release the interpreter lock for a moment without giving up the CPU.

    A zero-timeout ``select`` releases the lock (a thread waiting for it gets it) and returns at once;
    ``time.sleep(0)`` would also release it but enters the scheduler, where other processes take the CPU.
    Windows' select needs a socket: it sleeps 0.
    """
    if os.name == "nt":
        time.sleep(0)
    else:
        select.select((), (), (), 0)


@contextlib.contextmanager
def timer_slack(ns: int) -> Iterator[None]:
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


def check_rt_priority(priority: int | None) -> int | None:
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
    checked = check_rt_priority(priority)
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


@contextlib.contextmanager
def fair_slice(ns: int | None) -> Iterator[None]:
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


_PR_SET_TIMERSLACK = 29


_PR_GET_TIMERSLACK = 30


_SCHED_OTHER = 0


_SYS_SCHED_ATTR = {"x86_64": (314, 315), "aarch64": (274, 275), "arm64": (274, 275), "riscv64": (274, 275)}
"""``(sched_setattr, sched_getattr)`` system call numbers per machine."""
