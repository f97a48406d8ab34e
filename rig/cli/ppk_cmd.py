"""``rig ppk``: post-processed kinematic solutions of a recorded session with RTKLIB (:mod:`rig.ppk.rtklib`).

    rig ppk sessions/2026-05-04_track [--rover rover_a --rover rover_b] [--out FILE] [--keep DIR] [--base FILE]
            [--systems G,R]

Writes ``<session>.ppk.parquet`` (read by ``rig validate`` and the other analyses) and prints each rover's
fix ratio and the systems it was solved with. Without ``--systems``, GPS and GLONASS are used per rover where the
session has their observations and ephemerides; a system left out (an older session without GLOEPHEMERISB) is a
warning on stderr, never an error. With ``--systems``, a system that no rover can use is an error (exit 2); one
that only some rovers lack is a warning. Exit status 0 on success, 2 on an error (missing logs, a system asked
for that cannot be used, RTKLIB not installed, a failed RTKLIB run).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def ppk(
    session: Annotated[Path, typer.Argument(help="The recorded session (its base name or any part).")],
    rover: Annotated[list[str] | None, typer.Option("--rover", help="Rover receiver to process (repeat); "
                                                     "default: every rover of the session.")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Side file to write (default: <session>.ppk.parquet).")]
    = None,
    keep: Annotated[Path | None, typer.Option("--keep", help="Keep RTKLIB's inputs and outputs (RINEX, .pos) in "
                                              "this directory.")] = None,
    timeout_s: Annotated[float, typer.Option("--timeout", help="Seconds each RTKLIB call may take.", min=1.0)]
    = 600.0,
    base: Annotated[Path | None, typer.Option("--base", help="The base's own observations (RINEX 3 obs, or RTCM3 "
                                              "with 1005/1006) instead of the recorded relayed corrections.")] = None,
    mask_deg: Annotated[float, typer.Option("--mask-deg", help="Elevation mask (deg).", min=0.0, max=60.0)] = 10.0,
    systems: Annotated[str | None, typer.Option(
        "--systems", help="Satellite systems to solve with, RINEX letters (G GPS, R GLONASS). Default: G,R where "
        "the session has them (a rover without GLOEPHEMERISB is solved with GPS and a warning). Given explicitly, "
        "a system no rover can use is an error (exit 2); rovers that lack it are solved without it, with a "
        "warning.")] = None,
) -> None:
    """Post-process the rovers' raw observations against the base corrections with RTKLIB (kinematic, combined)."""
    from rig.ppk.rtklib import run_ppk

    res = run_ppk(session, rovers=rover, out=out, work_dir=keep, timeout_s=timeout_s, elevation_mask_deg=mask_deg,
                  base=base, systems=None if systems is None else tuple(
                      x.strip().upper() for x in systems.split(",") if x.strip()))
    for w in res.warnings:
        typer.echo(f"warning: {w}", err=True)
    for r in res.rovers:
        typer.echo(f"{r.rover}: fix ratio {r.fix_ratio:.1%} ({r.fixed} of {r.observation_epochs} epochs fixed, "
                   f"{r.epochs} solved, median {r.satellites_median:g} satellites, "
                   f"{r.systems_text}, {r.glonass_ephemerides} GLONASS ephemerides)")
    typer.echo(f"wrote {res.out}")
