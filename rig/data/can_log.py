"""Decoding a CAN log (candump, .asc, .blf, .trc, .csv, .db, .mf4) through a DBC into rows: every signal in
DBC units, or the mapped roles in SI; each channel of a multi-channel log on its own, with its own DBC.

Output layouts (docs/can.md):

- CSV, long format, one row per value, in time order::

      t_s,channel,message,signal,value,unit,label,flags      (all DBC signals, DBC units)
      t_s,channel,message,role,value,unit,label,flags        (roles: SI units, ISO 8855 signs)

  A frame with a frame-level flag (wrong length, checksum, counter, undecodable multiplexer) gives one
  row with empty name and value and the flags, e.g. ``CHECKSUM``.
- JSON lines, one object per frame:
  ``{"t_ns": …, "t_s": "…", "channel": …, "message": …, "id": …, "flags": [...], "values": {...},
  "units": {...}, "labels": {...}, "invalid": [...]}`` (NaN → null).

Frames with identifiers not in the DBC are counted in the summary, not written.
"""

from __future__ import annotations

import csv
import heapq
import importlib.resources
import json
import math
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from vsccore.errors import ConfigError

if TYPE_CHECKING:
    from cantools.database.can import Database

    from drivers.can.roles import RoleMap
    from drivers.can.vector_decode import BatchDecode, DecodedMessage, RoleBatch

__all__ = ["CanLogDecode", "decode_log", "load_roles"]


@dataclass(frozen=True, slots=True)
class CanLogDecode:
    """What :func:`decode_log` read and wrote (the summary line: :meth:`text`)."""

    log: Path
    frames: int
    written: int
    results: tuple[BatchDecode | RoleBatch, ...]
    skipped: int
    """Error and remote frames."""
    channels: tuple[str, ...]
    """The log's channels when it has several."""
    unmapped: dict[str, int]
    """Frames per channel the channel map gives no DBC."""
    not_selected: int

    def text(self) -> str:
        return _summary_text(self)


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


def load_roles(roles: Path, dbc: Path | None, bus: str | None) -> tuple[Database, RoleMap]:
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
            db, rolemap = load_roles(_dbc_beside(path, entry["roles"]), dbc, entry.get("bus"))
            out[str(name)] = _ChannelDecoding(db, rolemap)
        elif dbc is not None:
            out[str(name)] = _ChannelDecoding(load_dbc(dbc), None)
        else:
            raise ConfigError(f"{key}: give dbc = \"FILE.dbc\" (or roles = ...)")
    kinds = {d.rolemap is None for d in out.values()}
    if len(kinds) > 1:
        raise ConfigError(f"{path}: give roles for every channel or for none (one output layout for the log)")
    return out


def decode_log(log: Path, out: IO[str], *, dbc: Path | None = None, roles: Path | None = None,
               bus: str | None = None, channels: Sequence[str] | None = None, channel_map: Path | None = None,
               jsonl: bool = False) -> CanLogDecode:
    """Decode ``log`` into ``out`` (CSV, or JSON lines with ``jsonl``): every signal of ``dbc``, the roles of
    ``roles`` (a roles file or a session configuration; ``bus`` picks its ``[[can]]`` table), or per channel
    what ``channel_map`` gives; ``channels``: only these log channels.

    Raises:
        ConfigError: a missing or conflicting DBC/roles choice, a channel the log does not have.
    """
    channel = list(channels or ())
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
        common = _ChannelDecoding(*load_roles(roles, dbc, bus))
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
    written = _write_jsonl(merged, out) if jsonl else _write_csv(merged, out, name_column)
    skipped_channels = sum(n for c, n in zip(*np.unique(ch_array, return_counts=True), strict=True)
                           if c not in selected) if len(batch) else 0
    return CanLogDecode(log, len(batch), written, tuple(results), contents.error_frames + contents.remote_frames,
                        tuple(in_log) if len(in_log) > 1 else (), unmapped, int(skipped_channels))


def _id_text(key: int) -> str:
    """``0x123`` for a base frame, ``0x18FEF100x`` for an extended one (frame key with CAN_EFF_FLAG)."""
    from drivers.can.checks import CAN_EFF_FLAG

    if key & CAN_EFF_FLAG:
        return f"0x{key & 0x1FFFFFFF:08X}x"
    return f"0x{key:X}"


def _summary_text(d: CanLogDecode) -> str:
    import numpy as np

    from drivers.can.checks import FrameFlag

    log, frames, written, results, skipped = d.log, d.frames, d.written, d.results, d.skipped
    channels, unmapped, not_selected = d.channels, d.unmapped, d.not_selected
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
    return "; ".join(parts)
