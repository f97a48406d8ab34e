"""Reading CAN log files (any format python-can reads) into a :class:`FrameBatch`.

Formats are chosen by suffix through ``can.LogReader``: candump ``.log``, Vector ``.asc`` and
``.blf``, PEAK ``.trc``, python-can ``.csv``, ``.db`` (SQLite) and ``.mf4`` (needs the optional
``asammdf`` package), each possibly gzip-compressed (``.log.gz``). Timestamps become int ns
through the shortest decimal form of python-can's float seconds, so a log written with
microsecond (or nanosecond) digits converts without float rounding noise.

Error frames and remote frames carry no signal data; they are counted, not put in the batch.

Multi-channel logs (Vector ``.asc``/``.blf`` with several CAN channels, a candump of several
interfaces) keep each frame's channel (:attr:`LogContents.channels`): the channel as the log
names it — the CAN channel number of a Vector log as CANalyzer shows it (1-based), the interface
name of a candump log (``can0``), python-can's channel otherwise, ``""`` when the log has none.

candump's screen output (``candump can0`` printed to a terminal, one frame per line as
``  can0  123   [8]  11 22 33 44 55 66 77 88``, with ``-t a``/``-t z`` a ``(seconds)`` in front)
is read as well as its ``-L`` log format; without timestamps it is rejected with a clear error.
"""

from __future__ import annotations

import gzip
import logging
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path

import can
import numpy as np

from drivers.can.checks import frame_key
from drivers.can.vector_decode import FrameBatch
from vsccore.errors import ConfigError, DecodeError, SessionFileError

__all__ = [
    "LOG_SUFFIXES",
    "MF4_EXTRA",
    "LogContents",
    "batch_from_messages",
    "channel_name",
    "iter_log",
    "read_log",
    "seconds_to_ns",
]

_log = logging.getLogger(__name__)

LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc")
"""Suffixes python-can can read (optionally followed by ``.gz``)."""
MF4_EXTRA = "vsc-rig[mf4]"
"""The optional dependency set that brings asammdf (``pip install 'vsc-rig[mf4]'``)."""
_VECTOR_SUFFIXES = (".asc", ".blf")


@dataclass(frozen=True, slots=True)
class LogContents:
    """Frames of a log file plus what was left out."""

    source: str
    batch: FrameBatch
    error_frames: int
    remote_frames: int
    channels: tuple[str, ...] = field(default=())
    """The channel of each frame of ``batch`` as the log names it (see the module docstring); empty when
    the batch was made without channels."""

    def channel_names(self) -> list[str]:
        """The distinct channels, in order of first appearance."""
        return list(dict.fromkeys(self.channels))


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


_SCREEN_LINE = re.compile(
    r"^\s*(?:\((?P<ts>[^)]*)\)\s+)?(?P<ch>\S+)\s+(?:(?:RX|TX)\s+\S\s+\S\s+)?(?P<id>[0-9A-Fa-f]{1,8})\s+"
    r"\[(?P<len>\d{1,2})\](?P<rest>.*)$"
)
"""One frame of candump's screen output (optionally with ``-t a|z`` times and ``-x`` direction columns)."""
_HEX_BYTES = re.compile(r"^(?:\s*[0-9A-Fa-f]{2})*")


def _open_text(path: Path) -> Iterator[str]:
    opener = gzip.open if path.suffix.lower() == ".gz" else open
    with opener(path, "rt", encoding="utf-8", errors="replace") as fh:
        yield from fh


def _first_line(path: Path) -> str:
    try:
        for line in _open_text(path):
            if line.strip():
                return line
    except (OSError, EOFError) as exc:
        raise SessionFileError(f"{path}: cannot read CAN log: {exc}") from None
    return ""


def _is_screen_format(line: str) -> bool:
    """candump's screen output (``can0  123   [8]  ...``) rather than its ``-L`` log (``(t) can0 123#...``)."""
    return "#" not in line and _SCREEN_LINE.match(line) is not None


