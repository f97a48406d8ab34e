"""A recorded session turned into the arrays calibration and analysis need (the one place that does it).

``load_inputs(path) -> SessionInputs`` reads a session (:func:`rig.data.load_session`) and
returns a frozen :class:`SessionInputs`; everything is numpy, SI, ISO 8855, and on one common
time base: ``t_s`` is seconds since ``SessionInputs.t0_ns`` (UTC ns since the Unix epoch; the
first common GNSS epoch, else the first sample of any stream); every series also keeps its
absolute ``time_ns``.

API (stable; other commands import it)::

    from rig.data.inputs import load_inputs, SessionInputs
    inp = load_inputs(path, *, profile=None, imu_calibration=None, use_calibration_file=True,
                      can=True, optical=True, truth=True, gnss_min_latency_s=None,
                      bounded_memory=False, can_roles=None)

    inp.gnss                  DualGnss | None (None: see inp.missing["gnss"])
    inp.require_gnss()        DualGnss, or AnalysisError "session … has no receiver for antenna b …"
      .t_s .time_ns .gps_time_ns          common epochs of rovers A and B (BESTPOS GPS times in both)
      .a / .b: AntennaFixes   .receiver .lat_deg .lon_deg .height_m (ellipsoidal) .east_m .north_m .up_m
                              (ENU around the first fix of A, pymap3d) .sigma_east_m .sigma_north_m
                              .sigma_up_m .solution_status .position_type (str arrays) .solution_ok
                              .rtk_fixed .speed_mps .track_rad (clockwise from north) .vertical_speed_mps
                              .velocity_east_mps .velocity_north_mps .velocity_ok
      .baseline_azimuth_rad   azimuth of B → A, clockwise from north (raw: mounting offset NOT removed)
      .baseline_length_m      3-D antenna separation; .baseline_horizontal_m
      .rtk_fixed_both .valid (both solutions computed, A's velocity valid, all finite)
      .heading_rad(offset_rad)  vehicle x-axis azimuth = baseline azimuth − mounting offset
      .course_rad .speed_mps   course/speed over ground of antenna A
      .to_epochs()            rig.analysis.reference.GnssEpochs for reference_sideslip()
    inp.can: {role: Signal}   every CAN role of every bus (yaw_rate, lat_accel, long_accel, swa,
                              wheel_speed_fl…, vsc_beta_estimate, …); inp.signal(role) raises
                              AnalysisError naming the role and the roles present
      Signal .name .unit .source .time_ns .t_s .values .valid .valid_fraction .at(t_s, max_gap_s=0.25)
    inp.optical: {name: OpticalSeries}  .time_ns .t_s .vx_mps .vy_mps .slip_angle_rad .speed_mps .valid
                              .zero_applied_rad (removed when recorded) .zero_in_force_rad
                              .mount_xy_m .kind .wheel .corrected() → (vx, vy) with the zero in force
    inp.truth: TruthSeries | None (simulated sessions) .time_ns .t_s .truth (GroundTruth) — simulation!
    inp.simulation: dict | None  the recorded [simulation] table (true_mount_offset_deg, …)
    inp.profile: VehicleProfile  recorded vehicle/antennas/optical + the calibration in force
    inp.recorded_calibration: CalibrationConfig  what the file says was in force when recording
    inp.calibration_sources: tuple[str, ...]     where the calibration in force came from
    inp.events: tuple[EventRecord, ...]; inp.marks (operator marks only)
    inp.streams: {stream: StreamInfo}  per-stream samples, valid fraction, span, note
    inp.missing: {"gnss"|"can"|"optical"|"truth": reason}; inp.warnings: tuple[str, ...] (live: the
                              dataset's warnings added later, e.g. by inp.session.daq(...), show up)
    inp.session: the underlying rig.data.Session (raw access: DAQ, frames, …)

The baseline azimuth and length are resolved per epoch in the local east/north/up frame at
antenna B (``pymap3d.geodetic2enu``), not in the frame of the first fix: over a kilometre of
driving the meridian convergence would tilt a fixed frame by ~0.01°, half the calibration
tolerance. Velocity (BESTVEL) is interpolated onto the position epochs at its time of validity
(GPS time − ``latency_s``).

Calibration file: the ``rig calibrate-*`` commands record their results next to the session in
``<session>.calibration.json`` (:func:`calibration_file_path`, :func:`read_calibration_file`,
:func:`update_calibration_file`). With ``use_calibration_file`` (default) the values found there
override the recorded calibration in :attr:`SessionInputs.profile`.

IMU: ``imu_calibration`` (an :class:`rig.core.config.ImuCalibrationConfig`, or ``"in_force"`` for the
profile's ``[calibration.imu]``) corrects the CAN ``yaw_rate`` (gyro z), ``lat_accel`` (accel y) and
``long_accel`` (accel x) per axis: true = (measured − b_i) / M_ii (cross-axis terms need axes a
vehicle cluster does not report).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt
import pymap3d
from pydantic import ValidationError

import rig.core.topics as T  # noqa: N812 - the module is used as a namespace
from rig.core.config import CalibrationConfig, ImuCalibrationConfig, VehicleProfile
from rig.data import Session, load_session
from rig.data.sidefiles import apply_calibration_file, calibration_file_path, read_calibration_file
from rig.store.reader import session_base
from vsccore.angles import wrap_2pi
from vsccore.errors import AnalysisError, ConfigError, RigError
from vsccore.gpstime import GPS_EPOCH_UNIX_NS

if TYPE_CHECKING:
    from drivers.can.vector_decode import RoleSeries
    from rig.analysis.reference import GnssEpochs
    from sim_devices.vehicle.truth import GroundTruth

__all__ = [
    "AntennaFixes",
    "DualGnss",
    "EventRecord",
    "OpticalSeries",
    "SessionInputs",
    "Signal",
    "StreamInfo",
    "TruthSeries",
    "load_inputs",
]

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
StrArray = npt.NDArray[np.str_]

_NS = 1_000_000_000
GOOD_SOLUTION = "SOL_COMPUTED"
RTK_FIXED_TYPES = frozenset({"NARROW_INT", "L1_INT", "WIDE_INT", "INS_RTKFIXED"})
_VELOCITY_MAX_GAP_S = 0.3
"""BESTVEL further than this from a position epoch (both neighbours) leaves A's velocity invalid there."""


# ---------------------------------------------------------------------------------------------
# Result types
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Signal:
    """One scalar series (SI) on the common time base; ``valid`` False where the source flagged it or it is NaN."""

    name: str
    unit: str
    source: str
    """Where it came from: ``can:<bus>``, ``optical:<name>``, …"""
    time_ns: IntArray
    t_s: FloatArray
    values: FloatArray
    valid: BoolArray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def valid_fraction(self) -> float:
        return float(np.mean(self.valid)) if len(self) else 0.0

    def at(self, t_s: npt.ArrayLike, *, max_gap_s: float | None = 0.25) -> FloatArray:
        """The valid samples linearly interpolated at ``t_s``; NaN outside them and across gaps > ``max_gap_s``."""
        return _interp(np.asarray(t_s, dtype=float), self.t_s[self.valid], self.values[self.valid], max_gap_s)


