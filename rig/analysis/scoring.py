"""Score a VSC sideslip estimate against the reference: the library side of ``rig validate``.

Everything is on the reference's time base (the GNSS epochs): the caller (``rig/dataset``)
resamples the CAN roles onto it. The estimate comes either from the recorded CAN role
``vsc_beta_estimate`` or from a user's estimator run offline (:func:`load_estimator`,
``--estimator package.module:function``): the function is called with the decoded CAN roles as
a mapping of name → array (plus ``"t"``, the time base in s) and returns β(t) in rad.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rig.analysis.arrays import as_1d, check_time
from rig.analysis.manoeuvres import (
    Manoeuvre,
    ManoeuvreKind,
    ManoeuvreScore,
    SegmentationParams,
    apply_marks,
    score_manoeuvres,
    segment_manoeuvres,
)
from rig.analysis.metrics import Tolerances, ValidationMetrics, compare
from rig.analysis.reference import ReferenceSideslip
from vsccore.angles import FloatArray, wrap_pi
from vsccore.errors import AnalysisError

__all__ = [
    "Estimator",
    "ReferenceTruthScore",
    "ValidationResult",
    "load_estimator",
    "run_estimator",
    "score_reference_against_truth",
    "validate_estimate",
]

Estimator = Callable[[Mapping[str, FloatArray]], npt.ArrayLike]


def load_estimator(spec: str) -> Estimator:
    """Import ``package.module:function`` and return the function.

    Raises:
        AnalysisError: malformed spec, module not importable, or no such callable (the message names it).
    """
    mod_name, sep, func_name = spec.partition(":")
    if not sep or not mod_name or not func_name:
        raise AnalysisError(f"--estimator {spec!r}: expected 'package.module:function'")
    try:
        module = importlib.import_module(mod_name)
    except ImportError as exc:
        raise AnalysisError(f"--estimator {spec!r}: cannot import {mod_name!r} ({exc})") from exc
    obj: object = module
    for part in func_name.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise AnalysisError(f"--estimator {spec!r}: {mod_name!r} has no attribute {func_name!r}")
    if not callable(obj):
        raise AnalysisError(f"--estimator {spec!r}: {func_name!r} is not callable")
    fn: Estimator = obj
    return fn


def run_estimator(estimator: Estimator | str, t_s: npt.ArrayLike, roles: Mapping[str, npt.ArrayLike]) -> FloatArray:
    """Call an estimator with ``roles`` (each on ``t_s``) and ``"t"``; check it returns one β per sample.

    Raises:
        AnalysisError: the estimator raised, or returned the wrong shape.
    """
    fn = load_estimator(estimator) if isinstance(estimator, str) else estimator
    t = check_time("t_s", t_s)
    arrays = {name: as_1d(f"role {name!r}", v, t.size) for name, v in roles.items()}
    arrays["t"] = t
    name = getattr(fn, "__qualname__", repr(fn))
    try:
        out = fn(arrays)
    except Exception as exc:
        raise AnalysisError(f"estimator {name}: raised {type(exc).__name__}: {exc}") from exc
    try:
        beta = np.asarray(out, dtype=float)
    except (TypeError, ValueError) as exc:
        raise AnalysisError(f"estimator {name}: did not return numbers ({exc})") from exc
    if beta.shape != t.shape:
        raise AnalysisError(f"estimator {name}: returned shape {beta.shape}, expected {t.shape} (one β per sample)")
    return beta


@dataclass(frozen=True, slots=True)
class ReferenceTruthScore:
    """How a reference compares with simulator truth: error and coverage of its stated uncertainty."""

    name: str
    metrics: ValidationMetrics
    coverage: float
    """Fraction of valid epochs where |reference − truth| ≤ k·σ."""
    coverage_factor: float

    def to_dict(self) -> dict[str, object]:
        """JSON-able view."""
        return {
            "name": self.name,
            "coverage": self.coverage,
            "coverage_factor": self.coverage_factor,
            "metrics": self.metrics.to_dict(),
        }


def score_reference_against_truth(
    name: str,
    t_s: npt.ArrayLike,
    reference_rad: npt.ArrayLike,
    sigma_rad: npt.ArrayLike,
    truth_rad: npt.ArrayLike,
    *,
    valid: npt.ArrayLike | None = None,
    coverage_factor: float = 2.0,
) -> ReferenceTruthScore:
    """Score a reference (GNSS, optical, …) against the true sideslip of a simulated session."""
    t = check_time("t_s", t_s)
    ref = as_1d("reference_rad", reference_rad, t.size)
    sig = as_1d("sigma_rad", sigma_rad, t.size)
    tru = as_1d("truth_rad", truth_rad, t.size)
    m = compare(
        t, ref, tru, reference_valid=valid, tolerances=Tolerances(None, None, None, None, None, None)
    )
    ok = np.isfinite(ref) & np.isfinite(sig) & np.isfinite(tru)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    e = np.abs(np.asarray(wrap_pi(ref[ok] - tru[ok]), dtype=float))
    cov = float(np.mean(e <= coverage_factor * sig[ok])) if e.size else math.nan
    return ReferenceTruthScore(name, m, cov, coverage_factor)


@dataclass(frozen=True, slots=True)
class ValidationResult:
    """Everything ``rig validate`` reports (besides plots)."""

    estimate_source: str
    reference_method: str
    manoeuvres: tuple[Manoeuvre, ...]
    per_manoeuvre: tuple[ManoeuvreScore, ...]
    per_kind: tuple[ManoeuvreScore, ...]
    overall: ManoeuvreScore
    reference_valid_fraction: float
    truth: tuple[ReferenceTruthScore, ...]

    @property
    def passed(self) -> bool:
        """Overall verdict (the overall metrics against the tolerances)."""
        return self.overall.metrics is not None and self.overall.metrics.passed

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (what ``--json`` writes)."""
        return {
            "estimate_source": self.estimate_source,
            "reference_method": self.reference_method,
            "reference_valid_fraction": self.reference_valid_fraction,
            "passed": self.passed,
            "overall": self.overall.to_dict(),
            "per_kind": [s.to_dict() for s in self.per_kind],
            "per_manoeuvre": [s.to_dict() for s in self.per_manoeuvre],
            "truth": [s.to_dict() for s in self.truth],
        }

    def table_rows(self) -> list[dict[str, object]]:
        """One flat row per manoeuvre (what the CSV and the report table show; degrees)."""
        rows: list[dict[str, object]] = []
        for s in self.per_manoeuvre:
            m = s.manoeuvre
            if m is None:
                continue
            met = s.metrics
            rows.append(
                {
                    "kind": m.kind.value,
                    "t_start_s": round(m.t_start_s, 3),
                    "t_stop_s": round(m.t_stop_s, 3),
                    "source": m.source.value,
                    "label": m.label,
                    "n": 0 if met is None else met.n_compared,
                    "rmse_deg": None if met is None else math.degrees(met.rmse_rad),
                    "bias_deg": None if met is None else math.degrees(met.bias_rad),
                    "max_abs_deg": None if met is None else math.degrees(met.max_abs_rad),
                    "p95_deg": None if met is None else math.degrees(met.p95_abs_rad),
                    "lag_s": None if met is None or math.isnan(met.lag_s) else met.lag_s,
                    "passed": None if met is None else met.passed,
                }
            )
        return rows


