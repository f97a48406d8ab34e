"""``rig demo``: run the whole chain on simulated devices into one folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def demo(
    out: Annotated[Path, typer.Option("--out", help="Folder for everything the demo writes.")] = Path("demo-out"),
    fast: Annotated[bool, typer.Option("--fast", help="Shorter test programme (as in CI).")] = False,
    config: Annotated[
        Path | None, typer.Option("--config", help="Session configuration of a simulated car (default: shipped).")
    ] = None,
) -> None:
    """Simulate a test day with simulated devices, then show what each stage produced."""
    from rig.workflows.demo import run_demo

    result = run_demo(out, fast=fast, config=config)
    for stage in result.stages:
        typer.echo(f"[{stage.name}] {stage.summary} ({stage.seconds:.1f} s)")
        for f in stage.files:
            typer.echo(f"    {f}")
    typer.echo(f"demo finished: {result.out_dir}")
