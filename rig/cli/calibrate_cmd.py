"""``rig calibrate-baseline``, ``calibrate-steering-ratio``, ``steering-ratio manual`` and ``calibrate-imu``.

Thin commands: options → :mod:`rig.evaluate.calibrate` → text or JSON. Results are recorded next to the
session in ``<session>.calibration.json`` (read back by :func:`rig.data.inputs.load_inputs`) and,
with ``--write PROFILE``, into the vehicle profile's ``[calibration]`` table.
"""

from __future__ import annotations

import inspect
import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer

from vsccore.errors import ConfigError

_SESSION_HELP = "A session part (NAME.NNN.mcap), the session base path (DIR/NAME) or a directory holding one session."


def _dump(obj: Any) -> str:
    return json.dumps(obj, indent=1, allow_nan=True, default=str)


def _timing_headline(warnings: Any) -> None:
    """Degraded time-base verdicts (:mod:`rig.core.quality`) first, before the result they qualify."""
    for w in warnings:
        if str(w).startswith("TIMING DEGRADED"):
            typer.echo(str(w))


def _help(doc: str | None) -> str:
    """A docstring as command help: paragraphs re-flowed (one line each), rich markup brackets escaped."""
    paras = [" ".join(ln.strip() for ln in p.splitlines()) for p in inspect.cleandoc(doc or "").split("\n\n")]
    return "\n\n".join(p.replace("[", "\\[") for p in paras if p)


