"""Per-epoch choice between live RTK and PPK, and how the reference states it."""

from __future__ import annotations

import numpy as np
import pytest

from rig.analysis.reference import (
    PositionSource,
    ReferenceMethod,
    ReferenceSideslip,
    choose_position_source,
    epoch_source,
)
from vsccore.errors import AnalysisError


def test_live_rtk_fixed_first_then_ppk_fixed_then_none() -> None:
    rtk = np.array([True, True, False, False])
    ppk = np.array([True, False, True, False])
    src = choose_position_source(rtk, ppk)
    assert src.tolist() == [PositionSource.RTK, PositionSource.RTK, PositionSource.PPK, PositionSource.NONE]
    with pytest.raises(AnalysisError, match=r"rtk_fixed \(4,\) and ppk_fixed \(3,\) differ"):
        choose_position_source(rtk, ppk[:3])


def test_pair_source_names_both_antennas_when_they_differ() -> None:
    a = np.array(["rtk", "ppk", "rtk", "ppk"])
    b = np.array(["rtk", "ppk", "ppk", "none"])
    assert epoch_source(a, b).tolist() == ["rtk", "ppk", "rtk/ppk", "ppk/none"]


def _ref(source: np.ndarray | None, valid: np.ndarray) -> ReferenceSideslip:
    n = valid.size
    z = np.zeros(n)
    return ReferenceSideslip(t=np.arange(n, dtype=float), beta=z, sigma=z + 1e-3, valid=valid,
                             reasons=np.where(valid, 0, 1).astype(np.uint8), method=ReferenceMethod.RAW, speed=z + 10.0,
                             yaw_rate=z, heading=z, source=source)


def test_summary_counts_the_valid_epochs_per_source_and_says_why() -> None:
    valid = np.array([True, True, True, True, False])
    ref = _ref(np.array(["ppk", "ppk", "rtk", "rtk/ppk", "none"]), valid)
    assert ref.source_counts() == {"ppk": 2, "rtk": 1, "rtk/ppk": 1}
    text = ref.source_summary()
    assert text.startswith("reference positions per valid epoch (4): 2 PPK fixed on both antennas (live RTK not fixed)")
    assert "1 live RTK fixed on both antennas" in text and "1 live RTK on A, PPK on B" in text
    assert ref.to_dict()["position_sources"] == {"ppk": 2, "rtk": 1, "rtk/ppk": 1}
    live_only = _ref(None, valid)
    assert live_only.source_summary() == "" and live_only.to_dict()["position_sources"] == {}
