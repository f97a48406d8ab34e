"""``rig can``: CAN tools. ``rig can decode`` turns a CAN log into signal values (CSV or JSON lines),
``rig can monitor`` watches a live bus, ``rig can sim-ecu`` serves the simulated VSC ECU over socketcand.

Output layouts (documented in docs/can.md):

- CSV, long format, one row per value, in time order::

      t_s,channel,message,signal,value,unit,label,flags      (all DBC signals, DBC units)
      t_s,channel,message,role,value,unit,label,flags        (--roles: SI units, ISO 8855 signs)

  ``channel`` is the frame's channel as the log names it (Vector: 1, 2, …; candump: can0), empty
  when the log has none. Each channel is decoded on its own (its counters and checksums), with the
  DBC (and roles) that ``--channel-map`` gives it, or the one ``--dbc``/``--roles`` give them all;
  ``--channel`` keeps only the channels named.

  A frame with a frame-level flag (wrong length, checksum, counter, undecodable multiplexer)
  gives one row with empty name and value and the flags, e.g. ``CHECKSUM``.
- JSON lines, one object per frame:
  ``{"t_ns": …, "t_s": "…", "channel": …, "message": …, "id": …, "flags": [...], "values": {...},
  "units": {...}, "labels": {...}, "invalid": [...]}`` (NaN → null).

Frames with identifiers not in the DBC are counted in the summary on stderr, not written.
"""

from __future__ import annotations

import csv
import heapq
import importlib.resources
import json
import math
import sys
import tomllib
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import IO, TYPE_CHECKING, Annotated, Any

import typer

from vsccore.errors import ConfigError, SessionFileError

if TYPE_CHECKING:  # the CAN drivers (cantools, python-can) are imported by the commands: ``rig --help`` stays fast
    from cantools.database.can import Database

    from drivers.can.roles import RoleMap
    from drivers.can.vector_decode import BatchDecode, DecodedMessage, RoleBatch

app = typer.Typer(
    help="CAN tools: decode logs with a DBC and a role mapping, watch a live bus, run the simulated VSC ECU.",
    no_args_is_help=True,
)


class OutputFormat(StrEnum):
    """Output file format of ``rig can decode``."""

    CSV = "csv"
    JSONL = "jsonl"


@dataclass(frozen=True, slots=True)
class _Row:
    """One frame's output: values by name (signal or role)."""

    t_ns: int
    index: int  # row in the frame batch: the output keeps the log's frame order
    channel: str
    message: str
    frame_id: int
    flags: int
    values: dict[str, float]
    units: dict[str, str]
    labels: dict[str, str]
    invalid: tuple[str, ...]


def _t_s(t_ns: int) -> str:
    """Exact decimal seconds of an int-ns timestamp (floats would drop digits at epoch times)."""
    sign = "-" if t_ns < 0 else ""
    sec, ns = divmod(abs(t_ns), 1_000_000_000)
    return f"{sign}{sec}.{ns:09d}"


def _value_text(v: float) -> str:
    return "" if math.isnan(v) else repr(float(v))


def _signal_rows(decoded: DecodedMessage, channel: str = "", rows: list[int] | None = None) -> Iterator[_Row]:
    """Rows of one message; ``rows`` maps the decoded batch's indices to the whole log's (channel sub-batches)."""
    from drivers.can.checks import FrameFlag

    names = list(decoded.values)
    values = {n: decoded.values[n].tolist() for n in names}
    present = {n: decoded.present[n].tolist() for n in names}
    raw = {n: decoded.raw[n].tolist() for n in names}
    flags = decoded.flags.tolist()
    frame_level = int(FrameFlag.frame_level())
    for i, (t, b) in enumerate(zip(decoded.timestamps_ns.tolist(), decoded.batch_index.tolist(), strict=True)):
        b = b if rows is None else rows[b]
        if flags[i] & frame_level:
            yield _Row(t, b, channel, decoded.name, decoded.frame_id, flags[i], {}, {}, {}, ())
            continue
        row_values = {n: values[n][i] for n in names if present[n][i]}
        labels = {}
        for n in row_values:
            table = decoded.choices.get(n)
            if table is not None:
                label = table.get(int(raw[n][i]))
                if label is not None:
                    labels[n] = label
        units = {n: decoded.units.get(n, "") for n in row_values}
        yield _Row(t, b, channel, decoded.name, decoded.frame_id, flags[i], row_values, units, labels, ())