def validate_estimate(
    reference: ReferenceSideslip,
    estimate_rad: npt.ArrayLike,
    *,
    speed_mps: npt.ArrayLike,
    swa_rad: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    ay_mps2: npt.ArrayLike,
    marks: Sequence[tuple[float, float, str]] = (),
    tolerances: Tolerances | Mapping[ManoeuvreKind, Tolerances] | None = None,
    segmentation: SegmentationParams | None = None,
    estimate_source: str = "vsc_beta_estimate",
    truth_rad: npt.ArrayLike | None = None,
) -> ValidationResult:
    """Segment the drive, score the estimate per manoeuvre, per kind and overall; with truth, score the reference.

    All arrays are on ``reference.t``.

    Raises:
        AnalysisError: malformed arrays or no valid reference epoch outside low-speed driving.
    """
    t = reference.t
    n = t.size
    est = as_1d("estimate_rad", estimate_rad, n)
    ay = as_1d("ay_mps2", ay_mps2, n)
    mans = segment_manoeuvres(t, speed_mps, swa_rad, yaw_rate_rps, ay, params=segmentation)
    if marks:
        mans = apply_marks(t, mans, marks)
    per, kinds, overall = score_manoeuvres(
        t, est, reference.beta, mans, reference_valid=reference.valid, reference_sigma=reference.sigma, ay_mps2=ay,
        tolerances=tolerances,
    )
    truth_scores: list[ReferenceTruthScore] = []
    if truth_rad is not None:
        truth_scores.append(
            score_reference_against_truth(
                f"gnss ({reference.method})", t, reference.beta, reference.sigma, truth_rad,
                valid=reference.valid, coverage_factor=reference.coverage_factor,
            )
        )
    return ValidationResult(
        estimate_source=estimate_source,
        reference_method=str(reference.method),
        manoeuvres=tuple(mans),
        per_manoeuvre=tuple(per),
        per_kind=tuple(kinds),
        overall=overall,
        reference_valid_fraction=reference.valid_fraction,
        truth=tuple(truth_scores),
    )