@dataclass(frozen=True, slots=True)
class AntennaFixes:
    """One rover's BESTPOS/BESTVEL at the common epochs."""

    receiver: str
    antenna: str
    lat_deg: FloatArray
    lon_deg: FloatArray
    height_m: FloatArray
    """Ellipsoidal height (height above MSL + undulation)."""
    east_m: FloatArray
    north_m: FloatArray
    up_m: FloatArray
    sigma_east_m: FloatArray
    sigma_north_m: FloatArray
    sigma_up_m: FloatArray
    solution_status: StrArray
    position_type: StrArray
    solution_ok: BoolArray
    rtk_fixed: BoolArray
    speed_mps: FloatArray
    track_rad: FloatArray
    """Course over ground, azimuth clockwise from north."""
    vertical_speed_mps: FloatArray
    velocity_east_mps: FloatArray
    velocity_north_mps: FloatArray
    velocity_ok: BoolArray
    source: StrArray | None = None
    """Per epoch, where the position comes from (``rtk``, ``ppk``, ``none``: see
    :func:`rig.analysis.reference.choose_position_source`); None: no PPK side file, live only."""


@dataclass(frozen=True, slots=True)
class DualGnss:
    """Rovers A and B on their common GPS epochs, with the baseline B → A."""

    t_s: FloatArray
    time_ns: IntArray
    gps_time_ns: IntArray
    a: AntennaFixes
    b: AntennaFixes
    baseline_azimuth_rad: FloatArray
    """Azimuth of B → A, clockwise from north, in the local frame at B (mounting offset not removed)."""
    baseline_length_m: FloatArray
    baseline_horizontal_m: FloatArray
    rtk_fixed_both: BoolArray
    valid: BoolArray
    """Both solutions computed, A's velocity valid and every quantity finite."""
    origin_llh: tuple[float, float, float]
    """First fix of A (lat deg, lon deg, ellipsoidal height m): origin of the ENU positions."""

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t_s))) if len(self) > 1 else math.nan

    @property
    def course_rad(self) -> FloatArray:
        """Course over ground of antenna A (clockwise from north)."""
        return self.a.track_rad

    @property
    def speed_mps(self) -> FloatArray:
        """Horizontal speed of antenna A."""
        return self.a.speed_mps

    def heading_rad(self, mount_offset_rad: float = 0.0) -> FloatArray:
        """Vehicle x-axis azimuth: baseline azimuth − mounting offset (:func:`calibration.mount.apply_mount_offset`)."""
        from calibration.mount import apply_mount_offset

        return apply_mount_offset(self.baseline_azimuth_rad, mount_offset_rad)

    def to_epochs(self) -> GnssEpochs:
        """As :class:`rig.analysis.reference.GnssEpochs` (the input of ``reference_sideslip``)."""
        from rig.analysis.reference import GnssEpochs

        sig_a = np.sqrt(0.5 * (self.a.sigma_east_m**2 + self.a.sigma_north_m**2))
        sig_b = np.sqrt(0.5 * (self.b.sigma_east_m**2 + self.b.sigma_north_m**2))
        ok_a = self.a.solution_ok & self.a.velocity_ok
        return GnssEpochs(
            t=self.t_s,
            baseline_azimuth=self.baseline_azimuth_rad,
            baseline_length=self.baseline_length_m,
            velocity_east=np.where(ok_a, self.a.velocity_east_mps, np.nan),
            velocity_north=np.where(ok_a, self.a.velocity_north_mps, np.nan),
            fixed_a=self.a.rtk_fixed & self.a.solution_ok,
            fixed_b=self.b.rtk_fixed & self.b.solution_ok,
            position_sigma_a=sig_a,
            position_sigma_b=sig_b,
            source=self.source,
        )

    @property
    def source(self) -> StrArray | None:
        """Per-epoch position source of the pair (``rtk``, ``ppk``, ``rtk/ppk`` …); None without PPK."""
        if self.a.source is None or self.b.source is None:
            return None
        from rig.analysis.reference import epoch_source

        return epoch_source(self.a.source, self.b.source)


@dataclass(frozen=True, slots=True)
class OpticalSeries:
    """An optical slip sensor's outputs (SI, sensor axes) as recorded, with the zero offsets involved."""

    name: str
    kind: str
    """``body`` or ``wheel``."""
    wheel: str | None
    mount_xy_m: tuple[float, float]
    time_ns: IntArray
    t_s: FloatArray
    vx_mps: FloatArray
    vy_mps: FloatArray
    slip_angle_rad: FloatArray
    speed_mps: FloatArray
    valid: BoolArray
    zero_applied_rad: float
    """Zero offset already removed from the recorded values (the calibration in force while recording)."""
    zero_in_force_rad: float
    """The zero offset in force now (recorded calibration, or the session's calibration file)."""
    source: str
    """``topic`` (``/optical/<name>``) or ``daq`` (recomputed from the DAQ channels)."""

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def corrected(self, zero_rad: float | None = None) -> tuple[FloatArray, FloatArray]:
        """(vx, vy) with the zero ``zero_rad`` (default: the one in force) removed instead of the recorded one."""
        from calibration.mount import apply_optical_zero

        z = self.zero_in_force_rad if zero_rad is None else zero_rad
        return apply_optical_zero(self.vx_mps, self.vy_mps, z - self.zero_applied_rad)


@dataclass(frozen=True, slots=True)
class TruthSeries:
    """The simulator's ground truth (simulation, not a measurement)."""

    time_ns: IntArray
    t_s: FloatArray
    truth: GroundTruth
    simulated: bool = True


@dataclass(frozen=True, slots=True)
class EventRecord:
    """One ``/rig/events`` entry on the common time base (end: a mark with a duration, else None)."""

    time_ns: int
    t_s: float
    kind: T.EventKind
    source: str
    text: str
    end_t_s: float | None
    details: Mapping[str, Any]


@dataclass(frozen=True, slots=True)
class StreamInfo:
    """Per-stream summary: how many samples, what fraction is valid, over which span."""

    name: str
    samples: int
    valid_fraction: float
    t_start_s: float
    t_end_s: float
    note: str = ""

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "samples": self.samples, "valid_fraction": self.valid_fraction,
                "t_start_s": self.t_start_s, "t_end_s": self.t_end_s, "note": self.note}