def _role_rows_for_message(
    result: RoleBatch, rolemap: RoleMap, message: str, channel: str = "", rows: list[int] | None = None
) -> Iterator[_Row]:
    from drivers.can.checks import FrameFlag

    decoded = result.messages[message]
    frame_level = int(FrameFlag.frame_level())
    per_role: list[tuple[str, dict[int, int], list[float], list[int], list[Any], Any, str]] = []
    for spec in rolemap.roles_for_message(message):
        series = result.roles[spec.role]
        position = {b: j for j, b in enumerate(series.batch_index.tolist())}
        per_role.append(
            (
                spec.role,
                position,
                series.values.tolist(),
                series.flags.tolist(),
                series.raw.tolist(),
                series.choices,
                series.unit,
            )
        )
    flags = decoded.flags.tolist()
    for i, (t, b) in enumerate(zip(decoded.timestamps_ns.tolist(), decoded.batch_index.tolist(), strict=True)):
        if flags[i] & frame_level:
            yield _Row(t, b if rows is None else rows[b], channel, message, decoded.frame_id, flags[i], {}, {}, {}, ())
            continue
        values: dict[str, float] = {}
        units: dict[str, str] = {}
        labels: dict[str, str] = {}
        invalid: list[str] = []
        for role, position, role_values, role_flags, role_raw, choices, unit in per_role:
            j = position.get(b)
            if j is None:  # multiplexed out of this frame
                continue
            values[role] = role_values[j]
            units[role] = unit
            label = choices.get(int(role_raw[j])) if choices else None
            if label is not None:
                labels[role] = label
            if role_flags[j] & int(FrameFlag.INVALID):
                invalid.append(role)
        yield _Row(t, b if rows is None else rows[b], channel, message, decoded.frame_id, flags[i], values, units,
                   labels, tuple(invalid))


def _merge(streams: list[Iterator[_Row]]) -> Iterator[_Row]:
    """Merge per-message row streams (each in log order) back into the log's frame order."""
    keyed = [((row.index, row) for row in s) for s in streams]
    for _, row in heapq.merge(*keyed, key=lambda pair: pair[0]):
        yield row


def _flag_text(flags: int) -> str:
    from drivers.can.checks import FrameFlag

    return "|".join(FrameFlag(flags).names())


def _write_csv(rows: Iterator[_Row], out: IO[str], name_column: str) -> int:
    from drivers.can.checks import FrameFlag

    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["t_s", "channel", "message", name_column, "value", "unit", "label", "flags"])
    count = 0
    for row in rows:
        t = _t_s(row.t_ns)
        if not row.values and row.flags:
            writer.writerow([t, row.channel, row.message, "", "", "", "", _flag_text(row.flags)])
        for name, value in row.values.items():
            flags = row.flags | (int(FrameFlag.INVALID) if name in row.invalid else 0)
            writer.writerow(
                [
                    t,
                    row.channel,
                    row.message,
                    name,
                    _value_text(value),
                    row.units.get(name, ""),
                    row.labels.get(name, ""),
                    _flag_text(flags),
                ]
            )
        count += 1
    return count


def _write_jsonl(rows: Iterator[_Row], out: IO[str]) -> int:
    from drivers.can.checks import FrameFlag

    count = 0
    for row in rows:
        record = {
            "t_ns": row.t_ns,
            "t_s": _t_s(row.t_ns),
            "channel": row.channel,
            "message": row.message,
            "id": row.frame_id,
            "flags": FrameFlag(row.flags).names(),
            "values": {k: (None if math.isnan(v) else v) for k, v in row.values.items()},
            "units": row.units,
            "labels": row.labels,
            "invalid": list(row.invalid),
        }
        out.write(json.dumps(record, separators=(",", ":")) + "\n")
        count += 1
    return count


