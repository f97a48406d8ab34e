"""``rig preflight``: every device of a session configuration checked in the car park, GO / NO-GO per device.

    rig preflight car.toml                                  # the real devices, up to 60 s
    rig preflight rig/examples/sim.toml --set simulation.speed=8 --wait 30 --json

A configuration with a ``[simulation]`` table is checked on its simulated car: the simulated world is started
and passes its ports, CAN adapter and DAQ to the check, as it does to ``rig sim record``'s recording.
Exit status 0 when every device is GO, 1 on a NO-GO, 2 on a configuration error.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from rig.core.config import SessionConfig
    from rig.record.preflight import DeviceResult, PreflightReport

# the drivers, the simulator and rich are imported by the command (``rig --help`` stays fast); these equal
# rig.record.preflight's DEFAULT_WAIT_S and DEFAULT_DURATION_MIN
DEFAULT_WAIT_S = 60.0
DEFAULT_DURATION_MIN = 60.0
SIM_LEAD_S = 1.0
"""Simulated seconds before the simulated drive starts (the ECU sends from the drive's start on)."""


def preflight(
    config: Annotated[Path, typer.Argument(help="Session configuration (TOML).")],
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="Override a configuration key: KEY=VALUE (repeatable).")
    ] = None,
    wait: Annotated[float, typer.Option(
        "--wait", min=0.1,
        help="Longest wait for every device to be GO (s of the session clock: simulated time on a simulated car).",
    )] = DEFAULT_WAIT_S,
    duration_min: Annotated[float, typer.Option("--duration-min", min=0.0,
                                                help="Planned recording time the free disk must hold.")]
    = DEFAULT_DURATION_MIN,
    out: Annotated[Path | None, typer.Option("--out", help="Folder the session will be written to (default: "
                                             "the configuration's output directory).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as a JSON document.")] = False,
    device_process: Annotated[bool, typer.Option(
        "--device-process/--one-process",
        help="Simulated car: its receivers and ECU in a process of their own (as `rig sim record`), or in this one.",
    )] = False,
) -> None:
    """Check every device of CONFIG before the first run: GO / NO-GO per device with the reason and the fix."""
    from rig.core.config import load_session, parse_override

    overrides = dict(parse_override(item) for item in (set_ or []))
    cfg = load_session(config, overrides)
    with _progress(as_json) as tick:
        kwargs: dict[str, Any] = {"config_name": str(config), "wait_s": wait, "duration_min": duration_min,
                                  "out_dir": out, "on_tick": tick}
        report = (_simulated(cfg, device_process, kwargs) if cfg.simulation is not None else _real(cfg, kwargs))
    if as_json:
        typer.echo(json.dumps(report.to_json(), indent=2, ensure_ascii=False))
    elif sys.stdout.isatty():
        _rich_table(report)
    else:
        for line in plain_lines(report):
            typer.echo(line)
    raise typer.Exit(0 if report.go else 1)


def _real(cfg: SessionConfig, kwargs: dict[str, Any]) -> PreflightReport:
    from rig.record.preflight import run_preflight

    return run_preflight(cfg, **kwargs)


def _simulated(cfg: SessionConfig, device_process: bool, kwargs: dict[str, Any]) -> PreflightReport:
    """The check on the configuration's simulated car, through the world's ports, CAN adapter and DAQ."""
    from rig.record.preflight import run_preflight
    from rig.sim.world import GOVERNED_SWITCH_INTERVAL_S, SimWorld

    world = SimWorld(cfg, lead_s=SIM_LEAD_S, device_process=device_process)
    switch = sys.getswitchinterval()
    if world.governed:  # readers that wake for their data must get the interpreter soon (as rig sim record)
        sys.setswitchinterval(min(switch, GOVERNED_SWITCH_INTERVAL_S))
    try:
        world.start()
        assert world.clock is not None
        try:
            return run_preflight(cfg, clock=world.clock, ports=world, daq_factory=world.daq_session,
                                 can_factory=world.can_bus, simulated=True, **kwargs)
        finally:
            if world.clock.governor is not None:
                world.clock.governor.release()
    finally:
        sys.setswitchinterval(switch)
        world.stop()


@contextmanager
def _progress(quiet: bool) -> Iterator[Callable[[Sequence[DeviceResult], float], None] | None]:
    """A status line on stderr while the check runs (a terminal only)."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console

    console = Console(stderr=True)
    with console.status("preflight: opening the devices …") as status:

        def tick(results: Sequence[DeviceResult], watched_s: float) -> None:
            waiting = [r.device for r in results if r.verdict.value != "GO"]
            status.update(f"preflight {watched_s:.0f} s: {len(results) - len(waiting)} of {len(results)} GO"
                          + (f", waiting for {', '.join(waiting)}" if waiting else ""))

        yield tick


def _summary(report: PreflightReport) -> str:
    n = len(report.devices)
    bad = [d.device for d in report.devices if d.verdict.value != "GO"]
    where = "simulated car, " if report.simulated else ""
    if not bad:
        return (f"preflight: GO — all {n} devices ({where}GO after {report.time_to_go_s:.1f} s of the session clock, "
                f"{report.wall_s:.1f} s wall)")
    return (f"preflight: NO-GO — {len(bad)} of {n} devices ({', '.join(bad)}) after {report.watched_s:.1f} s "
            f"({where}{report.wall_s:.1f} s wall)")


def plain_lines(report: PreflightReport) -> list[str]:
    """The result as plain text: one line per device (verdict, device, reason), its fix, a summary."""
    width = max((len(d.device) for d in report.devices), default=6)
    lines = []
    for d in report.devices:
        lines.append(f"{d.verdict.value:<5}  {d.device:<{width}}  {d.reason}")
        if d.fix:
            lines.append(f"{'':<5}  {'':<{width}}  fix: {d.fix}")
    lines.append(_summary(report))
    return lines


def _rich_table(report: PreflightReport) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=f"rig preflight {report.config}", show_lines=True)
    table.add_column("device", no_wrap=True)
    table.add_column("", no_wrap=True)
    table.add_column("checks")
    table.add_column("fix")
    for d in report.devices:
        go = d.verdict.value == "GO"
        checks = "\n".join(f"{'[green]✓[/]' if c.ok else '[red]✗[/]'} {escape(c.name)}: {escape(c.detail)}"
                           for c in d.checks)
        table.add_row(escape(d.device), "[green]GO[/]" if go else "[bold red]NO-GO[/]", checks, escape(d.fix))
    console = Console()
    console.print(table)
    console.print(_summary(report), highlight=False)
