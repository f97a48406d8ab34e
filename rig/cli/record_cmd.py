"""``rig record`` (the devices of a session configuration into one MCAP file) and ``rig sim record``.

    rig record car.toml --out sessions/ --name run1          # until Ctrl-C / SIGTERM (or --duration)
    rig sim record rig/examples/sim.toml --out out/ --fast --set simulation.true_mount_offset_deg=0.5

While recording, :class:`rig.live.dashboard.Dashboard` shows every device on a terminal (``m`` + a note +
Enter records an operator mark on ``/rig/events`` at the time of the key press); otherwise a status
line is printed every few seconds. Ctrl-C or SIGTERM stop the session cleanly: devices stopped,
file finalized.

``--live`` also serves the session live (:mod:`rig.live`): Foxglove WebSocket on 127.0.0.1:8765
(``--live-port``), the status page for a phone on the next port; ``--live-bind ADDR`` with
``--live-token`` (or ``RIG_LIVE_TOKEN``) for a phone or tablet on the car's network.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from vsccore.errors import ConfigError

if TYPE_CHECKING:
    from rig.core.config import SessionConfig
    from rig.live import LiveOptions, LiveView
    from rig.live.dashboard import Dashboard
    from rig.record.recording import Recording, RecordingSummary

# the recorder and the simulator are imported by the commands that use them (``rig --help`` stays fast)
FAST_SPEED = 3.0
"""``rig.sim.record.FAST_SPEED`` (the --fast clock factor; a test keeps the two equal)."""


@contextmanager
def _stop_on_signals(stop: threading.Event) -> Iterator[dict[str, str]]:
    """SIGINT and SIGTERM set ``stop`` (the session then ends cleanly) instead of killing the process."""
    got: dict[str, str] = {}

    def handler(signum: int, _frame: Any) -> None:
        got["signal"] = signal.Signals(signum).name
        stop.set()

    if threading.current_thread() is not threading.main_thread():
        yield got
        return
    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield got
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def _dashboard(enabled: bool) -> Iterator[Callable[[Recording], None]]:
    """The live dashboard (or plain status lines) of the running session; yields the session's tick.

    The dashboard starts on the first tick (the session is recording then) and stops on exit.
    """
    from rig.live.dashboard import Dashboard

    running: list[Dashboard] = []

    def tick(session: Recording) -> None:
        if enabled and not running:
            dash = Dashboard(session.board, session.clock, on_mark=lambda m: session.mark(m.note, host_ns=m.host_ns))
            dash.start()
            running.append(dash)

    try:
        yield tick
    finally:
        for dash in running:
            dash.stop()


LiveFlag = Annotated[bool, typer.Option("--live", help="Serve the session live: Foxglove WebSocket and a status page.")]
LivePort = Annotated[int, typer.Option("--live-port", min=0, max=65535,
                                       help="Foxglove WebSocket port of --live (0: any free port).")]
LiveBind = Annotated[str, typer.Option("--live-bind", help="Address --live listens on; not a loopback address "
                                                          "(a phone on the car's network) needs --live-token.")]
LiveToken = Annotated[str | None, typer.Option("--live-token", help="Token of the live view (env RIG_LIVE_TOKEN); "
                                                                   "the status page and the WebSocket ask for it "
                                                                   "(?token=...).")]
LiveStatusPort = Annotated[int | None, typer.Option("--live-status-port", min=0, max=65535,
                                                    help="Port of the status page (default: --live-port + 1).")]
LiveFullRate = Annotated[bool, typer.Option("--live-full-rate",
                                            help="Serve every message live (default: plot channels at <= 50 Hz).")]


def _live_options(
    live: bool, port: int, bind: str, token: str | None, status_port: int | None, full_rate: bool
) -> LiveOptions | None:
    """The live view's options (checked before any device starts), or None without --live."""
    if not live:
        return None
    from rig.live import LiveOptions

    return LiveOptions.from_cli(port, bind, token, status_port=status_port, full_rate=full_rate)