@dataclass(frozen=True, slots=True)
class SessionInputs:
    """Everything calibration and analysis read from one session (see the module docstring)."""

    path: Path
    name: str
    t0_ns: int
    gnss: DualGnss | None
    can: Mapping[str, Signal]
    optical: Mapping[str, OpticalSeries]
    truth: TruthSeries | None
    simulation: Mapping[str, Any] | None
    profile: VehicleProfile
    recorded_calibration: CalibrationConfig
    calibration_sources: tuple[str, ...]
    events: tuple[EventRecord, ...]
    streams: Mapping[str, StreamInfo]
    missing: Mapping[str, str]
    load_warnings: tuple[str, ...]
    """Warnings of :func:`load_inputs` itself (profile, GNSS pairing, CAN, optical)."""
    imu_corrected: bool
    session: Session = field(repr=False, compare=False)

    @property
    def warnings(self) -> tuple[str, ...]:
        """Every warning so far, a live view: the dataset's (:attr:`Session.warnings`, which grows as
        its accessors run — a DAQ segment falling back to the host clock, a log latency that could not
        be measured — also after loading), then the loader's own; duplicates removed."""
        return tuple(dict.fromkeys((*self.session.warnings, *self.load_warnings)))

    @property
    def is_simulated(self) -> bool:
        return self.truth is not None or self.simulation is not None

    @property
    def marks(self) -> tuple[EventRecord, ...]:
        """Operator marks (``/rig/events`` of kind ``mark``)."""
        return tuple(e for e in self.events if e.kind is T.EventKind.MARK)

    def require_gnss(self) -> DualGnss:
        """The dual-antenna GNSS data, or AnalysisError saying why there is none."""
        if self.gnss is None:
            raise AnalysisError(self.missing.get("gnss", f"session {self.path}: no dual-antenna GNSS data"))
        return self.gnss

    def require_truth(self) -> TruthSeries:
        if self.truth is None:
            raise AnalysisError(self.missing.get("truth", f"session {self.path}: no simulator truth"))
        return self.truth

    def signal(self, role: str) -> Signal:
        """The CAN role ``role``, or AnalysisError naming it and the roles present."""
        try:
            return self.can[role]
        except KeyError:
            why = self.missing.get("can")
            present = sorted(self.can) or "none"
            extra = f" ({why})" if why else ""
            raise AnalysisError(
                f"session {self.path}: no CAN role {role!r}{extra}; roles: {present}"
            ) from None

    def optical_sensor(self, name: str | None = None) -> OpticalSeries:
        """An optical sensor's series (``name`` may be omitted when there is exactly one)."""
        if name is None:
            if len(self.optical) != 1:
                why = self.missing.get("optical", "")
                raise AnalysisError(
                    f"session {self.path}: name the optical sensor (sensors: {sorted(self.optical) or 'none'})"
                    + (f"; {why}" if why else "")
                )
            return next(iter(self.optical.values()))
        try:
            return self.optical[name]
        except KeyError:
            raise AnalysisError(
                f"session {self.path}: no optical sensor {name!r} (sensors: {sorted(self.optical) or 'none'})"
            ) from None

    def t_of(self, time_ns: npt.ArrayLike) -> FloatArray:
        """Absolute times (UTC ns) → ``t_s`` on this session's base."""
        return _rel(np.asarray(time_ns, dtype=np.int64), self.t0_ns)

    def summary(self) -> dict[str, object]:
        """JSON-able overview of what was found (streams, missing parts, warnings)."""
        return {
            "session": str(self.path),
            "t0_ns": self.t0_ns,
            "simulated": self.is_simulated,
            "streams": {k: v.to_dict() for k, v in self.streams.items()},
            "missing": dict(self.missing),
            "warnings": list(self.warnings),
            "calibration_sources": list(self.calibration_sources),
        }


# ---------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------


def _rel(time_ns: IntArray, t0_ns: int) -> FloatArray:
    return np.asarray((time_ns - np.int64(t0_ns)).astype(np.float64) / 1e9, dtype=np.float64)


def _interp(t: FloatArray, src_t: FloatArray, v: FloatArray, max_gap_s: float | None) -> FloatArray:
    if src_t.size == 0:
        return np.full(t.shape, np.nan)
    if src_t.size == 1:
        return np.where(np.abs(t - src_t[0]) <= (max_gap_s or 0.0), v[0], np.nan)
    out = np.interp(t, src_t, v, left=np.nan, right=np.nan)
    if max_gap_s is not None:
        j = np.clip(np.searchsorted(src_t, t), 1, src_t.size - 1)
        exact = src_t[j - 1] == t
        gap = src_t[j] - src_t[j - 1]
        out[(gap > max_gap_s) & ~exact] = np.nan
    return np.asarray(out, dtype=np.float64)


def _col(tbl: Any, name: str, n: int) -> FloatArray:
    if len(tbl) and name in tbl:
        return np.asarray(tbl[name], dtype=np.float64)
    return np.full(n, np.nan)


def _str_col(tbl: Any, name: str, n: int) -> StrArray:
    if len(tbl) and name in tbl:
        return np.asarray(tbl[name]).astype(str)
    return np.full(n, "", dtype=str)


def _antenna_receivers(session: Session) -> tuple[dict[str, str], str]:
    """Antenna → receiver name, from the recorded ``receivers`` table (else by the names rover_a/rover_b)."""
    found = session.receivers()
    out: dict[str, str] = {}
    how = "configuration"
    recs = session.config.get("receivers")
    if isinstance(recs, list):
        for r in recs:
            if isinstance(r, Mapping) and r.get("role") == "rover" and r.get("antenna") in ("a", "b"):
                out[str(r["antenna"])] = str(r["name"])
    if not out:
        how = "receiver names"
        for rx in found:
            low = rx.lower()
            for ant in ("a", "b"):
                if low.endswith((f"_{ant}", f"-{ant}")) or low == ant:
                    out.setdefault(ant, rx)
    return out, how


def _receiver_fixes(session: Session, receiver: str) -> dict[str, Any]:
    g = session.gnss(receiver)
    pos = g.bestpos
    n = len(pos)
    if n == 0 or "gps_time_ns" not in pos or pos["gps_time_ns"].dtype.kind != "i":
        raise AnalysisError(f"session {session.path}: receiver {receiver!r} recorded no BESTPOS with GPS times")
    return {"g": g, "gps": np.asarray(pos["gps_time_ns"], dtype=np.int64)}


