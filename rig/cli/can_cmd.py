"""``rig can``: CAN tools. ``rig can decode`` turns a CAN log into signal values (CSV or JSON lines,
:mod:`rig.data.can_log`), ``rig can monitor`` watches a live bus, ``rig can sim-ecu`` serves the simulated
VSC ECU over socketcand."""

from __future__ import annotations

import sys
from contextlib import ExitStack
from enum import StrEnum
from pathlib import Path
from typing import IO, TYPE_CHECKING, Annotated

import typer

from vsccore.errors import ConfigError, SessionFileError

if TYPE_CHECKING:  # the CAN drivers (cantools, python-can) are imported by the commands: ``rig --help`` stays fast

    pass

app = typer.Typer(
    help="CAN tools: decode logs with a DBC and a role mapping, watch a live bus, run the simulated VSC ECU.",
    no_args_is_help=True,
)


class OutputFormat(StrEnum):
    """Output file format of ``rig can decode``."""

    CSV = "csv"
    JSONL = "jsonl"


@app.command("decode")
def decode(
    log: Annotated[Path, typer.Argument(help="CAN log: candump .log, .asc, .blf, .trc, .csv, .db, .mf4 (or .gz).")],
    dbc: Annotated[
        Path | None,
        typer.Option("--dbc", help="DBC file (optional when --roles is a session config naming one)."),
    ] = None,
    roles: Annotated[
        Path | None,
        typer.Option("--roles", help="Roles file or session config: output roles in SI instead of all signals."),
    ] = None,
    bus: Annotated[str | None, typer.Option("--bus", help="[[can]] bus name when --roles has several.")] = None,
    channel: Annotated[
        list[str] | None,
        typer.Option("--channel", help="Decode only this log channel (repeatable): Vector 1, 2, …; candump can0."),
    ] = None,
    channel_map: Annotated[
        Path | None,
        typer.Option("--channel-map", help='TOML giving each log channel its DBC (and roles): [channels."1"] '
                     'dbc = "powertrain.dbc", roles = "roles.toml". Instead of --dbc/--roles.'),
    ] = None,
    fmt: Annotated[OutputFormat, typer.Option("--format", help="Output format.")] = OutputFormat.CSV,
    out: Annotated[Path | None, typer.Option("--out", help="Output file (default: standard output).")] = None,
) -> None:
    """Decode LOG with a DBC: every signal (DBC units), or with --roles the mapped roles in SI units.

    Every channel of a multi-channel log is decoded on its own; --channel-map gives each its DBC.
    """
    from rig.data.can_log import decode_log

    with ExitStack() as stack:
        if out is None:
            stream: IO[str] = sys.stdout
        else:
            try:
                stream = stack.enter_context(out.open("w", encoding="utf-8", newline=""))
            except OSError as exc:
                raise SessionFileError(f"{out}: cannot write: {exc.strerror or exc}") from None
        done = decode_log(log, stream, dbc=dbc, roles=roles, bus=bus, channels=channel, channel_map=channel_map,
                          jsonl=fmt is OutputFormat.JSONL)
    typer.echo(done.text(), err=True)


# --- rig can monitor ------------------------------------------------------------------------------


