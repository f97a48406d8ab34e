"""``rig relay``: relay RTK corrections from one source to one or more rover ports, with a live status line.

    rig relay --from ntrip://user@caster:2101/MOUNT --to /dev/ttyUSB1@115200 --to /dev/ttyUSB2@115200

SOURCE and SINK: a serial port (``/dev/ttyUSB0``, ``/dev/ttyUSB0@115200``),
``ntrip://user:password@host:port/MOUNTPOINT`` (source only; password better given in
``VSC_RIG_NTRIP_PASSWORD``), ``tcp://host:port`` or ``file:PATH`` (a capture to replay, paced with
``file:PATH@BAUD``; as a sink, appended to). Ctrl-C stops cleanly; a summary goes to stderr.
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Annotated

import typer

from vsccore.errors import ConfigError, DeviceError

if TYPE_CHECKING:
    from drivers.relay import RelayStats

# drivers.relay and rich are imported by the command (``rig --help`` stays fast); these equal
# drivers.relay.endpoints.DEFAULT_NTRIP_USER_ENV / _PASSWORD_ENV (a test keeps them equal)
DEFAULT_NTRIP_USER_ENV = "VSC_RIG_NTRIP_USER"
DEFAULT_NTRIP_PASSWORD_ENV = "VSC_RIG_NTRIP_PASSWORD"


def _parse_gga(text: str | None) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        lat, lon, height = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--gga {text!r}: expected LAT_DEG,LON_DEG,HEIGHT_M") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise ConfigError(f"--gga {text!r}: latitude or longitude out of range")
    return lat, lon, height


def _age(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}s"


def status_line(s: RelayStats) -> str:
    """One line: state, rates, correction age, rejected frames, per-sink queue/drops, rover ages."""
    types = " ".join(f"{k.split()[-1]}:{v:.1f}" for k, v in s.frames_per_s_by_type.items()) or "-"
    sinks = " ".join(
        f"[{x.name} {'up' if x.connected else 'DOWN'} q{x.queue_depth} drop{x.dropped_total}]" for x in s.sinks
    )
    rovers = " ".join(f"{n}:{_age(r.age_s)}" for n, r in s.rovers.items())
    parts = [
        f"{s.state}",
        f"{s.bytes_per_s / 1000:.2f} kB/s",
        f"{s.frames_per_s:.1f} fr/s ({types})",
        f"age {_age(s.last_correction_age_s)}",
        f"bad {s.rejected_frames}",
        sinks,
    ]
    if rovers:
        parts.append(f"rover diff age {rovers}")
    return " | ".join(p for p in parts if p)


def summary(s: RelayStats) -> str:
    lines = [
        (
            f"relay {s.source}: {s.state}, {s.bytes_in} bytes, {s.frames_in} frames in {s.uptime_s:.1f} s, "
            f"{s.rejected_frames} rejected, {s.truncated_frames} truncated"
        ),
        "  frames by type: " + (", ".join(f"{k} {v}" for k, v in s.frames_by_type.items()) or "none"),
    ]
    for x in s.sinks:
        lines.append(
            f"  -> {x.name}: {x.frames_out} frames, {x.bytes_out} bytes, dropped {x.dropped} (queue full) "
            f"+ {x.dropped_stale} (stale) + {x.dropped_disconnect} (disconnect) + {x.dropped_at_stop} (at stop), "
            f"reconnects {x.reconnects}"
        )
    if s.skipped_bytes:
        lines.append(f"  {s.skipped_bytes} bytes outside whole frames (sync search, rejected and truncated frames)")
    return "\n".join(lines)


def _outcome(s: RelayStats, *, finite: bool) -> DeviceError | None:
    """The error a run ends with although the relay did not fail: a source that never connected,
    or frames of a capture file that did not reach every sink."""
    if s.source_connects == 0:
        reason = s.source_error or "no connection before the end of the run"
        return DeviceError(f"relay source {s.source}: never connected: {reason}")
    lost = s.dropped_frames
    if finite and lost:
        where = ", ".join(f"{x.name} {x.dropped_total}" for x in s.sinks if x.dropped_total)
        return DeviceError(f"relay source {s.source}: {lost} frames were not delivered ({where})")
    return None


def relay(
    source: Annotated[str, typer.Option("--from", help="Correction source (port, ntrip://, tcp://, file:).")],
    sinks: Annotated[list[str], typer.Option("--to", help="Rover port or sink; repeat for several.")],
    duration: Annotated[float | None, typer.Option("--duration", help="Stop after this many seconds.", min=0.0)] = None,
    gga: Annotated[
        str | None, typer.Option("--gga", help="Position LAT,LON,HEIGHT sent to a network (VRS) NTRIP caster.")
    ] = None,
    gga_period_s: Annotated[float, typer.Option("--gga-period", help="GGA upload period (s).", min=0.1)] = 10.0,
    queue_frames: Annotated[int, typer.Option("--queue", help="Frames queued per sink.", min=1)] = 256,
    user_env: Annotated[str, typer.Option(help="Environment variable holding the NTRIP user.")] = (
        DEFAULT_NTRIP_USER_ENV
    ),
    password_env: Annotated[str, typer.Option(help="Environment variable holding the NTRIP password.")] = (
        DEFAULT_NTRIP_PASSWORD_ENV
    ),
    status_period_s: Annotated[float, typer.Option("--status-period", help="Status line update (s).", min=0.05)] = (
        0.5
    ),
) -> None:
    """Relay RTK corrections (RTCM3, RTCA, CMR) from a source to rover ports until Ctrl-C, the end of a
    file source, or --duration. SOURCE/SINK: /dev/ttyUSB0[@BAUD], ntrip://user:password@host:port/MOUNT
    (source only), tcp://host:port, file:PATH[@BAUD]."""
    from rich.console import Console
    from rich.live import Live
    from rich.text import Text

    from drivers.relay import Relay, open_sink, open_source

    position = _parse_gga(gga)
    src = open_source(
        source,
        env=os.environ,
        user_env=user_env,
        password_env=password_env,
        gga=(lambda: position) if position is not None else None,
        gga_period_s=gga_period_s,
    )
    outs = [open_sink(s, queue_frames=queue_frames) for s in sinks]
    relay = Relay(src, outs)
    err = Console(stderr=True)
    live_enabled = err.is_terminal
    deadline = None if duration is None else time.monotonic() + duration
    interrupted = False
    live = Live(Text(""), console=err, auto_refresh=False, transient=True) if live_enabled else None
    relay.start()
    try:
        if live is not None:
            live.start()
        while True:
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                break
            wait_s = status_period_s if left is None else min(status_period_s, left)
            if relay.finished.is_set():
                # a capture file ended: its frames are all queued; wait until the sinks wrote them
                if relay.error is not None or not src.finite or relay.drain(wait_s):
                    break
            else:
                relay.wait(wait_s)
            if live is not None:
                live.update(Text(status_line(relay.stats())), refresh=True)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if live is not None:
            live.stop()
        relay.stop(drain_s=2.0)
    final = relay.stats()
    err.print(summary(final), highlight=False, soft_wrap=True)
    if relay.error is not None:
        raise relay.error
    if interrupted:
        err.print("relay: stopped (Ctrl-C)", highlight=False)
    problem = _outcome(final, finite=src.finite)
    if problem is not None:
        raise problem
    if final.dropped_frames:
        err.print(f"relay: {final.dropped_frames} frames dropped (see above; a live source never waits for a sink)",
                  highlight=False)
