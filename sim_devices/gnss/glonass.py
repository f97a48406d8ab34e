"""GLONASS orbits as the broadcast-ephemeris model: PZ-90 equations of motion, integrated by RK4.

A GLONASS ephemeris is not a set of Keplerian elements but the satellite's state (position,
velocity in the rotating PZ-90 frame) at the reference time tb plus the lunisolar acceleration,
which a receiver integrates (ICD GLONASS 5.1, A.3.1.2) with 4th-order Runge-Kutta over at most
±15 minutes::

    r̈ = −μ r/|r|³ − (3/2) J2 μ aₑ² r/|r|⁵ · (1 − 5 z²/|r|², 1 − 5 z²/|r|², 3 − 5 z²/|r|²)
        + ω² (x, y, 0) + 2ω (ẏ, −ẋ, 0) + a_ls

(the J2 sign written for a positive J2 = 1082625.75e-9; RTKLIB's ``glorbit`` integrates the same
equations with 60 s steps.)

The simulator's GLONASS satellites move exactly on that model, so that what they broadcast is
what they do: the truth is integrated with the same RK4 and 60 s steps from a state once a day
(the Keplerian circular orbit of :class:`~sim_devices.gnss.constellation.Constellation` at that
instant), the lunisolar acceleration held constant over each 30-minute ephemeris interval (as the
receiver holds it). The grid of steps is aligned on the intervals' bounds, which are the whole and
half hours of GLONASS time (UTC + 3 h) for 18 leap seconds: tb, the middle of an interval, is a
step of the truth, and a receiver integrating from the broadcast state at tb steps through the
same states (forward bit for bit, backward to the RK4 truncation: < 0.01 mm over 15 minutes).

Each day's integration restarts from the Keplerian state at 23:30:18 GPS time, an interval bound:
the orbits jump there (up to kilometres), at the instant the broadcast ephemeris changes, so
positions from the ephemerides stay consistent with the observations on both sides of it (a
signal sent before it comes from the old day's orbit even when received after it, as a receiver
picks the old interval's ephemeris for it); only the Doppler of the epoch that straddles it is off
(up to ~56 km jumps: a day of J2 drift from the circular orbit). A day costs at most 1 470 RK4
steps of all GLONASS satellites at once (≈ 0.1 s), once per process (the truth is shared).

The lunisolar accelerations are deterministic, of the magnitude of the real ones (≤ 3e-6 m/s²)
and on the broadcast resolution (2⁻³⁰ km/s²), not computed from Sun and Moon positions.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

__all__ = [
    "AE_M",
    "ANCHOR_S",
    "INTERVAL_S",
    "J2",
    "MU_M3_S2",
    "OMEGA_E_RAD_S",
    "STEP_S",
    "TIME_OFFSET_S",
    "GlonassTruth",
    "derivatives",
    "lunisolar_mps2",
    "propagate",
    "rk4_step",
]

FloatArray = npt.NDArray[np.float64]

#: PZ-90 constants of ICD GLONASS 5.1 (m³/s², m, –, rad/s).
MU_M3_S2 = 398_600.4418e9
AE_M = 6_378_136.0
J2 = 1_082_625.75e-9
OMEGA_E_RAD_S = 7.2921151467e-5
#: Integration step (s), as a receiver (RTKLIB's TSTEP) takes it.
STEP_S = 60.0
#: Ephemeris interval (s): one tb every 30 min, valid ±15 min around it.
INTERVAL_S = 1800
#: GLONASS minus GPS time (s) for the simulator's 18 leap seconds: 3 h − 18 s.
TIME_OFFSET_S = 3 * 3600 - 18
#: Interval bounds are at GPS seconds ≡ ANCHOR_S (mod 1800): the whole and half hours of GLONASS time.
ANCHOR_S = (-TIME_OFFSET_S) % INTERVAL_S
_WEEK_S = 604_800
_LS_QUANTUM = 2.0**-30 * 1000.0  # m/s²
_STEPS_PER_INTERVAL = int(INTERVAL_S / STEP_S)


_K_J2 = 1.5 * J2 * MU_M3_S2 * AE_M**2
_W2 = OMEGA_E_RAD_S**2


def derivatives(x: FloatArray, acc: FloatArray) -> FloatArray:
    """d/dt of states ``x`` (6, n: position m, velocity m/s in PZ-90, one column per satellite) under the
    ICD A.3.1.2 equations with lunisolar accelerations ``acc`` (3, n)."""
    px, py, pz, vx, vy, vz = x
    r2 = px * px + py * py + pz * pz
    r3 = r2 * np.sqrt(r2)
    a = _K_J2 / (r2 * r3)
    c = -MU_M3_S2 / r3 - a + a * 5.0 * pz * pz / r2
    return np.stack((vx, vy, vz, (c + _W2) * px + 2.0 * OMEGA_E_RAD_S * vy + acc[0],
                     (c + _W2) * py - 2.0 * OMEGA_E_RAD_S * vx + acc[1], (c - 2.0 * a) * pz + acc[2]))


def rk4_step(x: FloatArray, acc: FloatArray, h: float | FloatArray) -> FloatArray:
    """One classical Runge-Kutta step of ``h`` seconds (one per column when ``h`` is an array) of states (6, n)."""
    k1 = derivatives(x, acc)
    k2 = derivatives(x + k1 * (h / 2.0), acc)
    k3 = derivatives(x + k2 * (h / 2.0), acc)
    k4 = derivatives(x + k3 * h, acc)
    return np.asarray(x + (k1 + 2.0 * k2 + 2.0 * k3 + k4) * (h / 6.0), dtype=np.float64)


def propagate(state: FloatArray | tuple[float, ...], acc: FloatArray | tuple[float, ...], dt_s: float) -> FloatArray:
    """The receiver's algorithm: integrate a broadcast state (6,) with constant lunisolar ``acc`` (3,) by
    ``dt_s`` in steps of ±60 s, the last one shorter (ICD A.3.1.2; RTKLIB ``geph2pos``). Returns the state (6,)."""
    x = np.asarray(state, dtype=np.float64).reshape(6, 1)
    a = np.asarray(acc, dtype=np.float64).reshape(3, 1)
    t = float(dt_s)
    step = -STEP_S if t < 0 else STEP_S
    while abs(t) > 1e-9:
        h = t if abs(t) < STEP_S else step
        x = rk4_step(x, a, h)
        t -= h
    return x[:, 0]


def lunisolar_mps2(slot: int, interval: int) -> tuple[float, float, float]:
    """The lunisolar acceleration (m/s², PZ-90) a satellite broadcasts for the 30-minute interval number
    ``interval`` (GPS seconds // 1800 of its start, counted from :data:`ANCHOR_S`): deterministic, smooth
    over hours, |a| ≤ 3e-6 m/s², on the broadcast resolution."""
    ph = 2.0 * math.pi * interval / 24.0  # a 12 h period, like the Moon's and Sun's tide on the orbit
    vals = (2.0e-6 * math.sin(ph + 0.7 * slot), 1.5e-6 * math.cos(ph + 1.3 * slot),
            1.0e-6 * math.sin(0.5 * ph + 2.1 * slot))
    return (round(vals[0] / _LS_QUANTUM) * _LS_QUANTUM, round(vals[1] / _LS_QUANTUM) * _LS_QUANTUM,
            round(vals[2] / _LS_QUANTUM) * _LS_QUANTUM)


class GlonassTruth:
    """Integrated truth orbits of a set of GLONASS satellites (see the module docstring), cached per day.

    ``initial(t_s)`` gives the states (n, 6) at the whole GPS second ``t_s`` (since the GPS epoch) from
    which a day's integration starts. Times are handled as a day number and seconds from that day's start,
    so that float64 keeps sub-nanosecond resolution.
    """

    def __init__(self, slots: tuple[int, ...], initial: Callable[[int], FloatArray]) -> None:
        self.slots = slots
        self._initial = initial
        self._lock = threading.Lock()
        self._days: dict[int, _Day] = {}

    def _day(self, day: int) -> _Day:
        with self._lock:
            d = self._days.get(day)
            if d is None:
                if len(self._days) >= 3:
                    self._days.pop(next(iter(self._days)))
                start = day * _DAY_S + _START_S
                d = _Day(start, np.asarray(self._initial(start), dtype=np.float64).T.copy(), self.slots)
                self._days[day] = d
            return d

    @staticmethod
    def interval_of(t_s: float) -> int:
        """Number of the 30-minute ephemeris interval containing GPS second ``t_s``."""
        return math.floor((t_s - ANCHOR_S) / INTERVAL_S)

    @staticmethod
    def tb_s(t_s: float) -> int:
        """tb (GPS seconds since the GPS epoch) of the ephemeris valid at ``t_s``: the middle of its interval."""
        return GlonassTruth.interval_of(t_s) * INTERVAL_S + ANCHOR_S + INTERVAL_S // 2

    @staticmethod
    def day_of_ns(t_gps_ns: int) -> int:
        """The day's integration that GPS time ``t_gps_ns`` belongs to."""
        return (t_gps_ns - _SWITCH_S * 1_000_000_000) // (_DAY_S * 1_000_000_000)

    def states_ns(self, t_gps_ns: int, dt_s: FloatArray) -> FloatArray:
        """States (n, 6) at ``t_gps_ns`` + ``dt_s`` (one offset per satellite, |dt| < 60 s), each on the truth of the
        day its own time belongs to (a signal sent just before the daily switch comes from the old day's orbit, as
        the ephemeris a receiver picks for it describes)."""
        dt = np.asarray(dt_s, dtype=np.float64)
        day = self.day_of_ns(t_gps_ns)
        d = self._day(day)
        rel = (t_gps_ns - d.start_s * 1_000_000_000) / 1e9 + dt
        switch = float(_SWITCH_S - _START_S)  # the day's truth takes over this far into its integration
        before, after = rel < switch, rel >= switch + _DAY_S
        if not (before.any() or after.any()):
            return d.states(rel).T
        out = np.empty((len(self.slots), 6))
        here = ~(before | after)
        if here.any():
            out[here] = d.states(rel).T[here]
        for mask, other in ((before, day - 1), (after, day + 1)):
            if mask.any():
                o = self._day(other)
                out[mask] = o.states(rel + (d.start_s - o.start_s)).T[mask]
        return out

    def acc(self, t_s: float) -> FloatArray:
        """Lunisolar accelerations (n, 3) in force at GPS second ``t_s``."""
        j = self.interval_of(t_s)
        return np.array([lunisolar_mps2(s, j) for s in self.slots], dtype=np.float64)


_DAY_S = 86_400
#: A day's truth takes over at this second of the GPS day, an interval bound (23:30:18 of the day before) …
_SWITCH_S = ANCHOR_S - INTERVAL_S
#: … and its integration starts one step earlier (light time reaches back before the switch).
_START_S = _SWITCH_S - int(STEP_S)


class _Day:
    """Nodes every 60 s of one day's integration, grown on demand, as arrays (node, 6, satellite)."""

    def __init__(self, start_s: int, x0: FloatArray, slots: tuple[int, ...]) -> None:
        self.start_s = start_s
        self.slots = slots
        self._first = (start_s - ANCHOR_S) // int(STEP_S)  # 60 s steps from the grid's origin
        n = len(slots)
        self._nodes = np.empty((_DAY_S // int(STEP_S) + 64, 6, n))
        self._accs = np.empty((self._nodes.shape[0], 3, n))
        self._nodes[0] = x0
        self._accs[0] = self._acc_of_node(0)
        self._count = 1
        self._lock = threading.Lock()

    def _acc_of_node(self, k: int) -> FloatArray:
        j = (self._first + k) // _STEPS_PER_INTERVAL
        return np.array([lunisolar_mps2(s, j) for s in self.slots], dtype=np.float64).T

    def _grow(self, k_max: int) -> None:
        with self._lock:
            if k_max >= self._nodes.shape[0]:
                raise ValueError(f"GLONASS truth: {k_max * STEP_S:g} s past the day's integration start")
            for k in range(self._count - 1, k_max):
                self._nodes[k + 1] = rk4_step(self._nodes[k], self._accs[k], STEP_S)
                if (self._first + k + 1) % _STEPS_PER_INTERVAL:
                    self._accs[k + 1] = self._accs[k]
                else:
                    self._accs[k + 1] = self._acc_of_node(k + 1)
            self._count = max(self._count, k_max + 1)

    def states(self, rel_s: FloatArray) -> FloatArray:
        k = np.floor(rel_s / STEP_S).astype(np.intp)
        if np.any(k < 0):
            raise ValueError(f"GLONASS truth: {float(rel_s.min())} s before the day's integration start")
        k_max = int(k.max())
        if k_max >= self._count:
            self._grow(k_max)
        cols = np.arange(len(self.slots))
        x = self._nodes[k, :, cols].T
        acc = self._accs[k, :, cols].T
        return rk4_step(x, acc, rel_s - k * STEP_S)
