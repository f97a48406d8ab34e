"""Helpers for the simulator tests: find a phase of a drive in the ground truth's metadata."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_devices.vehicle import GroundTruth

BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class PhaseInfo:
    """One phase of a simulated drive as recorded in GroundTruth.meta."""

    prefix: str
    label: str
    t_start: float
    t_end: float
    meta: dict[str, float | str]

    def number(self, key: str) -> float:
        value = self.meta[key]
        assert isinstance(value, float | int), f"{self.prefix}.{key} is not a number: {value!r}"
        return float(value)

    def mask(self, truth: GroundTruth, start_offset: float = 0.0, end_offset: float = 0.0) -> BoolArray:
        """Samples from t_start + start_offset to t_end − end_offset."""
        return (truth.t >= self.t_start + start_offset) & (truth.t < self.t_end - end_offset)


def phases(truth: GroundTruth, label: str) -> list[PhaseInfo]:
    """All phases whose label is ``label``, in drive order."""
    found: list[PhaseInfo] = []
    for key, value in truth.meta.items():
        if not key.endswith(".label") or value != label or ".phase." not in key:
            continue
        prefix = key[: -len(".label")]
        extra = {k[len(prefix) + 1 :]: v for k, v in truth.meta.items() if k.startswith(prefix + ".")}
        found.append(
            PhaseInfo(
                prefix=prefix,
                label=label,
                t_start=float(extra["t_start_s"]),
                t_end=float(extra["t_end_s"]),
                meta=extra,
            )
        )
    found.sort(key=lambda p: p.t_start)
    assert found, f"no phase labelled {label!r} in the ground truth"
    return found


def phase(truth: GroundTruth, label: str) -> PhaseInfo:
    """The one phase labelled ``label``."""
    (only,) = phases(truth, label)
    return only