def _fixes_at(
    receiver: str, antenna: str, g: Any, rows: npt.NDArray[np.intp], gps: IntArray, origin: tuple[float, float, float]
) -> AntennaFixes:
    pos = g.bestpos
    n_all = len(pos)
    lat = _col(pos, "lat_deg", n_all)[rows]
    lon = _col(pos, "lon_deg", n_all)[rows]
    und = _col(pos, "undulation_m", n_all)[rows]
    h = _col(pos, "height_msl_m", n_all)[rows] + np.where(np.isfinite(und), und, 0.0)
    e, nn, u = (np.asarray(x, dtype=np.float64)
                for x in pymap3d.geodetic2enu(lat, lon, h, origin[0], origin[1], origin[2]))
    status = _str_col(pos, "sol_status", n_all)[rows]
    ptype = _str_col(pos, "pos_type", n_all)[rows]
    sol_ok = status == GOOD_SOLUTION
    fixed = sol_ok & np.isin(ptype, list(RTK_FIXED_TYPES))
    # velocity at its time of validity (GPS time − latency), interpolated onto the position epochs
    vel = g.bestvel
    m = len(vel)
    if m and "gps_time_ns" in vel and vel["gps_time_ns"].dtype.kind == "i":
        lat_s = np.nan_to_num(_col(vel, "latency_s", m), nan=0.0)
        tv = (np.asarray(vel["gps_time_ns"], dtype=np.int64) - np.round(lat_s * 1e9).astype(np.int64))
        base = int(gps[0]) if gps.size else 0
        tv_s = (tv - base).astype(np.float64) / 1e9
        order = np.argsort(tv_s, kind="stable")
        tv_s = tv_s[order]
        spd = _col(vel, "hor_speed_mps", m)[order]
        trk = np.radians(_col(vel, "track_over_ground_deg", m))[order]
        vup = _col(vel, "vert_speed_mps", m)[order]
        ok = (_str_col(vel, "sol_status", m)[order] == GOOD_SOLUTION) & np.isfinite(spd) & np.isfinite(trk)
        ve, vn = spd * np.sin(trk), spd * np.cos(trk)
        te = (gps - base).astype(np.float64) / 1e9
        vel_e = _interp(te, tv_s[ok], ve[ok], _VELOCITY_MAX_GAP_S)
        vel_n = _interp(te, tv_s[ok], vn[ok], _VELOCITY_MAX_GAP_S)
        vel_u = _interp(te, tv_s[ok], vup[ok], _VELOCITY_MAX_GAP_S)
    else:
        vel_e = vel_n = vel_u = np.full(gps.shape, np.nan)
    vel_ok = np.isfinite(vel_e) & np.isfinite(vel_n)
    speed = np.hypot(vel_e, vel_n)
    track = np.asarray(wrap_2pi(np.arctan2(vel_e, vel_n)), dtype=np.float64)
    return AntennaFixes(
        receiver=receiver, antenna=antenna, lat_deg=lat, lon_deg=lon, height_m=h, east_m=e, north_m=nn, up_m=u,
        sigma_east_m=_col(pos, "lon_std_m", n_all)[rows], sigma_north_m=_col(pos, "lat_std_m", n_all)[rows],
        sigma_up_m=_col(pos, "height_std_m", n_all)[rows], solution_status=status, position_type=ptype,
        solution_ok=sol_ok, rtk_fixed=fixed, speed_mps=speed, track_rad=track, vertical_speed_mps=vel_u,
        velocity_east_mps=vel_e, velocity_north_mps=vel_n, velocity_ok=vel_ok,
    )


def _with_ppk(
    session: Session, fixes: tuple[AntennaFixes, AntennaFixes], gps: IntArray, origin: tuple[float, float, float],
    warnings: list[str],
) -> tuple[AntennaFixes, AntennaFixes]:
    """Both antennas with, per epoch, the better of live RTK and PPK (``<session>.ppk.parquet`` from ``rig ppk``)."""
    from rig.analysis.reference import PositionSource, choose_position_source
    from rig.data.sidefiles import ppk_file_path, read_ppk_file

    path = ppk_file_path(session.path)
    solutions = read_ppk_file(path)
    if not solutions:
        return fixes
    out = []
    for f in fixes:
        sol = solutions.get(f.receiver)
        ppk_fixed = np.zeros(gps.shape, dtype=bool)
        rows = np.zeros(gps.shape, dtype=np.intp)
        if sol is None:
            warnings.append(f"{path}: no PPK solution of {f.receiver} (antenna {f.antenna}); live RTK only")
        elif sol.gps_time_ns.size:
            rows = np.clip(np.searchsorted(sol.gps_time_ns, gps), 0, sol.gps_time_ns.size - 1)
            ppk_fixed = (sol.gps_time_ns[rows] == gps) & sol.fixed[rows]
        source = choose_position_source(f.rtk_fixed, ppk_fixed)
        use = source == PositionSource.PPK.value
        if sol is None or not np.any(use):
            out.append(replace(f, source=source))
            continue
        r = rows[use]
        lat, lon, h = f.lat_deg.copy(), f.lon_deg.copy(), f.height_m.copy()
        lat[use], lon[use], h[use] = sol.lat_deg[r], sol.lon_deg[r], sol.height_m[r]
        e, nn, u = (np.asarray(x, dtype=np.float64)
                    for x in pymap3d.geodetic2enu(lat, lon, h, origin[0], origin[1], origin[2]))
        sig_e, sig_n, sig_u = f.sigma_east_m.copy(), f.sigma_north_m.copy(), f.sigma_up_m.copy()
        sig_e[use], sig_n[use], sig_u[use] = sol.sde_m[r], sol.sdn_m[r], sol.sdu_m[r]
        ptype = f.position_type.astype(object)
        ptype[use] = "PPK_FIXED"
        out.append(replace(
            f, lat_deg=lat, lon_deg=lon, height_m=h, east_m=e, north_m=nn, up_m=u, sigma_east_m=sig_e,
            sigma_north_m=sig_n, sigma_up_m=sig_u, position_type=ptype.astype(np.str_),
            solution_ok=f.solution_ok | use, rtk_fixed=f.rtk_fixed | use, source=source,
        ))
    return out[0], out[1]


def _dual_gnss(session: Session) -> tuple[DualGnss | None, str | None, list[str]]:
    """(data, reason it is missing, warnings)."""
    warnings: list[str] = []
    ants, how = _antenna_receivers(session)
    present = session.receivers()
    for ant in ("a", "b"):
        rx = ants.get(ant)
        if rx is None:
            return None, (f"session {session.path} has no receiver for antenna {ant} "
                          f"(receivers with data: {present or 'none'}; antennas from the {how})"), warnings
        if rx not in present:
            return None, (f"session {session.path}: receiver {rx!r} (antenna {ant}) recorded no GNSS data "
                          f"(receivers with data: {present or 'none'})"), warnings
    try:
        fa = _receiver_fixes(session, ants["a"])
        fb = _receiver_fixes(session, ants["b"])
    except AnalysisError as exc:
        return None, str(exc), warnings
    ga, gb = fa["gps"], fb["gps"]
    common, ia, ib = np.intersect1d(ga, gb, assume_unique=False, return_indices=True)
    if common.size == 0:
        return None, (f"session {session.path}: receivers {ants['a']!r} and {ants['b']!r} have no common "
                      f"GPS epoch ({ga.size} and {gb.size} BESTPOS)"), warnings
    if session.leap_seconds is None:
        warnings.append(f"session {session.path}: no TIME log with leap seconds; GNSS times taken as GPS-as-UTC")
        time_ns = common.astype(np.int64) + np.int64(GPS_EPOCH_UNIX_NS)
    else:
        time_ns = session.gps_to_utc(common)
    drop_a = ga.size - common.size
    drop_b = gb.size - common.size
    if drop_a or drop_b:
        warnings.append(f"GNSS: {drop_a} epochs of {ants['a']} and {drop_b} of {ants['b']} have no partner epoch")
    pos_a = fa["g"].bestpos
    lat0 = float(np.asarray(pos_a["lat_deg"], dtype=float)[ia[0]])
    lon0 = float(np.asarray(pos_a["lon_deg"], dtype=float)[ia[0]])
    und0 = _col(pos_a, "undulation_m", len(pos_a))[ia[0]]
    h0 = float(np.asarray(pos_a["height_msl_m"], dtype=float)[ia[0]]) + (float(und0) if np.isfinite(und0) else 0.0)
    origin = (lat0, lon0, h0)
    a = _fixes_at(ants["a"], "a", fa["g"], ia, common, origin)
    b = _fixes_at(ants["b"], "b", fb["g"], ib, common, origin)
    a, b = _with_ppk(session, (a, b), common, origin, warnings)
    # baseline in the local frame at B, per epoch
    de, dn, du = (np.asarray(x, dtype=np.float64)
                  for x in pymap3d.geodetic2enu(a.lat_deg, a.lon_deg, a.height_m, b.lat_deg, b.lon_deg, b.height_m))
    az = np.asarray(wrap_2pi(np.arctan2(de, dn)), dtype=np.float64)
    hor = np.hypot(de, dn)
    length = np.sqrt(hor * hor + du * du)
    finite = np.isfinite(az) & np.isfinite(length) & np.isfinite(a.speed_mps) & np.isfinite(a.track_rad)
    valid = a.solution_ok & b.solution_ok & a.velocity_ok & finite
    t0 = int(time_ns[0])
    return DualGnss(
        t_s=_rel(time_ns, t0), time_ns=time_ns, gps_time_ns=common.astype(np.int64), a=a, b=b,
        baseline_azimuth_rad=az, baseline_length_m=length, baseline_horizontal_m=hor,
        rtk_fixed_both=a.rtk_fixed & b.rtk_fixed, valid=valid, origin_llh=origin,
    ), None, warnings


