"""Entry point of the ``rig`` command.

Each command parses its options, calls one library function and lets :class:`RigError` escape;
:func:`main` turns it into one line on stderr and exit status 2 (``--debug`` shows the traceback).

Start-up: the command modules are registered by name (:data:`COMMANDS`) and imported only when their
command runs or shows its help; ``rig --help`` and ``rig --version`` are answered from that table
without importing typer at all (typer, rich and the command tree cost most of a second on a loaded
laptop). ``app`` (the complete typer app, for tests and tools) is built on first access.
"""

from __future__ import annotations

import os
import sys
import textwrap
from importlib import import_module
from typing import TYPE_CHECKING, Any, NamedTuple

from vsccore import __version__
from vsccore.errors import RigError

if TYPE_CHECKING:
    import typer

APP_HELP = "vsc-rig: record, calibrate and validate vehicle-stability-control road tests."
VERSION_HELP = "Show the version."
DEBUG_HELP = "Show tracebacks and debug logs."
TRACE_FRAMES_HELP = "Log every CAN frame sent and received (debug level; implies --debug)."
HELP_HELP = "Show this message and exit."


class Command(NamedTuple):  # not a dataclass: `rig --help` would pay for importing dataclasses/inspect
    """A command (or command group) of ``rig``, registered without importing its module."""

    name: str
    module: str
    """The ``rig.cli`` module that implements it."""
    attr: str | None
    """Its function (a command) or typer app (a group) in ``module``; None: ``module.register(app)`` adds it."""
    help: str
    """The one-line help ``rig --help`` shows (tests/test_cli_startup.py keeps it equal to the command's own)."""


COMMANDS: tuple[Command, ...] = (
    Command("demo", "rig.cli.demo_cmd", "demo",
            "Simulate a test day with simulated devices, then show what each stage produced."),
    Command("relay", "rig.cli.relay_cmd", "relay",
            "Relay RTK corrections (RTCM3, RTCA, CMR) from a source to rover ports until Ctrl-C, the end of a "
            "file source, or --duration. SOURCE/SINK: /dev/ttyUSB0[@BAUD], "
            "ntrip://user:password@host:port/MOUNT (source only), tcp://host:port, file:PATH[@BAUD]."),
    Command("recover", "rig.cli.recover_cmd", "recover",
            "Write a finalized, indexed copy of FILE with every intact chunk: before and after any damage, up to "
            "its last complete record. Also removes the disk-space reserve a killed recorder left beside it."),
    Command("layout", "rig.cli.layout_cmd", "layout",
            "Write the Foxglove layout (import it in Foxglove: Layouts → Import from file)."),
    Command("preflight", "rig.cli.preflight_cmd", "preflight",
            "Check every device of CONFIG before the first run: GO / NO-GO per device with the reason and the fix."),
    Command("record", "rig.cli.record_cmd", "record",
            "Record every device of CONFIG (receivers, correction relay, CAN, DAQ) into one MCAP session file "
            "until Ctrl-C, SIGTERM or --duration."),
    Command("replay", "rig.cli.replay_cmd", "replay",
            "Play the recorded CAN frames of SESSION onto a live bus at their recorded times (HIL: drive a bench "
            "ECU with a road test). Frames go out byte-exact, counters and checksums as recorded; faults rewrite "
            "one signal each and reseal the checksum. Prints the plan, then the send-lateness figures at the end."),
    Command("info", "rig.cli.info_cmd", None,
            "Duration, topics with counts and rates, devices, gaps, time-base quality, calibration and events."),
    Command("export", "rig.cli.info_cmd", None,
            "Get data out of a session: CANape/asammdf, pandas/Polars/DuckDB, MATLAB, RTKLIB, NovAtel tools, "
            "spreadsheets."),
    Command("calibrate-baseline", "rig.cli.calibrate_cmd", None,
            "Antenna mounting offset from straight runs (heading of the baseline A→B minus the course over "
            "ground)."),
    Command("calibrate-steering-ratio", "rig.cli.calibrate_cmd", None,
            "Steering ratio SWA/δ per steering-wheel angle, forward and reverse, from circles at constant SWA."),
    Command("calibrate-imu", "rig.cli.calibrate_cmd", None,
            "Accelerometer and gyroscope calibration: bias, scale factors and misalignment (measured = M·true + b)."),
    Command("validate", "rig.cli.analysis_cmd", None,
            "Score the VSC sideslip estimate of SESSION against the GNSS (and optical) reference."),
    Command("ppk", "rig.cli.ppk_cmd", "ppk",
            "Post-process the rovers' raw observations against the base corrections with RTKLIB (kinematic, "
            "combined)."),
    Command("campaign", "rig.cli.campaign_cmd", "campaign",
            "Validate every session of a campaign as Dask tasks: one Parquet metrics table and an HTML trend report."),
    Command("rollover", "rig.cli.analysis_cmd", None,
            "Load-transfer ratio from the CAN lateral acceleration and the roll model, predicted 1, 2 and 3 s "
            "ahead."),
    Command("sim", "rig.cli.sim_cmd", "app", "Vehicle-dynamics simulator: scenarios and their ground truth."),
    Command("gnss", "rig.cli.gnss_cmd", "app", "GNSS receivers (NovAtel): decode raw captures, watch a live receiver."),
    Command("config", "rig.cli.config_cmd", "app", "Validate session configurations and vehicle profiles."),
    Command("can", "rig.cli.can_cmd", "app",
            "CAN tools: decode logs with a DBC and a role mapping, watch a live bus, run the simulated VSC ECU."),
    Command("steering-ratio", "rig.cli.calibrate_cmd", None, "Steering ratio from tape measurements."),
    Command("steering", "rig.cli.analysis_cmd", None,
            "Steering-angle reconstruction from GNSS speed and lateral acceleration."),
)
"""Every command of ``rig``, in the order ``rig --help`` lists them (README "Command tour")."""

