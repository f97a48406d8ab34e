"""``rig recover FILE``: a finalized, indexed copy of a session part that a crash left unfinished or damage hit."""

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
    """Write a finalized, indexed copy of FILE with every intact chunk: before and after any damage, up to
    its last complete record. Also removes the disk-space reserve a killed recorder left beside it."""
    from rig.store.recover import recover as recover_part

    report = recover_part(file, out, overwrite=overwrite)
    if report.was_finalized:
        typer.echo(f"{file} was already finalized and every chunk CRC checks out; copied to {report.path} "
                   f"({report.messages} messages)")
        return
    typer.echo(f"recovered {report.messages} messages in {report.chunks} chunks from {file} -> {report.path}")
    if report.damage:
        typer.echo(f"damaged: {report.damaged_chunks} chunks, {report.damaged_s:.3f} s of data "
                   f"(left out; every intact chunk before and after kept)")
        for d in report.damage:
            typer.echo(f"  ! {d.describe()}")
    if report.truncation is not None:
        typer.echo(f"truncated: {report.truncation} ({report.dropped_bytes} bytes dropped in all)")