def _imu_correct(roles: dict[str, Any], imu: ImuCalibrationConfig) -> dict[str, tuple[FloatArray, str]]:
    """Per-axis corrections: name → (corrected values, axis)."""
    acc_m = np.asarray(imu.accel_matrix, dtype=float)
    acc_b = np.asarray(imu.accel_bias_mps2, dtype=float)
    gyr_m = np.asarray(imu.gyro_matrix, dtype=float)
    gyr_b = np.asarray(imu.gyro_bias_rps, dtype=float)
    table = {"yaw_rate": (gyr_m, gyr_b, 2, "gyro z"), "lat_accel": (acc_m, acc_b, 1, "accel y"),
             "long_accel": (acc_m, acc_b, 0, "accel x")}
    out: dict[str, tuple[FloatArray, str]] = {}
    for role, (mat, bias, i, axis) in table.items():
        if role in roles:
            out[role] = ((np.asarray(roles[role], dtype=float) - bias[i]) / mat[i, i], axis)
    return out


def _profile_from_metadata(session: Session, warnings: list[str]) -> VehicleProfile:
    veh = session.vehicle
    cal = session.calibration
    data: dict[str, Any] = {}
    if isinstance(veh.get("vehicle"), Mapping) or isinstance(veh.get("antennas"), Mapping):
        for key in ("vehicle", "antennas", "optical"):
            if veh.get(key) is not None:
                data[key] = veh[key]
    else:
        cfg = session.config
        for key in ("vehicle", "antennas", "optical"):
            if isinstance(cfg.get(key), Mapping | list):
                data[key] = cfg[key]
        if not data and veh:
            warnings.append(f"session {session.path}: vehicle metadata {sorted(veh)} is not a vehicle profile; "
                            "using the default vehicle")
    if cal:
        data["calibration"] = cal
    try:
        return VehicleProfile.model_validate(data)
    except ValidationError as exc:
        # keep what validates: the parts one by one
        warnings.append(f"session {session.path}: recorded vehicle profile does not validate "
                        f"({exc.error_count()} problems); using defaults for the failing parts")
        good: dict[str, Any] = {}
        for key, value in data.items():
            try:
                VehicleProfile.model_validate({key: value})
                good[key] = value
            except ValidationError:
                warnings.append(f"session {session.path}: recorded [{key}] is invalid; default used")
        return VehicleProfile.model_validate(good)


# ---------------------------------------------------------------------------------------------
# Calibration file next to the session
# ---------------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------


def _stream(name: str, t_s: FloatArray, valid: BoolArray, note: str = "") -> StreamInfo:
    n = int(t_s.shape[0])
    return StreamInfo(name, n, float(np.mean(valid)) if n else 0.0,
                      float(t_s[0]) if n else math.nan, float(t_s[-1]) if n else math.nan, note)