@contextmanager
def _live(options: LiveOptions | None) -> Iterator[Callable[[Recording], None]]:
    """Yields the call that attaches the live view to the recording session; stops it on exit."""
    views: list[LiveView] = []

    def attach(session: Recording) -> None:
        if options is None:
            return
        from rig.live import LiveView

        view = LiveView(options)
        view.attach(session)
        views.append(view)
        typer.echo(f"live: Foxglove {view.ws_url}  status page {view.page_url}", err=True)

    try:
        yield attach
    finally:
        for view in views:
            view.detach()


def _report(summary: RecordingSummary, stopped_by: str | None) -> None:
    from rig.record.recording import summary_lines

    for line in summary_lines(summary):
        typer.echo(line, err=True)
    if stopped_by:
        typer.echo(f"rig: stopped by {stopped_by}; the file is finalized", err=True)
    if summary.recording.error is not None:
        raise summary.recording.error


def record(
    config: Annotated[Path, typer.Argument(help="Session configuration (TOML).")],
    out: Annotated[
        Path | None, typer.Option("--out", help="Output folder (default: the configuration's output directory).")
    ] = None,
    name: Annotated[
        str | None, typer.Option("--name", help="Session name (default: the output name or the start time).")
    ] = None,
    duration: Annotated[float | None, typer.Option("--duration", min=0.0, help="Stop after this many seconds.")] = None,
    no_dashboard: Annotated[bool, typer.Option("--no-dashboard", help="Plain status lines, no live view.")] = False,
    live: LiveFlag = False,
    live_port: LivePort = 8765,
    live_bind: LiveBind = "127.0.0.1",
    live_token: LiveToken = None,
    live_status_port: LiveStatusPort = None,
    live_full_rate: LiveFullRate = False,
) -> None:
    """Record every device of CONFIG (receivers, correction relay, CAN, DAQ) into one MCAP session file
    until Ctrl-C, SIGTERM or --duration."""
    from rig.core.config import load_session
    from rig.record.recording import Recording
    from rig.sim.world import SIM_PREFIX

    cfg = load_session(config)
    simulated = [r.name for r in cfg.receivers if r.port.startswith(SIM_PREFIX)]
    if simulated:
        raise ConfigError(
            f"{config}: receivers {simulated} are simulated (sim://); record them with `rig sim record {config}`"
        )
    _check_free_space(cfg, out)  # before any device is set up
    live_opts = _live_options(live, live_port, live_bind, live_token, live_status_port, live_full_rate)
    stop = threading.Event()
    session = Recording(cfg, out_dir=out, name=name, config_path=config)
    with _stop_on_signals(stop) as got, _live(live_opts) as attach_live:
        session.start()
        typer.echo(f"recording {session.name} to {session.base}.000.mcap (Ctrl-C to stop)", err=True)
        try:
            attach_live(session)
            with _dashboard(not no_dashboard) as tick:
                session.run(stop, duration_s=duration, tick=lambda: tick(session))
        finally:
            summary = session.stop()
    _report(summary, got.get("signal"))


