"""``rig validate``, ``rig rollover`` and ``rig steering error-model|reconstruct``: the analysis commands.

    rig validate sessions/run1 --report out/run1 --json out/run1.json [--estimator pkg.mod:fn] [--method rts]
    rig rollover sessions/run1 --plot ltr.png [--json]
    rig steering error-model --mass 1550 --wheelbase 2.8 --cornering-stiffness 60000 \\
        --front-axle-load-share 0.571 --roll-gain-deg-per-g 4.5 [--json] [--plot gamma.png]
    rig steering reconstruct sessions/run1 [--json]

Exit status of ``rig validate``: 0 when the estimate passes the configured tolerances, 1 when it
fails them (so a CI script can gate on it), 2 on an error (unreadable session, bad option) and when
a stream the result uses has an unusable time base (:mod:`rig.core.quality`; the message names the stream,
the figure and the fix). A degraded stream is a ``TIMING DEGRADED`` line in the output and the JSON
(``timing_warnings``, ``time_base``), as for ``rig rollover`` and ``rig steering reconstruct``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from vsccore.errors import ConfigError, SessionFileError


class ReferenceChoice(StrEnum):
    """``--method``: the values of :class:`rig.analysis.reference.ReferenceMethod` (a test keeps them equal;
    the analysis modules, which pull in scipy, are imported by the commands, so ``rig --help`` stays fast)."""

    RAW = "raw"
    WAVELET = "wavelet"
    RTS = "rts"


steering_app = typer.Typer(help="Steering-angle reconstruction from GNSS speed and lateral acceleration.",
                           no_args_is_help=True)

_SESSION_HELP = "A session part (NAME.NNN.mcap), the session base path (DIR/NAME) or a directory holding one session."
DEFAULT_SPEEDS_KMH = tuple(float(v) for v in range(10, 210, 10))


def _parse_speeds(text: str | None) -> list[float]:
    if text is None:
        return list(DEFAULT_SPEEDS_KMH)
    out: list[float] = []
    for item in text.replace(" ", "").split(","):
        if not item:
            continue
        try:
            v = float(item)
        except ValueError:
            raise ConfigError(f"--speeds: {item!r} is not a number (give km/h, e.g. 20,50,100)") from None
        if not (v > 0.0 and math.isfinite(v)):
            raise ConfigError(f"--speeds: {item!r} must be a positive speed in km/h")
        out.append(v)
    if not out:
        raise ConfigError("--speeds: give at least one speed in km/h, e.g. 20,50,100")
    return out


def error_model_cmd(
    mass: Annotated[float, typer.Option("--mass", help="Vehicle mass (kg), the whole car.")],
    wheelbase: Annotated[float, typer.Option("--wheelbase", help="Wheelbase l (m).")],
    cornering_stiffness: Annotated[
        float,
        typer.Option(
            "--cornering-stiffness",
            help="Cornering stiffness of one front tyre (N/rad per tyre, not per axle: an axle has two tyres); "
            "also each rear tyre's unless --cornering-stiffness-rear.",
        ),
    ],
    front_axle_load_share: Annotated[
        float,
        typer.Option("--front-axle-load-share", help="b/l: share of the weight on the front axle (e.g. 0.6)."),
    ],
    roll_gain_deg_per_g: Annotated[
        float,
        typer.Option("--roll-gain-deg-per-g", help="Static roll gain (deg of body roll per g of lateral accel.)."),
    ],
    cornering_stiffness_rear: Annotated[
        float | None,
        typer.Option(
            "--cornering-stiffness-rear",
            help="Cornering stiffness of one rear tyre (N/rad per tyre; default: same as the front tyre).",
        ),
    ] = None,
    speeds: Annotated[
        str | None, typer.Option("--speeds", help="Comma-separated speeds (km/h; default 10, 20, …, 200).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON (sign-change speed, γ at each speed).")] = False,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write a plot of γ(v) to this PNG file.")] = None,
) -> None:
    """Relative error γ = 1 − l(1 + g·k_φ)/(l + K·v²) of the kinematic road-wheel angle a_y·l/v² over speed."""
    from rig.analysis.steering import SteeringModel, error_table

    try:
        model = SteeringModel.from_degrees_per_g(
            wheelbase_m=wheelbase, mass_kg=mass, front_axle_load_share=front_axle_load_share,
            cornering_stiffness_n_per_rad_per_tyre=cornering_stiffness, roll_gain_deg_per_g=roll_gain_deg_per_g,
            cornering_stiffness_rear_n_per_rad_per_tyre=cornering_stiffness_rear,
        )
    except ValueError as exc:  # AnalysisError names the parameter
        raise ConfigError(f"rig steering error-model: {exc}") from exc
    em = error_table(model, _parse_speeds(speeds))
    if plot is not None:
        import numpy as np

        from rig.analysis.steering import error_model
        from rig.evaluate.report import plot_error_model

        hi = max(float(np.max(em.speeds_mps)), 1.0)
        dense = error_model(model, np.linspace(hi / 200.0, hi, 400))
        plot_error_model(dense, plot)
    if as_json:
        doc = em.to_dict()
        doc["parameters"] = {
            "mass_kg": mass, "wheelbase_m": wheelbase, "cornering_stiffness_front_n_per_rad": cornering_stiffness,
            "cornering_stiffness_rear_n_per_rad": cornering_stiffness if cornering_stiffness_rear is None
            else cornering_stiffness_rear,
            "front_axle_load_share": front_axle_load_share, "roll_gain_deg_per_g": roll_gain_deg_per_g,
        }
        if plot is not None:
            doc["plot"] = str(plot)
        typer.echo(json.dumps(doc, indent=1))
        return
    k_deg_g = math.degrees(em.understeer_gradient_rad_per_mps2) * 9.80665
    typer.echo(f"understeer gradient K = {k_deg_g:.3f} deg/g, roll factor 1 + g·k_φ = {em.roll_factor:.4f}")
    v0 = em.sign_change_speed_mps
    if v0 is None:
        typer.echo("γ does not change sign (needs K > 0 and a positive roll gain)")
    else:
        typer.echo(f"γ changes sign at {3.6 * v0:.1f} km/h (δ_kin reads high below, low above)")
    typer.echo(f"{'speed [km/h]':>12}  {'γ [%]':>8}")
    for v, g in zip(em.speeds_mps, em.gamma, strict=True):
        typer.echo(f"{3.6 * float(v):12.1f}  {100.0 * float(g):8.2f}")
    if plot is not None:
        typer.echo(f"wrote {plot}")


@contextmanager
def _progress(enabled: bool, total: int) -> Iterator[Callable[[str], None]]:
    """A rich progress bar on stderr (a terminal only) advanced by step names; a no-op elsewhere."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(stderr=True)
    if not (enabled and console.is_terminal):
        yield lambda _step: None
        return
    with Progress(TextColumn("{task.description:<26}"), BarColumn(), TimeElapsedColumn(), console=console,
                  transient=True) as bar:
        task = bar.add_task("starting", total=total)
        started = [False]

        def step(name: str) -> None:
            if started[0]:
                bar.advance(task)
            started[0] = True
            bar.update(task, description=name)

        yield step
        bar.update(task, completed=total)