def load_inputs(
    path: Path | str,
    *,
    profile: VehicleProfile | None = None,
    imu_calibration: ImuCalibrationConfig | Literal["in_force"] | None = None,
    use_calibration_file: bool = True,
    can: bool = True,
    optical: bool = True,
    truth: bool = True,
    optical_from_daq: bool = False,
    gnss_min_latency_s: float | None = None,
    bounded_memory: bool = False,
    can_roles: Collection[str] | None = None,
) -> SessionInputs:
    """Read a session into :class:`SessionInputs` (see the module docstring).

    ``profile`` replaces the recorded vehicle profile (its calibration included); ``can``,
    ``optical`` and ``truth`` skip those streams when False (faster). ``optical_from_daq``
    recomputes the optical sensors from the DAQ channels (sync-pulse timing when the DAQ has a
    sync channel) instead of the decimated ``/optical/<name>`` topic.

    ``bounded_memory`` (long sessions; ``rig export``'s sideslip struct): the same series with a peak
    memory that no longer grows with the whole bus's CAN traffic. Only the topics the series asked for
    need are read into :attr:`SessionInputs.session` (:func:`_bounded_topics`: the decoded GNSS logs, the
    events, and the optical/DAQ topics and the truth only when ``optical``/``truth``), and each CAN bus is
    read a batch of blocks at a time (:func:`_streamed_can_roles`), keeping only the frames of the messages
    its role map decodes: the roles, times and validity equal the default path's. ``inp.session`` then
    lacks the topics left out (its CAN frames, DAQ blocks, LocationFix, …: reading them there gives nothing).
    ``can_roles``: only these CAN roles are kept (None: every role of every bus); with ``bounded_memory`` only
    the messages that carry them are decoded.

    Raises:
        SessionFileError: the session cannot be found or read, or its calibration file is unreadable.
        ConfigError: a bad ``imu_calibration`` or calibration file content.
    """
    session = load_session(path, gnss_min_latency_s=gnss_min_latency_s,
                           include=_bounded_topics(optical=optical, truth=truth) if bounded_memory else None)
    warnings: list[str] = []  # the loader's own; the dataset's are read live (SessionInputs.warnings)
    missing: dict[str, str] = {}
    streams: dict[str, StreamInfo] = {}
    spath = Path(path)
    parts = session.parts
    name = session_base(parts[0]).name if parts else spath.name

    # --- profile and calibration in force
    recorded_profile = _profile_from_metadata(session, warnings)
    prof = profile if profile is not None else recorded_profile
    recorded_cal = recorded_profile.calibration
    sources = ["profile given" if profile is not None else "recorded metadata"]
    cal = prof.calibration
    if use_calibration_file:
        doc = read_calibration_file(parts[0] if parts else spath)
        if doc:
            cal, applied = apply_calibration_file(cal, doc)
            if applied:
                sources.append(f"{calibration_file_path(parts[0])} ({', '.join(applied)})")
    prof = prof.model_copy(update={"calibration": cal})

    # --- GNSS
    gnss, why, w = _dual_gnss(session)
    warnings += w
    if why is not None:
        missing["gnss"] = why
    streamed: dict[str, _StreamedCan] = {}
    if bounded_memory:  # each bus read once, before t0 (which, without GNSS, is the first CAN frame's time)
        for bus in session.can_buses():
            if can or gnss is None:
                streamed[bus] = _streamed_can_roles(session, bus, decode=can, first_time=gnss is None,
                                                    only=can_roles)
    if gnss is not None:
        t0 = int(gnss.time_ns[0])
    else:
        t0 = _first_time(session, streamed, truth_read=truth) if bounded_memory else _first_time(session)

    def rel(x: IntArray) -> FloatArray:
        return _rel(x, t0)

    if gnss is not None:
        streams["gnss.a"] = _stream(f"gnss:{gnss.a.receiver}", gnss.t_s, gnss.a.solution_ok,
                                    f"RTK fixed {np.mean(gnss.a.rtk_fixed):.0%}")
        streams["gnss.b"] = _stream(f"gnss:{gnss.b.receiver}", gnss.t_s, gnss.b.solution_ok,
                                    f"RTK fixed {np.mean(gnss.b.rtk_fixed):.0%}")
        streams["gnss.baseline"] = _stream("baseline", gnss.t_s, gnss.valid & gnss.rtk_fixed_both,
                                           "valid: both RTK fixed, velocity of A present")

    # --- CAN roles
    signals: dict[str, Signal] = {}
    imu_done = False
    if can:
        buses = session.can_buses()
        if not buses:
            missing["can"] = f"session {session.path} recorded no CAN bus"
        for bus in buses:
            try:
                if bounded_memory:
                    sc = streamed[bus]
                    if sc.error is not None:
                        raise sc.error
                    roles = sc.roles
                else:
                    roles = session.can_roles(bus)
                    if can_roles is not None:
                        roles = {r: rs for r, rs in roles.items() if r in can_roles}
            except RigError as exc:
                missing["can"] = f"bus {bus!r}: {exc}"
                warnings.append(missing["can"])
                continue
            for role, rs in roles.items():
                if role in signals:
                    warnings.append(f"CAN role {role!r} on bus {bus!r} ignored: already read from "
                                    f"{signals[role].source}")
                    continue
                tns = np.asarray(rs.timestamps_ns, dtype=np.int64)
                order = np.argsort(tns, kind="stable")
                vals = np.asarray(rs.values, dtype=np.float64)[order]
                ok = np.asarray(rs.ok, dtype=bool)[order] & np.isfinite(vals)
                tns = tns[order]
                signals[role] = Signal(role, rs.unit, f"can:{bus}", tns, rel(tns), vals, ok)
                streams[f"can.{role}"] = _stream(f"can:{bus}:{role}", signals[role].t_s, ok)
            time_source = streamed[bus].time_source if bounded_memory else session.can_frames(bus).time_source
            if time_source == "host_unmapped":
                warnings.append(f"CAN bus {bus!r}: frame times are host times (no GNSS clock to map them)")
        imu_cfg: ImuCalibrationConfig | None
        if imu_calibration == "in_force":
            imu_cfg = prof.calibration.imu
            if imu_cfg is None:
                raise ConfigError("imu_calibration='in_force' but the calibration in force has no [calibration.imu]")
        else:
            imu_cfg = imu_calibration
        if imu_cfg is not None:
            corr = _imu_correct({k: v.values for k, v in signals.items()}, imu_cfg)
            for role, (vals, axis) in corr.items():
                s = signals[role]
                signals[role] = Signal(role, s.unit, f"{s.source} (IMU-corrected, {axis})", s.time_ns, s.t_s,
                                       vals, s.valid & np.isfinite(vals))
            imu_done = bool(corr)
            if not corr:
                warnings.append("imu_calibration given but the session has none of yaw_rate, lat_accel, long_accel")

    # --- optical sensors
    optical_out: dict[str, OpticalSeries] = {}
    if optical:
        _load_optical(session, prof, recorded_cal, optical_from_daq, rel, optical_out, streams, missing, warnings)

    # --- truth
    truth_out: TruthSeries | None = None
    if truth:
        if session.topic_counts.get(T.TOPIC_SIM_TRUTH, 0):
            tr = session.truth()
            truth_out = TruthSeries(tr.time_ns, rel(tr.time_ns), tr.truth)
            streams["truth"] = _stream("truth (simulation)", truth_out.t_s, np.ones(truth_out.t_s.size, bool),
                                       "simulator ground truth")
        else:
            missing["truth"] = f"session {session.path}: no {T.TOPIC_SIM_TRUTH} (not a simulated session)"
    sim = session.config.get("simulation")
    simulation = dict(sim) if isinstance(sim, Mapping) else None

    # --- events
    events: list[EventRecord] = []
    for ev_ns, ev in session.events:
        end = (ev.end_ns - t0) / 1e9 if isinstance(ev.end_ns, int) else None
        start = ev.start_ns if isinstance(ev.start_ns, int) else ev_ns
        events.append(EventRecord(int(start), (int(start) - t0) / 1e9, ev.kind, ev.source, ev.text, end,
                                  dict(ev.details)))
    events.sort(key=lambda e: e.time_ns)

    return SessionInputs(
        path=spath, name=name, t0_ns=t0, gnss=gnss, can=signals, optical=optical_out, truth=truth_out,
        simulation=simulation, profile=prof, recorded_calibration=recorded_cal, calibration_sources=tuple(sources),
        events=tuple(events), streams=streams, missing=missing, load_warnings=tuple(dict.fromkeys(warnings)),
        imu_corrected=imu_done, session=session,
    )


_GNSS_LOGS = frozenset(f("r").rsplit("/", 1)[1] for f in (T.gnss_bestpos, T.gnss_bestvel, T.gnss_heading,
                                                           T.gnss_markpos, T.gnss_marktime, T.gnss_time))
"""The decoded GNSS logs :class:`rig.data.Session` reads for :meth:`~rig.data.Session.gnss` and its clocks."""


def _bounded_topics(*, optical: bool, truth: bool) -> Callable[[str], bool]:
    """The topics ``load_inputs(bounded_memory=True)`` reads into its session: every receiver's decoded GNSS logs
    (the rovers' fixes, the leap seconds and the host clock come from them), the events, the DAQ blocks (their sync
    pulse measures the receivers' output latency), the optical sensors' topics (``optical``) and the simulator's
    truth (``truth``). Left out: the CAN frames (read
    streamed), the raw bytes, LocationFix, the relay and anything else the series do not use."""
    opt_prefix = T.optical("s").removesuffix("s")
    daq_prefix = T.daq_samples("d").split("/d/", 1)[0] + "/"

    def want(topic: str) -> bool:
        if topic == T.TOPIC_EVENTS:
            return True
        if topic.startswith("/gnss/") and topic.count("/") == 3:
            return topic.rsplit("/", 1)[1] in _GNSS_LOGS
        if topic.startswith(daq_prefix):
            return True  # the sync pulse measures the receivers' output latency (Session.measured_output_latency)
        if topic.startswith(opt_prefix):
            return optical
        return truth and topic == T.TOPIC_SIM_TRUTH

    return want


@dataclass(slots=True)
class _StreamedCan:
    """One CAN bus read by :func:`_streamed_can_roles`."""

    roles: dict[str, RoleSeries]
    time_source: str
    """As :attr:`rig.data.CanFrames.time_source`."""
    first_time_ns: int | None
    """The earliest frame time on the common base (only when asked for; None without frames)."""
    error: RigError | None = None
    """Why the roles could not be decoded (no DBC or role map, an unreadable block), as Session.can_roles raises it."""


