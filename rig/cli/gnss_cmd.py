"""``rig gnss``: NovAtel receivers at the bench: decode raw captures, watch a live receiver.

``rig gnss decode FILE``: decode a raw capture from a NovAtel receiver port into JSON lines.
The capture may hold any mix of what such a port carries (NovAtel ASCII / abbreviated / binary /
short-binary logs, command responses, prompts, NMEA, RTCM3). Output, one JSON object per line:

- one per frame: ``{"kind": "novatel_binary", "type": "BESTPOS", "header": {...}, "body": {...}}``
  (field names carry their units, enums their names; see :mod:`drivers.novatel.jsonview`),
- a final ``{"kind": "summary", "frames": {kind: n}, "bytes_skipped": {reason: n}, "crc_failures":
  {kind: n}, …}`` with the frames by kind and the rejected bytes by reason.

``rig gnss monitor PORT``: a live view of one receiver (solution status and type, satellites,
position with its standard deviations, speed and course, differential age, message rates by type,
CRC failures and rejected bytes, connection state, last error), built on
:class:`drivers.novatel.receiver.NovatelReceiver` and its ``health()``. It requests a few logs on
the port it is connected to (``--log NAME@PERIOD``; ``--no-configure`` only listens), shows a rich
table on a terminal and prints one plain line per interval otherwise, and stops on Ctrl-C or after
``--duration``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from vsccore.errors import DeviceError, SessionFileError

if TYPE_CHECKING:  # the NovAtel driver and rich are imported where used: ``rig --help`` stays fast

    pass

app = typer.Typer(help="GNSS receivers (NovAtel): decode raw captures, watch a live receiver.", no_args_is_help=True)


@app.command("decode")
def decode(
    file: Annotated[str, typer.Argument(help="Raw capture file, or '-' for standard input.")],
    summary_only: Annotated[bool, typer.Option("--summary-only", help="Print only the summary line.")] = False,
) -> None:
    """Decode FILE (any mix of NovAtel logs, responses, NMEA, RTCM3) and print one JSON object per message."""
    from rig.data.gnss_capture import decode_capture

    try:
        if file == "-":
            decode_capture(sys.stdin.buffer, sys.stdout, summary_only=summary_only)
            return
        path = Path(file)
        try:
            handle = path.open("rb")
        except OSError as exc:
            raise SessionFileError(f"{path}: cannot read capture: {exc.strerror or exc}") from None
        with handle:
            decode_capture(handle, sys.stdout, summary_only=summary_only)
    except BrokenPipeError:  # output piped into head & co.: stop quietly (Python docs' recipe)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        raise typer.Exit(0) from None


# --- rig gnss monitor ----------------------------------------------------------------------------

#: Logs requested when no ``--log`` is given: position and velocity at 20 Hz, time (leap seconds).
DEFAULT_MONITOR_LOGS = ("BESTPOSB@0.05", "BESTVELB@0.05", "TIMEB@1")


@app.command("monitor")
def monitor(
    port: Annotated[str, typer.Argument(help="Serial device or pyserial URL of the receiver.")],
    baud: Annotated[int, typer.Option("--baud", min=1, help="Baud rate (the first one tried with --autobaud).")] = (
        115200
    ),
    logs: Annotated[
        list[str] | None,
        typer.Option(
            "--log",
            help="Log to request on this port, NAME@PERIOD_S or NAME@TRIGGER; repeat for several. "
            f"Default: {' '.join(DEFAULT_MONITOR_LOGS)}.",
        ),
    ] = None,
    duration: Annotated[float | None, typer.Option("--duration", min=0.0, help="Stop after this many seconds.")] = (
        None
    ),
    configure: Annotated[
        bool,
        typer.Option("--configure/--no-configure", help="Request the logs (else only listen to what the port sends)."),
    ] = True,
    autobaud: Annotated[bool, typer.Option("--autobaud", help="Detect the receiver's baud rate.")] = False,
    interval: Annotated[
        float, typer.Option("--interval", min=0.05, help="Seconds between status lines when output is not a terminal.")
    ] = 1.0,
) -> None:
    """Live view of one NovAtel receiver for bench checks: solution, satellites, position, speed, rates, errors.

    Stops on Ctrl-C or after --duration. On a terminal the view is a table; otherwise one line per --interval.
    """
    from rich.console import Console

    from drivers.novatel.receiver import ReceiverSettings
    from rig.live.gnss_monitor import (
        ReceiverMonitor,
        last_error_text,
        monitor_commands,
        monitor_line,
        parse_log_option,
        run_monitor,
    )

    requests = [parse_log_option(text) for text in (logs or DEFAULT_MONITOR_LOGS)]
    commands = monitor_commands(requests) if configure else ()
    name = Path(port).name or port
    settings = ReceiverSettings(name=name, port=port, baud=baud, commands=commands, autobaud=autobaud)
    session = ReceiverMonitor(settings, configure=configure)
    console = Console()
    err = Console(stderr=True)
    interrupted = False
    try:
        final = run_monitor(session, duration_s=duration, interval_s=interval, console=console,
                            live=console.is_terminal)
    except KeyboardInterrupt:  # run_monitor has stopped the session in its finally
        interrupted = True
        final = session.snapshot()
    if not console.is_terminal:
        console.print(monitor_line(final), highlight=False, soft_wrap=True, markup=False)
    if interrupted:
        err.print("gnss monitor: stopped (Ctrl-C)", highlight=False)
    if final.health.connection == 0:
        raise DeviceError(
            f"NovAtel receiver {name} on {port}: never connected ({last_error_text(final)})"
        )
