"""The live rollover index of the dashboard: LTR from the lateral acceleration and its AR prediction.

Pure numerics on the last few seconds of body-fixed lateral acceleration; the recording feeds it and
the dashboard asks for the figures at its own pace (:mod:`rig.analysis.rollover` holds the model).
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from typing import Protocol

import numpy as np

from rig.analysis.rollover import (
    CONFIRM_S,
    RollModel,
    VehicleRollParams,
    horizontal_ay,
    ltr_from_lateral,
    predict_ltr,
)
from vsccore.errors import AnalysisError
from vsccore.gpstime import NS_PER_S

__all__ = ["LiveLtr", "LiveLtrVehicle"]

log = logging.getLogger(__name__)


class LiveLtrVehicle(VehicleRollParams, Protocol):
    """What :class:`LiveLtr` reads of a vehicle: the roll parameters and the two track widths (SI)."""

    @property
    def track_front_m(self) -> float: ...
    @property
    def track_rear_m(self) -> float: ...


class LiveLtr:
    """The live LTR from the lateral acceleration (role ``lat_accel``, body-fixed) through the vehicle's
    roll model, and its AR prediction over the last few seconds."""

    def __init__(self, vehicle: LiveLtrVehicle, history_s: float = 4.0, rate_hz: float = 50.0) -> None:
        self._vehicle = vehicle
        self._history_ns = round(history_s * NS_PER_S)
        self._rate_hz = rate_hz
        self._lock = threading.Lock()
        self._samples: deque[tuple[int, float]] = deque()
        self._model: RollModel | None = None
        self._failed = False
        self._last: tuple[tuple[int, int], dict[str, float | bool]] | None = None  # ((newest stamp, samples), figures)

    def add(self, t_ns: int, ay_body: float) -> None:
        with self._lock:
            self._samples.append((t_ns, ay_body))
            while self._samples and self._samples[0][0] < t_ns - self._history_ns:
                self._samples.popleft()

    def figures(self) -> dict[str, float | bool]:
        """``ltr``, ``ltr_predicted`` (the largest predicted magnitude, signed) and ``ltr_warning``; {} without data.

        Computed again only when samples came since the last call (a slowed or paused simulated clock
        brings none), and only the newest epochs' AR prediction (``predict_ltr``'s ``tail_s``: the same
        figures for a fraction of the fits)."""
        with self._lock:
            if len(self._samples) < 2 or self._failed:
                return {}
            key = (self._samples[-1][0], len(self._samples))
            if self._last is not None and self._last[0] == key:
                return dict(self._last[1])
            data = list(self._samples)
        figures = self._compute(data)
        self._last = (key, figures)
        return dict(figures)

    def _compute(self, data: list[tuple[int, float]], *, whole_window: bool = False) -> dict[str, float | bool]:
        """The figures of ``data``; ``whole_window``: the AR prediction over the whole window, not only its
        newest epochs (the same figures, for checking)."""
        v = self._vehicle
        try:
            if self._model is None:
                self._model = RollModel.from_vehicle(v)
            t_ns = np.asarray([d[0] for d in data], dtype=np.int64)
            t = (t_ns - t_ns[0]) / 1e9
            grid = np.arange(0.0, t[-1], 1.0 / self._rate_hz)
            if grid.size < 2 * self._rate_hz:
                return {}
            ay = np.interp(grid, t, np.asarray([d[1] for d in data], dtype=np.float64))
            roll, _acc = self._model.roll_from_body_ay(grid, ay)
            track = 0.5 * (v.track_front_m + v.track_rear_m)
            ltr = ltr_from_lateral(horizontal_ay(ay, roll), roll, cg_height_m=v.cg_height_m,
                                   roll_axis_height_m=v.roll_axis_height_m, track_m=track)
            recent = grid >= grid[-1] - 3.5
            pred = predict_ltr(grid[recent], ltr[recent], window_s=3.0, tail_s=None if whole_window else CONFIRM_S)
        except (AnalysisError, ValueError, np.linalg.LinAlgError) as exc:
            self._failed = True  # a model the profile cannot give: no live LTR rather than noise
            log.warning("live LTR switched off: %s", exc)
            return {}
        last = pred.predicted[-1]
        worst = float(last[np.nanargmax(np.abs(last))]) if np.any(np.isfinite(last)) else math.nan
        return {"ltr": float(ltr[-1]), "ltr_predicted": worst, "ltr_warning": bool(pred.warning[-1])}