_SLICE = 1 << 20
"""Frames per slice in :func:`_streamed_can_roles` (its temporaries: a few arrays of this length)."""
_CAN_BATCH_ROWS = 131_072
"""Frames per batch read by :func:`_streamed_can_roles` (:func:`rig.data.stream.iter_groups`'s ``chunk_rows``)."""


def _slices(n: int) -> list[tuple[int, int]]:
    """[a, b) slices of ``range(n)``, each of at most :data:`_SLICE` and (but for a lone one) at least 16 items
    (ClockEstimator.add_many takes fewer than 16 pairs one by one: the same bins, but kept simple)."""
    starts = list(range(0, n, _SLICE))
    if len(starts) > 1 and n - starts[-1] < 16:
        starts.pop()
    return [(a, starts[i + 1] if i + 1 < len(starts) else n) for i, a in enumerate(starts)]


def _concat(parts: list[npt.NDArray[Any]], dtype: type) -> npt.NDArray[Any]:
    """``np.concatenate(parts)`` emptying ``parts`` as it goes (each part freed once copied)."""
    out: npt.NDArray[Any] = np.empty(sum(int(p.shape[0]) for p in parts), dtype=dtype)
    i = 0
    while parts:
        p = parts.pop(0)
        out[i : i + p.shape[0]] = p
        i += p.shape[0]
    return out


@dataclass(slots=True)
class _BusPass:
    """What one pass over a bus's blocks kept (:func:`_read_bus`)."""

    n: int = 0
    """Frames on the bus."""
    all_dev: bool = True
    """Every frame has an interface time."""
    monotone: bool = True
    """The interface times never go back in file order."""
    clock: Any = None
    """ClockEstimator fed every frame in file order (None: not asked for, or the times are not all there and
    in order)."""
    dev: IntArray | None = None
    host: IntArray | None = None
    """Both clock readings of every frame (only when asked for)."""
    rows_dev: list[IntArray] = field(default_factory=list)
    rows_host: list[IntArray] = field(default_factory=list)
    ids: list[npt.NDArray[np.uint32]] = field(default_factory=list)
    data: list[npt.NDArray[np.uint8]] = field(default_factory=list)
    lens: list[npt.NDArray[np.int16]] = field(default_factory=list)
    width: int = 8
    """The bus's widest payload (its one block array's width)."""


def _read_bus(session: Session, bus: str, keys: npt.NDArray[np.uint32] | None, *, keep_clocks: bool) -> _BusPass:
    """One pass over ``bus``, :data:`_CAN_BATCH_ROWS` frames at a time: the data frames whose identifier is in
    ``keys`` (None: none) kept whole; every frame's clock readings kept (``keep_clocks``) or else fed to a
    ClockEstimator as they come while the interface times run forward (fed in device-time order, as
    :meth:`Session.can_frames` feeds it: add_many carries its open bin from one call to the next)."""
    from drivers.can.checks import CAN_EFF_FLAG
    from rig.core.timebase import ClockEstimator
    from rig.data.stream import iter_groups, open_stream

    out = _BusPass(clock=None if keep_clocks else ClockEstimator(f"can:{bus}"))
    devs: list[IntArray] = []
    hosts: list[IntArray] = []
    last: int | None = None
    pend_dev: list[IntArray] = []  # fewer than 16 pairs go to add_many one by one: gathered to 16 first
    pend_host: list[IntArray] = []
    for ch in iter_groups(open_stream(session.path), topics=[T.can_frames(bus)], roles=False,
                          chunk_rows=_CAN_BATCH_ROWS):
        c = ch.columns
        dev = np.asarray(c["device_ns"], dtype=np.int64)
        host = np.asarray(c["host_ns"], dtype=np.int64)
        out.n += int(dev.shape[0])
        out.width = max(out.width, int(c["data"].shape[1]))
        if dev.size and out.all_dev and bool(np.any(dev == T.NO_TIME_NS)):
            out.all_dev = False
        if dev.size:
            if out.monotone and ((last is not None and int(dev[0]) < last) or bool(np.any(dev[1:] < dev[:-1]))):
                out.monotone = False
            last = int(dev[-1])
        if keep_clocks:
            devs.append(dev)
            hosts.append(host)
        elif out.all_dev and out.monotone:
            pend_dev.append(dev)
            pend_host.append(host)
            if sum(d.size for d in pend_dev) >= 16:
                out.clock.add_many(np.concatenate(pend_dev), np.concatenate(pend_host))
                pend_dev, pend_host = [], []
        if keys is not None:
            fid = np.where(c["extended"], c["can_id"] | np.uint32(CAN_EFF_FLAG), c["can_id"]).astype(np.uint32)
            sel = ~(c["error_frame"] | c["remote_frame"]) & np.isin(fid, keys)
            out.rows_dev.append(dev[sel])
            out.rows_host.append(host[sel])
            out.ids.append(fid[sel])
            out.data.append(np.ascontiguousarray(c["data"][sel]))
            out.lens.append(c["len"][sel].astype(np.int16))
    if keep_clocks:
        out.dev = _concat(devs, np.int64)
        out.host = _concat(hosts, np.int64)
    elif out.all_dev and out.monotone and pend_dev:
        out.clock.add_many(np.concatenate(pend_dev), np.concatenate(pend_host))
    if not (out.all_dev and out.monotone):
        out.clock = None
    return out


