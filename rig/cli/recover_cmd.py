"""``rig recover FILE``: a finalized, indexed copy of a session part that a crash left unfinished."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def recover(
    file: Annotated[Path, typer.Argument(help="The session part (.mcap) to recover.", exists=True, dir_okay=False)],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Where to write the copy (default: FILE.recovered.mcap).")
    ] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an existing output file.")] = False,
) -> None:
    """Write a finalized, indexed copy of FILE with everything up to its last complete record."""
    from rig.recorder.recover import recover as recover_part

    report = recover_part(file, out, overwrite=overwrite)
    if report.was_finalized:
        typer.echo(f"{file} was already finalized; copied to {report.path} ({report.messages} messages)")
        return
    typer.echo(
        f"recovered {report.messages} messages in {report.chunks} chunks from {file} -> {report.path} "
        f"({report.dropped_bytes} trailing bytes dropped: {report.problem})"
    )