def _write_json(path: Path, doc: object) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(doc, indent=1, allow_nan=False), encoding="utf-8")
    except OSError as exc:
        raise SessionFileError(f"cannot write {path}: {exc}") from exc


def validate(
    session: Annotated[Path, typer.Argument(help=_SESSION_HELP)],
    estimator: Annotated[
        str | None,
        typer.Option("--estimator", help="Score package.module:function run offline on the CAN roles instead of "
                     "the recorded vsc_beta_estimate."),
    ] = None,
    report: Annotated[
        Path | None, typer.Option("--report", help="Write report.html (+ PNGs, metrics.json, metrics.csv) into DIR.")
    ] = None,
    json_file: Annotated[Path | None, typer.Option("--json", help="Write the metrics as JSON to FILE.")] = None,
    method: Annotated[
        ReferenceChoice, typer.Option("--method", help="Reference sideslip noise treatment.", case_sensitive=False)
    ] = ReferenceChoice.RTS,
    no_progress: Annotated[bool, typer.Option("--no-progress", help="No progress bar.")] = False,
) -> None:
    """Score the VSC sideslip estimate of SESSION against the GNSS (and optical) reference.

    Exit status: 0 PASS, 1 FAIL (the configured [validation] tolerances), 2 error.
    """
    from rig.analysis.reference import ReferenceMethod
    from rig.evaluate.report import write_metrics_csv, write_validation_report
    from rig.evaluate.validate import validate_session, validation_lines

    with _progress(not no_progress, 8) as step:
        sv = validate_session(session, estimator=estimator, method=ReferenceMethod(method.value), progress=step)
        if report is not None:
            step("report")
            files = write_validation_report(sv, report)
    res = sv.result
    o = res.overall.metrics
    for line in validation_lines(sv):
        typer.echo(line)
    for w in sv.warnings:
        typer.echo(f"warning: {w}", err=True)
    if json_file is not None:
        _write_json(json_file, sv.to_dict())
        write_metrics_csv(res.table_rows(), json_file.with_suffix(".csv"))
        typer.echo(f"wrote {json_file} and {json_file.with_suffix('.csv')}")
    if report is not None:
        typer.echo(f"wrote {files.html} ({len(files.plots)} plots, {files.metrics_json.name}, "
                   f"{files.metrics_csv.name})")
    typer.echo("PASS" if sv.passed else "FAIL: " + "; ".join(o.failures if o is not None else ["no metrics"]))
    if not sv.passed:
        raise typer.Exit(1)


