"""Loading DBC files with cantools, with errors that name the file, the line and the reason.

cantools reports a syntax error as ``UnsupportedDatabaseFormatError`` wrapping a textparser
error that knows the line and column; semantic errors (overlapping signals, a signal outside its
message) carry only a message. Both become :class:`~vsccore.errors.ConfigError` naming the file
and, where it can be found, the line.

A signal whose bits run past its message's length (a DBC edited by hand, a length cut from 8 to 6
bytes) is accepted by cantools when not ``strict`` and decodes silently from zero padding; the
loader logs one warning per database naming every such signal (:func:`signals_outside_message`).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from cantools.database.can import Database

from vsccore.errors import ConfigError

__all__ = ["dbc_text_line_of", "load_dbc", "parse_dbc_text", "signal_last_byte", "signals_outside_message"]

log = logging.getLogger(__name__)


def load_dbc(path: str | Path, *, strict: bool = False) -> Database:
    """Load a DBC file.

    ``strict`` turns on cantools' checks that signals fit in their message and do not
    overlap. It is off by default because production DBCs (the public VW MQB one among them)
    contain overlapping alternative definitions that decode fine.

    Raises:
        ConfigError: the file is missing or unreadable, or does not parse (the message names
            the file, the line and column when known, and the reason).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="cp1252")
    except FileNotFoundError:
        raise ConfigError(f"{p}: DBC file not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read DBC file: {exc.strerror or exc}") from None
    return parse_dbc_text(text, source=str(p), strict=strict)


def parse_dbc_text(text: str, *, source: str = "<dbc>", strict: bool = False) -> Database:
    """Parse DBC text (see :func:`load_dbc`); ``source`` names it in error messages."""
    db = Database(strict=strict)
    try:
        db.add_dbc_string(text)
    except Exception as exc:  # cantools raises many types here (its own, ValueError, KeyError...)
        raise ConfigError(_describe(exc, text, source)) from exc
    outside = signals_outside_message(db)
    if outside:
        where = []
        for name in outside:
            line = dbc_text_line_of(text, name.partition(".")[2])
            where.append(f"{name} (line {line})" if line else name)
        log.warning(
            "%s: %d DBC signal%s lie%s outside %s message's length and would decode from zero padding: %s",
            source, len(outside), "s" if len(outside) != 1 else "", "" if len(outside) != 1 else "s",
            "their" if len(outside) != 1 else "its", ", ".join(where),
        )
    return db


def signal_last_byte(start: int, length: int, byte_order: str) -> int:
    """0-based index of the last payload byte a signal occupies (DBC start bit, length, byte order).

    Intel (``little_endian``): bits ``start … start+length-1``; Motorola (``big_endian``): ``start``
    is the most significant bit in DBC numbering, and the signal runs on towards later bytes.
    """
    if byte_order == "big_endian":
        msb = (start // 8) * 8 + (7 - start % 8)
        return (msb + length - 1) // 8
    return (start + length - 1) // 8


def signals_outside_message(db: Database) -> list[str]:
    """``MESSAGE.SIGNAL`` of every signal whose bits run past its message's length, in DBC order."""
    out: list[str] = []
    for message in db.messages:
        for signal in message.signals:
            if signal_last_byte(signal.start, signal.length, signal.byte_order) >= message.length:
                out.append(f"{message.name}.{signal.name}")
    return out


def _describe(exc: BaseException, text: str, source: str) -> str:
    parse_error = _find_parse_error(exc)
    if parse_error is not None:
        line, column, reason = parse_error
        return f"{source}:{line}:{column}: DBC syntax error: {reason}"
    reason = str(exc) or type(exc).__name__
    found = _line_for_reason(reason, text)
    where = f"{source}:{found}" if found else source
    return f"{where}: invalid DBC: {reason}"


def _find_parse_error(exc: BaseException) -> tuple[int, int, str] | None:
    seen: set[int] = set()
    stack: list[BaseException | None] = [exc]
    while stack:
        e = stack.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        line = getattr(e, "line", None)
        column = getattr(e, "column", None)
        if isinstance(line, int) and isinstance(column, int):
            return line, column, str(e)
        stack.extend([e.__cause__, e.__context__])
        stack.extend(v for v in vars(e).values() if isinstance(v, BaseException))
    return None


def _line_for_reason(reason: str, text: str) -> int | None:
    """Best effort: the line of the first message or signal named in a semantic error."""
    for name in re.findall(r"[A-Za-z_][A-Za-z0-9_]*", reason):
        line = dbc_text_line_of(text, name)
        if line is not None:
            return line
    return None


def dbc_text_line_of(text: str, name: str) -> int | None:
    """1-based line where message or signal ``name`` is defined in DBC ``text`` (None if absent)."""
    pattern = re.compile(rf"^\s*(?:BO_\s+\d+\s+{re.escape(name)}\s*:|SG_\s+{re.escape(name)}\b)")
    for number, line in enumerate(text.splitlines(), start=1):
        if pattern.match(line):
            return number
    return None