_BY_NAME = {c.name: c for c in COMMANDS}

FRAME_LOGGER = "can"
"""python-can's logger tree: its interfaces log every frame sent and received at DEBUG level
(socketcand: "Received Ascii Message", socketcan: "sending: …"), so it stays at INFO unless
``--trace-frames`` asks for the frames."""

_state = {"debug": False}
_app: typer.Typer | None = None
_registered: set[str] = set()
"""Command modules (and groups) already attached to ``_app``: each is attached once per process."""


def _version_callback(value: bool) -> None:
    if value:
        import typer

        typer.echo(f"vsc-rig {__version__}")
        raise typer.Exit()


def _new_app() -> typer.Typer:
    import typer

    app = typer.Typer(
        name="rig",
        help=APP_HELP,
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
    )

    # options as defaults, not Annotated: typer resolves the (postponed) annotations in this module's
    # globals, where typer is not imported (``rig --help`` must not import it)
    @app.callback()
    def _root(
        version: bool = typer.Option(False, "--version", callback=_version_callback, is_eager=True,
                                     help=VERSION_HELP),
        debug: bool = typer.Option(False, "--debug", help=DEBUG_HELP),
        trace_frames: bool = typer.Option(False, "--trace-frames", help=TRACE_FRAMES_HELP),
    ) -> None:
        """vsc-rig: record, calibrate and validate vehicle-stability-control road tests."""
        import logging

        debug = debug or trace_frames
        _state["debug"] = debug
        logging.basicConfig(
            level=logging.DEBUG if debug else logging.WARNING,
            format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        )
        # thousands of lines a second on a live bus: only on request
        logging.getLogger(FRAME_LOGGER).setLevel(logging.NOTSET if trace_frames else logging.INFO)

    return app


