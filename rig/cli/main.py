"""Entry point of the ``rig`` command.

Each command parses its options, calls one library function and lets :class:`RigError` escape;
:func:`main` turns it into one line on stderr and exit status 2 (``--debug`` shows the traceback).
"""

from __future__ import annotations

import logging
import sys
from typing import Annotated

import typer

from vsccore import __version__
from vsccore.errors import RigError

app = typer.Typer(
    name="rig",
    help="vsc-rig: record, calibrate and validate vehicle-stability-control road tests.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

_state = {"debug": False}


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"vsc-rig {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version_callback, is_eager=True, help="Show the version."),
    ] = False,
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks and debug logs.")] = False,
) -> None:
    """vsc-rig: record, calibrate and validate vehicle-stability-control road tests."""
    _state["debug"] = debug
    logging.basicConfig(
        level=logging.DEBUG if debug else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )


def _register() -> None:
    """Attach the command groups (each lives in its own module)."""
    from rig.cli import (
        analysis_cmd,
        calibrate_cmd,
        can_cmd,
        config_cmd,
        demo_cmd,
        gnss_cmd,
        info_cmd,
        record_cmd,
        recover_cmd,
        relay_cmd,
        sim_cmd,
    )

    app.add_typer(sim_cmd.app, name="sim")
    app.add_typer(gnss_cmd.app, name="gnss")
    app.add_typer(config_cmd.app, name="config")
    app.add_typer(can_cmd.app, name="can")
    app.command("demo")(demo_cmd.demo)
    app.command("relay")(relay_cmd.relay)
    app.command("recover")(recover_cmd.recover)
    app.command("record")(record_cmd.record)
    sim_cmd.app.command("record")(record_cmd.sim_record)
    info_cmd.register(app)  # rig info, rig export
    calibrate_cmd.register(app)  # rig calibrate-*, steering-ratio
    analysis_cmd.register(app)  # rig validate, rig rollover, rig steering


_register()


def main(argv: list[str] | None = None) -> None:
    """Run the CLI; project errors become one line on stderr and exit status 2."""
    debug = "--debug" in (argv if argv is not None else sys.argv[1:])
    try:
        # without standalone mode click returns a command's exit code instead of exiting with it
        code = app(args=argv, standalone_mode=False)
    except RigError as exc:
        if debug:
            raise
        typer.echo(f"rig: error: {exc}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.echo("rig: interrupted", err=True)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("rig: aborted", err=True)
        sys.exit(1)
    except Exception as exc:  # click usage errors carry their own exit code
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            sys.exit(exc.exit_code)
        raise
    if isinstance(code, int) and code != 0:
        sys.exit(code)
