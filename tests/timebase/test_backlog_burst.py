"""A device that sends a backlog in one burst must not make the clock fit believe in an absurd drift."""

from __future__ import annotations

import numpy as np

from rig.core.timebase import ClockEstimator

MS = 1_000_000
S = 1_000_000_000


def test_backlog_burst_is_not_taken_for_drift() -> None:
    est = ClockEstimator("can:test", window_s=20.0, bin_s=0.5)
    rng = np.random.default_rng(3)
    host0 = 1_700_000_000 * S
    # 10 s of frames every 10 ms: the first 6 s of device time arrive in one burst at host t = 6 s
    # (the sender ran behind), the rest on time with 0.2-1 ms latency
    dev = np.arange(0, 10 * S, 10 * MS)
    late = dev < 6 * S
    host = np.where(late, host0 + 6 * S + (dev // 1000), host0 + dev + rng.integers(200_000, 1 * MS, dev.size))
    for d, h in zip(dev, host, strict=True):
        est.add(int(d), int(h))
    fit = est.fit()
    assert fit is not None
    _x, _y, slope = fit
    assert abs(slope - 1.0) < 2000e-6  # never the ~0.4 (400 000 ppm) slope the burst's envelope implies
    # frames sent on time map to within a few ms of their true host time
    mapped = est.to_ref(int(9 * S))
    assert mapped is not None
    assert abs(mapped - (host0 + 9 * S)) < 10 * MS