@app.command("monitor")
def monitor(
    config: Annotated[
        Path | None, typer.Option("--config", help="Session configuration: the bus, its DBC and roles from [[can]].")
    ] = None,
    bus: Annotated[str | None, typer.Option("--bus", help="[[can]] bus name when --config has several.")] = None,
    interface: Annotated[
        str | None,
        typer.Option("--interface", help="python-can interface (socketcan, pcan, socketcand, virtual, …)."),
    ] = None,
    channel: Annotated[str | None, typer.Option("--channel", help="Interface channel (can0, PCAN_USBBUS1, …).")] = None,
    bitrate: Annotated[int, typer.Option("--bitrate", help="Nominal bitrate (bit/s).")] = 500_000,
    host: Annotated[str | None, typer.Option("--host", help="socketcand server host.")] = None,
    port: Annotated[int | None, typer.Option("--port", help="socketcand server port.")] = None,
    dbc: Annotated[Path | None, typer.Option("--dbc", help="DBC to decode roles with (with --roles).")] = None,
    roles: Annotated[Path | None, typer.Option("--roles", help="Roles file: show each role's latest value.")] = None,
    option: Annotated[
        list[str] | None,
        typer.Option("--option", help="python-can interface option KEY=VALUE (repeatable; TOML value), e.g. "
                     "app_name=vsc-rig; added to the [[can]] options of --config."),
    ] = None,
    active: Annotated[
        bool,
        typer.Option("--active", help="Open the interface acknowledging frames (default: listen-only where it "
                     "can be, or as listen_only in --config says)."),
    ] = False,
    duration: Annotated[float | None, typer.Option("--duration", help="Stop after this many seconds.")] = None,
    interval: Annotated[float, typer.Option("--interval", help="Seconds between status lines.")] = 1.0,
) -> None:
    """Watch a live CAN bus: frames/s, bus load, controller state, error frames, gaps and role values.

    The monitor never transmits: it opens the bus listen-only unless --active (or listen_only = false).
    """
    import queue
    import threading
    import time

    from drivers.can.bus import BusEvent, BusStats, CanBusConfig, CanBusLink, CanFrame, CanFrameFlag
    from drivers.can.checks import FrameFlag
    from drivers.can.roles import RoleDecoder
    from rig.core.config import parse_override
    from rig.data.can_log import load_roles
    from vsccore.clock import SystemClock

    options: dict[str, object] = {}
    for item in option or []:
        key, value = parse_override(item)
        if not key:
            raise ConfigError(f"rig can monitor: --option {item!r} is not KEY=VALUE")
        options[key] = value
    listen_only = False if active else None
    decoder: RoleDecoder | None = None
    if config is not None:
        from rig.core.config import load_session

        session_cfg = load_session(config)
        buses = {c.name: c for c in session_cfg.can}
        if not buses:
            raise ConfigError(f"{config}: no [[can]] bus configured")
        if bus is None and len(buses) > 1:
            raise ConfigError(f"{config}: {len(buses)} [[can]] buses; choose one with --bus ({', '.join(buses)})")
        if bus is not None and bus not in buses:
            raise ConfigError(f"{config}: no [[can]] bus named {bus!r} (have: {', '.join(buses)})")
        can_cfg = buses[bus] if bus is not None else session_cfg.can[0]
        bus_cfg = CanBusConfig.from_mapping(
            can_cfg.model_dump(), interface=interface, channel=channel, host=host, port=port,
            options={**can_cfg.options, **options} if options else None, listen_only=listen_only,
        )
        if can_cfg.roles:
            db, rolemap = load_roles(config, dbc, can_cfg.name)
            decoder = RoleDecoder(db, rolemap)
    else:
        if interface is None or channel is None:
            raise ConfigError("rig can monitor: give --config FILE, or --interface and --channel")
        given = {"interface": interface, "channel": channel, "bitrate": bitrate, "host": host, "port": port,
                 "options": options, "listen_only": listen_only}
        bus_cfg = CanBusConfig.from_mapping({**given, "name": channel})
    if roles is not None:
        db, rolemap = load_roles(roles, dbc, bus)
        decoder = RoleDecoder(db, rolemap)
    if interval <= 0:
        raise ConfigError(f"rig can monitor: --interval must be > 0, got {interval}")

    latest: dict[str, tuple[float, str, bool]] = {}
    lock = threading.Lock()
    events: queue.Queue[BusEvent] = queue.Queue()

    def on_frame(frame: CanFrame) -> None:
        if decoder is None or frame.flags & (CanFrameFlag.ERROR_FRAME | CanFrameFlag.REMOTE):
            return
        decoded = decoder.decode(frame.arbitration_id, frame.data, frame.host_ts_ns, frame.is_extended)
        if decoded.samples:
            with lock:
                for s in decoded.samples:
                    latest[s.role] = (s.value, s.unit, bool(s.flags & FrameFlag.INVALID))

    def on_event(event: BusEvent) -> None:
        if not isinstance(event, BusStats):
            events.put(event)

    session = CanBusLink(bus_cfg, on_frame, on_event, clock=SystemClock(), stats_period_s=None)
    typer.echo(f"monitoring {bus_cfg.describe()} at {bus_cfg.bitrate or '?'} bit/s (Ctrl-C to stop)")
    start = time.monotonic()
    pace = threading.Event()  # never set: paces the status lines
    session.start()
    try:
        while duration is None or time.monotonic() - start < duration:
            wait = interval if duration is None else min(interval, max(duration - (time.monotonic() - start), 0.0))
            pace.wait(wait)
            while not events.empty():
                typer.echo(f"  event: {_event_text(events.get_nowait())}")
            stats = session.stats()
            load = "?" if stats.bus_load_pct is None else f"{stats.bus_load_pct:5.1f} %"
            typer.echo(
                f"{time.monotonic() - start:7.1f} s  {stats.state.value:<12} {stats.frames_per_s:8.1f} frames/s  "
                f"load {load}  error frames {stats.error_frames_total}  gaps {stats.gaps_total}"
                + (
                    ""
                    if stats.tx_error_counter is None
                    else f"  TEC {stats.tx_error_counter} REC {stats.rx_error_counter}"
                )
            )
            with lock:
                shown = sorted(latest.items())
            if shown:
                values = (f"{role}={v:.4g} {unit}{' (invalid)' if bad else ''}" for role, (v, unit, bad) in shown)
                typer.echo("          " + "  ".join(values))
            if session.stopped.is_set():
                break
    finally:
        session.stop()
    if session.failure is not None:
        raise session.failure
    stats = session.stats()
    summary = f"{stats.frames_total} frames, {stats.error_frames_total} error frames, {stats.gaps_total} gaps"
    if decoder is not None:
        flagged = decoder.stats().flagged
        if flagged:
            summary += "; flagged: " + ", ".join(f"{k} {v}" for k, v in sorted(flagged.items()))
    typer.echo(summary)


