"""Steering ratio: from driven circles (GNSS track) and from tape measurements of a wheel track.

At low speed tyres hardly slip, so the rear-axle centre moves on a circle of radius R with
tan δ = L / R (single-track model: L wheelbase, δ the equivalent front road-wheel angle). The
steering ratio at a steering-wheel angle SWA is SWA / δ. It varies with SWA (variable-ratio
racks, Ackermann and linkage geometry) and may differ between forward and reverse, so it is
measured per SWA and direction. Tyre slip biases the kinematic δ: at 5 km/h the simulated car
reads ≈ 0.2 % high in ratio driving forward (understeer: δ_kin = δ − K·a_y, K·v²/L ≈ 0.18 %) and
as much low in reverse, growing to ≈ ±0.5 % near the lock; it grows as v².

Angles are in rad, positive to the left (ISO 8855); GNSS azimuths clockwise from north.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize

from calibration.segments import Direction, SwaSegment, check_time
from vsccore.angles import FloatArray, azimuth_to_yaw, unwrap
from vsccore.errors import CalibrationError

DEFAULT_TAPE_SIGMA_M = 0.01
DEFAULT_MIN_ARC_RAD = math.radians(90.0)


# --------------------------------------------------------------------------------------------
# geometry


@dataclass(frozen=True, slots=True)
class CircleFit:
    """A circle fitted to a planar track (ENU metres)."""

    east_m: float
    """Centre east."""
    north_m: float
    """Centre north."""
    radius_m: float
    rms_residual_m: float
    """RMS of the geometric (radial) residuals."""
    n_points: int
    swept_rad: float
    """Angle swept about the centre in sample order, counter-clockwise positive (may exceed 2π)."""
    arc_coverage_rad: float
    """Part of the circle covered by the points (2π minus the largest angular gap)."""
    radius_se_m: float = math.nan
    """Standard error of the radius: the fit's covariance with the residual variance, inflated for the
    residuals' autocorrelation (n_eff = n / (1 + 2 Σ ρ_k), summed to the first negative ρ_k)."""

    def to_dict(self) -> dict[str, float | int]:
        """JSON-able view (units in the key names)."""
        return {
            "east_m": self.east_m,
            "north_m": self.north_m,
            "radius_m": self.radius_m,
            "radius_se_m": self.radius_se_m,
            "rms_residual_m": self.rms_residual_m,
            "n_points": self.n_points,
            "swept_deg": math.degrees(self.swept_rad),
            "arc_coverage_deg": math.degrees(self.arc_coverage_rad),
        }