def rollover(
    session: Annotated[Path, typer.Argument(help=_SESSION_HELP)],
    plot: Annotated[Path | None, typer.Option("--plot", help="Write a plot of the LTR and its prediction (PNG).")]
    = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of text.")] = False,
    model: Annotated[
        str, typer.Option("--model", help="auto (physics when the session has swa, else ar), ar, arx or physics.")
    ] = "auto",
    threshold: Annotated[float, typer.Option("--threshold", help="Warning threshold on |LTR|.")] = 0.9,
) -> None:
    """Load-transfer ratio from the CAN lateral acceleration and the roll model, predicted 1, 2 and 3 s ahead."""
    from rig.evaluate.validate import rollover_session

    if not 0.0 < threshold <= 1.0:
        raise ConfigError(f"--threshold must be in (0, 1], got {threshold}")
    rep = rollover_session(session, model=model, threshold=threshold)
    if plot is not None:
        from rig.evaluate.report import plot_rollover

        plot_rollover(rep, plot)
    if as_json:
        doc = rep.to_dict()
        if plot is not None:
            doc["plot"] = str(plot)
        typer.echo(json.dumps(doc, indent=1))
        return
    d = rep.to_dict()
    typer.echo(f"session {rep.session_name}: {d['duration_s']:.1f} s, peak |LTR| {d['peak_abs_ltr']:.3f}, "
               f"model {rep.model}")
    for w in rep.timing_warnings:
        typer.echo(w)
    typer.echo(f"formula: {rep.formula}")
    first = rep.prediction.first_warning_s()
    if first is None:
        typer.echo(f"no warning: neither the LTR nor a prediction reached {threshold:g}")
    else:
        spans = ", ".join(f"{a:.2f}–{b:.2f} s" for a, b in rep.prediction.warning_intervals)
        typer.echo(f"WARNING |LTR| ≥ {threshold:g} (or predicted to): {spans}")
    if rep.truth_ltr is not None:
        typer.echo(f"against the simulator's LTR (wheel loads): RMS {rep.ltr_error_rms:.4f}, "
                   f"max {rep.ltr_error_max:.4f}")
        if rep.prediction_errors:
            typer.echo("prediction error (mean |e| as % of peak |LTR|): "
                       + ", ".join(f"{e.horizon_s:g} s {e.percent_of_peak:.1f} %" for e in rep.prediction_errors))
            typer.echo(f"  over: {rep.evaluation}")
    if plot is not None:
        typer.echo(f"wrote {plot}")


def reconstruct_cmd(
    session: Annotated[Path, typer.Argument(help=_SESSION_HELP)],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    min_speed_kmh: Annotated[float, typer.Option("--min-speed", help="Lowest speed used (km/h).")] = 18.0,
    start: Annotated[float | None, typer.Option("--start", help="Only from this time (s, as rig validate).")] = None,
    stop: Annotated[float | None, typer.Option("--stop", help="Only up to this time (s, as rig validate).")] = None,
) -> None:
    """Front road-wheel angle from GNSS speed and CAN lateral acceleration, against SWA / steering ratio."""
    from rig.evaluate.validate import steering_session

    rep = steering_session(session, min_speed_kmh=min_speed_kmh, start_s=start, stop_s=stop)
    d = rep.to_dict()
    if as_json:
        typer.echo(json.dumps(d, indent=1))
        return

    def f(x: object, unit: str) -> str:
        return "–" if x is None else f"{x:.3f}{unit}"

    typer.echo(f"session {rep.session_name}: δ reconstructed vs SWA / ratio: mean |error| "
               f"{f(d['mean_abs_error_deg'], '°')}, max |error| {f(d['max_abs_error_deg'], '°')}, "
               f"max relative error at the peaks {f(d['max_relative_error_at_peaks_percent'], ' %')}")
    for w in rep.timing_warnings:
        typer.echo(w)


def register(app: typer.Typer) -> None:
    """Attach ``rig validate``, ``rig rollover`` and the ``rig steering`` group to the root command."""
    steering_app.command("error-model")(error_model_cmd)
    steering_app.command("reconstruct")(reconstruct_cmd)
    app.add_typer(steering_app, name="steering")
    app.command("validate")(validate)
    app.command("rollover")(rollover)