def _streamed_can_roles(session: Session, bus: str, *, decode: bool, first_time: bool,
                        only: Collection[str] | None = None) -> _StreamedCan:
    """:meth:`Session.can_roles` of ``bus`` (those named in ``only``, None: all; and the earliest frame time,
    ``first_time``) with bounded memory.

    The bus's blocks are read a batch at a time (:func:`_read_bus`); only the data frames whose identifier the
    role map decodes are kept whole. Then, as :meth:`Session.can_frames` does over every frame: the interface
    clock is mapped onto the host clock by one lower envelope over all frames (when every frame has an
    interface time), the host clock onto the common base (:meth:`Session.host_to_utc`); both maps are
    per-frame functions, so evaluating them on the kept frames only gives those frames the same times. The
    envelope is fed as the frames come when their interface times run forward (a bus's usual case: nothing of
    the whole bus is kept); else, and for ``first_time``, every frame's two clock readings (16 bytes) are kept
    and fed in device-time order. The decoder treats each identifier on its own, in receive order, so decoding
    only those frames gives the same roles (values, flags, times) as decoding the whole bus.
    """
    from drivers.can.checks import frame_key
    from drivers.can.roles import RoleMap
    from drivers.can.vector_decode import FrameBatch, VectorRoleDecoder
    from rig.core.timebase import ClockEstimator

    error: RigError | None = None
    decoder: VectorRoleDecoder | None = None
    keys: npt.NDArray[np.uint32] | None = None
    if decode:
        try:
            db = session.dbc()
            rm = session.rolemap(db, bus)
            if only is not None:  # the messages of the roles asked for (each message is decoded on its own)
                specs = tuple(r for r in rm.roles if r.role in only)
                kept = {r.message for r in specs}
                rm = RoleMap(specs, tuple(c for c in rm.checks if c.message in kept))
            decoder = VectorRoleDecoder(db, rm)
            keys = np.asarray(sorted({frame_key(m.frame_id, m.is_extended_frame)
                                      for m in (db.get_message_by_name(n) for n in rm.messages)}), dtype=np.uint32)
        except RigError as exc:
            error = exc
    if decoder is None and not first_time:
        return _StreamedCan({}, "host", None, error)
    try:
        bp = _read_bus(session, bus, keys, keep_clocks=first_time)
        if bp.n and bp.all_dev and bp.clock is None and bp.dev is None:  # interface times out of order
            again = _read_bus(session, bus, None, keep_clocks=True)
            bp.dev, bp.host = again.dev, again.host
    except RigError as exc:
        return _StreamedCan({}, "host", None, exc)
    rows_dev = _concat(bp.rows_dev, np.int64)
    rows_host = _concat(bp.rows_host, np.int64)
    source = "host"
    first: int | None = None
    if bp.n and bp.all_dev:  # as Session.can_frames: interface clock → host over the whole session
        est = bp.clock
        if est is None:
            assert bp.dev is not None and bp.host is not None
            dev, host = bp.dev, bp.host
            est = ClockEstimator(f"can:{bus}")
            order = np.argsort(dev, kind="stable")
            for a, b in _slices(bp.n):  # the temporaries: a few arrays of _SLICE frames
                o = order[a:b]
                est.add_many(dev[o], host[o])
            del order
        to_host = est.mapping()
        if first_time and bp.dev is not None:
            first = min(int(np.min(session.host_to_utc(to_host(bp.dev[a:b]))[0])) for a, b in _slices(bp.n))
        rows_host = to_host(rows_dev)
        source = "interface"
    elif first_time and bp.n and bp.host is not None:
        first = min(int(np.min(session.host_to_utc(bp.host[a:b])[0])) for a, b in _slices(bp.n))
    bp.dev = bp.host = None
    t, mapped = session.host_to_utc(rows_host)
    if not mapped:
        source = "host_unmapped"
    roles: dict[str, RoleSeries] = {}
    if decoder is not None:
        payload = np.zeros((t.size, bp.width), dtype=np.uint8)
        i = 0
        while bp.data:
            d = bp.data.pop(0)
            payload[i : i + d.shape[0], : d.shape[1]] = d
            i += d.shape[0]
        batch = FrameBatch(t, _concat(bp.ids, np.uint32), payload, _concat(bp.lens, np.int16))
        roles = dict(decoder.decode(batch).roles)
    return _StreamedCan(roles, source, first, error)


def _first_time(session: Session, streamed: Mapping[str, _StreamedCan] | None = None, truth_read: bool = True) -> int:
    """The session's first CAN frame, truth or event time (its time base without GNSS). ``streamed``: the buses as
    :func:`_streamed_can_roles` read them (``bounded_memory``); ``truth_read``: False when the session was read
    without its truth topic (then the truth's first time is read from the file, streamed)."""
    cands: list[int] = []
    for bus in session.can_buses():
        if streamed is not None:
            first = streamed[bus].first_time_ns
            if first is not None:
                cands.append(first)
            continue
        f = session.can_frames(bus)
        if len(f):
            cands.append(int(np.min(f.time_ns)))
    if session.topic_counts.get(T.TOPIC_SIM_TRUTH, 0):
        if truth_read:
            cands.append(int(session.truth().time_ns[0]))
        else:
            from rig.data.stream import iter_groups, open_stream

            times = [int(np.min(c.time_ns)) for c in iter_groups(open_stream(session.path),
                                                                 topics=[T.TOPIC_SIM_TRUTH]) if len(c)]
            if not times:
                raise AnalysisError(f"{session.path}: no {T.TOPIC_SIM_TRUTH} (not a simulated session)")
            cands.append(min(times))
    if not cands and session.events:
        cands.append(session.events[0][0])
    return min(cands) if cands else 0


def _load_optical(
    session: Session,
    prof: VehicleProfile,
    recorded_cal: CalibrationConfig,
    from_daq: bool,
    rel: Any,
    out: dict[str, OpticalSeries],
    streams: dict[str, StreamInfo],
    missing: dict[str, str],
    warnings: list[str],
) -> None:
    from drivers.optical import OpticalSensorSpec

    if not prof.optical:
        missing["optical"] = f"session {session.path}: the vehicle profile has no [[optical]] sensor"
        return
    daq_cfg = session.config.get("daq")
    sync_channel = daq_cfg.get("sync_channel") if isinstance(daq_cfg, Mapping) else None
    ants, _how = _antenna_receivers(session)
    for o in prof.optical:
        zero_rec = math.radians(recorded_cal.optical_zero_deg.get(o.name, 0.0))
        zero_now = math.radians(prof.calibration.optical_zero_deg.get(o.name, 0.0))
        topic = T.optical(o.name)
        try:
            if from_daq or not session.topic_counts.get(topic, 0):
                spec = OpticalSensorSpec.from_config(o.model_dump(), zero_offset_deg=math.degrees(zero_rec),
                                                     where=f"optical.{o.name}")
                kw: dict[str, Any] = {}
                if sync_channel and ants.get("a") in session.receivers():
                    kw = {"sync_channel": str(sync_channel), "receiver": ants["a"]}
                tns, smp = session.optical(o.name, spec, **kw)
                source = "daq"
            else:
                tns, smp = session.optical(o.name)
                source = "topic"
        except RigError as exc:
            msg = f"optical sensor {o.name!r}: {exc}"
            missing["optical"] = msg
            warnings.append(msg)
            continue
        applied = smp.zero_offset_applied_rad if math.isfinite(smp.zero_offset_applied_rad) else zero_rec
        tns = np.asarray(tns, dtype=np.int64)
        order = np.argsort(tns, kind="stable")
        # The recorder never lets log_time run back on a channel: where the DAQ's time base steps back
        # (host estimate → sync pulse) it holds the samples at the last time until the new time
        # catches up, so a few samples share one stamp. Keep the first of each stamp; the analysis
        # needs strictly increasing times.
        repeated = np.r_[False, np.diff(tns[order]) <= 0]
        if repeated.any():
            warnings.append(f"optical sensor {o.name!r}: {int(repeated.sum())} samples share a time stamp with the "
                            "one before (log_time held where the time base stepped back); left out")
            order = order[~repeated]
        valid = np.asarray(smp.valid, dtype=bool)[order]
        ser = OpticalSeries(
            name=o.name, kind=o.kind, wheel=o.wheel, mount_xy_m=o.mount.xy, time_ns=tns[order], t_s=rel(tns[order]),
            vx_mps=np.asarray(smp.vx, dtype=float)[order], vy_mps=np.asarray(smp.vy, dtype=float)[order],
            slip_angle_rad=np.asarray(smp.slip_angle, dtype=float)[order],
            speed_mps=np.asarray(smp.speed, dtype=float)[order], valid=valid, zero_applied_rad=float(applied),
            zero_in_force_rad=zero_now, source=source,
        )
        out[o.name] = ser
        streams[f"optical.{o.name}"] = _stream(f"optical:{o.name}", ser.t_s, valid, f"from {source}")

