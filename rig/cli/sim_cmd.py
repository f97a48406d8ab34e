"""``rig sim``: run the vehicle-dynamics simulator and write its ground truth (CSV or Parquet).

``rig sim list`` shows the scenarios with their parameters (unit, default, range);
``rig sim run SCENARIO --param NAME=VALUE … --out FILE`` drives one scenario (or ``demo``, the
demo session drive) and writes one row per sample with unit-suffixed columns (``t_s``,
``east_m``, ``lat_deg``, ``beta_cg_deg``, …; see ``sim_devices.vehicle.COLUMNS``).
"""

from __future__ import annotations

import difflib
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from vsccore.errors import ConfigError, SimulationError

if TYPE_CHECKING:
    from sim_devices.vehicle import Drive, Scenario, VehicleParams

# the simulator is imported by the commands (``rig --help`` stays fast); these are
# sim_devices.vehicle.TRUTH_FILE_SUFFIXES' keys (a test keeps them equal)
TRUTH_FILE_SUFFIXES = (".csv", ".parquet", ".pq")

app = typer.Typer(help="Vehicle-dynamics simulator: scenarios and their ground truth.", no_args_is_help=True)

DEMO = "demo"
"""Pseudo-scenario name for :func:`sim_devices.vehicle.demo_drive` (takes no --param)."""


def parse_params(items: list[str], scenario: str) -> dict[str, str]:
    """Turn ``NAME=VALUE`` strings into a dict; raises SimulationError naming the bad ``--param``."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name:
            raise SimulationError(f"--param {item!r}: expected NAME=VALUE (see `rig sim list` for {scenario!r})")
        if name in out:
            raise SimulationError(f"--param {item!r}: parameter {name!r} given twice")
        out[name] = value
    return out


def build_drive(scenario: str, params: dict[str, str]) -> Drive | Scenario:
    """The scenario (or the demo drive) to simulate; raises SimulationError with a did-you-mean hint."""
    from sim_devices.vehicle import SCENARIOS, demo_drive, make_scenario

    if scenario == DEMO:
        if params:
            raise SimulationError(f"scenario {DEMO!r} takes no --param (got {', '.join(params)})")
        return demo_drive()
    if scenario not in SCENARIOS:
        close = difflib.get_close_matches(scenario, [*SCENARIOS, DEMO], n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise SimulationError(
            f"unknown scenario {scenario!r}{hint}; known: {', '.join(SCENARIOS)}, {DEMO} (see `rig sim list`)"
        )
    return make_scenario(scenario, **params)


def load_vehicle(path: Path) -> VehicleParams:
    """Vehicle parameters from a vehicle profile or a session configuration (its ``[vehicle]``)."""
    from rig.core.config import SessionConfig, check_file
    from sim_devices.vehicle import VehicleParams

    cfg = check_file(path)
    vehicle = (cfg.profile if isinstance(cfg, SessionConfig) else cfg).vehicle
    try:
        return VehicleParams.from_mapping(vehicle.model_dump(), section="vehicle")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


@app.command("list")
def list_scenarios() -> None:
    """List the scenarios with their parameters, units and defaults."""
    from sim_devices.vehicle import COLUMNS, SCENARIOS

    for spec in SCENARIOS.values():
        ref = f" [{spec.reference}]" if spec.reference else ""
        typer.echo(f"{spec.name}: {spec.title}{ref}")
        for p in spec.params:
            if p.choices:
                allowed = "|".join(p.choices)
            elif p.minimum is not None and p.maximum is not None:
                allowed = f"{p.minimum:g} … {p.maximum:g}"
            elif p.minimum is not None:
                allowed = f">= {p.minimum:g}"
            elif p.maximum is not None:
                allowed = f"<= {p.maximum:g}"
            else:
                allowed = ""
            typer.echo(f"    {p.name:<16} {p.unit or '-':<6} default {p.describe_default():<6} {allowed:<14} {p.help}")
    typer.echo(f"{DEMO}: the demo session drive (straights both ways, SWA circles, circle, lane change, J-turn)")
    typer.echo("columns written by `rig sim run`: " + ", ".join(COLUMNS))


@app.command("run")
def run(
    scenario: Annotated[str, typer.Argument(help="Scenario name (see `rig sim list`) or 'demo'.")],
    out: Annotated[
        Path, typer.Option("--out", "-o", help=f"Output file: {', '.join(TRUTH_FILE_SUFFIXES)} by its ending.")
    ],
    param: Annotated[
        list[str] | None, typer.Option("--param", "-p", help="Scenario parameter NAME=VALUE (repeatable).")
    ] = None,
    vehicle: Annotated[
        Path | None,
        typer.Option("--vehicle", help="Vehicle profile or session configuration (TOML) whose [vehicle] to use."),
    ] = None,
    rate: Annotated[float, typer.Option("--rate", help="Output rate of the ground truth (Hz).")] = 1000.0,
) -> None:
    """Simulate SCENARIO and write its ground truth to --out (CSV or Parquet, unit-suffixed columns)."""
    from sim_devices.vehicle import VehicleParams, simulate, write_truth

    if out.suffix.lower() not in TRUTH_FILE_SUFFIXES:
        raise SimulationError(
            f"--out {out}: unknown output format {out.suffix or '(no ending)'!r}; "
            f"use one of {', '.join(TRUTH_FILE_SUFFIXES)}"
        )
    if not (rate > 0.0 and rate < float("inf")):
        raise SimulationError(f"--rate must be a positive number of Hz, got {rate!r}")
    drive = build_drive(scenario, parse_params(param or [], scenario))
    params = VehicleParams() if vehicle is None else load_vehicle(vehicle)
    t0 = time.perf_counter()
    truth = simulate(drive, params, rate_hz=rate)
    elapsed = time.perf_counter() - t0
    write_truth(truth, out)
    typer.echo(
        f"{out}: {len(truth)} samples, {truth.t[-1] - truth.t[0]:.1f} s at {rate:g} Hz "
        f"({params.name}; simulated in {elapsed:.2f} s)"
    )