def _event_text(event: object) -> str:
    """One line for a bus event of ``rig can monitor``."""
    from drivers.can.bus import BusGap, BusLost, BusOpened, BusStateChanged

    if isinstance(event, BusGap):
        state = "recovered" if event.recovered else "not recovered"
        return f"gap of {(event.end_ns - event.start_ns) / 1e9:.2f} s ({event.reason}; {state})"
    if isinstance(event, BusLost):
        return f"lost: {event.reason}"
    if isinstance(event, BusOpened):
        times = (f"{event.timestamp_source.value} timestamps" if event.frame_time.value == "interface"
                 else "host receive times")
        mode = {True: ", listen-only", False: ", active", None: ""}[event.listen_only]
        return f"opened {event.interface} {event.channel} ({times}{mode})" + "".join(
            f"\n  note: {note}" for note in event.notes)
    if isinstance(event, BusStateChanged):
        return f"state {event.previous.value} -> {event.state.value}"
    return repr(event)


# --- rig can sim-ecu --------------------------------------------------------------------------------


@app.command("sim-ecu")
def sim_ecu(
    scenario: Annotated[
        str, typer.Option("--scenario", help="Driving scenario of the simulated car (sim_devices.vehicle).")
    ] = "steady_state_circle",
    param: Annotated[
        list[str] | None, typer.Option("--param", help="Scenario parameter NAME=VALUE (repeatable).")
    ] = None,
    host: Annotated[str, typer.Option("--host", help="Address the socketcand server listens on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", help="socketcand server port (0: any free port).")] = 29536,
    bus_name: Annotated[str, typer.Option("--bus-name", help="Bus name clients open (socketcand channel).")] = "vsc0",
    speed: Annotated[float, typer.Option("--speed", help="Time scale: 2 runs the drive twice as fast.")] = 1.0,
    delay: Annotated[float, typer.Option("--delay", help="Seconds (of drive time) before the drive starts.")] = 0.5,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the sensor errors.")] = 0,
) -> None:
    """Run the simulated VSC ECU and serve its bus over socketcand, for recorders in other processes.

    Connect with python-can's socketcand interface (``interface = "socketcand"``, ``host``, ``port``,
    ``channel`` = the bus name) and decode with the simulated car's DBC and
    ``examples/roles/vsc_sim.toml``. Prints one line with the address and the drive's start time
    (``t0_ns``, on the ECU's clock), then runs until the drive ends or Ctrl-C.
    """
    import time

    from sim_devices.vehicle import make_scenario, simulate
    from sim_devices.vsc_ecu import SimulatedVscBus, VscEcuConfig
    from vsccore.clock import Clock, ScaledClock, SystemClock

    if speed <= 0:
        raise ConfigError(f"rig can sim-ecu: --speed must be > 0, got {speed}")
    params: dict[str, object] = {}
    for item in param or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"rig can sim-ecu: --param {item!r} is not NAME=VALUE")
        params[key.strip()] = value.strip()
    truth = simulate(make_scenario(scenario, **params))
    clock: Clock = SystemClock() if speed == 1.0 else ScaledClock(time.time_ns(), speed=speed)
    t0_ns = clock.now_ns() + round(delay * 1e9)
    channel = f"vsc-sim-{port}-{time.monotonic_ns()}"
    with SimulatedVscBus(
        truth,
        clock=clock,
        t0_ns=t0_ns,
        channel=channel,
        config=VscEcuConfig(seed=seed),
        host=host,
        port=port,
        bus_name=bus_name,
    ) as sim:
        address = sim.address
        assert address is not None
        duration = float(truth.t[-1])
        typer.echo(
            f"simulated VSC ECU: scenario {scenario} ({duration:.1f} s), socketcand server on "
            f"{address[0]}:{address[1]} bus {bus_name!r}, t0_ns={t0_ns}, speed {speed:g}"
        )
        sys.stdout.flush()
        try:
            while not sim.finished.wait(0.5):
                pass
        except KeyboardInterrupt:
            typer.echo("interrupted", err=True)
        ecu = sim.ecu
        assert ecu is not None
        sent, skipped = ecu.frames_sent, ecu.frames_skipped
    typer.echo(f"drive finished: {sent} frames sent, {skipped} skipped")
