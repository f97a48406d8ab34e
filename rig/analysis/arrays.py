"""Small array helpers shared by the analysis modules: input checks and runs of True samples."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from vsccore.angles import FloatArray
from vsccore.errors import AnalysisError

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


def as_1d(name: str, x: npt.ArrayLike, n: int | None = None) -> FloatArray:
    """``x`` as a 1-D float array (of length ``n`` when given); NaN is allowed.

    Raises:
        AnalysisError: not 1-D, wrong length, or not numeric.
    """
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise AnalysisError(f"{name}: not a numeric array ({exc})") from exc
    if a.ndim == 0 and n is not None:
        return np.full(n, float(a))
    if a.ndim != 1:
        raise AnalysisError(f"{name}: expected a 1-D array, got shape {a.shape}")
    if n is not None and a.size != n:
        raise AnalysisError(f"{name}: has {a.size} samples, expected {n}")
    return a


def as_bool(name: str, x: npt.ArrayLike | None, n: int, default: bool = True) -> BoolArray:
    """``x`` as a 1-D bool array of length ``n`` (``default`` everywhere when None)."""
    if x is None:
        return np.full(n, default, dtype=bool)
    a = np.asarray(x)
    if a.ndim != 1 or a.size != n:
        raise AnalysisError(f"{name}: expected {n} booleans, got shape {a.shape}")
    return a.astype(bool)


def check_time(name: str, t: npt.ArrayLike, *, min_samples: int = 1) -> FloatArray:
    """A finite, strictly increasing time vector (s).

    Raises:
        AnalysisError: too short, non-finite or not strictly increasing.
    """
    a = as_1d(name, t)
    if a.size < min_samples:
        raise AnalysisError(f"{name}: needs at least {min_samples} samples, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise AnalysisError(f"{name}: contains NaN or infinite times")
    if a.size > 1:
        bad = np.diff(a) <= 0.0
        if np.any(bad):
            i = int(np.argmax(bad)) + 1
            raise AnalysisError(f"{name}: not strictly increasing at sample {i} (t = {a[i]:.6f} s)")
    return a


def runs(mask: npt.ArrayLike) -> list[tuple[int, int]]:
    """Maximal runs [start, stop) of True samples, in order."""
    m = np.asarray(mask, dtype=bool)
    if m.size == 0:
        return []
    d = np.diff(np.concatenate(([0], m.astype(np.int8), [0])))
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def split_at_gaps(t: FloatArray, mask: BoolArray, max_gap_s: float) -> list[tuple[int, int]]:
    """Runs of True samples in ``mask`` that are also not broken by a time gap > ``max_gap_s``."""
    out: list[tuple[int, int]] = []
    for a, b in runs(mask):
        if b - a > 1:
            cut = np.flatnonzero(np.diff(t[a:b]) > max_gap_s) + a + 1
        else:
            cut = np.empty(0, dtype=np.int64)
        edges = [a, *cut.tolist(), b]
        out.extend((int(s), int(e)) for s, e in zip(edges[:-1], edges[1:], strict=True))
    return out
