"""JSON-able dict views of decoded frames (for ``rig gnss decode`` and logs).

- NovAtel log: ``{"kind", "type": "BESTPOS", "header": {...}, "body": {...}}``; header and body
  fields keep their unit-suffixed names, enums become their names, a raw body becomes
  ``{"raw_hex": ...}`` (binary) or ``{"raw_text": ...}`` (ASCII).
- Response / prompt: ``{"kind": "response", "ok", "text"}`` / ``{"kind": "prompt", "port"}``.
- NMEA: ``{"kind": "nmea", "type": "GGA", "talker": "GP", "fields": {...}}`` with pynmea2's
  field names and values.
- RTCM3: ``{"kind": "rtcm3", "type": "1005", "message_number": 1005, "fields": {...}}`` with
  pyrtcm's data-field names.

Values that JSON cannot carry (times, bytes, non-finite floats, other objects) become strings.
"""

from __future__ import annotations

import math
from dataclasses import fields
from enum import Enum
from typing import Any

from drivers.novatel.framer import LOG_KINDS, Frame, FrameKind
from drivers.novatel.messages import BodyFormat, Header, Log, Prompt, RawBody, Response


def jsonable(value: Any) -> Any:
    """A value made JSON-safe (enums by name, bytes as hex, sequences as lists, others as str)."""
    if value is None or isinstance(value, bool | int | str):
        if isinstance(value, Enum):
            return value.name
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, Enum):
        return value.name
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    return str(value)


def _dataclass_dict(obj: Any) -> dict[str, Any]:
    return {f.name: jsonable(getattr(obj, f.name)) for f in fields(obj)}


def header_to_dict(header: Any) -> dict[str, Any]:
    """Header fields plus ``gps_ns``."""
    out = _dataclass_dict(header)
    out["gps_ns"] = header.gps_ns
    if isinstance(header, Header):
        out["receiver_status"] = f"{header.receiver_status:08x}"
        out["reserved"] = f"{header.reserved:04x}"
    return out


def body_to_dict(body: Any) -> dict[str, Any]:
    """Body fields (typed) or the raw body as hex / text."""
    if isinstance(body, RawBody):
        if body.fmt is BodyFormat.BINARY:
            return {"raw_hex": body.data.hex()}
        return {"raw_text": body.data.decode("latin-1")}
    out = _dataclass_dict(body)
    if hasattr(body, "leap_seconds"):
        out["leap_seconds"] = body.leap_seconds
    return out


def log_to_dict(log: Log) -> dict[str, Any]:
    """``{"type", "header", "body"}`` of a NovAtel log."""
    return {"type": log.header.message_name, "header": header_to_dict(log.header), "body": body_to_dict(log.body)}


def nmea_to_dict(sentence: Any) -> dict[str, Any]:
    """``{"type", "talker", "fields"}`` of a pynmea2 sentence."""
    out: dict[str, Any] = {"type": getattr(sentence, "sentence_type", type(sentence).__name__)}
    talker = getattr(sentence, "talker", None)
    if talker is not None:
        out["talker"] = talker
    values: dict[str, Any] = {}
    for spec in getattr(sentence, "fields", ()):
        attr = spec[1]
        try:
            values[attr] = jsonable(getattr(sentence, attr))
        except (ValueError, TypeError, AttributeError, IndexError):
            # pynmea2 converts lazily; an empty or odd field fails only when read
            values[attr] = None
    extra = list(getattr(sentence, "data", ()))[len(values) :]
    if extra:
        values["extra"] = extra
    out["fields"] = values
    return out


def rtcm_to_dict(message: Any) -> dict[str, Any]:
    """``{"type", "message_number", "fields"}`` of a pyrtcm message."""
    identity = str(getattr(message, "identity", ""))
    out: dict[str, Any] = {"type": identity}
    number = identity.split("_")[0]
    if number.isdigit():
        out["message_number"] = int(number)
    out["fields"] = {k: jsonable(v) for k, v in vars(message).items() if not k.startswith("_")}
    return out


def frame_to_dict(frame: Frame) -> dict[str, Any]:
    """JSON-able view of any frame (``kind`` first; ``error`` when its payload did not decode)."""
    out: dict[str, Any] = {"kind": frame.kind.value}
    msg = frame.message
    if frame.kind in LOG_KINDS and isinstance(msg, Log):
        out.update(log_to_dict(msg))
    elif isinstance(msg, Response):
        out.update({"ok": msg.ok, "text": msg.text})
    elif isinstance(msg, Prompt):
        out["port"] = msg.port
    elif frame.kind is FrameKind.NMEA and msg is not None:
        out.update(nmea_to_dict(msg))
    elif frame.kind is FrameKind.RTCM3 and msg is not None:
        out.update(rtcm_to_dict(msg))
    else:
        out["raw_hex"] = frame.raw.hex()
    if frame.error is not None:
        out["error"] = frame.error
    return out