def _attach(app: typer.Typer, cmd: Command) -> None:
    """Import ``cmd``'s module and attach what it implements (once per process)."""
    key = cmd.module if cmd.attr is None else f"{cmd.module}:{cmd.attr}:{cmd.name}"
    if key in _registered:
        return
    _registered.add(key)
    module = import_module(cmd.module)
    if cmd.attr is None:
        module.register(app)  # the module attaches its commands (rig info + rig export, rig calibrate-*, …)
        return
    obj = getattr(module, cmd.attr)
    if callable(obj) and not hasattr(obj, "registered_commands"):
        app.command(cmd.name)(obj)
        return
    if cmd.name == "sim":  # `rig sim record` lives with `rig record`
        from rig.cli import record_cmd

        obj.command("record")(record_cmd.sim_record)
    app.add_typer(obj, name=cmd.name)


def build_app(names: Any = None) -> typer.Typer:
    """The ``rig`` typer app with the commands ``names`` attached (None: every command).

    One app per process; commands attached earlier stay attached.
    """
    global _app
    if _app is None:
        _app = _new_app()
    for cmd in COMMANDS:
        if names is None or cmd.name in names:
            _attach(_app, cmd)
    return _app


def __getattr__(name: str) -> Any:
    if name == "app":  # the complete app (tests, tools): every command module imported
        return build_app()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _command_of(args: list[str]) -> str | None:
    """The command that ``args`` run (the first word that is not a root option), or None."""
    for a in args:
        if not a.startswith("-"):
            return a
    return None


def _columns() -> int:
    """The terminal width as rich sees it: ``COLUMNS``, else the terminal's, else 80 (shutil, which does
    the same, imports compression modules)."""
    try:
        return int(os.environ["COLUMNS"])
    except (KeyError, ValueError):
        pass
    try:
        return os.get_terminal_size(sys.stdout.fileno()).columns
    except (OSError, ValueError, AttributeError):
        return 80


def _fast_help() -> str:
    """``rig --help`` without typer: the same panels as typer's rich help, plain text."""
    width = max(60, _columns())
    try:
        "╭─│╰╮╯".encode(sys.stdout.encoding or "ascii")
        tl, tr, bl, br, h, v = "╭", "╮", "╰", "╯", "─", "│"
    except (UnicodeEncodeError, LookupError):
        tl, tr, bl, br, h, v = "+", "+", "+", "+", "-", "|"

    def panel(title: str, rows: list[tuple[str, str]]) -> list[str]:
        left = max(len(k) for k, _ in rows) + 2
        inner = width - 4
        out = [f"{tl}{h} {title} " + h * (width - len(title) - 5) + tr]
        for key, text in rows:
            lines = textwrap.wrap(text, max(20, inner - left)) or [""]
            for i, line in enumerate(lines):
                cell = (key if i == 0 else "").ljust(left) + line
                out.append(f"{v} {cell.ljust(inner)} {v}")
        out.append(bl + h * (width - 2) + br)
        return out

    lines = ["", " Usage: rig [OPTIONS] COMMAND [ARGS]...", ""]
    lines += [" " + t for t in textwrap.wrap(APP_HELP, width - 2)] + [""]
    lines += panel("Options", [("--version", VERSION_HELP), ("--debug", DEBUG_HELP),
                               ("--trace-frames", TRACE_FRAMES_HELP), ("--help", HELP_HELP)])
    lines += panel("Commands", [(c.name, c.help) for c in COMMANDS])
    text = "\n".join(lines) + "\n"
    encoding = sys.stdout.encoding or "ascii"
    try:  # what the terminal cannot show (→, δ, ·) becomes "?", as a crash would help nobody
        return text.encode(encoding, "replace").decode(encoding)
    except LookupError:
        return text


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
    if args == ["--help"]:  # answered from COMMANDS: no typer, no command module
        sys.stdout.write(_fast_help())
        sys.exit(0)
    if args == ["--version"]:
        sys.stdout.write(f"vsc-rig {__version__}\n")
        sys.exit(0)
    import typer

    debug = "--debug" in args or "--trace-frames" in args
    try:
        name = _command_of(args)
        # only the command that runs is imported (an unknown one: all, so that typer names the choices);
        # a module attribute ``app`` set from outside (a test's stand-in) runs instead
        app = globals().get("app") or build_app(None if name not in _BY_NAME else {name})
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
