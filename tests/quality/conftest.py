"""Sessions for the time-base quality tests: one clean truth session and its timing-damaged copies."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

import rig.core.topics as T  # noqa: N812 - short alias
from tests.quality.synth import NS, clean_session, rewrite

IntArray = npt.NDArray[np.int64]
NO_TIME = np.int64(T.NO_TIME_NS)


def starved_interface(t: IntArray, host: IntArray, _dev: IntArray) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:
    """Interface-stamped frames whose reader falls behind by 0.5 s per second after 2 s; at the end of the
    recording the backlog is never read (frames the host did not take before its last frame time are lost)."""
    back = np.clip((t - 2 * NS) // 2, 0, None)
    return host - 300_000, host + back, host + back <= host[-1]


def starved_host(t: IntArray, host: IntArray, dev: IntArray) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:
    """The same reader with host stamps only (no interface clock)."""
    _dev, h, keep = starved_interface(t, host, dev)
    return np.full(t.size, NO_TIME), h, keep


def stalled(t: IntArray, host: IntArray, _dev: IntArray) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:
    """No frames from 3.0 to 3.5 s (the bus or the reader stopped), otherwise clean."""
    return np.full(t.size, NO_TIME), host, ~((t > 3 * NS) & (t < 3 * NS + NS // 2))


def jittery(t: IntArray, host: IntArray, _dev: IntArray) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:
    """Host-stamped frames of which half arrive 3 ms late: a loaded host, not a starved one."""
    late = (np.random.default_rng(1).random(t.size) < 0.5) * 3_000_000
    return np.full(t.size, NO_TIME), host + late, np.ones(t.size, dtype=bool)


@pytest.fixture(scope="package")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("quality")
    clean = clean_session(out)
    return {
        "clean": clean,
        "starved_interface": rewrite(clean, out, "starved_interface", starved_interface),
        "starved_host": rewrite(clean, out, "starved_host", starved_host),
        "stalled": rewrite(clean, out, "stalled", stalled),
        "jittery": rewrite(clean, out, "jittery", jittery),
    }
