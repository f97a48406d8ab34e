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
    from rig.core.config import PORT_BUDGET_WARN, SessionConfig, check_file, port_budget

    cfg = check_file(file)
    if isinstance(cfg, SessionConfig):
        prof = cfg.profile
        typer.echo(
            f"{file}: OK (session: {len(cfg.receivers)} receivers, {len(cfg.can)} CAN buses, "
            f"DAQ {'yes' if cfg.daq else 'no'}, vehicle {prof.vehicle.name!r})"
        )
        for rc in cfg.receivers:
            need, carry = port_budget(rc)
            note = "  WARNING: little margin for an epoch's burst" if need > PORT_BUDGET_WARN * carry else ""
            typer.echo(f"  receivers.{rc.name}: logs need ~{need / 1e3:.1f} of {carry / 1e3:.1f} kB/s at "
                       f"{rc.baud} Bd ({100 * need / carry:.0f} %){note}")
    else:
        typer.echo(f"{file}: OK (vehicle profile {cfg.vehicle.name!r}, {len(cfg.optical)} optical sensors)")
