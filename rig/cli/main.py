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

FRAME_LOGGER = "can"
"""python-can's logger tree: its interfaces log every frame sent and received at DEBUG level
(socketcand: "Received Ascii Message", socketcan: "sending: …"), so it stays at INFO unless
``--trace-frames`` asks for the frames."""


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
    trace_frames: Annotated[
        bool,
        typer.Option("--trace-frames", help="Log every CAN frame sent and received (debug level; implies --debug)."),
    ] = False,
) -> None:
    """vsc-rig: record, calibrate and validate vehicle-stability-control road tests."""
    debug = debug or trace_frames
    _state["debug"] = debug
    logging.basicConfig(
        level=logging.DEBUG if debug else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    # thousands of lines a second on a live bus: only on request
    logging.getLogger(FRAME_LOGGER).setLevel(logging.NOTSET if trace_frames else logging.INFO)


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
        layout_cmd,
        record_cmd,
        recover_cmd,
        relay_cmd,
        replay_cmd,
        sim_cmd,
    )

    app.add_typer(sim_cmd.app, name="sim")
    app.add_typer(gnss_cmd.app, name="gnss")
    app.add_typer(config_cmd.app, name="config")
    app.add_typer(can_cmd.app, name="can")
    app.command("demo")(demo_cmd.demo)
    app.command("relay")(relay_cmd.relay)
    app.command("recover")(recover_cmd.recover)
    app.command("layout")(layout_cmd.layout)
    app.command("record")(record_cmd.record)
    app.command("replay")(replay_cmd.replay)
    sim_cmd.app.command("record")(record_cmd.sim_record)
    info_cmd.register(app)  # rig info, rig export
    calibrate_cmd.register(app)  # rig calibrate-*, steering-ratio
    analysis_cmd.register(app)  # rig validate, rig rollover, rig steering


_register()


def _usage_line(exc: typer.TyperException) -> str:
    """One line for a usage error: the command it concerns, the message and where to look."""
    ctx = getattr(exc, "ctx", None)
    command = ctx.command_path if ctx is not None else "rig"
    message = " ".join(exc.format_message().split())  # one line, whatever the message held
    return f"{command}: error: {message} (see '{command} --help')"


def main(argv: list[str] | None = None) -> None:
    """Run the CLI and turn every way it can end into an exit status and at most one line on stderr.

    - project errors (:class:`RigError`): ``rig: error: …``, status 2;
    - usage errors (unknown option, missing or bad parameter): ``rig CMD: error: …``, status 2;
    - any other exception: ``rig: internal error: …``, status 1;
    - ``--debug`` re-raises project and unexpected errors, so Python prints the traceback.
    """
    args = argv if argv is not None else sys.argv[1:]
    debug = "--debug" in args or "--trace-frames" in args
    try:
        # without standalone mode typer returns a command's exit code instead of exiting with it
        code = app(args=args, standalone_mode=False, prog_name="rig")
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
    except typer.TyperException as exc:  # usage errors (exit code 2) and file-argument errors
        if _is_help_request(exc):
            # `rig`, `rig sim`: a group without a command shows its help (rich has printed it already)
            text = exc.format_message()
            if text.strip():
                typer.echo(text, err=True)
        else:
            typer.echo(_usage_line(exc), err=True)
        sys.exit(exc.exit_code)
    except Exception as exc:
        if debug:
            raise
        detail = " ".join(str(exc).split()) or "(no message)"
        hint = "run with --debug for the traceback"
        typer.echo(f"rig: internal error: {type(exc).__name__}: {detail} ({hint})", err=True)
        sys.exit(1)
    if isinstance(code, int) and code != 0:
        sys.exit(code)


def _is_help_request(exc: typer.TyperException) -> bool:
    """A group called without a command (``no_args_is_help``): typer raises it as a usage error."""
    return type(exc).__name__ == "NoArgsIsHelpError"