def _dbc_beside(roles: Path, named: str) -> Path:
    """The DBC a roles file names: ``pkg:package/file`` (package data) or a path relative to the file."""
    if named.startswith("pkg:"):
        package, _, name = named.removeprefix("pkg:").partition("/")
        try:
            return Path(str(importlib.resources.files(package).joinpath(name)))
        except ModuleNotFoundError:
            raise ConfigError(f"{roles}: dbc {named!r}: no package {package!r}") from None
    path = Path(named)
    return path if path.is_absolute() else roles.parent / path


def _load_roles(roles: Path, dbc: Path | None, bus: str | None) -> tuple[Database, RoleMap]:
    """A roles file (``[roles.*]``) or a session configuration (``[[can]]`` with roles)."""
    from drivers.can.dbc import load_dbc
    from drivers.can.roles import RoleMap

    try:
        doc = tomllib.loads(roles.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{roles}: role configuration not found") from None
    except OSError as exc:
        raise ConfigError(f"{roles}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{roles}: TOML syntax error: {exc}") from None
    if isinstance(doc.get("can"), list):
        from rig.core.config import load_session

        cfg = load_session(roles)
        buses = {c.name: c for c in cfg.can}
        if bus is None:
            if len(cfg.can) != 1:
                raise ConfigError(f"{roles}: {len(cfg.can)} [[can]] buses; choose one with --bus ({', '.join(buses)})")
            can_cfg = cfg.can[0]
        elif bus in buses:
            can_cfg = buses[bus]
        else:
            raise ConfigError(f"{roles}: no [[can]] bus named {bus!r} (have: {', '.join(buses)})")
        db = load_dbc(dbc if dbc is not None else can_cfg.dbc)
        return db, RoleMap.from_mapping(can_cfg.model_dump(), db, source=str(roles), key_prefix=f"can.{can_cfg.name}.")
    if dbc is None:
        named = doc.get("dbc")
        candidate = _dbc_beside(roles, named) if isinstance(named, str) else None
        if candidate is None or not candidate.is_file():
            raise ConfigError(f"{roles}: give the DBC with --dbc (the roles file names {named!r}, not found beside it)")
        dbc = candidate
    db = load_dbc(dbc)
    return db, RoleMap.from_toml(roles, db)


@dataclass(frozen=True, slots=True)
class _ChannelDecoding:
    """How one log channel is decoded: its DBC and, for roles output, its role map."""

    db: Database
    rolemap: RoleMap | None


def _load_channel_map(path: Path) -> dict[str, _ChannelDecoding]:
    """``--channel-map``: ``[channels.<channel>]`` tables with ``dbc`` and optional ``roles`` (and ``bus``).

    Paths are relative to the map file (or ``pkg:package/file``); ``roles`` is a roles file or a
    session configuration (then ``bus`` names its ``[[can]]`` bus, and ``dbc`` defaults to that bus's).
    """
    from drivers.can.dbc import load_dbc

    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: channel map not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: TOML syntax error: {exc}") from None
    table = doc.get("channels")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f'{path}: no [channels."<channel>"] tables (e.g. [channels."1"] dbc = "powertrain.dbc")')
    out: dict[str, _ChannelDecoding] = {}
    for name, entry in table.items():
        key = f"{path}: channels.{name}"
        if not isinstance(entry, dict):
            raise ConfigError(f"{key}: must be a table with dbc = ... (and optionally roles = ...)")
        unknown = sorted(set(entry) - {"dbc", "roles", "bus"})
        if unknown:
            raise ConfigError(f"{key}: unknown key(s) {', '.join(unknown)} (allowed: dbc, roles, bus)")
        for k in ("dbc", "roles", "bus"):
            if k in entry and not isinstance(entry[k], str):
                raise ConfigError(f"{key}.{k}: must be a string, got {entry[k]!r}")
        dbc = _dbc_beside(path, entry["dbc"]) if "dbc" in entry else None
        if "roles" in entry:
            db, rolemap = _load_roles(_dbc_beside(path, entry["roles"]), dbc, entry.get("bus"))
            out[str(name)] = _ChannelDecoding(db, rolemap)
        elif dbc is not None:
            out[str(name)] = _ChannelDecoding(load_dbc(dbc), None)
        else:
            raise ConfigError(f"{key}: give dbc = \"FILE.dbc\" (or roles = ...)")
    kinds = {d.rolemap is None for d in out.values()}
    if len(kinds) > 1:
        raise ConfigError(f"{path}: give roles for every channel or for none (one output layout for the log)")
    return out


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
    import numpy as np

    from drivers.can.dbc import load_dbc
    from drivers.can.logs import read_log
    from drivers.can.vector_decode import FrameBatch, VectorDecoder, VectorRoleDecoder

    per_channel: dict[str, _ChannelDecoding] | None = None
    common: _ChannelDecoding | None = None
    if channel_map is not None:
        if dbc is not None or roles is not None:
            raise ConfigError("rig can decode: give either --channel-map or --dbc/--roles, not both")
        per_channel = _load_channel_map(channel_map)
    elif roles is not None:
        common = _ChannelDecoding(*_load_roles(roles, dbc, bus))
    elif dbc is not None:
        common = _ChannelDecoding(load_dbc(dbc), None)
    else:
        raise ConfigError("rig can decode: give --dbc FILE (or --roles with a session configuration, or --channel-map)")
    contents = read_log(log)
    batch = contents.batch
    channels_of_frames = contents.channels or ("",) * len(batch)
    in_log = list(dict.fromkeys(channels_of_frames))
    if channel:
        missing = [c for c in channel if c not in in_log]
        if missing:
            raise ConfigError(f"{log}: no frames on channel(s) {', '.join(missing)} (channels in the log: "
                              f"{', '.join(repr(c) for c in in_log) or 'none'})")
        selected = [c for c in in_log if c in channel]
    else:
        selected = in_log
    unmapped: dict[str, int] = {}
    streams: list[Iterator[_Row]] = []
    results: list[BatchDecode | RoleBatch] = []
    ch_array = np.asarray(channels_of_frames, dtype=object)
    with_roles = False
    for ch in selected:
        decoding = common if per_channel is None else per_channel.get(ch)
        rows = np.flatnonzero(ch_array == ch) if len(in_log) > 1 else None
        if decoding is None:
            unmapped[ch] = len(batch) if rows is None else int(rows.size)
            continue
        sub = batch if rows is None else FrameBatch(batch.timestamps_ns[rows], batch.ids[rows], batch.data[rows],
                                                    batch.dlc[rows])
        index = None if rows is None else rows.tolist()
        result: BatchDecode | RoleBatch
        if decoding.rolemap is not None:
            with_roles = True
            rolemap = decoding.rolemap
            result = VectorRoleDecoder(decoding.db, rolemap).decode(sub)
            names = [m for m in rolemap.messages if m in result.messages and rolemap.roles_for_message(m)]
            streams += [_role_rows_for_message(result, rolemap, m, ch, index) for m in names]
        else:
            result = VectorDecoder(decoding.db).decode(sub)
            streams += [_signal_rows(d, ch, index) for d in result.messages.values()]
        results.append(result)
    name_column = "role" if with_roles else "signal"
    merged = _merge(streams)
    with ExitStack() as stack:
        if out is None:
            stream: IO[str] = sys.stdout
        else:
            try:
                stream = stack.enter_context(out.open("w", encoding="utf-8", newline=""))
            except OSError as exc:
                raise SessionFileError(f"{out}: cannot write: {exc.strerror or exc}") from None
        written = _write_csv(merged, stream, name_column) if fmt is OutputFormat.CSV else _write_jsonl(merged, stream)
    skipped_channels = sum(n for c, n in zip(*np.unique(ch_array, return_counts=True), strict=True)
                           if c not in selected) if len(batch) else 0
    _summary(log, len(batch), written, results, contents.error_frames + contents.remote_frames,
             in_log if len(in_log) > 1 else [], unmapped, int(skipped_channels))


