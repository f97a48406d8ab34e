"""``rig info FILE`` (what a session holds) and ``rig export FILE`` (MDF4, Parquet, MAT, CSV; raw GNSS streams)."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from vsccore.errors import ConfigError

if TYPE_CHECKING:
    from rig.export.files import ExportReport

_FILE_HELP = "A session part (NAME.NNN.mcap), the session base path (DIR/NAME) or a directory holding one session."


def info(
    file: Annotated[Path, typer.Argument(help=_FILE_HELP)],
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON (keys: rig.data.info).")]
    = False,
    gap_factor: Annotated[
        float, typer.Option("--gap-factor", help="An interval longer than this many median periods is a gap.")
    ] = 5.0,
    min_gap_s: Annotated[float, typer.Option("--min-gap", help="Shortest interval reported as a gap (s).")] = 0.5,
    max_list: Annotated[int, typer.Option("--max-list", help="Longest list of gaps or events in the text.")] = 20,
    verify: Annotated[
        bool, typer.Option("--verify", help="Check every chunk's CRC (reads all data); report damaged chunks; "
                     "recompute the time-base verdicts from the data.")
    ] = False,
) -> None:
    """Duration, topics with counts and rates, devices, gaps, time-base quality, calibration and events."""
    from rig.data.info import VerdictSource, format_info, info_to_json, read_session_info

    if gap_factor <= 1.0 or min_gap_s < 0 or max_list < 0:
        raise ConfigError(f"--gap-factor must be > 1, --min-gap >= 0 and --max-list >= 0 "
                          f"(got {gap_factor}, {min_gap_s}, {max_list})")
    # the thorough path also recomputes the time-base verdicts from the data (seconds on a long session)
    summary = read_session_info(file, gap_factor=gap_factor, min_gap_s=min_gap_s, verify=verify,
                                verdicts=VerdictSource.DATA if verify else VerdictSource.RECORDED)
    if as_json:
        typer.echo(json.dumps(info_to_json(summary), indent=1))
    else:
        typer.echo(format_info(summary, max_list=max_list), nl=False)


def _print_report(report: ExportReport) -> None:
    from rig.data.info import format_utc
    from rig.export.files import ExportKind

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


class _Format(StrEnum):
    """``rig export --format`` (mirrors :class:`rig.export.ExportFormat`; kept here so ``rig --help`` stays light)."""

    MDF4 = "mdf4"
    PARQUET = "parquet"
    MAT = "mat"
    CSV = "csv"


@contextmanager
def _progress(label: str) -> Iterator[Callable[[int, int, int], None] | None]:
    """A rich progress bar over the session's log time when stderr is a terminal (else no progress)."""
    if not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(label, total=1.0)

        def update(done_ns: int, start_ns: int, end_ns: int) -> None:
            span = max(end_ns - start_ns, 1)
            bar.update(task, completed=min(max((done_ns - start_ns) / span, 0.0), 1.0))

        yield update


def export(
    file: Annotated[Path, typer.Argument(help=_FILE_HELP)],
    fmt: Annotated[
        _Format | None,
        typer.Option("--format", help="mdf4 (ASAM MDF 4 through asammdf: CAN bus logging + channel groups), "
                     "parquet (a dataset per topic group, hive-partitioned by session=NAME), mat (MATLAB v7.3 "
                     "structs, raw CAN frames included, + the sideslip reference/estimate/error), "
                     "csv (decoded tables)."),
    ] = None,
    topics: Annotated[
        list[str] | None,
        typer.Option("--topics", help="Only these topic groups or topics (repeatable; patterns: gnss_*, /can/*)."),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output directory of --format (default: ./export).")]
    = None,
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
    mat_version: Annotated[
        str,
        typer.Option("--mat-version", help="With --format mat: 7.3 (HDF5, streamed with bounded memory; default) "
                     "or 5 (scipy.io: each group held in memory, at most 2 GB per variable)."),
    ] = "7.3",
) -> None:
    """Get data out of a session: CANape/asammdf, pandas/Polars/DuckDB, MATLAB, RTKLIB, NovAtel tools, spreadsheets."""
    from rig.export.csv import export_csv
    from rig.export.files import ExportKind
    from rig.export.mat import export_mat
    from rig.export.mdf4 import export_mdf4
    from rig.export.parquet import export_parquet
    from rig.export.raw_gnss import export_raw_gnss, rtklib_format

    if raw_gnss is None and csv_dir is None and fmt is None:
        raise ConfigError("rig export: say what to export: --format mdf4|parquet|mat|csv [--out DIR], "
                          "--raw-gnss DIR and/or --csv DIR")
    if (topics or out is not None) and fmt is None:
        raise ConfigError("rig export: --topics and --out go with --format")
    if fmt is not None:
        target = out if out is not None else Path("export")
        if fmt is _Format.CSV:
            if topics:
                raise ConfigError("rig export: --topics is not supported with --format csv")
            _print_report(export_csv(file, target, overwrite=overwrite))
        else:
            fn = {_Format.MDF4: export_mdf4, _Format.PARQUET: export_parquet, _Format.MAT: export_mat}[fmt]
            with _progress(f"exporting {fmt.value}") as progress:
                kw = {"version": mat_version} if fmt is _Format.MAT else {}
                report = fn(file, target, topics=topics, overwrite=overwrite, progress=progress, **kw)
            _print_report(report)
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
