"""The common time base: every device clock mapped to GPS time, and GPS time to UTC.

Three estimators, one per kind of clock evidence:

- :class:`ClockEstimator` — a device clock against a reference clock from (device time, reference
  receive time) pairs. Transport latency (serial, USB, scheduling) is only ever positive, so the
  reference time of an event is the *lower envelope* of the pairs: the line under all points that
  lies as close to them as possible (the linear programme of Moon, Skelly & Towsley, "Estimation and
  removal of clock skew from network delay measurements", 1999: its solution is the lower convex
  hull edge spanning the mean device time). Streaming: each pair costs O(1) (per-bin minima are
  kept); fits are local (``window_s``) and joined into a piecewise-linear :class:`ClockMap`, so slow
  oscillator wander is followed. Isolated pairs *below* the envelope (a glitch, a wrong stamp) are
  rejected against a robust line through the bin minima before the hull is taken.
  Used for GNSS receivers (device time = GPS time of the log header, reference = host receive
  time: this estimates the GPS↔host mapping) and for CAN interfaces with their own timestamps.
- :func:`align_sync_pulses` — the DAQ sample clock against GPS time from sync-pulse edges: the
  fractional sample index of each edge (``drivers.daq.sync``) is matched one-to-one with the
  MARKTIME/MARKPOS GPS times of the same edges (missing and extra pulses on either side are
  tolerated), and sample index → GPS time is a least-squares fit of the matched pairs (per window
  for long sessions), which averages the per-edge location error down.
- :func:`causality_bound_ns` — how early a map puts the arrivals of items timed on another clock (DAQ
  blocks timed by the sync pulse): nothing arrives before it happened, so that is the map's error
  no statistic of its own pairs can see (used by :mod:`rig.core.quality` for the host → GPS map).
- :class:`Timebase` — the session's set of clocks: host → GPS through the reference receiver's
  mapping, CAN interface → host → GPS, GPS → UTC with the receiver-reported leap seconds, and the
  quality records (jitter, drift, residuals) written to ``/rig/timebase``.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from vsccore.errors import AnalysisError
from vsccore.gpstime import GPS_EPOCH_UNIX_NS

__all__ = [
    "OEM7_OUTPUT_LATENCY_S",
    "ClockEstimator",
    "ClockMap",
    "ClockQuality",
    "FitStatus",
    "SyncFit",
    "TimeStep",
    "Timebase",
    "align_sync_pulses",
    "causality_bound_ns",
    "envelope_line",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


OEM7_OUTPUT_LATENCY_S = 0.025
"""A NovAtel OEM7's BESTPOS/BESTVEL output latency when it is neither configured nor measurable: 20–30 ms
typical, 50 ms at most (OEM7 Commands and Logs Reference, BESTPOS)."""


class FitStatus(StrEnum):
    """How far a clock mapping can be trusted."""

    OK = "ok"
    CONVERGING = "converging"
    """Too few pairs or too short a span for a drift estimate yet (offset only)."""
    NO_DATA = "no_data"


# ---------------------------------------------------------------------------------------------
# Piecewise-linear maps
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ClockMap:
    """A monotonic piecewise-linear map from a device clock to a reference clock.

    ``ref = y0 + interp(x − x0)``; knots are relative to ``x0``/``y0`` so float64 keeps sub-ns
    precision over days. Outside the knots the end segments are extended (one knot: slope 1 + drift).
    Device units are ns for clocks and samples for a DAQ sample index.
    """

    x0: int
    y0: int
    knots_x: FloatArray
    knots_y: FloatArray
    end_slope: tuple[float, float] = (1.0, 1.0)
    """Slopes used before the first and after the last knot."""

    def __post_init__(self) -> None:
        if self.knots_x.shape != self.knots_y.shape or self.knots_x.size == 0:
            raise ValueError("ClockMap needs the same non-zero number of x and y knots")
        if np.any(np.diff(self.knots_x) <= 0):
            raise ValueError("ClockMap knots must be strictly increasing in x")

    @classmethod
    def linear(cls, x0: int, y0: int, slope: float) -> ClockMap:
        """``ref = y0 + slope·(x − x0)``."""
        return cls(x0, y0, np.zeros(1), np.zeros(1), (slope, slope))

    @property
    def slope(self) -> float:
        """Mean slope over the knots (the end slope with one knot)."""
        if self.knots_x.size < 2:
            return self.end_slope[1]
        return float((self.knots_y[-1] - self.knots_y[0]) / (self.knots_x[-1] - self.knots_x[0]))

    def _fwd(self, xr: FloatArray) -> FloatArray:
        kx, ky = self.knots_x, self.knots_y
        y = np.interp(xr, kx, ky)
        lo = xr < kx[0]
        hi = xr > kx[-1]
        if lo.any():
            y[lo] = ky[0] + (xr[lo] - kx[0]) * self.end_slope[0]
        if hi.any():
            y[hi] = ky[-1] + (xr[hi] - kx[-1]) * self.end_slope[1]
        return y

    def __call__(self, x: npt.ArrayLike) -> IntArray:
        """Reference times (int64 ns) of device times/indices ``x`` (int ns or float sample indices)."""
        xa = np.asarray(x)
        xr = (xa - self.x0).astype(np.float64) if xa.dtype.kind in "iu" else np.asarray(xa, np.float64) - self.x0
        return self.y0 + np.round(self._fwd(np.atleast_1d(xr))).astype(np.int64).reshape(xa.shape)

    def one(self, x: int | float) -> int:
        """:meth:`__call__` for one value."""
        return int(self(np.asarray([x]))[0])

    def inverse(self, y: npt.ArrayLike) -> FloatArray:
        """Device times/indices (float, relative precision of float64 after adding ``x0``) of reference times."""
        ya = np.asarray(y)
        yr = np.atleast_1d((ya - self.y0).astype(np.float64))
        kx, ky = self.knots_x, self.knots_y
        x = np.interp(yr, ky, kx)
        lo = yr < ky[0]
        hi = yr > ky[-1]
        if lo.any():
            x[lo] = kx[0] + (yr[lo] - ky[0]) / self.end_slope[0]
        if hi.any():
            x[hi] = kx[-1] + (yr[hi] - ky[-1]) / self.end_slope[1]
        return (x + self.x0).reshape(ya.shape)

    def inverse_ns(self, y: npt.ArrayLike) -> IntArray:
        """:meth:`inverse` for a clock in ns, as exact int64 (the offset is added in integers)."""
        ya = np.asarray(y)
        yr = np.atleast_1d((ya - self.y0).astype(np.float64))
        kx, ky = self.knots_x, self.knots_y
        x = np.interp(yr, ky, kx)
        lo = yr < ky[0]
        hi = yr > ky[-1]
        if lo.any():
            x[lo] = kx[0] + (yr[lo] - ky[0]) / self.end_slope[0]
        if hi.any():
            x[hi] = kx[-1] + (yr[hi] - ky[-1]) / self.end_slope[1]
        return (self.x0 + np.round(x).astype(np.int64)).reshape(ya.shape)


# ---------------------------------------------------------------------------------------------
# Lower envelope
# ---------------------------------------------------------------------------------------------


def _lower_hull(xa: FloatArray, ya: FloatArray) -> list[int]:
    """Indices of the lower convex hull of points sorted by x (Andrew's monotone chain)."""
    # on Python floats: the same IEEE arithmetic as on numpy scalars, without their per-operation cost
    x: list[float] = xa.tolist()
    y: list[float] = ya.tolist()
    hull: list[int] = []
    for i in range(len(x)):
        xi, yi = x[i], y[i]
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            # keep b only if it lies strictly below the segment a→i
            if (x[b] - x[a]) * (yi - y[a]) - (y[b] - y[a]) * (xi - x[a]) <= 0:
                hull.pop()
            else:
                break
        if hull and x[hull[-1]] == xi:
            if yi < y[hull[-1]]:
                hull.pop()
            else:
                continue
        hull.append(i)
    return hull


def _robust_line(x: FloatArray, y: FloatArray, iterations: int = 4) -> tuple[float, float, float]:
    """Slope, intercept and robust σ of an LS line with iterative rejection of far points."""
    keep = np.ones(x.size, dtype=bool)
    slope, icpt, sigma = 0.0, float(np.median(y)), 0.0
    for _ in range(iterations):
        xs, ys = x[keep], y[keep]
        if xs.size >= 2 and np.ptp(xs) > 0:
            slope, icpt = (float(v) for v in np.polyfit(xs, ys, 1))
        else:
            slope, icpt = 0.0, float(np.median(ys))
        r = y - (icpt + slope * x)
        med = float(np.median(r[keep]))
        sigma = 1.4826 * float(np.median(np.abs(r[keep] - med)))
        new = np.abs(r - med) <= 4.0 * sigma + 1.0
        if new.sum() < max(2, keep.sum() // 2) or np.array_equal(new, keep):
            break
        keep = new
    return slope, icpt, sigma


def envelope_line(
    x: npt.ArrayLike, y: npt.ArrayLike, *, reject_below: float | None = None
) -> tuple[float, float, npt.NDArray[np.bool_]]:
    """The lower-envelope line ``y ≈ a + b·x`` under points (x sorted ascending or not).

    Returns ``(a, b, used)``: the supporting line of the lower convex hull at the mean x (the
    solution of: minimise Σ(yᵢ − a − b·xᵢ) subject to yᵢ ≥ a + b·xᵢ), and the mask of points used.
    Points further than ``reject_below`` under a robust line through the data (default: 6 robust σ
    + 0.1 % of the y spread, at least 1) are treated as glitches and left out. With one distinct x
    the slope is 0.
    """
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.size == 0:
        raise AnalysisError("lower envelope of no points")
    order = np.argsort(xa, kind="stable")
    xs, ys = xa[order], ya[order]
    slope, icpt, sigma = _robust_line(xs, ys)
    r = ys - (icpt + slope * xs)
    med = float(np.median(r))
    thr = reject_below if reject_below is not None else 6.0 * sigma + 1e-3 * float(np.ptp(ys)) + 1.0
    ok = r >= med - thr
    # never reject everything (then nothing is a glitch)
    if ok.sum() == 0:
        ok[:] = True
    xk, yk = xs[ok], ys[ok]
    hull = _lower_hull(xk, yk)
    if len(hull) == 1:
        a, b = float(yk[hull[0]]), 0.0
    else:
        xm = float(xk.mean())
        hx = xk[hull]
        k = int(np.searchsorted(hx, xm, side="right")) - 1
        k = min(max(k, 0), len(hull) - 2)
        i, j = hull[k], hull[k + 1]
        b = float((yk[j] - yk[i]) / (xk[j] - xk[i]))
        a = float(yk[i] - b * xk[i])
    used = np.zeros(xa.size, dtype=bool)
    used[order[ok]] = True
    return a, b, used


@dataclass(frozen=True, slots=True)
class ClockQuality:
    """How well a clock is mapped (one ``/rig/timebase`` record, see :meth:`to_json`)."""

    clock: str
    method: str
    reference: str
    status: FitStatus
    n: int
    span_s: float
    offset_ns: int | None = None
    drift_ppm: float | None = None
    jitter_ns: float | None = None
    latency_p50_ns: float | None = None
    latency_p95_ns: float | None = None
    rms_ns: float | None = None
    max_abs_ns: float | None = None
    leap_seconds: int | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "clock": self.clock,
            "method": self.method,
            "reference": self.reference,
            "status": self.status.value,
            "n": self.n,
            "span_s": self.span_s,
        }
        for key in ("offset_ns", "drift_ppm", "jitter_ns", "latency_p50_ns", "latency_p95_ns", "rms_ns",
                    "max_abs_ns", "leap_seconds"):
            out[key] = getattr(self, key)
        return out


class ClockEstimator:
    """Online lower-envelope estimate of a device clock against a reference clock.

    Feed ``add(device_ns, ref_ns)`` for every stamped message (``ref_ns`` is when the reference
    clock — usually the host — saw it). Pairs are reduced to per-bin minima (``bin_s`` of device
    time), so memory grows by one point per bin. ``mapping()`` fits a line per ``window_s`` window
    (half-overlapping) and joins the windows into a piecewise-linear :class:`ClockMap`; ``to_ref``
    uses the latest window's line, cached: refitted whenever a bin closes while there are fewer than
    4·``refit_s`` of bins (the first seconds, while it converges), then once per ``refit_s`` of
    device time (a refit costs about a millisecond; a CAN bus asks for ``to_ref`` thousands of times
    a second, and a line two seconds old differs from a fresh one by its drift error times two
    seconds, nanoseconds). ``min_latency_ns`` is a
    known constant part of the latency (e.g. the serial transmission time of a log) that the
    envelope cannot see; it is subtracted. A window whose line implies a drift beyond
    ``max_drift_ppm`` (no quartz clock is that far off; a device that sends a backlog in a burst
    makes such envelopes) is taken as offset only, at its lowest point. Thread-safe.
    """

    def __init__(
        self,
        name: str,
        *,
        reference: str = "host",
        bin_s: float = 0.5,
        window_s: float = 120.0,
        min_latency_ns: int = 0,
        recent: int = 4096,
        min_span_s: float = 2.0,
        max_drift_ppm: float = 2000.0,
        refit_s: float = 2.0,
    ) -> None:
        if bin_s <= 0 or window_s < 4 * bin_s:
            raise ValueError(f"clock {name}: need bin_s > 0 and window_s >= 4·bin_s, got {bin_s}, {window_s}")
        if refit_s < 0:
            raise ValueError(f"clock {name}: refit_s must be >= 0, got {refit_s}")
        self.name = name
        self.reference = reference
        self._bin_ns = int(bin_s * 1e9)
        self._window_ns = int(window_s * 1e9)
        self._min_latency = int(min_latency_ns)
        self._min_span_ns = int(min_span_s * 1e9)
        self._max_drift = max_drift_ppm * 1e-6
        self._lock = threading.Lock()
        self._x0: int | None = None
        self._y_base = 0
        self._bin_key: int | None = None
        self._cur: tuple[int, int] | None = None  # (x_rel, y) lowest pair of the open bin
        self._bx: list[int] = []
        self._by: list[int] = []
        self._recent: deque[tuple[int, int]] = deque(maxlen=recent)
        self._n = 0
        self._first_x: int | None = None
        self._last_x: int | None = None
        self._fit: tuple[int, int, float] | None = None  # (x0 abs, y0 abs, slope) of the latest window
        self._fit_bins = -1
        self._refit_bins = max(1, round(refit_s / bin_s))

    @property
    def n(self) -> int:
        """Pairs added."""
        return self._n

    def add(self, device_ns: int, ref_ns: int) -> None:
        """One (device time, reference receive time) pair."""
        with self._lock:
            self._add(int(device_ns), int(ref_ns) - self._min_latency)

    @property
    def min_latency_ns(self) -> int:
        """The known constant latency taken off every reference time."""
        return self._min_latency

    def add_min_latency(self, delta_ns: int) -> None:
        """Take ``delta_ns`` more constant latency off every reference time, the pairs seen so far included (a
        latency measured during the recording: the map moves as if it had been known from the start)."""
        delta = int(delta_ns)
        with self._lock:
            self._min_latency += delta
            self._y_base -= delta
            self._recent = deque(((x, r - delta) for x, r in self._recent), maxlen=self._recent.maxlen)
            if self._fit is not None:
                x, y, slope = self._fit
                self._fit = (x, y - delta, slope)

    def add_many(self, device_ns: npt.ArrayLike, ref_ns: npt.ArrayLike) -> None:
        """Many pairs at once (vectorised; best in device-time order)."""
        d = np.asarray(device_ns, dtype=np.int64).reshape(-1)
        r = np.asarray(ref_ns, dtype=np.int64).reshape(-1) - self._min_latency
        if d.shape != r.shape:
            raise ValueError(f"clock {self.name}: {d.size} device times but {r.size} reference times")
        if d.size == 0:
            return
        with self._lock:
            if d.size < 16:
                for a, b in zip(d.tolist(), r.tolist(), strict=True):
                    self._add(a, b)
                return
            if self._x0 is None:
                self._x0 = int(d[0])
                self._y_base = int(r[0]) - int(d[0])
            xr = d - self._x0
            y = r - d - self._y_base
            self._n += int(d.size)
            tail = min(d.size, self._recent.maxlen or 0)
            self._recent.extend(zip(d[-tail:].tolist(), r[-tail:].tolist(), strict=True))
            lo, hi = int(d.min()), int(d.max())
            self._first_x = lo if self._first_x is None else min(self._first_x, lo)
            self._last_x = hi if self._last_x is None else max(self._last_x, hi)
            keys = xr // self._bin_ns
            if self._cur is not None and self._bin_key is not None:
                xr = np.r_[self._cur[0], xr]
                y = np.r_[self._cur[1], y]
                keys = np.r_[self._bin_key, keys]
            order = np.lexsort((y, keys))
            ks = keys[order]
            first = np.r_[True, ks[1:] != ks[:-1]]
            sel = order[first]  # the lowest pair of each bin, bins ascending
            self._bx.extend(xr[sel[:-1]].tolist())
            self._by.extend(y[sel[:-1]].tolist())
            last = int(sel[-1])
            self._cur = (int(xr[last]), int(y[last]))
            self._bin_key = int(keys[last])

    def _add(self, x: int, ref: int) -> None:
        if self._x0 is None:
            self._x0 = x
            self._y_base = ref - x
        xr = x - self._x0
        y = ref - x - self._y_base  # offset relative to the first pair: small numbers
        self._n += 1
        self._recent.append((x, ref))
        self._first_x = x if self._first_x is None else min(self._first_x, x)
        self._last_x = x if self._last_x is None else max(self._last_x, x)
        key = xr // self._bin_ns
        if key != self._bin_key:
            if self._cur is not None:
                self._bx.append(self._cur[0])
                self._by.append(self._cur[1])
            self._bin_key = key
            self._cur = (xr, y)
        elif self._cur is None or y < self._cur[1]:
            self._cur = (xr, y)

    def _points(self) -> tuple[FloatArray, FloatArray]:
        bx = list(self._bx)
        by = list(self._by)
        if self._cur is not None:
            bx.append(self._cur[0])
            by.append(self._cur[1])
        x = np.asarray(bx, dtype=np.float64)
        y = np.asarray(by, dtype=np.float64)
        if x.size > 1 and np.any(np.diff(x) < 0):  # pairs came out of order: re-merge into bins
            order = np.argsort(x, kind="stable")
            x, y = x[order], y[order]
        return x, y

    def status(self) -> FitStatus:
        if self._n == 0:
            return FitStatus.NO_DATA
        assert self._first_x is not None and self._last_x is not None
        if self._last_x - self._first_x < self._min_span_ns or len(self._bx) < 3:
            return FitStatus.CONVERGING
        return FitStatus.OK

    def _window_line(self, x: FloatArray, y: FloatArray, lo: float, hi: float) -> tuple[float, float]:
        m = (x >= lo) & (x <= hi)
        if m.sum() == 0:
            m[np.argmin(np.abs(x - 0.5 * (lo + hi)))] = True
        a, b, _ = envelope_line(x[m], y[m])
        if m.sum() < 3 or np.ptp(x[m]) < self._min_span_ns or abs(b) > self._max_drift:
            # too little span for a drift, or an implausible one: offset only, at the lowest point
            return float(np.min(y[m])), 0.0
        return a, b

    def last_ref_ns(self) -> int | None:
        """Reference (host) time of the latest pair added (None before any)."""
        with self._lock:
            return self._recent[-1][1] if self._recent else None

    def fit(self) -> tuple[int, int, float] | None:
        """The latest window's line as (device x, reference y at x, slope dy/dx), or None without data."""
        with self._lock:
            return self._current_fit()

    def add_to_ref(self, device_ns: int, ref_ns: int) -> int:
        """:meth:`add` the pair, then :meth:`to_ref` of its device time (one lock for both)."""
        with self._lock:
            self._add(int(device_ns), int(ref_ns) - self._min_latency)
            f = self._current_fit()
        assert f is not None
        x, y, slope = f
        return y + round((device_ns - x) * slope)

    def _current_fit(self) -> tuple[int, int, float] | None:
        if self._n == 0:
            return None
        nb = len(self._bx)
        fit = self._fit
        if fit is not None:
            new = nb - self._fit_bins
            if new == 0 or (new < self._refit_bins and nb >= 4 * self._refit_bins):
                return fit
        x, y = self._points()
        assert self._x0 is not None
        hi = float(x[-1])
        a, b = self._window_line(x, y, hi - self._window_ns, hi)
        xr = int(x[-1])
        fit = (self._x0 + xr, self._x0 + xr + self._y_base + round(a + b * xr), 1.0 + b)
        self._fit = fit
        self._fit_bins = nb
        return fit

    def to_ref(self, device_ns: int) -> int | None:
        """Reference time of a device time from the latest fit (None before any pair)."""
        f = self.fit()
        if f is None:
            return None
        x, y, slope = f
        return y + round((device_ns - x) * slope)

    def to_device(self, ref_ns: int) -> int | None:
        """Inverse of :meth:`to_ref`."""
        f = self.fit()
        if f is None:
            return None
        x, y, slope = f
        return x + round((ref_ns - y) / slope)

    def mapping(self) -> ClockMap:
        """Piecewise-linear device → reference map over everything seen (raises without data)."""
        with self._lock:
            if self._n == 0:
                raise AnalysisError(f"clock {self.name}: no (device, {self.reference}) pairs to map")
            x, y = self._points()
            assert self._x0 is not None
            x0, base = self._x0, self._y_base
            span = float(x[-1] - x[0])
            w = float(self._window_ns)
            if span <= w:
                centres = [0.5 * (x[0] + x[-1])]
            else:
                n_knots = int(math.ceil(span / (0.5 * w))) + 1
                centres = list(np.linspace(x[0], x[-1], n_knots))
            kx: list[float] = []
            ky: list[float] = []
            slopes: list[float] = []
            for c in centres:
                a, b = self._window_line(x, y, c - 0.5 * w, c + 0.5 * w)
                kx.append(c)
                ky.append(a + b * c + c)  # reference − y0 at device c (y was ref − x − base)
                slopes.append(1.0 + b)
        return ClockMap(x0, x0 + base, np.asarray(kx), np.asarray(ky), (slopes[0], slopes[-1]))

    def residuals(self) -> FloatArray:
        """Reference − mapped time of the recent pairs (ns, ≥ 0 up to glitches): their latency above the envelope."""
        with self._lock:
            pairs = list(self._recent)
        if not pairs:
            return np.zeros(0)
        m = self.mapping()
        d = np.asarray([p[0] for p in pairs], dtype=np.int64)
        r = np.asarray([p[1] for p in pairs], dtype=np.int64)
        return (r - m(d)).astype(np.float64)

    def _bin_heights(self) -> tuple[npt.NDArray[Any], int, FloatArray] | None:
        """(bin device offsets, device origin ns, |lowest pair of each bin − map| ns), or None before two bins."""
        with self._lock:
            if self._n == 0:
                return None
            x, y = self._points()
            x0, base = self._x0, self._y_base
        if x.size < 2 or x0 is None:
            return None
        m = self.mapping()
        dev = x0 + x.astype(np.int64)
        ref = dev + base + y.astype(np.int64)
        return x, x0, np.abs(ref - m(dev)).astype(np.float64)

    def envelope_error_ns(self, percentile: float = 95.0, group_s: float = 1.0) -> float | None:
        """``percentile`` of |lowest pair − map| per ``group_s`` (ns): the time-base gate's previous figure.

        It reads a second whose every pair was late (a descheduled reader) as error of the map; the gate
        now uses :meth:`map_error_ns` (``benchmarks/study_timebase_gate.py`` compares the two).

        Each bin (``bin_s`` of device time) keeps its lowest pair; the bins are grouped by ``group_s``
        of device time (at least one bin). On a clean link every group holds a message that came
        through at the latency floor, so its minimum lies on the map (tens to hundreds of µs, the
        latency's own scatter). A group whose every message was late (a starved reader, a backlog
        sent in a burst) has its minimum far above it: the map there rests on other groups, and its
        error is unknown up to that height. None before two bins exist.
        """
        bins = self._bin_heights()
        if bins is None:
            return None
        x, _x0, r = bins
        group = (x // max(int(group_s * 1e9), self._bin_ns)).astype(np.int64)
        starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
        return float(np.percentile(np.minimum.reduceat(r, starts), percentile))

    def floor_heights(self, span_s: float = 5.0) -> tuple[FloatArray, FloatArray] | None:
        """How high above the map the stream's latency floor sat, span by span: (device ns, height ns).

        For every ``span_s`` window of device time (one starting at each bin that holds pairs, whole
        windows only; half the stream's span when that is shorter than two windows) the height is the
        smallest |bin minimum − map| inside it: the floor the lowest pairs held for that whole window.
        Device times are the windows' first pairs. None before two bins.
        """
        bins = self._bin_heights()
        if bins is None:
            return None
        x, x0, r = bins
        key = (x // self._bin_ns).astype(np.int64)
        key -= key[0]
        # a stream shorter than two windows is judged on windows of half its length (a starved reader's
        # few seconds of frames must not all fall in one window that holds its one prompt frame)
        k = max(1, min(round(span_s * 1e9 / self._bin_ns), (int(key[-1]) + 1) // 2))
        # one window from each bin that holds pairs (bins are unique and ascending: a window holds at most
        # k of them), whole windows only; sparse, so a silence or a wild stamp costs no memory
        first = np.flatnonzero(key + k - 1 <= key[-1])
        idx = np.minimum(first[:, None] + np.arange(k)[None, :], key.size - 1)
        inside = key[idx] < (key[first] + k)[:, None]
        h = np.where(inside, r[idx], np.inf).min(axis=1)
        return (x0 + x[first]).astype(np.float64), h

    def map_error_ns(self, span_s: float = 5.0) -> float | None:
        """Upper bound of the map's error that the pairs show: the highest the latency floor held above
        the map for ``span_s`` on end (the maximum of :meth:`floor_heights`, ns). None before two bins.

        Transport latency is never negative, so where the map is right, some pair in every few seconds
        comes through at the floor and sits on the map (the floor's own scatter: tens of µs); a pair
        that is merely late (a scheduling hiccup, a burst) is latency — the frame's time comes from
        its device stamp through the map, so its lateness costs the analysis nothing. Where the pairs'
        floor stays above the map for a whole ``span_s`` either the latency floor rose or the clock
        moved away from the map (an NTP step or slew, a device clock reset), and the pairs cannot tell
        which: the map there can be wrong by that height, so that height is the bound. No quartz clock
        wanders from a 120 s piecewise-linear map by a measurable amount within ``span_s``, so a shorter
        excursion is latency. See :mod:`rig.core.quality` for how the figures compare with the truth.
        """
        fh = self.floor_heights(span_s)
        if fh is None:
            return None
        return float(fh[1].max()) if fh[1].size else None

    def floor_pairs(self) -> tuple[IntArray, IntArray]:
        """The lowest pair of every bin (``bin_s`` of device time) that holds pairs: (device ns, reference ns),
        in device-time order. The most prompt message of each bin (empty arrays before any pair)."""
        with self._lock:
            x, y = self._points()
            x0, base = self._x0, self._y_base
        if x0 is None or x.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        dev = x0 + x.astype(np.int64)
        return dev, dev + base + y.astype(np.int64)

    def quality(self, leap_seconds: int | None = None) -> ClockQuality:
        """The record for ``/rig/timebase``."""
        st = self.status()
        if st is FitStatus.NO_DATA:
            return ClockQuality(self.name, "lower_envelope", self.reference, st, 0, 0.0, leap_seconds=leap_seconds)
        assert self._first_x is not None and self._last_x is not None
        f = self.fit()
        assert f is not None
        res = self.residuals()
        return ClockQuality(
            clock=self.name,
            method="lower_envelope",
            reference=self.reference,
            status=st,
            n=self._n,
            span_s=(self._last_x - self._first_x) / 1e9,
            offset_ns=f[1] - f[0],
            drift_ppm=(f[2] - 1.0) * 1e6,
            jitter_ns=float(np.std(res)) if res.size else None,
            latency_p50_ns=float(np.percentile(res, 50)) if res.size else None,
            latency_p95_ns=float(np.percentile(res, 95)) if res.size else None,
            leap_seconds=leap_seconds,
        )


# ---------------------------------------------------------------------------------------------
# Causality: nothing arrives before it happened
# ---------------------------------------------------------------------------------------------

CAUSALITY_BIN_S = 0.5
"""Bins of event time in which :func:`causality_bound_ns` keeps the most prompt item."""
CAUSALITY_SPAN_S = 10.0
"""The window of event time over which a causality violation must persist."""
CAUSALITY_PERSIST = 3
"""…shown by this many bins of the window (the ``CAUSALITY_PERSIST``-th largest bin maximum)."""


def causality_bound_ns(
    event_ns: npt.ArrayLike,
    arrival_ns: npt.ArrayLike,
    *,
    bin_s: float = CAUSALITY_BIN_S,
    span_s: float = CAUSALITY_SPAN_S,
    persist: int = CAUSALITY_PERSIST,
) -> float | None:
    """How much too early a map puts the arrivals of items timed independently of it (ns, ≥ 0): a lower bound.

    ``event_ns``: the latest true instant each item holds, on a time base the map under test does not
    enter (a DAQ block's last sample timed by the sync pulse against MARKTIME, on GPS time);
    ``arrival_ns``: when the host received the item, mapped through the map under test (the host →
    GPS map) onto the same base. Nothing arrives before it happened, so ``arrival − event`` is the
    item's delivery latency (≥ 0) plus the map's error there; where it is negative the map puts host
    instants earlier than they were by at least ``event − arrival``. That is the error no statistic
    of the map's own pairs can see: a constant lateness of every pair the map was fitted to (a
    receiver that writes its logs late, a wrong configured output latency) shifts the map and its
    pairs alike, and only evidence from outside them (here another clock's causality) shows it.

    Robustness (one wild item must not condemn a session): per ``bin_s`` of event time the most
    prompt item (largest ``event − arrival``) is kept; over every ``span_s`` window of event time (one
    starting at each bin that holds items; the whole series when it is shorter) the bound is the
    ``persist``-th largest of the window's bin maxima, and the figure is the largest over the windows,
    0 when causality holds. A map error is a property of the map over its fitting windows (a
    piecewise-linear fit over tens of seconds), so it shows in every bin whose item came through
    promptly; a wrong stamp, a sample index that jumped or a host clock glitch shows in one bin. A
    violation must therefore be held by ``persist`` bins within ``span_s``: fewer wild bins than that
    in any window cost nothing, and under load, where most bins' items are late, a few prompt bins in
    ``span_s`` still show the map's error (a low quantile of the latencies, not their floor, so the
    figure stays a lower bound). None with fewer than ``persist`` bins.
    """
    ev = np.asarray(event_ns, dtype=np.int64).reshape(-1)
    arr = np.asarray(arrival_ns, dtype=np.int64).reshape(-1)
    if ev.shape != arr.shape:
        raise ValueError(f"causality: {ev.size} event times but {arr.size} arrival times")
    if persist < 1 or bin_s <= 0 or span_s < bin_s:
        raise ValueError(f"causality: need persist >= 1 and span_s >= bin_s > 0, got {persist}, {bin_s}, {span_s}")
    if ev.size == 0:
        return None
    bin_ns = int(bin_s * 1e9)
    order = np.argsort(ev, kind="stable")
    ev, early = ev[order], (ev - arr)[order].astype(np.float64)
    key = (ev - ev[0]) // bin_ns
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    bkey, bmax = key[starts], np.maximum.reduceat(early, starts)
    if bkey.size < persist:
        return None
    k = max(1, round(span_s / bin_s))
    # one window from each bin that holds items (whole windows only; one over everything when shorter)
    first = np.flatnonzero(bkey + k - 1 <= bkey[-1])
    if first.size == 0:
        first = np.zeros(1, dtype=np.int64)
        k = int(bkey[-1]) + 1
    pos = first[:, None] + np.arange(k)[None, :]  # bins are unique and ascending: a window holds at most k
    idx = np.minimum(pos, bkey.size - 1)
    inside = (pos < bkey.size) & (bkey[idx] < (bkey[first] + k)[:, None])
    held = np.sort(np.where(inside, bmax[idx], -np.inf), axis=1)[:, -min(persist, k)]
    if persist > k or not np.isfinite(held).any():
        return None  # no window can hold ``persist`` bins: not judged
    return max(0.0, float(held.max()))


# ---------------------------------------------------------------------------------------------
# DAQ sync pulses
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SyncFit:
    """Sample index → GPS time of a DAQ, from matched sync-pulse edges."""

    device: str
    map: ClockMap
    """Fractional sample index → GPS ns."""
    rate_hz: float
    """Nominal sample rate."""
    matched_edges: npt.NDArray[np.float64]
    """Fractional sample indices of the matched edges."""
    matched_marks: IntArray
    """GPS ns of the marks they were matched with."""
    residual_ns: FloatArray
    """Matched mark − mapped edge time (ns)."""
    unmatched_edges: int
    unmatched_marks: int

    @property
    def drift_ppm(self) -> float:
        """How much faster the DAQ runs than its nominal rate, in ppm (positive: more samples per GPS second)."""
        return (1e9 / (self.map.slope * self.rate_hz) - 1.0) * 1e6

    @property
    def rms_ns(self) -> float:
        return float(np.sqrt(np.mean(self.residual_ns**2))) if self.residual_ns.size else math.nan

    def gps_ns(self, sample_index: npt.ArrayLike) -> IntArray:
        """GPS time (ns) of sample indices."""
        return self.map(np.asarray(sample_index, dtype=np.float64))

    def quality(self, leap_seconds: int | None = None) -> ClockQuality:
        n = int(self.matched_edges.size)
        span = float(self.matched_marks[-1] - self.matched_marks[0]) / 1e9 if n else 0.0
        return ClockQuality(
            clock=self.device,
            method="sync_pulse",
            reference="gps",
            status=FitStatus.OK if n >= 2 else FitStatus.CONVERGING,
            n=n,
            span_s=span,
            offset_ns=self.map.one(0.0),
            drift_ppm=self.drift_ppm,
            rms_ns=self.rms_ns,
            max_abs_ns=float(np.max(np.abs(self.residual_ns))) if n else None,
            leap_seconds=leap_seconds,
        )


def _match_nearest(pred: IntArray, marks: IntArray, tol_ns: float) -> tuple[IntArray, IntArray]:
    """One-to-one matching of predicted edge times to marks: nearest first, within ``tol_ns``."""
    if pred.size == 0 or marks.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    j = np.clip(np.searchsorted(marks, pred), 1, marks.size - 1) if marks.size > 1 else np.zeros(pred.size, np.int64)
    if marks.size > 1:
        left = j - 1
        use_left = np.abs(pred - marks[left]) <= np.abs(pred - marks[j])
        j = np.where(use_left, left, j)
    d = np.abs(pred - marks[j]).astype(np.float64)
    cand = np.flatnonzero(d <= tol_ns)
    cand = cand[np.argsort(d[cand], kind="stable")]
    used_marks: set[int] = set()
    ei: list[int] = []
    mi: list[int] = []
    for e in cand.tolist():
        m = int(j[e])
        if m not in used_marks:
            used_marks.add(m)
            ei.append(e)
            mi.append(m)
    order = np.argsort(np.asarray(ei, dtype=np.int64), kind="stable")
    return np.asarray(ei, dtype=np.int64)[order], np.asarray(mi, dtype=np.int64)[order]


def _ls_map(idx: FloatArray, gps: IntArray, window_s: float, rate_hz: float) -> ClockMap:
    """LS line (or windowed LS lines joined) of GPS ns against fractional sample index."""
    i0 = float(idx[0])
    g0 = int(gps[0])
    x = idx - i0
    y = (gps - g0).astype(np.float64)
    span = float(y[-1] - y[0]) / 1e9
    if idx.size < 2:
        slope = 1e9 / rate_hz
        return ClockMap(0, g0, np.asarray([i0]), np.asarray([0.0]), (slope, slope))
    if span <= window_s or idx.size < 6:
        b, a = np.polyfit(x, y, 1)
        return ClockMap(0, g0, np.asarray([i0]), np.asarray([float(a)]), (float(b), float(b)))
    w = window_s * rate_hz  # window in samples
    n_knots = int(math.ceil((x[-1] - x[0]) / (0.5 * w))) + 1
    centres = np.linspace(x[0], x[-1], n_knots)
    ky: list[float] = []
    slopes: list[float] = []
    for c in centres:
        m = np.abs(x - c) <= 0.5 * w
        if m.sum() < 3:
            nearest = np.argsort(np.abs(x - c))[:3]
            m = np.zeros(x.size, dtype=bool)
            m[nearest] = True
        b, a = np.polyfit(x[m], y[m], 1)
        ky.append(float(a + b * c))
        slopes.append(float(b))
    return ClockMap(0, g0, centres + i0, np.asarray(ky), (slopes[0], slopes[-1]))


def align_sync_pulses(
    device: str,
    edge_index: npt.ArrayLike,
    mark_gps_ns: npt.ArrayLike,
    rate_hz: float,
    *,
    approx_gps_ns: npt.ArrayLike | None = None,
    prior_tolerance_s: float = 0.25,
    max_drift_ppm: float = 300.0,
    tolerance_ns: float = 1_000_000.0,
    window_s: float = 300.0,
) -> SyncFit:
    """Map a DAQ's sample index to GPS time from sync-pulse edges and their MARKTIME/MARKPOS times.

    ``edge_index``: fractional sample indices of the sync edges found on the DAQ channel;
    ``mark_gps_ns``: GPS times of the same switch edges from the receiver's event input. Either
    side may miss pulses or have extra ones. ``approx_gps_ns`` (one per edge, e.g. from the DAQ
    blocks' host receive times through the GNSS host mapping) makes the first match unambiguous
    within ``prior_tolerance_s``; without it the offset is found by voting over edge/mark pairs
    (which needs irregular pulse intervals, as a hand-operated switch gives). Final pairs must agree
    with the fitted map within ``tolerance_ns``.

    Raises :class:`~vsccore.errors.AnalysisError` naming the device when fewer than two edges match.
    """
    edges = np.sort(np.asarray(edge_index, dtype=np.float64))
    marks = np.sort(np.asarray(mark_gps_ns, dtype=np.int64))
    if edges.size == 0 or marks.size == 0:
        raise AnalysisError(f"DAQ {device}: no sync edges ({edges.size}) or no marks ({marks.size}) to align")
    period = 1e9 / rate_hz
    if approx_gps_ns is not None:
        approx = np.asarray(approx_gps_ns, dtype=np.int64)
        if approx.shape != np.asarray(edge_index).shape:
            raise ValueError(f"DAQ {device}: approx_gps_ns needs one value per edge")
        approx = approx[np.argsort(np.asarray(edge_index, dtype=np.float64), kind="stable")]
        ei, mi = _match_nearest(approx, marks, prior_tolerance_s * 1e9)
    else:
        ei, mi = _vote(edges, marks, period, max_drift_ppm)
    if ei.size < 2:
        raise AnalysisError(f"DAQ {device}: only {ei.size} sync edge(s) match a GPS mark; cannot align")
    # Grow and clean the match with the fitted map: rematch all edges, tighter each time.
    tol = max(tolerance_ns * 50, 20e6)
    for _ in range(6):
        fmap = _ls_map(edges[ei], marks[mi], window_s, rate_hz)
        pred = fmap(edges)
        ei, mi = _match_nearest(pred, marks, tol)
        if ei.size < 2:
            raise AnalysisError(f"DAQ {device}: sync edges and GPS marks do not agree on one clock")
        if tol <= tolerance_ns:
            break
        tol = max(tolerance_ns, tol / 10)
    fmap = _ls_map(edges[ei], marks[mi], window_s, rate_hz)
    resid = (marks[mi] - fmap(edges[ei])).astype(np.float64)
    return SyncFit(
        device=device,
        map=fmap,
        rate_hz=rate_hz,
        matched_edges=edges[ei],
        matched_marks=marks[mi],
        residual_ns=resid,
        unmatched_edges=int(edges.size - ei.size),
        unmatched_marks=int(marks.size - mi.size),
    )


def _vote(edges: FloatArray, marks: IntArray, period_ns: float, max_drift_ppm: float) -> tuple[IntArray, IntArray]:
    """Initial matching without a prior: the offset most edge/mark pairs agree on (early pulses only)."""
    n_e = min(edges.size, 40)
    n_m = min(marks.size, 60)
    e = edges[:n_e]
    m = marks[:n_m]
    offs = (m[None, :] - np.round(e[:, None] * period_ns).astype(np.int64)).ravel()
    offs.sort()
    span = float(np.ptp(e)) * period_ns if n_e > 1 else 0.0
    tol = 2e6 + 2 * max_drift_ppm * 1e-6 * span
    # densest window of width tol over the sorted offsets
    hi = np.searchsorted(offs, offs + tol, side="right")
    best = int(np.argmax(hi - np.arange(offs.size)))
    offset = float(np.median(offs[best : hi[best]]))
    pred = (offset + edges * period_ns).astype(np.int64)
    return _match_nearest(pred, marks, tol)


# ---------------------------------------------------------------------------------------------
# The session's clocks
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TimeStep:
    """A jump of the live time base: the common time of one host instant changed by ``step_ns``."""

    at_ns: int
    """Common time (after the step) of the host instant."""
    host_ns: int
    step_ns: int
    reason: str
    slew_ns: int = 0
    """0 for a step; for a slew, the device time over which the live map absorbs ``step_ns``."""


LIVE_SLEW = 0.5
"""How fast a device clock's live map absorbs a move back: its common time runs at 1 − this of device time."""
_SLEW_RECORD_NS = 100_000
"""Moves back of a live map from this size on are recorded as time-base slews (refits move it by µs)."""
_SLEW_MAX_NS = 100_000_000
"""A live map that moved back further is not slewed (it would run slow for twice as long): it starts
over at the new time, and the recorder holds the channel's messages at its last log_time until it
catches up (clamped, counted, reported: a host clock far off UTC, a device clock that reset)."""


class _LiveMap:
    """The last live common time given for one device clock or host-timed channel, so that the next is
    never earlier."""

    __slots__ = ("behind_ns", "device_ns", "lock", "utc_ns")

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.device_ns: int | None = None
        self.utc_ns = 0
        self.behind_ns = 0
        """How far the last time given lies past the fit (a slew in progress)."""


class Timebase:
    """Every clock of a session on the common time base (GPS-derived UTC, ns since the Unix epoch).

    - ``gnss_clock(receiver)``: GPS → host estimator of a receiver (add (GPS time of the log header,
      host receive time) for every log); the first receiver added, or ``reference_receiver``, maps
      host times to GPS time;
    - ``clock(name)``: a device clock (e.g. a CAN interface) → host estimator;
    - ``leap_seconds``: GPS − UTC from the receiver's TIME log (``set_leap_seconds``); until it is
      known, :meth:`gps_to_utc` raises and :meth:`host_to_utc` returns the host time unchanged;
    - ``daq``: DAQ sample index → GPS maps from :func:`align_sync_pulses` (``set_daq``).

    ``window_s`` and ``refit_s`` go to every :class:`ClockEstimator`.

    The one deliberate jump of :meth:`host_to_utc` — from the host time itself to GPS-derived UTC when
    the leap seconds become known (the first TIME log), or a change of them — is decided in
    :meth:`set_leap_seconds` and recorded as a :class:`TimeStep` (:meth:`steps`); the recording
    session writes each as a ``timebase`` event, and the recorder keeps every channel's ``log_time``
    monotonic across it.

    A device clock's live map (:meth:`device_to_utc` with a receive time) moves whenever its fit or the
    reference receiver's is refitted — back by milliseconds in the first seconds, while the envelopes
    find the latency floor. It is never stepped back: for device times in order, the common time runs
    at least at 1 − :data:`LIVE_SLEW` of the device time until the fit catches up (a slew, recorded as a
    :class:`TimeStep` with ``slew_ns`` from 0.1 ms on), so every channel timed on it stays monotonic.
    Host-timed channels get the same from :meth:`live_host_to_utc`. Moves back beyond 100 ms are not
    slewed (:data:`_SLEW_MAX_NS`). The offline maps (:meth:`ClockEstimator.mapping`) are not affected.
    """

    def __init__(self, *, reference_receiver: str | None = None, window_s: float = 120.0, refit_s: float = 2.0,
                 ) -> None:
        self._lock = threading.Lock()
        self._window_s = window_s
        self._refit_s = refit_s
        self._gnss: dict[str, ClockEstimator] = {}
        self._clocks: dict[str, ClockEstimator] = {}
        self._daq: dict[str, SyncFit] = {}
        self._reference = reference_receiver
        self.leap_seconds: int | None = None
        self._steps: list[TimeStep] = []
        self._live: dict[str, _LiveMap] = {}

    def gnss_clock(self, receiver: str) -> ClockEstimator:
        with self._lock:
            est = self._gnss.get(receiver)
            if est is None:
                est = ClockEstimator(f"gnss:{receiver}", reference="host", window_s=self._window_s,
                                     refit_s=self._refit_s)
                self._gnss[receiver] = est
                if self._reference is None:
                    self._reference = receiver
            return est

    def clock(self, name: str) -> ClockEstimator:
        with self._lock:
            est = self._clocks.get(name)
            if est is None:
                est = ClockEstimator(name, reference="host", window_s=self._window_s, refit_s=self._refit_s)
                self._clocks[name] = est
            return est

    def set_leap_seconds(self, leap_seconds: int) -> None:
        """GPS − UTC from a TIME log; a new value is a step of the time base (see :meth:`steps`)."""
        leap = int(leap_seconds)
        if leap == self.leap_seconds:
            return
        ref = self._ref()
        host = ref.last_ref_ns() if ref is not None else None
        before = self.host_to_utc(host) if host is not None else None
        with self._lock:
            old, self.leap_seconds = self.leap_seconds, leap
        if host is None or before is None:
            return
        after = self.host_to_utc(host)
        reason = ("GPS time (leap seconds from the TIME log) replaces the host-clock estimate" if old is None
                  else f"leap seconds changed {old} → {leap}")
        with self._lock:
            self._steps.append(TimeStep(after, host, after - before, reason))

    def steps(self) -> list[TimeStep]:
        """Every jump of the time base so far, in order."""
        with self._lock:
            return list(self._steps)

    def set_daq(self, fit: SyncFit) -> None:
        self._daq[fit.device] = fit

    @property
    def reference_receiver(self) -> str | None:
        return self._reference

    def _ref(self) -> ClockEstimator | None:
        return None if self._reference is None else self._gnss.get(self._reference)

    def host_to_gps(self, host_ns: int) -> int | None:
        """GPS time (ns since the GPS epoch) of a host time, from the live fit (None before GNSS data)."""
        ref = self._ref()
        return None if ref is None else ref.to_device(host_ns)

    def gps_to_utc(self, gps_ns: int) -> int:
        """UTC ns since the Unix epoch (needs the leap seconds)."""
        if self.leap_seconds is None:
            raise AnalysisError("time base: GPS − UTC leap seconds not known yet (no TIME log)")
        return gps_ns + GPS_EPOCH_UNIX_NS - self.leap_seconds * 1_000_000_000

    def host_to_utc(self, host_ns: int) -> int:
        """Common-time-base time of a host time (the host time itself until GPS and leap seconds are known)."""
        gps = self.host_to_gps(host_ns)
        if gps is None or self.leap_seconds is None:
            return host_ns
        return self.gps_to_utc(gps)

    def device_to_utc(self, clock: str, device_ns: int, host_ns: int | None = None) -> int:
        """Common time of a device-stamped event; ``host_ns`` (its receive time) also feeds the estimator."""
        est = self._clocks.get(clock)  # runs per CAN frame: the lock only to create the estimator
        if est is None:
            est = self.clock(clock)
        if host_ns is not None:
            return self._no_step_back(clock, device_ns, self.host_to_utc(est.add_to_ref(device_ns, host_ns)),
                                      host_ns)
        host = est.to_ref(device_ns)
        return self.host_to_utc(host if host is not None else device_ns)

    def live_host_to_utc(self, channel: str, host_ns: int) -> int:
        """:meth:`host_to_utc` for the messages of one host-timed ``channel`` (a topic), given in host order.

        The reference receiver's map is refitted as its logs come in; a refit that moves it back (µs
        once converged) must not make the channel's time run back: it is slewed like a device clock's.
        """
        return self._no_step_back(channel, host_ns, self.host_to_utc(host_ns), host_ns)

    def _no_step_back(self, key: str, device_ns: int, utc_ns: int, host_ns: int) -> int:
        """``utc_ns``, or the least time not before ``key``'s last live one (see the class docstring)."""
        live = self._live.get(key)
        if live is None:
            with self._lock:
                live = self._live.setdefault(key, _LiveMap())
        with live.lock:
            last = live.device_ns
            behind = 0
            if last is not None and device_ns >= last:
                floor = live.utc_ns + int((device_ns - last) * (1.0 - LIVE_SLEW))
                if floor - _SLEW_MAX_NS <= utc_ns < floor:
                    behind = floor - utc_ns
                    moved = behind - live.behind_ns  # > 0: the map moved back since the last time
                    if moved >= _SLEW_RECORD_NS:
                        reason = (f"{key}: the live map moved back {moved / 1e6:.3f} ms (a refit, or a step of "
                                  f"the time base); slewed at {1.0 - LIVE_SLEW:g}× device time so that log_time "
                                  "stays monotonic")
                        with self._lock:
                            self._steps.append(TimeStep(floor, host_ns, -moved, reason,
                                                        round(behind / LIVE_SLEW)))
                    utc_ns = floor
            live.device_ns, live.utc_ns, live.behind_ns = device_ns, utc_ns, behind
        return utc_ns

    def host_to_gps_map(self) -> ClockMap:
        """Offline host → GPS map over the whole session (inverse of the reference receiver's map)."""
        ref = self._ref()
        if ref is None:
            raise AnalysisError("time base: no GNSS receiver clock to map host time to GPS")
        return _invert(ref.mapping())

    def quality(self) -> list[ClockQuality]:
        """One record per clock for ``/rig/timebase``."""
        out = [e.quality(self.leap_seconds) for e in self._gnss.values()]
        out += [e.quality(self.leap_seconds) for e in self._clocks.values()]
        out += [f.quality(self.leap_seconds) for f in self._daq.values()]
        return out

    def quality_json(self) -> list[dict[str, Any]]:
        return [q.to_json() for q in self.quality()]


def _invert(m: ClockMap) -> ClockMap:
    """The inverse of a monotonic piecewise-linear map."""
    kx = m.knots_y.copy()
    ky = m.knots_x.copy()
    # after swapping, the origin shifts: new x0 = old y0, new y0 = old x0
    return ClockMap(m.y0, m.x0, kx, ky, (1.0 / m.end_slope[0], 1.0 / m.end_slope[1]))


def compose(outer: ClockMap, inner: ClockMap) -> Callable[[npt.ArrayLike], IntArray]:
    """``outer ∘ inner`` as a function (e.g. CAN interface → host → GPS)."""

    def f(x: npt.ArrayLike) -> IntArray:
        return outer(inner(x))

    return f


def quality_records(records: Sequence[ClockQuality] | Mapping[str, ClockQuality]) -> list[dict[str, Any]]:
    """JSON records for ``/rig/timebase``."""
    items = records.values() if isinstance(records, Mapping) else records
    return [q.to_json() for q in items]
