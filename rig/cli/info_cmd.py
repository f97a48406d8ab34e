"""``rig info FILE`` (what a session holds) and ``rig export FILE`` (raw GNSS streams, CSV tables)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from vsccore.errors import ConfigError

if TYPE_CHECKING:
    from rig.export import ExportReport

_FILE_HELP = "A session part (NAME.NNN.mcap), the session base path (DIR/NAME) or a directory holding one session."


def info(
    file: Annotated[Path, typer.Argument(help=_FILE_HELP)],
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON (keys documented in rig.inspect).")]
    = False,
    gap_factor: Annotated[
        float, typer.Option("--gap-factor", help="An interval longer than this many median periods is a gap.")
    ] = 5.0,
    min_gap_s: Annotated[float, typer.Option("--min-gap", help="Shortest interval reported as a gap (s).")] = 0.5,
    max_list: Annotated[int, typer.Option("--max-list", help="Longest list of gaps or events in the text.")] = 20,
    verify: Annotated[
        bool, typer.Option("--verify", help="Check every chunk's CRC (reads all data); report damaged chunks.")
    ] = False,
) -> None:
    """Duration, topics with counts and rates, devices, gaps, time-base quality, calibration and events."""
    from rig.inspect import format_info, info_to_json, read_session_info

    if gap_factor <= 1.0 or min_gap_s < 0 or max_list < 0:
        raise ConfigError(f"--gap-factor must be > 1, --min-gap >= 0 and --max-list >= 0 "
                          f"(got {gap_factor}, {min_gap_s}, {max_list})")
    summary = read_session_info(file, gap_factor=gap_factor, min_gap_s=min_gap_s, verify=verify)
    if as_json:
        typer.echo(json.dumps(info_to_json(summary), indent=1))
    else:
        typer.echo(format_info(summary, max_list=max_list), nl=False)


def _print_report(report: ExportReport) -> None:
    from rig.export import ExportKind
    from rig.inspect import format_utc

    for f in report.files:
        if f.kind is ExportKind.TABLE:
            typer.echo(f"wrote {f.path}  {f.bytes} bytes  {f.records} rows  ({f.source})")
            continue
        typer.echo(
            f"wrote {f.path}  {f.bytes} bytes  {f.records} reads from {f.parts} part{'s' if f.parts != 1 else ''}  "
            f"({f.source}, {format_utc(f.first_ns)} → {format_utc(f.last_ns)})"
        )
    for w in report.warnings:
        typer.echo(f"warning: {w}", err=True)


def export(
    file: Annotated[Path, typer.Argument(help=_FILE_HELP)],
    raw_gnss: Annotated[
        Path | None,
        typer.Option("--raw-gnss", help="Write each receiver's raw bytes (DIR/<receiver>.gps, RTKLIB/NovAtel) and "
                     "the relayed corrections (DIR/corrections.rtcm3) into DIR."),
    ] = None,
    csv_dir: Annotated[
        Path | None,
        typer.Option("--csv", help="Write decoded GNSS logs, CAN roles, optical data and events as CSV into DIR."),
    ] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace existing output files.")] = False,
) -> None:
    """Get data out of a session for post-processing (RTKLIB convbin/rtkpost, NovAtel tools, spreadsheets)."""
    from rig.export import ExportKind, export_csv, export_raw_gnss, rtklib_format

    if raw_gnss is None and csv_dir is None:
        raise ConfigError("rig export: say what to export: --raw-gnss DIR and/or --csv DIR")
    if raw_gnss is not None:
        report = export_raw_gnss(file, raw_gnss, overwrite=overwrite)
        _print_report(report)
        for path in [f.path for f in report.files if f.kind is ExportKind.GNSS_RAW]:
            typer.echo(f"post-process with RTKLIB, e.g.: convbin -r {rtklib_format(path)} {path}")
    if csv_dir is not None:
        _print_report(export_csv(file, csv_dir, overwrite=overwrite))


def register(app: typer.Typer) -> None:
    """Attach ``rig info`` and ``rig export`` to the root command."""
    app.command("info")(info)
    app.command("export")(export)
