"""``rig replay SESSION --bus CONFIG``: play a recorded session's CAN frames onto a live bus (HIL bench)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Annotated

import typer

from vsccore.errors import ConfigError

_BUS_HELP = (
    "Bus to replay onto: a session configuration FILE.toml[#NAME] (its [[can]] table), or "
    "INTERFACE:CHANNEL[,KEY=VALUE...], e.g. socketcan:can0, pcan:PCAN_USBBUS1,bitrate=500000, "
    "socketcand:vsc0,host=127.0.0.1,port=29536, virtual:bench."
)
_FAULT_HELP = (
    "Rewrite a signal: TARGET:KIND[=VALUE][@T0[..T1]]. TARGET a role (VALUE in SI) or MESSAGE.SIGNAL "
    "(VALUE in DBC units); KIND offset=VALUE, freeze, dropout[=VALUE]; T0..T1 seconds from the recorded bus's "
    "first frame. E.g. yaw_rate:offset=0.05@10..20, swa:freeze@12.0, wheel_speed_fl:dropout@10..12. Repeatable."
)


def replay(
    session: Annotated[Path, typer.Argument(help="The recorded session (base path, a part, or its directory).")],
    bus: Annotated[str, typer.Option("--bus", help=_BUS_HELP)],
    speed: Annotated[float, typer.Option("--speed", help="Time scale: 2 plays twice as fast.")] = 1.0,
    loop: Annotated[bool, typer.Option("--loop", help="Play over and over until Ctrl-C (counters continue).")] = False,
    recorded_bus: Annotated[
        str | None, typer.Option("--recorded-bus", help="Which recorded CAN bus (default: the only one).")
    ] = None,
    ids: Annotated[
        list[str] | None, typer.Option("--id", help="Only this identifier (0x101, 257) or DBC message. Repeatable.")
    ] = None,
    roles: Annotated[
        list[str] | None, typer.Option("--role", help="Only the message carrying this role (yaw_rate, …). Repeatable.")
    ] = None,
    faults: Annotated[list[str] | None, typer.Option("--fault", help=_FAULT_HELP)] = None,
    dbc: Annotated[Path | None, typer.Option("--dbc", help="DBC (default: the one attached to the session).")] = None,
    roles_file: Annotated[
        Path | None, typer.Option("--roles", help="Role map (default: the one attached to the session).")
    ] = None,
    rt_priority: Annotated[
        int | None, typer.Option("--rt-priority", help=(
            "Run the player on the SCHED_FIFO real-time policy at this priority (1-99), so that a busy host does "
            "not delay its frames (a virtual machine's hypervisor still can). Needs root, CAP_SYS_NICE or an "
            "rtprio limit (limits.conf)."))
    ] = None,
) -> None:
    """Play the recorded CAN frames of SESSION onto a live bus at their recorded times (HIL: drive a bench ECU
    with a road test). Frames go out byte-exact, counters and checksums as recorded; faults rewrite one
    signal each and reseal the checksum. Prints the plan, then the send-lateness figures at the end."""
    from drivers.can.dbc import load_dbc
    from drivers.can.roles import RoleMap
    from rig.replay.faults import parse_fault
    from rig.replay.plan import ReplayPlan, describe_plan
    from rig.replay.player import ReplayStats, parse_bus_spec, replay_session

    if not speed > 0 or speed != speed or speed == float("inf"):
        raise ConfigError(f"rig replay: --speed must be a finite number > 0, got {speed}")
    bus_config = parse_bus_spec(bus, bus=recorded_bus)
    parsed = [parse_fault(f) for f in faults or []]
    db = load_dbc(dbc) if dbc is not None else None
    rolemap = None
    if roles_file is not None:
        if db is None:
            raise ConfigError("rig replay: --roles needs --dbc (the role map is checked against it)")
        rolemap = RoleMap.from_toml(roles_file, db)

    def on_plan(plan: ReplayPlan) -> None:
        typer.echo(f"replaying {describe_plan(plan)} onto {bus_config.describe()} at {speed:g}x"
                   f"{', looping (Ctrl-C stops)' if loop else ''}")
        if plan.clamped:
            typer.echo(f"  {plan.clamped} frames recorded out of time order are sent right after their predecessor")

    # the replay runs on a thread so that Ctrl-C (the normal end of --loop) stops it between frames and the
    # figures are still printed
    stop = threading.Event()
    result: list[ReplayStats] = []
    failure: list[BaseException] = []

    def work() -> None:
        try:
            result.append(replay_session(
                session, bus_config, recorded_bus=recorded_bus, ids=ids or (), roles=roles or (), faults=parsed,
                speed=speed, passes=None if loop else 1, stop=stop, db=db, rolemap=rolemap, on_plan=on_plan,
                rt_priority=rt_priority))
        except BaseException as exc:  # re-raised on the command's thread
            failure.append(exc)

    worker = threading.Thread(target=work, name="rig-replay")
    worker.start()
    try:
        while worker.is_alive():
            worker.join(0.2)
    except KeyboardInterrupt:
        stop.set()
        worker.join()
        typer.echo("interrupted", err=True)
    if failure:
        raise failure[0]
    if result:
        typer.echo(result[0].summary())