def calibrate_baseline_cmd(
    session: Annotated[Path, typer.Argument(help=_SESSION_HELP)],
    write: Annotated[
        Path | None,
        typer.Option("--write", help="Vehicle profile TOML to update in place: \\[calibration] mount_offset_deg, "
                     "mount_offset_u95_deg, mount_offset_date, mount_offset_session and optical_zero_deg.<sensor> "
                     "(comments and layout kept)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    min_speed_kmh: Annotated[float, typer.Option("--min-speed-kmh", help="Straight runs: minimum speed (km/h).")]
    = 25.0,
    min_duration_s: Annotated[float, typer.Option("--min-duration-s", help="Straight runs: minimum duration (s).")]
    = 5.0,
    max_yaw_rate_dps: Annotated[float, typer.Option("--max-yaw-rate-dps", help="Straight runs: maximum |yaw rate| "
                                                    "(°/s, after removing the yaw-rate sensor's zero).")] = 0.5,
    max_course_std_deg: Annotated[float, typer.Option("--max-course-std-deg", help="Straight runs: maximum course "
                                                      "standard deviation within a run (°).")] = 0.5,
    length_tolerance_m: Annotated[
        float | None, typer.Option("--length-tolerance-m", help="Baseline length tolerance (m; default: the "
                                   "profile's antennas.baseline_tolerance_m).")
    ] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write a PNG plot of the runs and offsets.")] = None,
    no_record: Annotated[bool, typer.Option("--no-record", help="Do not record the result next to the session.")]
    = False,
) -> None:
    """Antenna mounting offset from straight runs (heading of the baseline A→B minus the course over ground).

    Straight runs are found automatically: speed above --min-speed-kmh, |yaw rate| below
    --max-yaw-rate-dps (the CAN yaw-rate sensor's zero offset against the GNSS heading rate is removed
    first), a stable course, at least --min-duration-s long, both rovers RTK fixed.

    Uncertainty: samples 50 ms apart are correlated, so each run's robust (Huber) mean gets its
    standard error from an AR(1) model of the within-run noise (lag-1 coefficient pooled over all runs);
    runs in one direction are combined by inverse-variance weights (Birge-ratio inflation when they
    disagree), and the two directions' means are averaged, which cancels cross-wind and road-crown
    effects; a disagreement between the directions is warned about. The ±95 % half-width uses a
    coverage factor simulated for this estimator.

    Also checks the measured baseline length against the configured one (flagged beyond the
    tolerance: wrong RTK fix or wrong configuration) and estimates each body-mounted optical sensor's
    slip-angle zero from the same runs. The result is recorded in <session>.calibration.json (later
    commands use it) unless --no-record; --write PROFILE puts it into the vehicle profile.
    """
    from rig.data.inputs import load_inputs
    from rig.data.sidefiles import update_calibration_file
    from rig.evaluate.calibrate import (
        BaselineOptions,
        baseline_record,
        calibrate_baseline,
        format_baseline,
        optical_record,
        plot_baseline,
        write_profile_calibration,
    )

    opts = BaselineOptions(min_speed_kmh=min_speed_kmh, min_duration_s=min_duration_s,
                           max_yaw_rate_dps=max_yaw_rate_dps, max_course_std_deg=max_course_std_deg,
                           length_tolerance_m=length_tolerance_m)
    opts.check()
    inputs = load_inputs(session, truth=True, optical=True)
    cal = calibrate_baseline(inputs, opts)
    out = cal.to_dict()
    files: dict[str, str] = {}
    if plot is not None:
        files["plot"] = str(plot_baseline(cal, plot))
    if not no_record:
        path = update_calibration_file(session, "mount_offset", baseline_record(cal))
        if cal.optical:
            path = update_calibration_file(session, "optical_zero", optical_record(cal))
        files["calibration_file"] = str(path)
    if write is not None:
        values: dict[str, Any] = {
            "mount_offset_deg": cal.offset_deg, "mount_offset_u95_deg": cal.u95_deg,
            "mount_offset_date": baseline_record(cal)["date"], "mount_offset_session": cal.session,
        }
        if cal.optical:
            values["optical_zero_deg"] = {o.sensor: math.degrees(o.zero_rad) for o in cal.optical}
        files["profile"] = str(write_profile_calibration(write, values))
    out["files"] = files
    if as_json:
        typer.echo(_dump(out))
        return
    _timing_headline(cal.warnings)
    typer.echo(format_baseline(cal), nl=False)
    if "calibration_file" in files:
        typer.echo(f"recorded in {files['calibration_file']}")
    if "profile" in files:
        typer.echo(f"wrote [calibration] of {files['profile']}")
    if "plot" in files:
        typer.echo(f"plot: {files['plot']}")


def calibrate_steering_ratio_cmd(
    session: Annotated[Path, typer.Argument(help=_SESSION_HELP)],
    as_json: Annotated[bool, typer.Option("--json", help="Print the table as JSON.")] = False,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write a PNG plot (ratio vs SWA, circles).")] = None,
    max_speed_kmh: Annotated[float, typer.Option("--max-speed-kmh", help="Circles: maximum speed (km/h).")] = 15.0,
    max_swa_spread_deg: Annotated[float, typer.Option("--max-swa-spread-deg", help="Circles: steering-wheel angle "
                                                      "peak-to-peak within a circle (°).")] = 2.0,
    min_arc_deg: Annotated[float, typer.Option("--min-arc-deg", help="Circles: minimum angle driven (°).")] = 60.0,
    no_record: Annotated[bool, typer.Option("--no-record", help="Do not record the result next to the session.")]
    = False,
) -> None:
    """Steering ratio SWA/δ per steering-wheel angle, forward and reverse, from circles at constant SWA.

    Finds low-speed runs at constant steering-wheel angle (CAN role swa), moves antenna A's RTK
    track to the rear-axle centre with the dual-antenna heading (mounting offset in force removed)
    and the lever arms, fits a circle (least squares), and converts its radius R to the road-wheel
    angle δ = atan(L/R).
    """
    from rig.data.inputs import load_inputs
    from rig.data.sidefiles import update_calibration_file
    from rig.evaluate.calibrate import (
        SteeringOptions,
        calibrate_steering_ratio,
        format_steering,
        plot_steering,
        steering_record,
    )

    opts = SteeringOptions(max_speed_kmh=max_speed_kmh, max_swa_spread_deg=max_swa_spread_deg,
                           min_arc_deg=min_arc_deg)
    inputs = load_inputs(session, optical=False)
    cal = calibrate_steering_ratio(inputs, opts)
    out = cal.to_dict()
    files: dict[str, str] = {}
    if plot is not None:
        files["plot"] = str(plot_steering(cal, plot))
    if not no_record:
        files["calibration_file"] = str(update_calibration_file(session, "steering_ratio", steering_record(cal)))
    out["files"] = files
    if as_json:
        typer.echo(_dump(out))
        return
    _timing_headline(cal.warnings)
    typer.echo(format_steering(cal), nl=False)
    if "calibration_file" in files:
        typer.echo(f"recorded in {files['calibration_file']}")
    if "plot" in files:
        typer.echo(f"plot: {files['plot']}")


steering_app = typer.Typer(help="Steering ratio from tape measurements.", no_args_is_help=True)


def steering_ratio_manual(
    swa_deg: Annotated[float, typer.Option("--swa-deg", help="Steering-wheel angle held (°, left positive).")],
    wheelbase: Annotated[float, typer.Option("--wheelbase", help="Wheelbase L (m).")],
    track_rear: Annotated[float, typer.Option("--track-rear", help="Rear track width (m).")],
    chords: Annotated[
        tuple[float, float, float] | None,
        typer.Option("--chords", help="Distances A B C (m) between three points marked on the inner rear wheel's "
                     "track."),
    ] = None,
    diameter: Annotated[float | None, typer.Option("--diameter", help="Diameter D (m) of the inner rear wheel's "
                                                   "track, taped across a half circle.")] = None,
    tape_sigma_m: Annotated[float, typer.Option("--tape-sigma-m", help="Tape measurement uncertainty (m, 1σ).")]
    = 0.01,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
) -> None:
    """Steering ratio from tape measurements of a circle driven at constant SWA.

    Three points on the inner rear wheel's track (circumradius R = abc / 4S, S from Heron's formula)
    or a half circle (R = D/2); the rear-axle centre's radius is R + track/2 and δ = atan(L / R).
    """
    from calibration.steering import manual_ratio_from_chords, manual_ratio_from_diameter

    if (chords is None) == (diameter is None):
        raise ConfigError("rig steering-ratio manual: give either --chords A B C or --diameter D")
    swa = math.radians(swa_deg)
    if chords is not None:
        res = manual_ratio_from_chords(swa, chords, wheelbase_m=wheelbase, track_rear_m=track_rear,
                                       tape_sigma_m=tape_sigma_m)
    else:
        assert diameter is not None
        res = manual_ratio_from_diameter(swa, diameter, wheelbase_m=wheelbase, track_rear_m=track_rear,
                                         tape_sigma_m=tape_sigma_m)
    if as_json:
        typer.echo(_dump(res.to_dict()))
        return
    typer.echo(f"inner rear wheel radius {res.inner_radius_m:.3f} m → rear-axle centre R = {res.radius_m:.3f} m "
               f"(± {res.radius_sigma_m:.3f} m)")
    typer.echo(f"road-wheel angle δ = {math.degrees(res.delta_rad):.3f}°, steering ratio {res.ratio:.3f} "
               f"(± {res.ratio_sigma:.3f}) at SWA {swa_deg:g}°")


steering_app.command("manual", help=_help(steering_ratio_manual.__doc__))(steering_ratio_manual)


def calibrate_imu_cmd(
    accel: Annotated[Path | None, typer.Option("--accel", help="CSV of static positions: columns position "
                                               "(+x … -z, the axis pointing up), ax_mps2, ay_mps2, az_mps2 (or "
                                               "ax_g, ay_g, az_g); one row per sample.")] = None,
    gyro: Annotated[Path | None, typer.Option("--gyro", help="CSV of turntable runs: columns axis (+x … -z on the "
                                              "spin axis), rate_dps (table rate, 0 for static), gx_dps, gy_dps, "
                                              "gz_dps (or *_rps); one row per sample.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    write: Annotated[Path | None, typer.Option("--write", help="Vehicle profile TOML: write \\[calibration.imu] in "
                                               "place.")] = None,
    session: Annotated[Path | None, typer.Option("--session", help="Record the result next to this session, so "
                                                 "its yaw rate and accelerations are corrected (sessiondata "
                                                 "imu_calibration='in_force').")] = None,
) -> None:
    """Accelerometer and gyroscope calibration: bias, scale factors and misalignment (measured = M·true + b).

    Accelerometer from static positions (each axis up and down, ±g; more positions only add
    equations); gyroscope from turntable runs at known rates about each axis (e.g. ±80, ±90,
    ±100 °/s). Least squares over the runs' means; residuals per run are reported. The rows of one
    position (accelerometer) or one axis and rate (gyroscope) form one run; lines starting with # are
    comments. The result corrects the recorded CAN yaw_rate (gyro z), lat_accel (accel y) and
    long_accel (accel x) per axis.
    """
    from rig.data.sidefiles import update_calibration_file
    from rig.evaluate.calibrate import (
        calibrate_imu,
        format_imu,
        read_accel_csv,
        read_gyro_csv,
        write_profile_calibration,
    )

    positions = read_accel_csv(accel) if accel is not None else None
    runs = read_gyro_csv(gyro) if gyro is not None else None
    src = ", ".join(str(p) for p in (accel, gyro) if p is not None)
    res = calibrate_imu(positions, runs, source=src)
    out = res.to_dict()
    files: dict[str, str] = {}
    if write is not None:
        files["profile"] = str(write_profile_calibration(write, {"imu": res.config.model_dump(mode="json")}))
    if session is not None:
        files["calibration_file"] = str(update_calibration_file(session, "imu", {"config": out["config"]}))
    out["files"] = files
    if as_json:
        typer.echo(_dump(out))
        return
    typer.echo(format_imu(res), nl=False)
    for what, p in files.items():
        typer.echo(f"wrote {what}: {p}")


def register(app: typer.Typer) -> None:
    """Attach the calibration commands to the root command."""
    for name, fn in (("calibrate-baseline", calibrate_baseline_cmd),
                     ("calibrate-steering-ratio", calibrate_steering_ratio_cmd),
                     ("calibrate-imu", calibrate_imu_cmd)):
        app.command(name, help=_help(fn.__doc__))(fn)
    app.add_typer(steering_app, name="steering-ratio")
