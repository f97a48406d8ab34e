"""``rig config``: validate session configurations and vehicle profiles."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="Validate session configurations and vehicle profiles.", no_args_is_help=True)


@app.command("check")
def check(
    file: Annotated[Path, typer.Argument(help="A session configuration or vehicle profile (TOML).")],
) -> None:
    """Validate FILE and report every problem with its key path and line."""
    from rig.core.config import SessionConfig, check_file

    cfg = check_file(file)
    if isinstance(cfg, SessionConfig):
        prof = cfg.profile
        typer.echo(
            f"{file}: OK (session: {len(cfg.receivers)} receivers, {len(cfg.can)} CAN buses, "
            f"DAQ {'yes' if cfg.daq else 'no'}, vehicle {prof.vehicle.name!r})"
        )
    else:
        typer.echo(f"{file}: OK (vehicle profile {cfg.vehicle.name!r}, {len(cfg.optical)} optical sensors)")