def _autocorrelation_inflation(res: FloatArray) -> float:
    """1 + 2 Σ ρ_k over the lags before the first negative autocorrelation (≥ 1): variance factor of a mean."""
    r = res - float(np.mean(res))
    n = r.size
    var = float(r @ r)
    if n < 4 or var <= 0.0:
        return 1.0
    spec = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[:n] / var
    total = 0.0
    for k in range(1, n // 2):
        if acf[k] <= 0.0:
            break
        total += float(acf[k])
    return max(1.0, 1.0 + 2.0 * total)


def fit_circle(east_m: npt.ArrayLike, north_m: npt.ArrayLike) -> CircleFit:
    """Least-squares circle through planar points: Kåsa algebraic fit refined geometrically.

    The algebraic fit (x² + y² + Dx + Ey + F = 0, linear least squares) is biased towards small
    radii on short noisy arcs; it only seeds a Levenberg–Marquardt minimisation of the radial
    distances |p − c| − R (scipy.optimize.least_squares). Coordinates are centred and scaled
    first so that the fit is well conditioned far from the ENU origin. NaN points are dropped.

    Raises:
        CalibrationError: fewer than 3 finite points, all points identical, or points on a line.
    """
    x = np.asarray(east_m, dtype=float)
    y = np.asarray(north_m, dtype=float)
    if x.shape != y.shape or x.ndim != 1:
        raise CalibrationError(f"fit_circle: east and north must be 1-D of equal length, got {x.shape}, {y.shape}")
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = int(x.size)
    if n < 3:
        raise CalibrationError(f"fit_circle: need at least 3 finite points, got {n}")
    x0, y0 = float(np.mean(x)), float(np.mean(y))
    u, v = x - x0, y - y0
    scale = float(np.sqrt(np.mean(u * u + v * v)))
    if scale == 0.0:
        raise CalibrationError(f"fit_circle: all {n} points are identical (vehicle standing still?)")
    u, v = u / scale, v / scale
    sv = np.linalg.svd(np.column_stack([u, v]), compute_uv=False)
    if sv[1] <= 1e-9 * sv[0]:
        raise CalibrationError(f"fit_circle: the {n} points lie on a straight line; no circle")
    a = np.column_stack([u, v, np.ones(n)])
    (d, e, f), *_ = np.linalg.lstsq(a, -(u * u + v * v), rcond=None)
    uc, vc = -d / 2.0, -e / 2.0
    r2 = uc * uc + vc * vc - f
    r0 = math.sqrt(r2) if r2 > 0.0 else 1.0

    def residuals(p: FloatArray) -> FloatArray:
        return np.asarray(np.hypot(u - p[0], v - p[1]) - p[2], dtype=float)

    def jacobian(p: FloatArray) -> FloatArray:
        du, dv = u - p[0], v - p[1]
        dist = np.maximum(np.hypot(du, dv), 1e-300)
        return np.column_stack([-du / dist, -dv / dist, -np.ones(n)])

    sol = optimize.least_squares(
        residuals, np.array([uc, vc, r0]), jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15
    )
    uc, vc, rr = (float(p) for p in sol.x)
    rr = abs(rr)
    if not math.isfinite(rr) or rr > 1e6:
        raise CalibrationError(f"fit_circle: the {n} points are (nearly) on a straight line; radius diverged")
    res = residuals(np.array([uc, vc, rr]))
    jac = jacobian(np.array([uc, vc, rr]))
    try:
        cov = np.linalg.inv(jac.T @ jac) * float(res @ res) / max(n - 3, 1) * _autocorrelation_inflation(res)
        radius_se = scale * math.sqrt(max(float(cov[2, 2]), 0.0))
    except np.linalg.LinAlgError:
        radius_se = math.inf
    ang = np.arctan2(v - vc, u - uc)
    swept = float(unwrap(ang)[-1] - unwrap(ang)[0])
    srt = np.sort(ang)
    gaps = np.diff(np.concatenate([srt, [srt[0] + 2.0 * math.pi]]))
    return CircleFit(
        east_m=x0 + scale * uc,
        north_m=y0 + scale * vc,
        radius_m=scale * rr,
        rms_residual_m=scale * float(np.sqrt(np.mean(res * res))),
        n_points=n,
        swept_rad=swept,
        arc_coverage_rad=float(2.0 * math.pi - np.max(gaps)),
        radius_se_m=radius_se,
    )


def move_body_point(
    east_m: npt.ArrayLike,
    north_m: npt.ArrayLike,
    heading_rad: npt.ArrayLike,
    from_xy_m: tuple[float, float],
    to_xy_m: tuple[float, float],
) -> tuple[FloatArray, FloatArray]:
    """ENU track of another point of the (rigid, level) body.

    ``east_m``/``north_m`` is the track of the body point ``from_xy_m``; ``heading_rad`` the
    vehicle x-axis azimuth (clockwise from north, e.g. the dual-antenna heading corrected for the
    mounting offset); body points are (x forward, y left) in metres from any common origin.
    """
    yaw = azimuth_to_yaw(np.asarray(heading_rad, dtype=float))
    dx = to_xy_m[0] - from_xy_m[0]
    dy = to_xy_m[1] - from_xy_m[1]
    c, s = np.cos(yaw), np.sin(yaw)
    e = np.asarray(east_m, dtype=float) + c * dx - s * dy
    n = np.asarray(north_m, dtype=float) + s * dx + c * dy
    return np.asarray(e, dtype=float), np.asarray(n, dtype=float)


def antenna_to_rear_axle(
    east_m: npt.ArrayLike,
    north_m: npt.ArrayLike,
    heading_rad: npt.ArrayLike,
    antenna_xy_m: tuple[float, float],
    rear_axle_xy_m: tuple[float, float],
) -> tuple[FloatArray, FloatArray]:
    """Track of the rear-axle centre from antenna A's track (see :func:`move_body_point`)."""
    return move_body_point(east_m, north_m, heading_rad, antenna_xy_m, rear_axle_xy_m)


def road_wheel_angle(radius_m: float, wheelbase_m: float) -> float:
    """Kinematic (single-track) road-wheel angle δ = atan(L / R) of the rear-axle-centre radius (rad, ≥ 0)."""
    if not wheelbase_m > 0.0:
        raise CalibrationError(f"wheelbase must be positive, got {wheelbase_m} m")
    if not radius_m > 0.0:
        raise CalibrationError(f"turn radius must be positive, got {radius_m} m")
    return math.atan2(wheelbase_m, radius_m)


# --------------------------------------------------------------------------------------------
# steering ratio from circles


@dataclass(frozen=True, slots=True)
class SteeringRatioRow:
    """One measured circle: steering-wheel angle, direction and the ratio it gives."""

    swa_rad: float
    direction: Direction
    radius_m: float
    """Radius of the rear-axle-centre circle."""
    delta_rad: float
    """Equivalent road-wheel angle, signed like the turn (left positive)."""
    ratio: float
    """SWA / δ."""
    n_points: int
    rms_residual_m: float
    arc_rad: float
    """|Angle swept| about the centre."""
    t_start_s: float
    duration_s: float
    delta_se_rad: float = math.nan
    """Standard error of δ from the circle fit's radius (:attr:`CircleFit.radius_se_m`)."""
    swa_zero_removed_rad: float = 0.0
    """SAS zero offset already removed from ``swa_rad`` (:func:`apply_sas_zero`)."""
    ratio_u95: float = math.nan
    """95 % uncertainty of the ratio, relative (0.01 = 1 %): δ from the fit, the SAS zero's uncertainty / SWA."""

    @property
    def swa_deg(self) -> float:
        """Steering-wheel angle (deg)."""
        return math.degrees(self.swa_rad)

    @property
    def delta_deg(self) -> float:
        """Road-wheel angle (deg)."""
        return math.degrees(self.delta_rad)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        return {
            "swa_deg": self.swa_deg,
            "direction": self.direction.value,
            "radius_m": self.radius_m,
            "delta_deg": self.delta_deg,
            "ratio": self.ratio,
            "n_points": self.n_points,
            "rms_residual_m": self.rms_residual_m,
            "arc_deg": math.degrees(self.arc_rad),
            "t_start_s": self.t_start_s,
            "duration_s": self.duration_s,
            "delta_se_deg": math.degrees(self.delta_se_rad),
            "swa_zero_removed_deg": math.degrees(self.swa_zero_removed_rad),
            "ratio_u95_percent": 100.0 * self.ratio_u95,
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> SteeringRatioRow:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(
                swa_rad=math.radians(_num(d["swa_deg"])),
                direction=Direction(d["direction"]),
                radius_m=_num(d["radius_m"]),
                delta_rad=math.radians(_num(d["delta_deg"])),
                ratio=_num(d["ratio"]),
                n_points=int(_num(d["n_points"])),
                rms_residual_m=_num(d["rms_residual_m"]),
                arc_rad=math.radians(_num(d["arc_deg"])),
                t_start_s=_num(d["t_start_s"]),
                duration_s=_num(d["duration_s"]),
                delta_se_rad=math.radians(_num(d.get("delta_se_deg", math.nan))),
                swa_zero_removed_rad=math.radians(_num(d.get("swa_zero_removed_deg", 0.0))),
                ratio_u95=_num(d.get("ratio_u95_percent", math.nan)) / 100.0,
            )
        except KeyError as exc:
            raise CalibrationError(f"steering ratio row: key {exc.args[0]!r} missing") from None
        except ValueError as exc:
            raise CalibrationError(f"steering ratio row: {exc}") from None


def _num(x: object) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float):
        raise ValueError(f"expected a number, got {x!r}")
    return float(x)


@dataclass(frozen=True, slots=True)
class SteeringRatioTable:
    """Steering ratio per steering-wheel angle and direction, sorted by direction then SWA."""

    wheelbase_m: float
    rows: tuple[SteeringRatioRow, ...]
    warnings: tuple[str, ...] = ()
    flagged: tuple[SteeringRatioRow, ...] = ()
    """Rows whose ratio is too uncertain to be a result (:func:`apply_sas_zero`); not in ``rows``."""
    sas_zero: SasZeroEstimate | None = None
    """The SAS zero offset removed from the rows, when one was."""

    def ratio_at(self, swa_rad: npt.ArrayLike, direction: Direction = Direction.FORWARD) -> FloatArray:
        """Ratio at any SWA by linear interpolation in SWA (held constant beyond the measured range).

        Rows at the same SWA are averaged.

        Raises:
            CalibrationError: no row for that direction.
        """
        rows = [r for r in self.rows if r.direction is direction]
        if not rows:
            raise CalibrationError(f"steering ratio table has no {direction.value} rows")
        swa = np.array([r.swa_rad for r in rows])
        ratio = np.array([r.ratio for r in rows])
        keys, inv = np.unique(np.round(swa, 9), return_inverse=True)
        mean_ratio = np.bincount(inv, weights=ratio) / np.bincount(inv)
        return np.asarray(np.interp(np.asarray(swa_rad, dtype=float), keys, mean_ratio), dtype=float)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        return {
            "wheelbase_m": self.wheelbase_m,
            "rows": [r.to_dict() for r in self.rows],
            "flagged": [r.to_dict() for r in self.flagged],
            "sas_zero": None if self.sas_zero is None else self.sas_zero.to_dict(),
            "warnings": list(self.warnings),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> SteeringRatioTable:
        """Inverse of :meth:`to_dict`.

        Raises:
            CalibrationError: a key is missing or has the wrong type (the message names it).
        """
        rows = d.get("rows")
        if not isinstance(rows, list):
            raise CalibrationError("steering ratio table: key 'rows' missing or not a list")
        warnings = d.get("warnings", [])
        if not isinstance(warnings, list):
            raise CalibrationError("steering ratio table: key 'warnings' is not a list")
        try:
            wheelbase = _num(d["wheelbase_m"])
        except (KeyError, ValueError):
            raise CalibrationError("steering ratio table: key 'wheelbase_m' missing or not a number") from None
        flagged = d.get("flagged", [])
        if not isinstance(flagged, list):
            raise CalibrationError("steering ratio table: key 'flagged' is not a list")
        return cls(
            wheelbase_m=wheelbase,
            rows=tuple(SteeringRatioRow.from_dict(r) for r in rows),
            warnings=tuple(str(w) for w in warnings),
            flagged=tuple(SteeringRatioRow.from_dict(r) for r in flagged),
        )


def steering_ratio_from_circles(
    segments: Sequence[SwaSegment],
    t_s: npt.ArrayLike,
    east_m: npt.ArrayLike,
    north_m: npt.ArrayLike,
    *,
    wheelbase_m: float,
    min_arc_rad: float = DEFAULT_MIN_ARC_RAD,
) -> SteeringRatioTable:
    """Steering-ratio table from constant-SWA circles driven at low speed.

    ``east_m``/``north_m`` is the track of the rear-axle centre on ``t_s`` (use
    :func:`antenna_to_rear_axle` first); each segment from
    :func:`calibration.segments.find_constant_swa_segments` is selected by time. The sign of δ
    comes from the sense of rotation and the direction of travel (forward and counter-clockwise,
    or reverse and clockwise, is a left turn). Circles sweeping less than ``min_arc_rad``
    (default 90°) are skipped with a warning: short arcs give poorly determined radii.

    Raises:
        CalibrationError: no segment yields a usable circle (the message says why each failed).
    """
    t, _ = check_time(t_s)
    e = np.asarray(east_m, dtype=float)
    n = np.asarray(north_m, dtype=float)
    if e.shape != t.shape or n.shape != t.shape:
        raise CalibrationError(f"east_m/north_m: shapes {e.shape}, {n.shape} differ from t_s shape {t.shape}")
    if not wheelbase_m > 0.0:
        raise CalibrationError(f"wheelbase must be positive, got {wheelbase_m} m")
    rows: list[SteeringRatioRow] = []
    warnings: list[str] = []
    for seg in segments:
        where = f"SWA {math.degrees(seg.swa_rad):+.0f}° {seg.direction.value} at t = {seg.t_start_s:.1f} s"
        m = seg.mask(t)
        try:
            fit = fit_circle(e[m], n[m])
        except CalibrationError as exc:
            warnings.append(f"{where} skipped: {exc}")
            continue
        arc = abs(fit.swept_rad)
        if arc < min_arc_rad:
            warnings.append(
                f"{where} skipped: only {math.degrees(arc):.0f}° of the circle driven "
                f"(need {math.degrees(min_arc_rad):.0f}°)"
            )
            continue
        rotation = math.copysign(1.0, fit.swept_rad)
        sign = rotation if seg.direction is Direction.FORWARD else -rotation
        delta = sign * road_wheel_angle(fit.radius_m, wheelbase_m)
        # dδ/dR = −L / (R² + L²)
        delta_se = wheelbase_m / (fit.radius_m**2 + wheelbase_m**2) * fit.radius_se_m
        if seg.swa_rad != 0.0 and math.copysign(1.0, seg.swa_rad) != sign:
            warnings.append(
                f"{where}: the car turned {'left' if sign > 0 else 'right'} with the steering wheel "
                f"{'left' if seg.swa_rad > 0 else 'right'}: steering-angle sign or direction of travel wrong?"
            )
        rows.append(
            SteeringRatioRow(
                swa_rad=seg.swa_rad,
                direction=seg.direction,
                radius_m=fit.radius_m,
                delta_rad=delta,
                ratio=seg.swa_rad / delta,
                n_points=fit.n_points,
                rms_residual_m=fit.rms_residual_m,
                arc_rad=arc,
                t_start_s=seg.t_start_s,
                duration_s=seg.duration_s,
                delta_se_rad=delta_se,
                ratio_u95=1.96 * abs(delta_se / delta) if delta != 0.0 else math.inf,
            )
        )
    if not rows:
        detail = "; ".join(warnings) if warnings else "no constant-SWA segments given"
        raise CalibrationError(f"no usable steering circle: {detail}")
    rows.sort(key=lambda r: (r.direction.value != Direction.FORWARD.value, r.swa_rad))
    return SteeringRatioTable(wheelbase_m=float(wheelbase_m), rows=tuple(rows), warnings=tuple(warnings))


# --------------------------------------------------------------------------------------------
# steering-angle sensor zero offset

DEFAULT_PAIR_TOLERANCE = 0.10
"""Left and right circles pair up when their |SWA| differ by less than this fraction."""
DEFAULT_MAX_RATIO_U95 = 0.01
"""Rows whose 95 % ratio uncertainty exceeds this (1 %) are flagged, not reported as results."""
_Z95 = 1.959963984540054


@dataclass(frozen=True, slots=True)
class SasZeroSource:
    """One estimate of the SAS zero offset."""

    method: str
    """"circle pairs" or "straight runs"."""
    offset_rad: float
    se_rad: float
    """Standard error."""
    n: int
    """Pairs of circles, or straight-run epochs."""

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (degrees)."""
        return {"method": self.method, "offset_deg": math.degrees(self.offset_rad),
                "u95_deg": math.degrees(_Z95 * self.se_rad), "n": self.n}


@dataclass(frozen=True, slots=True)
class SasZeroEstimate:
    """Zero offset c of the steering-angle sensor (SWA_measured = SWA_true + c) with its 95 % uncertainty."""

    offset_rad: float
    u95_rad: float
    sources: tuple[SasZeroSource, ...]
    warnings: tuple[str, ...] = ()

    @property
    def offset_deg(self) -> float:
        """Offset (deg)."""
        return math.degrees(self.offset_rad)

    @property
    def u95_deg(self) -> float:
        """95 % uncertainty (deg)."""
        return math.degrees(self.u95_rad)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (degrees)."""
        return {"offset_deg": self.offset_deg, "u95_deg": self.u95_deg,
                "sources": [x.to_dict() for x in self.sources], "warnings": list(self.warnings)}


def sas_zero_from_circle_pairs(
    rows: Sequence[SteeringRatioRow], *, tolerance: float = DEFAULT_PAIR_TOLERANCE
) -> SasZeroSource | None:
    """SAS zero from left/right circle pairs of the same direction of travel (rows with the raw SWA).

    An odd steering gear gives δ(−s) = −δ(s); with measured angles m_L > 0 > m_R, fitted δ_L and δ_R
    and the gear's local slope k = dδ/dSWA there: c = (m_L + m_R)/2 − (δ_L + δ_R)/(2k). k comes from
    the curve through the origin and the pairs' mid-points ((m_L − m_R)/2, (δ_L − δ_R)/2). Holding
    the measured or the true angles symmetric both work. Forward and reverse pairs see the tyre-slip
    bias of δ with opposite signs; all pairs are averaged with weights 1/σ², σ from the fits' δ
    uncertainties, and the standard error is the larger of the formal one and the pairs' scatter.
    None when no pair matches within ``tolerance`` (fraction of |SWA|).
    """
    est: list[tuple[float, float]] = []
    for direction in Direction:
        left = sorted((r for r in rows if r.direction is direction and r.swa_rad > 0.0), key=lambda r: r.swa_rad)
        right = [r for r in rows if r.direction is direction and r.swa_rad < 0.0]
        pairs: list[tuple[SteeringRatioRow, SteeringRatioRow]] = []
        for rl in left:
            if not right:
                break
            rr = min(right, key=lambda r: abs(abs(r.swa_rad) - rl.swa_rad))
            if abs(abs(rr.swa_rad) - rl.swa_rad) > tolerance * rl.swa_rad:
                continue
            right.remove(rr)
            if rl.delta_rad > 0.0 > rr.delta_rad:
                pairs.append((rl, rr))
        if not pairs:
            continue
        # the local slope dδ/dSWA at each pair's |SWA|: the gear curve through the origin and the pairs'
        # mid-points (second-order differences); one pair alone: its secant
        half_swa = np.array([0.0] + [0.5 * (rl.swa_rad - rr.swa_rad) for rl, rr in pairs])
        half_delta = np.array([0.0] + [0.5 * (rl.delta_rad - rr.delta_rad) for rl, rr in pairs])
        slopes = (np.gradient(half_delta, half_swa, edge_order=2)[1:] if len(pairs) > 1
                  else half_delta[1:] / half_swa[1:])
        for (rl, rr), k in zip(pairs, slopes, strict=True):
            if not k > 0.0:
                continue
            c = 0.5 * (rl.swa_rad + rr.swa_rad) - 0.5 * (rl.delta_rad + rr.delta_rad) / float(k)
            se_d = math.hypot(rl.delta_se_rad, rr.delta_se_rad)
            se = 0.5 * se_d / float(k) if math.isfinite(se_d) else math.inf
            est.append((c, se))
    if not est:
        return None
    return _weighted("circle pairs", est)


def _weighted(method: str, est: Sequence[tuple[float, float]]) -> SasZeroSource:
    c = np.array([e[0] for e in est])
    se = np.array([e[1] for e in est])
    finite = np.isfinite(se) & (se > 0.0)
    if not finite.any():
        return SasZeroSource(method, float(np.mean(c)), math.inf, len(est))
    w = np.where(finite, 1.0 / np.where(finite, se, 1.0) ** 2, 0.0)
    mean = float(np.sum(w * c) / np.sum(w))
    formal = math.sqrt(1.0 / float(np.sum(w)))
    n = int(np.count_nonzero(finite))
    if n > 1:
        scatter = math.sqrt(float(np.sum(w * (c - mean) ** 2)) / (float(np.sum(w)) * (n - 1)))
        formal = max(formal, scatter)
    return SasZeroSource(method, mean, formal, len(est))


def sas_zero_from_straights(
    t_s: npt.ArrayLike,
    swa_rad: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    masks: Sequence[npt.ArrayLike],
    *,
    min_samples: int = 40,
) -> SasZeroSource | None:
    """SAS zero from straight runs: SWA = c + G·κ regressed on the path curvature κ = r / v (intercept c).

    ``masks`` select the samples of each straight run (e.g. ``Segment`` index ranges). A common gain G
    absorbs the steering the driver's small corrections need, so weaving does not bias c. The standard
    error comes from the residuals, inflated for their autocorrelation per run. None with fewer than
    ``min_samples`` usable samples.
    """
    t, _ = check_time(t_s)
    swa = np.asarray(swa_rad, dtype=float)
    r = np.asarray(yaw_rate_rps, dtype=float)
    v = np.asarray(speed_mps, dtype=float)
    if swa.shape != t.shape or r.shape != t.shape or v.shape != t.shape:
        raise CalibrationError("sas_zero_from_straights: swa, yaw rate and speed must be sampled on t_s")
    sel: list[npt.NDArray[np.intp]] = []
    for m in masks:
        mm = np.asarray(m, dtype=bool)
        if mm.shape != t.shape:
            raise CalibrationError(f"sas_zero_from_straights: a mask has shape {mm.shape}, t_s has {t.shape}")
        idx = np.flatnonzero(mm & np.isfinite(swa) & np.isfinite(r) & np.isfinite(v) & (np.abs(v) > 1.0))
        if idx.size >= 3:
            sel.append(idx)
    n = sum(i.size for i in sel)
    if n < min_samples:
        return None
    idx_all = np.concatenate(sel)
    kappa = r[idx_all] / np.abs(v[idx_all])
    a = np.column_stack([np.ones(n), kappa])
    y = swa[idx_all]
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    pos = 0
    infl_num = 0.0
    for idx in sel:
        part = res[pos: pos + idx.size]
        infl_num += idx.size * _autocorrelation_inflation(part)
        pos += idx.size
    inflation = infl_num / n
    try:
        cov = np.linalg.inv(a.T @ a) * float(res @ res) / max(n - 2, 1) * inflation
    except np.linalg.LinAlgError:
        return None
    return SasZeroSource("straight runs", float(coef[0]), math.sqrt(max(float(cov[0, 0]), 0.0)), n)


def combine_sas_zero(sources: Sequence[SasZeroSource | None], *, resolution_rad: float = 0.0) -> SasZeroEstimate:
    """Inverse-variance mean of the available estimates; widened by the Birge ratio when they disagree.

    ``resolution_rad`` is the sensor's quantisation step: a steady angle does not dither between steps, so
    averaging cannot beat it, and the standard uncertainty is at least resolution / √12.

    Raises:
        CalibrationError: no estimate at all (no left/right circle pair, no straight run).
    """
    floor = max(resolution_rad / math.sqrt(12.0), 1e-9)
    got = [x if x.se_rad >= floor else dataclasses.replace(x, se_rad=floor)
           for x in sources if x is not None and math.isfinite(x.se_rad)]
    if not got:
        raise CalibrationError(
            "SAS zero offset: no estimate (needs left and right circles at the same |SWA| in one direction, or "
            "straight runs at speed)"
        )
    w = np.array([1.0 / x.se_rad**2 for x in got])
    c = np.array([x.offset_rad for x in got])
    mean = float(np.sum(w * c) / np.sum(w))
    se = math.sqrt(1.0 / float(np.sum(w)))
    warnings: list[str] = []
    if len(got) > 1:
        chi2 = float(np.sum(w * (c - mean) ** 2))
        birge = math.sqrt(chi2 / (len(got) - 1))
        if birge > 2.0:
            warnings.append(
                "SAS zero: the estimates disagree ("
                + ", ".join(f"{x.method} {math.degrees(x.offset_rad):+.3f}°" for x in got)
                + f"); uncertainty widened ×{birge:.1f}"
            )
        se *= max(1.0, birge)
    se = max(se, resolution_rad / math.sqrt(12.0))
    return SasZeroEstimate(mean, _Z95 * se, tuple(got), tuple(warnings))


def apply_sas_zero(
    table: SteeringRatioTable, zero: SasZeroEstimate, *, max_ratio_u95: float = DEFAULT_MAX_RATIO_U95
) -> SteeringRatioTable:
    """Remove the SAS zero from every row, recompute the ratios and their uncertainties, flag the uncertain ones.

    A row's relative 95 % uncertainty combines δ's (from the circle fit) and the zero's divided by the
    SWA. Rows above ``max_ratio_u95`` move to ``flagged`` with a warning naming them (short holds at
    small angles: the radius is poorly determined and the zero weighs most).
    """
    u_c = zero.u95_rad / _Z95
    rows: list[SteeringRatioRow] = []
    flagged: list[SteeringRatioRow] = []
    warnings = list(table.warnings) + list(zero.warnings)
    for r in table.rows:
        swa = r.swa_rad + r.swa_zero_removed_rad - zero.offset_rad
        rel = math.hypot(r.delta_se_rad / r.delta_rad if r.delta_rad else math.inf,
                         u_c / swa if swa else math.inf)
        u95 = _Z95 * rel if math.isfinite(rel) else math.inf
        new = dataclasses.replace(r, swa_rad=swa, ratio=swa / r.delta_rad, swa_zero_removed_rad=zero.offset_rad,
                                  ratio_u95=u95)
        if not u95 <= max_ratio_u95:
            flagged.append(new)
            warnings.append(
                f"SWA {math.degrees(swa):+.0f}° {r.direction.value} at t = {r.t_start_s:.1f} s: ratio "
                f"{new.ratio:.3f} ± {100 * u95:.1f} % (95 %), too uncertain for a {100 * max_ratio_u95:g} % row "
                f"({r.duration_s:.0f} s hold, {math.degrees(r.arc_rad):.0f}° of a {r.radius_m:.0f} m circle): "
                "flagged, not a result; hold it longer"
            )
        else:
            rows.append(new)
    return dataclasses.replace(table, rows=tuple(rows), flagged=tuple(flagged), warnings=tuple(warnings),
                               sas_zero=zero)


# --------------------------------------------------------------------------------------------
# manual (tape-measure) methods


class ManualMethod(enum.Enum):
    """Field methods for measuring the turn radius with a tape."""

    CHORDS = "three chords"
    DIAMETER = "half circle"


@dataclass(frozen=True, slots=True)
class ManualSteeringResult:
    """Steering ratio from a tape-measured track of the inner rear wheel."""

    method: ManualMethod
    swa_rad: float
    inner_radius_m: float
    """Radius of the inner rear wheel's track (as measured)."""
    radius_m: float
    """Radius of the rear-axle centre: inner radius + half the rear track width."""
    delta_rad: float
    """Equivalent road-wheel angle, signed like the SWA."""
    ratio: float
    radius_sigma_m: float
    """Standard uncertainty of the radius from the tape uncertainty (first-order propagation)."""
    ratio_sigma: float
    wheelbase_m: float
    track_rear_m: float
    measurements_m: tuple[float, ...]

    @property
    def delta_deg(self) -> float:
        """Road-wheel angle (deg)."""
        return math.degrees(self.delta_rad)

    def to_dict(self) -> dict[str, object]:
        """JSON-able view (units in the key names)."""
        return {
            "method": self.method.value,
            "swa_deg": math.degrees(self.swa_rad),
            "inner_radius_m": self.inner_radius_m,
            "radius_m": self.radius_m,
            "delta_deg": self.delta_deg,
            "ratio": self.ratio,
            "radius_sigma_m": self.radius_sigma_m,
            "ratio_sigma": self.ratio_sigma,
            "wheelbase_m": self.wheelbase_m,
            "track_rear_m": self.track_rear_m,
            "measurements_m": list(self.measurements_m),
        }


def circumradius(a_m: float, b_m: float, c_m: float) -> float:
    """Radius of the circle through three points from the distances between them: R = abc / 4S.

    The triangle area S comes from Heron's formula in Kahan's cancellation-free arrangement
    (sides sorted a ≥ b ≥ c), so nearly flat triangles keep their accuracy.

    Raises:
        CalibrationError: a chord is not positive, the chords violate the triangle inequality,
            or the points are collinear.
    """
    sides = (float(a_m), float(b_m), float(c_m))
    if not all(math.isfinite(s) and s > 0.0 for s in sides):
        raise CalibrationError(f"chords must be positive lengths, got {sides} m")
    a, b, c = sorted(sides, reverse=True)
    if a >= b + c:
        kind = "collinear (the longest chord equals the sum of the others)" if a == b + c else "not a triangle"
        raise CalibrationError(
            f"chords {sides[0]:g}, {sides[1]:g}, {sides[2]:g} m: the three points are {kind}; "
            "mark three points spread around the circle and measure again"
        )
    p = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    area = 0.25 * math.sqrt(max(p, 0.0))
    if area <= 1e-9 * a * a:
        raise CalibrationError(
            f"chords {sides[0]:g}, {sides[1]:g}, {sides[2]:g} m: the three points are collinear; "
            "mark three points spread around the circle and measure again"
        )
    return a * b * c / (4.0 * area)


def _ratio_from_inner_radius(
    method: ManualMethod,
    swa_rad: float,
    inner_radius_m: float,
    inner_radius_grad: Sequence[float],
    measurements: tuple[float, ...],
    wheelbase_m: float,
    track_rear_m: float,
    tape_sigma_m: float,
) -> ManualSteeringResult:
    if not wheelbase_m > 0.0:
        raise CalibrationError(f"wheelbase must be positive, got {wheelbase_m} m")
    if not track_rear_m >= 0.0:
        raise CalibrationError(f"rear track width must not be negative, got {track_rear_m} m")
    if swa_rad == 0.0 or not math.isfinite(swa_rad):
        raise CalibrationError(f"steering-wheel angle must be non-zero, got {math.degrees(swa_rad)}°")
    if not tape_sigma_m >= 0.0:
        raise CalibrationError(f"tape uncertainty must not be negative, got {tape_sigma_m} m")
    radius = inner_radius_m + 0.5 * track_rear_m
    delta = math.copysign(road_wheel_angle(radius, wheelbase_m), swa_rad)
    radius_sigma = tape_sigma_m * math.sqrt(sum(g * g for g in inner_radius_grad))
    # dδ/dR = −L / (R² + L²); ratio = SWA/δ, so d ratio = −SWA/δ² dδ.
    d_delta = wheelbase_m / (radius * radius + wheelbase_m * wheelbase_m) * radius_sigma
    ratio = swa_rad / delta
    return ManualSteeringResult(
        method=method,
        swa_rad=swa_rad,
        inner_radius_m=inner_radius_m,
        radius_m=radius,
        delta_rad=delta,
        ratio=ratio,
        radius_sigma_m=radius_sigma,
        ratio_sigma=abs(ratio / delta) * d_delta,
        wheelbase_m=wheelbase_m,
        track_rear_m=track_rear_m,
        measurements_m=measurements,
    )


def manual_ratio_from_chords(
    swa_rad: float,
    chords_m: tuple[float, float, float],
    *,
    wheelbase_m: float,
    track_rear_m: float,
    tape_sigma_m: float = DEFAULT_TAPE_SIGMA_M,
) -> ManualSteeringResult:
    """Three points marked on the inner rear wheel's track, the three distances between them taped.

    Raises:
        CalibrationError: degenerate triangle (collinear points) or invalid geometry.
    """
    if len(chords_m) != 3:
        raise CalibrationError(f"need exactly three chord lengths, got {len(chords_m)}")
    a, b, c = (float(x) for x in chords_m)
    r = circumradius(a, b, c)
    # Sensitivity of R to each chord, by central differences (the closed form is unwieldy).
    grad = []
    for i in range(3):
        h = 1e-6 * max(a, b, c)
        up = [a, b, c]
        dn = [a, b, c]
        up[i] += h
        dn[i] -= h
        try:
            grad.append((circumradius(*up) - circumradius(*dn)) / (2.0 * h))
        except CalibrationError:
            grad.append(math.inf)
    return _ratio_from_inner_radius(
        ManualMethod.CHORDS, swa_rad, r, grad, (a, b, c), wheelbase_m, track_rear_m, tape_sigma_m
    )


def manual_ratio_from_diameter(
    swa_rad: float,
    diameter_m: float,
    *,
    wheelbase_m: float,
    track_rear_m: float,
    tape_sigma_m: float = DEFAULT_TAPE_SIGMA_M,
) -> ManualSteeringResult:
    """Half a circle driven; the distance between its ends (the diameter of the inner rear wheel's track) taped.

    Raises:
        CalibrationError: non-positive diameter or invalid geometry.
    """
    d = float(diameter_m)
    if not (math.isfinite(d) and d > 0.0):
        raise CalibrationError(f"diameter must be a positive length, got {diameter_m} m")
    return _ratio_from_inner_radius(
        ManualMethod.DIAMETER, swa_rad, d / 2.0, (0.5,), (d,), wheelbase_m, track_rear_m, tape_sigma_m
    )
