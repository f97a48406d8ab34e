"""``rig layout``: write the Foxglove layout of a session (map, β reference against the VSC estimate,
yaw rate, a_y, SWA, speed, RTK status, LTR, events; see :mod:`rig.live.layout`).

    rig layout --out vsc-rig.json                 # the demo names (rover_a, rover_b, bus vsc)
    rig layout --config car.toml --out car.json   # the receivers and CAN bus of a configuration
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from vsccore.errors import ConfigError


def layout(
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Write the layout here (default: stdout).")] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="Session configuration whose receivers and CAN bus to use.")
    ] = None,
    bus: Annotated[
        str | None, typer.Option("--bus", help="CAN bus carrying the VSC roles (default: the first).")
    ] = None,
) -> None:
    """Write the Foxglove layout (import it in Foxglove: Layouts → Import from file)."""
    from rig.live.layout import layout_json, session_layout

    if config is None:
        text = layout_json(session_layout(bus=bus or "vsc"))
    else:
        from rig.core.config import load_session

        cfg = load_session(config)
        ant = {r.antenna: r.name for r in cfg.receivers if r.role == "rover" and r.antenna}
        missing = [a for a in ("a", "b") if a not in ant]
        if missing:
            raise ConfigError(f"{config}: no rover receiver with antenna {' or '.join(missing)} (receivers.antenna)")
        buses = [c.name for c in cfg.can]
        if bus is None and not buses:
            raise ConfigError(f"{config}: no [[can]] bus; give --bus NAME")
        if bus is not None and buses and bus not in buses:
            raise ConfigError(f"--bus {bus}: not a CAN bus of {config} ({', '.join(buses)})")
        text = layout_json(session_layout(ant["a"], ant["b"], bus or buses[0]))
    if out is None:
        typer.echo(text, nl=False)
    else:
        try:
            out.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"--out {out}: cannot write the layout: {exc.strerror}") from None
        typer.echo(f"{out}: Foxglove layout", err=True)