def _iter_candump_screen(path: Path) -> Iterator[can.Message]:
    """Frames of candump's screen output; times from ``-t a`` (absolute) or ``-t z`` (from the start)."""
    last = None
    after_error = False
    for number, line in enumerate(_open_text(path), start=1):
        if not line.strip():
            continue
        m = _SCREEN_LINE.match(line)
        if m is None:
            if after_error and line[:1].isspace():
                continue  # candump -e explains an error frame on indented continuation lines
            raise DecodeError(f"{path}:{number}: not a candump screen line: {line.strip()[:80]!r}")
        ts_text = m.group("ts")
        if ts_text is None:
            raise DecodeError(
                f"{path}:{number}: candump screen output without timestamps; record with 'candump -t a' "
                "(or 'candump -L' for a log file) so that frames have times"
            )
        try:
            ts = float(ts_text)
        except ValueError:
            raise DecodeError(
                f"{path}:{number}: timestamp ({ts_text}) is not seconds; use 'candump -t a' or '-t z'"
            ) from None
        if last is not None and ts < last:
            raise DecodeError(
                f"{path}:{number}: timestamp {ts_text} runs backwards (a 'candump -t d' capture of deltas?); "
                "record with 'candump -t a' or '-t z'"
            )
        last = ts
        after_error = "ERRORFRAME" in m.group("rest")
        ident = m.group("id")
        length = int(m.group("len"))
        rest = m.group("rest")
        extended = len(ident) > 3
        arbitration_id = int(ident, 16)
        if "remote request" in rest:
            yield can.Message(timestamp=ts, channel=m.group("ch"), arbitration_id=arbitration_id,
                              is_extended_id=extended, is_remote_frame=True, dlc=length)
            continue
        hex_part = _HEX_BYTES.match(rest)
        data = bytes.fromhex(hex_part.group(0)) if hex_part else b""
        if "ERRORFRAME" in rest:
            yield can.Message(timestamp=ts, channel=m.group("ch"), arbitration_id=arbitration_id & 0x1FFFFFFF,
                              is_extended_id=extended, is_error_frame=True, data=data)
            continue
        if len(data) != length:
            raise DecodeError(f"{path}:{number}: [{length}] bytes announced, {len(data)} given")
        yield can.Message(timestamp=ts, channel=m.group("ch"), arbitration_id=arbitration_id,
                          is_extended_id=extended, data=data, is_fd=length > 8)


def _asammdf_available() -> bool:
    try:
        import asammdf  # noqa: F401
    except ImportError:
        return False
    return True


def iter_log(path: str | Path) -> Iterator[can.Message]:
    """Yield the messages of a log file in file order.

    Raises:
        SessionFileError: the file is missing or unreadable.
        ConfigError: the suffix is not a log format python-can reads, or the format needs a
            package that is not installed (``.mf4`` needs ``asammdf``: the ``vsc-rig[mf4]`` extra).
        DecodeError: the file's content does not parse (names the file and the frame index, or
            the line of a candump screen capture).
    """
    p = Path(path)
    if not p.is_file():
        raise SessionFileError(f"{p}: CAN log file not found")
    suffix = _suffix(p)
    if suffix not in LOG_SUFFIXES:
        raise ConfigError(f"{p}: unknown CAN log format {suffix!r} (readable: {', '.join(LOG_SUFFIXES)}, also .gz)")
    if suffix == ".mf4" and not _asammdf_available():
        raise ConfigError(
            f"{p}: reading .mf4 CAN logs needs the asammdf package: install the {MF4_EXTRA} extra "
            f"(pip install '{MF4_EXTRA}')"
        )
    if suffix == ".log" and _is_screen_format(_first_line(p)):
        try:
            yield from _iter_candump_screen(p)
        except OSError as exc:
            raise SessionFileError(f"{p}: read error: {exc.strerror or exc}") from None
        return
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
                    hint = (" (candump logs: 'candump -L' lines '(t) can0 123#11223344' or the screen output "
                            "'can0  123   [4]  11 22 33 44' with 'candump -t a')" if suffix == ".log" else "")
                    raise DecodeError(f"{p}: cannot parse the log after frame {index}: {exc}{hint}") from None
                index += 1
                if suffix in _VECTOR_SUFFIXES and isinstance(msg.channel, int):
                    msg.channel = msg.channel + 1  # python-can counts from 0; the log and CANalyzer from 1
                yield msg
    except OSError as exc:  # closing a truncated compressed file
        raise SessionFileError(f"{p}: read error: {exc.strerror or exc}") from None


def channel_name(channel: object) -> str:
    """A python-can message channel as text (``""`` for none)."""
    return "" if channel is None else str(channel)


def batch_from_messages(messages: Iterable[can.Message], *, source: str = "messages") -> LogContents:
    """Collect python-can messages into a :class:`FrameBatch` (error/remote frames counted)."""
    stamps: list[int] = []
    ids: list[int] = []
    payloads: list[bytes] = []
    channels: list[str] = []
    errors = remotes = 0
    for msg in messages:
        if msg.is_error_frame:
            errors += 1
            continue
        if msg.is_remote_frame:
            remotes += 1
            continue
        channels.append(channel_name(msg.channel))
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
    return LogContents(source, batch, errors, remotes, tuple(channels))


def read_log(path: str | Path) -> LogContents:
    """Read a whole CAN log file into a batch (see :func:`iter_log` for the errors raised)."""
    return batch_from_messages(iter_log(path), source=str(path))