def _id_text(key: int) -> str:
    """``0x123`` for a base frame, ``0x18FEF100x`` for an extended one (frame key with CAN_EFF_FLAG)."""
    from drivers.can.checks import CAN_EFF_FLAG

    if key & CAN_EFF_FLAG:
        return f"0x{key & 0x1FFFFFFF:08X}x"
    return f"0x{key:X}"


def _summary(
    log: Path,
    frames: int,
    written: int,
    results: list[BatchDecode | RoleBatch],
    skipped: int,
    channels: list[str] | None = None,
    unmapped: dict[str, int] | None = None,
    not_selected: int = 0,
) -> None:
    import numpy as np

    from drivers.can.checks import FrameFlag

    flagged: dict[str, int] = {}
    unknown_ids: dict[int, int] = {}
    for result in results:
        for decoded in result.messages.values():
            for value, count in zip(*np.unique(decoded.flags, return_counts=True), strict=True):
                for name in FrameFlag(int(value)).names():
                    flagged[name] = flagged.get(name, 0) + int(count)
        for key, n in result.unknown_ids.items():
            unknown_ids[key] = unknown_ids.get(key, 0) + n
    unknown_frames = sum(unknown_ids.values())
    parts = [f"{log}: {frames} frames, {written} decoded frames written"]
    if channels:
        parts.append(f"channels {', '.join(channels)}")
    if not_selected:
        parts.append(f"{not_selected} frames on channels not selected")
    for ch, n in (unmapped or {}).items():
        parts.append(f"{n} frames on channel {ch!r} not decoded (not in the channel map)")
    if unknown_frames:
        top = sorted(unknown_ids.items(), key=lambda kv: -kv[1])[:5]
        ids = ", ".join(f"{_id_text(i)}×{n}" for i, n in top)
        parts.append(f"{unknown_frames} with ids not in the DBC ({ids}{', …' if len(unknown_ids) > 5 else ''})")
    if flagged:
        parts.append("flagged: " + ", ".join(f"{k} {v}" for k, v in sorted(flagged.items())))
    if skipped:
        parts.append(f"{skipped} error/remote frames skipped")
    typer.echo("; ".join(parts), err=True)


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
    duration: Annotated[float | None, typer.Option("--duration", help="Stop after this many seconds.")] = None,
    interval: Annotated[float, typer.Option("--interval", help="Seconds between status lines.")] = 1.0,
) -> None:
    """Watch a live CAN bus: frames/s, bus load, controller state, error frames, gaps and role values."""
    import queue
    import threading
    import time

    from drivers.can.bus import BusEvent, BusStats, CanBusConfig, CanBusSession, CanFrame, CanFrameFlag
    from drivers.can.checks import FrameFlag
    from drivers.can.roles import RoleDecoder
    from vsccore.clock import SystemClock

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
            can_cfg.model_dump(), interface=interface, channel=channel, host=host, port=port
        )
        if can_cfg.roles:
            db, rolemap = _load_roles(config, dbc, can_cfg.name)
            decoder = RoleDecoder(db, rolemap)
    else:
        if interface is None or channel is None:
            raise ConfigError("rig can monitor: give --config FILE, or --interface and --channel")
        given = {"interface": interface, "channel": channel, "bitrate": bitrate, "host": host, "port": port}
        bus_cfg = CanBusConfig.from_mapping({**given, "name": channel})
    if roles is not None:
        db, rolemap = _load_roles(roles, dbc, bus)
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

    session = CanBusSession(bus_cfg, on_frame, on_event, clock=SystemClock(), stats_period_s=None)
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
        return f"opened {event.interface} {event.channel} ({event.timestamp_source.value} timestamps)"
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