def sim_record(
    config: Annotated[Path, typer.Argument(help="Session configuration with a simulation table.")],
    out: Annotated[Path, typer.Option("--out", help="Output folder.")],
    name: Annotated[
        str | None, typer.Option("--name", help="Session name (default: the simulated start time).")
    ] = None,
    drive: Annotated[
        str | None, typer.Option("--drive", help="Drive: 'demo' or a scenario (NAME or NAME:key=value,...).")
    ] = None,
    set_: Annotated[
        list[str] | None, typer.Option("--set", help="Override a configuration key: KEY=VALUE (repeatable).")
    ] = None,
    fast: Annotated[bool, typer.Option("--fast", help=f"Run at least {FAST_SPEED:g}× real time.")] = False,
    speed: Annotated[float | None, typer.Option("--speed", min=0.01, help="Clock speed factor.")] = None,
    no_dashboard: Annotated[bool, typer.Option("--no-dashboard", help="Plain status lines, no live view.")] = False,
    device_process: Annotated[
        bool,
        typer.Option(
            "--device-process/--one-process",
            help="Run the simulated receivers and ECU in a process of their own (CAN over socketcand on "
                 "127.0.0.1), as real devices run on their own hardware, so the recorder has this process to "
                 "itself and the clock can run faster; --one-process keeps everything in one process.",
        ),
    ] = True,
    live: LiveFlag = False,
    live_port: LivePort = 8765,
    live_bind: LiveBind = "127.0.0.1",
    live_token: LiveToken = None,
    live_status_port: LiveStatusPort = None,
    live_full_rate: LiveFullRate = False,
    fault: Annotated[
        list[str] | None,
        typer.Option("--fault", help="A fault to rehearse, KIND[:TARGET][@T0[..T1]] in s of drive time (repeatable): "
                     "corrections:RECEIVER@T0..T1 (correction cable pulled), reset:RECEIVER@T, "
                     "unplug:RECEIVER@T0..T1, can-unplug@T0..T1, can-bus-off@T0..T1, daq-unplug@T0..T1, "
                     "daq-float:CHANNEL (open input). "
                     "The devices then run in this process."),
    ] = None,
) -> None:
    """Record a simulated session: the simulated car of CONFIG with every device on pseudo-terminals, a
    virtual CAN bus and the simulated DAQ, through the real recording path, until the drive ends."""
    from rig.core.config import load_session, parse_override
    from rig.sim.faults import fault_actions, floating_channels, parse_fault
    from rig.sim.record import FAST_SPEED, record_simulated

    overrides = dict(parse_override(item) for item in (set_ or []))
    if drive is not None:
        overrides["simulation.drive"] = drive
    cfg = load_session(config, overrides)
    _check_simulated(cfg, config)
    assert cfg.simulation is not None
    factor = speed if speed is not None else cfg.simulation.speed
    if fast:
        factor = max(factor, FAST_SPEED)
    faults = [parse_fault(text, cfg) for text in (fault or [])]
    if faults and device_process:
        device_process = False  # the faults act on the devices, which are then in this process
    _check_free_space(cfg, out)  # before the simulated world and its devices start
    live_opts = _live_options(live, live_port, live_bind, live_token, live_status_port, live_full_rate)
    stop = threading.Event()

    with _stop_on_signals(stop) as got, _dashboard(not no_dashboard) as tick, _live(live_opts) as attach_live:

        def started(s: Recording) -> None:
            typer.echo(f"recording {s.name} to {s.base}.000.mcap (Ctrl-C to stop)", err=True)
            attach_live(s)

        result = record_simulated(
            cfg, out, name=name, speed=factor, stop=stop, tick=tick, config_path=config, device_process=device_process,
            on_started=started, actions=fault_actions(faults, cfg), floating=floating_channels(faults),
        )
    world = result.world
    typer.echo(
        f"simulated {world.duration_s:.1f} s drive (+{world.lead_s:.0f} s lead) at {world.speed:g}× in "
        f"{result.wall_s:.1f} s{'' if result.completed else ' (stopped early)'}",
        err=True,
    )
    typer.echo(result.governor_text, err=True)
    _report(result.summary, got.get("signal"))


def _check_free_space(cfg: SessionConfig, out: Path | None) -> None:
    """Refuse a disk below ``output.min_free_disk_mb`` at once, not after the devices were set up."""
    from rig.store import RecorderOptions
    from rig.store.writer import check_free_space

    check_free_space(out if out is not None else Path(cfg.output.directory), RecorderOptions.from_output(cfg.output))


def _check_simulated(cfg: SessionConfig, path: Path) -> None:
    from rig.sim.world import SIM_PREFIX

    if cfg.simulation is None:
        raise ConfigError(f"{path}: no [simulation] table; `rig sim record` records a simulated car")
    real = [r.name for r in cfg.receivers if not r.port.startswith(SIM_PREFIX)]
    if real:
        raise ConfigError(f"{path}: receivers {real} have real ports; a simulated session needs sim://NAME ports")
