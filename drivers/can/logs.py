"""Reading CAN log files (any format python-can reads) into a :class:`FrameBatch`.

Formats are chosen by suffix through ``can.LogReader``: candump ``.log``, Vector ``.asc`` and
``.blf``, PEAK ``.trc``, python-can ``.csv``, ``.db`` (SQLite) and ``.mf4`` (needs the optional
``asammdf`` package), each possibly gzip-compressed (``.log.gz``). Timestamps become int ns
through the shortest decimal form of python-can's float seconds, so a log written with
microsecond (or nanosecond) digits converts without float rounding noise.

Error frames and remote frames carry no signal data; they are counted, not put in the batch.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path

import can
import numpy as np

from drivers.can.checks import frame_key
from drivers.can.vector_decode import FrameBatch
from vsccore.errors import ConfigError, DecodeError, SessionFileError

__all__ = ["LOG_SUFFIXES", "LogContents", "batch_from_messages", "iter_log", "read_log", "seconds_to_ns"]

_log = logging.getLogger(__name__)

LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc")
"""Suffixes python-can can read (optionally followed by ``.gz``)."""


@dataclass(frozen=True, slots=True)
class LogContents:
    """Frames of a log file plus what was left out."""

    source: str
    batch: FrameBatch
    error_frames: int
    remote_frames: int


def seconds_to_ns(seconds: float) -> int:
    """Float seconds → int ns via the float's shortest decimal form (exact for logged digits)."""
    try:
        return int((Decimal(repr(float(seconds))) * 1_000_000_000).to_integral_value())
    except (InvalidOperation, ValueError, OverflowError):
        raise DecodeError(f"timestamp {seconds!r} is not a finite number of seconds") from None


def _suffix(path: Path) -> str:
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return suffixes[-1] if suffixes else ""


def iter_log(path: str | Path) -> Iterator[can.Message]:
    """Yield the messages of a log file in file order.

    Raises:
        SessionFileError: the file is missing or unreadable.
        ConfigError: the suffix is not a log format python-can reads, or the format needs a
            package that is not installed (``.mf4`` needs ``asammdf``).
        DecodeError: the file's content does not parse (names the file and the frame index).
    """
    p = Path(path)
    if not p.is_file():
        raise SessionFileError(f"{p}: CAN log file not found")
    suffix = _suffix(p)
    if suffix not in LOG_SUFFIXES:
        raise ConfigError(f"{p}: unknown CAN log format {suffix!r} (readable: {', '.join(LOG_SUFFIXES)}, also .gz)")
    try:
        reader = can.LogReader(p)
    except ImportError as exc:
        raise ConfigError(f"{p}: reading {suffix} logs needs an optional package: {exc}") from None
    except OSError as exc:
        raise SessionFileError(f"{p}: cannot open CAN log: {exc.strerror or exc}") from None
    except Exception as exc:  # python-can readers raise ValueError, struct.error, ... on bad headers
        raise DecodeError(f"{p}: not a valid {suffix} CAN log: {exc}") from None
    index = 0
    try:
        with reader:
            it = iter(reader)
            while True:
                try:
                    msg = next(it)
                except StopIteration:
                    return
                except OSError as exc:
                    raise SessionFileError(f"{p}: read error after frame {index}: {exc.strerror or exc}") from None
                except Exception as exc:  # malformed line/object inside the log
                    raise DecodeError(f"{p}: cannot parse the log after frame {index}: {exc}") from None
                index += 1
                yield msg
    except OSError as exc:  # closing a truncated compressed file
        raise SessionFileError(f"{p}: read error: {exc.strerror or exc}") from None


def batch_from_messages(messages: Iterable[can.Message], *, source: str = "messages") -> LogContents:
    """Collect python-can messages into a :class:`FrameBatch` (error/remote frames counted)."""
    stamps: list[int] = []
    ids: list[int] = []
    payloads: list[bytes] = []
    errors = remotes = 0
    for msg in messages:
        if msg.is_error_frame:
            errors += 1
            continue
        if msg.is_remote_frame:
            remotes += 1
            continue
        stamps.append(seconds_to_ns(msg.timestamp))
        ids.append(frame_key(int(msg.arbitration_id), bool(msg.is_extended_id)))
        payloads.append(bytes(msg.data))
    longest = max((len(p) for p in payloads), default=0)
    width = 8 if longest <= 8 else 64
    if longest > 64:
        raise DecodeError(f"{source}: a {longest}-byte payload is longer than CAN FD allows")
    n = len(payloads)
    joined = np.zeros((n, width), dtype=np.uint8)
    dlc = np.fromiter((len(p) for p in payloads), dtype=np.int16, count=n)
    if n:
        # Pad every payload to the width and copy them in one go.
        flat = b"".join(p.ljust(width, b"\0") for p in payloads)
        joined = np.frombuffer(flat, dtype=np.uint8).reshape(n, width).copy()
    batch = FrameBatch(np.asarray(stamps, dtype=np.int64), np.asarray(ids, dtype=np.uint32), joined, dlc)
    if errors or remotes:
        _log.info("%s: skipped %d error frames and %d remote frames", source, errors, remotes)
    return LogContents(source, batch, errors, remotes)


def read_log(path: str | Path) -> LogContents:
    """Read a whole CAN log file into a batch (see :func:`iter_log` for the errors raised)."""
    return batch_from_messages(iter_log(path), source=str(path))
