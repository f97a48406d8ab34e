"""Every topic of a vsc-rig session file: names, schemas, encodings and the binary block layouts.

This module is the single source of truth for what a session file (MCAP) contains. The recorder
registers channels from it, the readers and analysis decode with it, and the README's "Topics"
table is generated from it (:func:`topics_markdown`). Nothing else in the project spells a topic name or a schema.

Two kinds of topic:

- *raw*, lossless, as received (``/gnss/<receiver>/raw``, ``/relay/raw``, ``/can/<bus>/frames``,
  ``/daq/<device>/samples``, ``/sim/truth``): little-endian binary blocks whose layout is given
  here as numpy dtypes and ``struct`` formats (message encoding :data:`BINARY_ENCODING`, schema
  encoding :data:`LAYOUT_SCHEMA_ENCODING`: the schema record holds a JSON description of the
  layout, so a file explains itself);
- *decoded*, for people and tools: JSON messages with JSON Schemas, so Foxglove can plot and map
  them (``foxglove.LocationFix`` uses the official Foxglove field names). No JSON integer reaches 2^53,
  where a JavaScript reader's double stops being exact: integer-ns times are objects of two integers
  (:class:`NsField`: GPS time as ``{week, tow_ns}``, Unix times as ``foxglove.Time``, offsets as
  ``foxglove.Duration``), and readers get them back as int ns (decision record 0005).

Times: ``log_time`` is the best estimate of when the thing happened on the common time base
(GPS-derived UTC, ns since the Unix epoch); ``publish_time`` is the host receive time.
"""

from __future__ import annotations

import json
import math
import re
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum, IntFlag, StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from vsccore.roles import ROLE_SI_UNITS

if TYPE_CHECKING:
    import can

    from sim_devices.vehicle.truth import GroundTruth

__all__ = [
    "BINARY_ENCODING",
    "CAN_BLOCK_HEADER",
    "CAN_DEVICE_TIME",
    "DAQ_BLOCK_HEADER",
    "EVENT_END",
    "EVENT_START",
    "GPS_TIME",
    "GPS_WEEK_NS",
    "JSON_ENCODING",
    "JSON_SCHEMA_ENCODING",
    "JS_EXACT_INT",
    "LAYOUT_SCHEMA_ENCODING",
    "METADATA_CALIBRATION",
    "METADATA_PART",
    "METADATA_PART_END",
    "METADATA_RECORDER",
    "METADATA_SESSION",
    "METADATA_VEHICLE",
    "NO_TIME_NS",
    "TIMEBASE_OFFSET",
    "TOPICS",
    "TOPIC_EVENTS",
    "TOPIC_RELAY_RAW",
    "TOPIC_RELAY_STATS",
    "TOPIC_SIM_TRUTH",
    "TOPIC_TIMEBASE",
    "TRUTH_DTYPE",
    "CanFlag",
    "CanFrameRecord",
    "DaqBlock",
    "Event",
    "EventKind",
    "NsField",
    "NsForm",
    "SchemaSpec",
    "Severity",
    "TopicSpec",
    "can_dtype",
    "can_frames",
    "can_roles",
    "daq_samples",
    "decode_json",
    "encode_json",
    "encode_record",
    "flatten_metadata",
    "foxglove_duration",
    "foxglove_time",
    "gnss_bestpos",
    "gnss_bestvel",
    "gnss_fix",
    "gnss_heading",
    "gnss_markpos",
    "gnss_marktime",
    "gnss_raw",
    "gnss_time",
    "gps_week_tow",
    "location_fix",
    "optical",
    "pack_can_block",
    "pack_can_columns",
    "pack_daq_block",
    "pack_truth_block",
    "spec_for_topic",
    "topics_markdown",
    "unpack_can_block",
    "unpack_can_blocks",
    "unpack_can_frames",
    "unpack_daq_block",
    "unpack_truth_block",
    "validate_json",
]

JSON_ENCODING = "json"
"""MCAP message encoding of decoded topics."""
JSON_SCHEMA_ENCODING = "jsonschema"
"""MCAP schema encoding of decoded topics (well known: Foxglove understands it)."""
BINARY_ENCODING = "vsc_rig.binary"
"""MCAP message encoding of raw topics: little-endian binary blocks described by the schema."""
LAYOUT_SCHEMA_ENCODING = "vsc_rig.layout+json"
"""MCAP schema encoding of raw topics: a JSON document describing the binary layout."""

NO_TIME_NS = -(2**63)
"""Sentinel for "no device time" in int64 time columns (e.g. a CAN interface without timestamps)."""

# Metadata record names (MCAP metadata: name → {str: str}).
METADATA_SESSION = "vsc_rig.session"
"""Session configuration as given by the caller (flattened, see :func:`flatten_metadata`)."""
METADATA_VEHICLE = "vsc_rig.vehicle"
"""Vehicle configuration (profile) as given by the caller."""
METADATA_CALIBRATION = "vsc_rig.calibration"
"""Calibration values in force during the session."""
METADATA_RECORDER = "vsc_rig.recorder"
"""Written by the recorder in every part: software version, host, part index, options."""
METADATA_PART = METADATA_RECORDER
METADATA_PART_END = "vsc_rig.part_end"
"""Written by the recorder at the end of every part: why it ended, counts, the next part."""

_NAME_RE = re.compile(r"[A-Za-z0-9_\-]+")


# ---------------------------------------------------------------------------------------------
# JSON
# ---------------------------------------------------------------------------------------------


def _json_default(obj: object) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Enum):
        return obj.value
    if isinstance(obj, bytes | bytearray | memoryview):
        return bytes(obj).hex()
    raise TypeError(f"cannot encode {type(obj).__name__} as JSON")


def _finite(obj: Any) -> Any:
    """Replace NaN and ±inf by None (JSON has no NaN; Foxglove rejects it)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, np.floating):
        return _finite(float(obj))
    return obj


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_json_default)
"""One encoder for every record (json.dumps with options builds a new one per call; this runs per CAN frame)."""


def encode_json(obj: Any) -> bytes:
    """Compact UTF-8 JSON; numpy scalars/arrays and enums are converted, NaN/inf become null."""
    try:
        text = _ENCODER.encode(obj)
    except ValueError:
        text = _ENCODER.encode(_finite(obj))
    return text.encode()


def _without_nulls(obj: Any) -> Any:
    """``obj`` with every object member whose value is None, NaN or ±inf left out (arrays keep their length)."""
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            v = _finite(v) if isinstance(v, float | np.floating) else v
            if v is not None:
                out[k] = _without_nulls(v)
        return out
    if isinstance(obj, list | tuple):
        return [_without_nulls(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, float | np.floating):
        return _finite(obj)
    return obj


def encode_record(obj: Any) -> bytes:
    """A decoded message as compact JSON, a field whose value is unknown (None, NaN, ±inf) left out.

    A schema field that can be unknown is optional and has exactly one type: JSON-Schema validators
    (Draft 2020-12) accept its absence, where they reject ``null`` for ``"type": "number"``, and
    Foxglove's schema reader takes one type per field (no ``["number", "null"]``). Readers treat an
    absent field as unknown.
    """
    try:
        text = _ENCODER.encode(obj)
    except ValueError:
        text = "null"  # NaN or inf somewhere: take the slow path below
    if "null" in text:
        text = _ENCODER.encode(_without_nulls(obj))
    return text.encode()


def decode_json(data: bytes) -> Any:
    """Inverse of :func:`encode_json`."""
    return json.loads(data)


def flatten_metadata(obj: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Flatten nested configuration into MCAP metadata (``{"a.b": "1"}``; lists as JSON).

    MCAP metadata values are strings; dotted keys keep them readable in Foxglove and ``rig info``.
    """
    out: dict[str, str] = {}
    for key, value in obj.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            if value:
                out.update(flatten_metadata(value, prefix=f"{name}."))
            else:
                out[name] = "{}"
        elif isinstance(value, str):
            out[name] = value
        elif value is None:
            out[name] = "null"
        else:
            out[name] = encode_json(value).decode()
    return out


def validate_json(schema: Mapping[str, Any], value: Any, path: str = "$") -> list[str]:
    """Check ``value`` against the subset of JSON Schema used here; return the problems found.

    Supports ``type`` (one or a list), ``properties``, ``required``, ``additionalProperties``,
    ``items``, ``minItems``/``maxItems``, ``enum``, ``const``, ``oneOf``, ``minimum``/``maximum``. A
    member whose value is None counts as absent, as :func:`encode_record` writes it (see :func:`_num`).
    """
    problems: list[str] = []
    types = schema.get("type")
    if types is not None:
        allowed = [types] if isinstance(types, str) else list(types)
        if not any(_is_type(value, t) for t in allowed):
            return [f"{path}: expected {'/'.join(allowed)}, got {type(value).__name__}"]
    if "const" in schema and value != schema["const"]:
        problems.append(f"{path}: expected {schema['const']!r}, got {value!r}")
    if "enum" in schema and value not in schema["enum"]:
        problems.append(f"{path}: {value!r} is not one of {schema['enum']}")
    if "oneOf" in schema:
        matches = sum(1 for sub in schema["oneOf"] if not validate_json(sub, value, path))
        if matches != 1:
            problems.append(f"{path}: matches {matches} of the oneOf alternatives, expected exactly 1")
    if isinstance(value, int | float) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            problems.append(f"{path}: {value} < minimum {schema['minimum']}")
        if "maximum" in schema and value > schema["maximum"]:
            problems.append(f"{path}: {value} > maximum {schema['maximum']}")
    if isinstance(value, dict):
        props: Mapping[str, Any] = schema.get("properties", {})
        for req in schema.get("required", ()):
            if value.get(req) is None:
                problems.append(f"{path}: missing required field {req!r}")
        extra = schema.get("additionalProperties", True)
        for key, sub in value.items():
            if sub is None:
                continue
            if key in props:
                problems.extend(validate_json(props[key], sub, f"{path}.{key}"))
            elif extra is False:
                problems.append(f"{path}: unexpected field {key!r}")
            elif isinstance(extra, Mapping):
                problems.extend(validate_json(extra, sub, f"{path}.{key}"))
    if isinstance(value, list):
        if "minItems" in schema and len(value) < schema["minItems"]:
            problems.append(f"{path}: {len(value)} items < minItems {schema['minItems']}")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            problems.append(f"{path}: {len(value)} items > maxItems {schema['maxItems']}")
        if "items" in schema:
            for i, item in enumerate(value):
                problems.extend(validate_json(schema["items"], item, f"{path}[{i}]"))
    return problems


def _is_type(value: Any, t: str) -> bool:
    if t == "object":
        return isinstance(value, dict)
    if t == "array":
        return isinstance(value, list)
    if t == "string":
        return isinstance(value, str)
    if t == "boolean":
        return isinstance(value, bool)
    if t == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if t == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    if t == "null":
        return value is None
    raise ValueError(f"unknown JSON Schema type {t!r}")


# ---------------------------------------------------------------------------------------------
# Schemas and topics
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SchemaSpec:
    """One MCAP schema: name, schema encoding, message encoding and the schema document."""

    name: str
    message_encoding: str
    schema_encoding: str
    document: Mapping[str, Any]
    """The JSON Schema (decoded topics) or the layout description (raw topics)."""
    ns_fields: tuple[NsField, ...] = ()
    """The integer-ns values of a JSON topic written as objects of two integers (readers get int ns columns)."""

    @property
    def data(self) -> bytes:
        """The schema record's data (the document as JSON)."""
        return json.dumps(self.document, indent=1, sort_keys=False).encode()

    @property
    def is_json(self) -> bool:
        return self.message_encoding == JSON_ENCODING


@dataclass(frozen=True, slots=True)
class TopicSpec:
    """A topic (or family of topics: ``/gnss/{receiver}/bestpos``) and its schema."""

    pattern: str
    schema: SchemaSpec
    raw: bool
    description: str
    _regex: re.Pattern[str] = field(init=False, repr=False, compare=False)
    _params: tuple[str, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        params = tuple(re.findall(r"\{(\w+)\}", self.pattern))
        regex = re.escape(self.pattern)
        for p in params:
            regex = regex.replace(re.escape("{" + p + "}"), f"(?P<{p}>[A-Za-z0-9_\\-]+)")
        object.__setattr__(self, "_regex", re.compile(f"^{regex}$"))
        object.__setattr__(self, "_params", params)

    @property
    def params(self) -> tuple[str, ...]:
        """Names of the placeholders (``("receiver",)``)."""
        return self._params

    def topic(self, **names: str) -> str:
        """The concrete topic; names must be ``[A-Za-z0-9_-]+``."""
        if set(names) != set(self._params):
            raise ValueError(f"topic {self.pattern} needs {list(self._params)}, got {sorted(names)}")
        for key, value in names.items():
            if not _NAME_RE.fullmatch(value):
                raise ValueError(f"topic {self.pattern}: {key} {value!r} must match [A-Za-z0-9_-]+")
        return self.pattern.format(**names)

    def match(self, topic: str) -> dict[str, str] | None:
        """The placeholder values if ``topic`` belongs to this family, else None."""
        m = self._regex.match(topic)
        return None if m is None else m.groupdict()


def _obj(
    title: str,
    description: str,
    properties: Mapping[str, Any],
    required: Sequence[str],
    additional: bool | Mapping[str, Any] = True,
) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": dict(properties),
        "required": list(required),
        "additionalProperties": additional,
    }


# Foxglove's JSON-Schema reader takes exactly one "type" per field (no ["number", "null"]) and needs
# "properties" on every object, while standard validators reject null for "type": "number". So a field
# that can be unknown is optional (never in "required") and left out of the message when unknown
# (encode_record); its description says so.


JS_EXACT_INT = 2**53
"""JavaScript readers (Foxglove) read every JSON number as a double: integers with ``|v| < 2**53`` are exact,
larger ones are rounded (ns since 1970, ~2^60.6, land on a 256 ns grid: up to 128 ns off). No JSON message
of a session carries an integer that large (decision record 0005)."""

_NS_PER_S = 1_000_000_000
GPS_WEEK_NS = 604_800 * _NS_PER_S
"""One GPS week in ns."""


def foxglove_time(ns: int) -> dict[str, int]:
    """``foxglove.Time`` ``{sec, nsec}`` of integer ns since the Unix epoch. JavaScript readers (Foxglove)
    read a JSON integer as a double: ns since 1970 (~2^60.6) come out on a 256 ns grid, up to 128 ns off;
    seconds and nanoseconds apart are exact."""
    sec, nsec = divmod(int(ns), _NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def foxglove_duration(ns: int) -> dict[str, int]:
    """``foxglove.Duration`` ``{sec, nsec}`` of a signed interval in integer ns (``nsec`` in [0, 1e9), in the
    positive direction: −1.5 s is ``{sec: -2, nsec: 500000000}``)."""
    sec, nsec = divmod(int(ns), _NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def gps_week_tow(gps_ns: int) -> dict[str, int]:
    """``{week, tow_ns}`` of integer ns since the GPS epoch (1980-01-06 00:00:00 GPS time, no leap seconds):
    the full GPS week number and the time of week in ns, as a NovAtel log header states it (week and ms)."""
    week, tow_ns = divmod(int(gps_ns), GPS_WEEK_NS)
    return {"week": week, "tow_ns": tow_ns}


class NsForm(StrEnum):
    """How an integer-ns value is written in JSON: two integers, each exact in a JavaScript reader."""

    GPS_WEEK_TOW = "gps_week_tow"
    """``{week, tow_ns}`` on the GPS time scale (:func:`gps_week_tow`); not a ``foxglove.Time``, which is
    Unix time to a viewer."""
    TIME = "time"
    """``foxglove.Time`` ``{sec, nsec}``, ns since the Unix epoch (:func:`foxglove_time`)."""
    DURATION = "duration"
    """``foxglove.Duration`` ``{sec, nsec}``, a signed interval (:func:`foxglove_duration`)."""


_NS_PARTS: dict[NsForm, tuple[str, str, int]] = {
    NsForm.GPS_WEEK_TOW: ("week", "tow_ns", GPS_WEEK_NS),
    NsForm.TIME: ("sec", "nsec", _NS_PER_S),
    NsForm.DURATION: ("sec", "nsec", _NS_PER_S),
}


@dataclass(frozen=True, slots=True)
class NsField:
    """An integer-ns value of a JSON topic: member ``key`` holds it as an object of two integers (``form``);
    readers get it as int ns under ``column``, which is also the plain-integer member that files written
    before decision record 0005 carry instead (read back as well)."""

    key: str
    column: str
    form: NsForm

    @property
    def parts(self) -> tuple[str, str]:
        """The two members of the object (``("week", "tow_ns")`` or ``("sec", "nsec")``)."""
        hi, lo, _scale = _NS_PARTS[self.form]
        return hi, lo

    @property
    def scale(self) -> int:
        """ns per unit of the high part: ns = high·scale + low."""
        return _NS_PARTS[self.form][2]

    def to_json(self, ns: int | None) -> dict[str, int] | None:
        """The JSON object of ``ns`` (None stays None: the member is then left out, see :func:`encode_record`)."""
        if ns is None:
            return None
        hi, lo, scale = _NS_PARTS[self.form]
        a, b = divmod(int(ns), scale)
        return {hi: a, lo: b}

    def from_json(self, value: Any) -> int:
        """Integer ns of the JSON object (exact: Python integers).

        Raises:
            ValueError: ``value`` is not an object of the two integers, or the low part is out of range.
        """
        hi, lo, scale = _NS_PARTS[self.form]
        a = value.get(hi) if isinstance(value, Mapping) else None
        b = value.get(lo) if isinstance(value, Mapping) else None
        if not (isinstance(a, int) and isinstance(b, int)) or isinstance(a, bool) or isinstance(b, bool):
            raise ValueError(f"{self.key}: expected an object of integers {{{hi}, {lo}}}, got {value!r}")
        if not 0 <= b < scale:
            raise ValueError(f"{self.key}.{lo}: {b} is outside [0, {scale})")
        return a * scale + b

    def read(self, record: Mapping[str, Any]) -> int | None:
        """The value of ``record`` in int ns: from ``key`` (this form) or from ``column`` (a plain integer,
        as written before); None when it has neither.

        Raises:
            ValueError: a member of the wrong shape (naming it).
        """
        value = record.get(self.key)
        if value is not None:
            return self.from_json(value)
        old = record.get(self.column)
        if old is None:
            return None
        if not isinstance(old, int) or isinstance(old, bool):
            raise ValueError(f"{self.column}: expected integer ns, got {old!r}")
        return old

    def schema(self, desc: str) -> dict[str, Any]:
        """The JSON-Schema property of ``key``."""
        hi, lo, scale = _NS_PARTS[self.form]
        if self.form is NsForm.GPS_WEEK_TOW:
            return {"type": "object", "title": "vsc_rig.GpsWeekTow",
                    "description": f"{desc}: GPS time (GPS time scale, no leap seconds; not Unix time) as the full "
                    "GPS week number since 1980-01-06 and the time of week in ns; ns since the GPS epoch = "
                    "week·604800·10^9 + tow_ns",
                    "properties": {hi: {"type": "integer", "minimum": 0, "description": "GPS week number"},
                                   lo: {"type": "integer", "minimum": 0, "maximum": scale - 1,
                                        "description": "Time of week (ns)"}},
                    "required": [hi, lo], "additionalProperties": False}
        if self.form is NsForm.TIME:
            return {"type": "object", "title": "time", "description": f"{desc} as foxglove.Time (ns since the Unix "
                    "epoch = sec·10^9 + nsec)",
                    "properties": {hi: {"type": "integer", "minimum": 0},
                                   lo: {"type": "integer", "minimum": 0, "maximum": scale - 1}},
                    "required": [hi, lo], "additionalProperties": False}
        return {"type": "object", "title": "duration", "description": f"{desc} as foxglove.Duration (ns = "
                "sec·10^9 + nsec, nsec in the positive direction)",
                "properties": {hi: {"type": "integer"}, lo: {"type": "integer", "minimum": 0, "maximum": scale - 1}},
                "required": [hi, lo], "additionalProperties": False}


GPS_TIME = NsField("gps_time", "gps_time_ns", NsForm.GPS_WEEK_TOW)
"""GPS time of a decoded GNSS record (readers: ``gps_time_ns``, ns since the GPS epoch)."""
CAN_DEVICE_TIME = NsField("device_time", "device_time_ns", NsForm.TIME)
"""A decoded CAN frame's interface timestamp (readers: ``device_time_ns``)."""
TIMEBASE_OFFSET = NsField("offset", "offset_ns", NsForm.DURATION)
"""``/rig/timebase`` reference − device offset (readers: ``offset_ns``)."""
EVENT_START = NsField("start", "start_ns", NsForm.TIME)
"""Start of an event's interval (readers: :attr:`Event.start_ns`)."""
EVENT_END = NsField("end", "end_ns", NsForm.TIME)
"""End of an event's interval (readers: :attr:`Event.end_ns`)."""

_BIG_INT_RE = re.compile(r"-?[0-9]{16,19}")


def _big_ints_as_text(obj: Any) -> Any:
    """``obj`` with every integer of ``|v| >= 2**53`` as its decimal string (inside objects and arrays)."""
    if isinstance(obj, bool):
        return obj
    if isinstance(obj, int | np.integer):
        v = int(obj)
        return str(v) if abs(v) >= JS_EXACT_INT else v
    if isinstance(obj, Mapping):
        return {k: _big_ints_as_text(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_big_ints_as_text(v) for v in obj]
    return obj


def _big_ints_from_text(obj: Any) -> Any:
    """Inverse of :func:`_big_ints_as_text`: a decimal string of ``|v| >= 2**53`` (and < 2**63) is the integer."""
    if isinstance(obj, str):
        if _BIG_INT_RE.fullmatch(obj):
            v = int(obj)
            if JS_EXACT_INT <= abs(v) < 2**63:
                return v
        return obj
    if isinstance(obj, Mapping):
        return {k: _big_ints_from_text(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_big_ints_from_text(v) for v in obj]
    return obj


def _num(desc: str, nullable: bool = False) -> dict[str, Any]:
    return {"type": "number", "description": f"{desc} (absent when unknown)" if nullable else desc}


def _int(desc: str, nullable: bool = False) -> dict[str, Any]:
    return {"type": "integer", "description": f"{desc} (absent when unknown)" if nullable else desc}


def _map(desc: str, values: Mapping[str, Any] | bool, known: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """An object used as a map (``known`` keys are listed so Foxglove offers them as plot paths)."""
    return {"type": "object", "description": desc, "properties": dict(known or {}), "additionalProperties": values}


def _str(desc: str) -> dict[str, Any]:
    return {"type": "string", "description": desc}


def _bool(desc: str) -> dict[str, Any]:
    return {"type": "boolean", "description": desc}


_GPS_TIME = GPS_TIME.schema("GPS time of the solution or event from the log header")
_SOL_STATUS = _str("NovAtel solution status name (e.g. SOL_COMPUTED)")
_POS_TYPE = _str("NovAtel position or velocity type name (e.g. NARROW_INT)")

_POSITION_PROPS: dict[str, Any] = {
    "gps_time": _GPS_TIME,
    "time_status": _str("NovAtel time status of the log header (e.g. FINESTEERING)"),
    "sol_status": _SOL_STATUS,
    "pos_type": _POS_TYPE,
    "lat_deg": _num("Latitude (deg, WGS84 unless datum says otherwise)"),
    "lon_deg": _num("Longitude (deg)"),
    "height_msl_m": _num("Height above mean sea level (m)"),
    "undulation_m": _num("Geoid undulation: ellipsoidal height = height_msl_m + undulation_m (m)", True),
    "datum": _str("Datum name (WGS84)"),
    "lat_std_m": _num("Latitude standard deviation (m)"),
    "lon_std_m": _num("Longitude standard deviation (m)"),
    "height_std_m": _num("Height standard deviation (m)"),
    "base_station_id": _str("Differential base station id"),
    "diff_age_s": _num("Differential age (s)", True),
    "sol_age_s": _num("Solution age (s)", True),
    "num_svs": _int("Satellites tracked", True),
    "num_sol_svs": _int("Satellites used in the solution", True),
    "ext_sol_status": _int("Extended solution status bits", True),
}
_POSITION_REQUIRED = (
    "gps_time",
    "sol_status",
    "pos_type",
    "lat_deg",
    "lon_deg",
    "height_msl_m",
    "lat_std_m",
    "lon_std_m",
    "height_std_m",
)

SCHEMA_BESTPOS = SchemaSpec(
    "vsc_rig.gnss.BestPos",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj("vsc_rig.gnss.BestPos", "NovAtel BESTPOS of one receiver", _POSITION_PROPS, _POSITION_REQUIRED),
    ns_fields=(GPS_TIME,),
)
SCHEMA_MARKPOS = SchemaSpec(
    "vsc_rig.gnss.MarkPos",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.gnss.MarkPos",
        "NovAtel MARKPOS: position at the event-input (sync switch) edge; gps_time is the mark time",
        {**_POSITION_PROPS, "event_input": _str("Event input (MARK1, MARK2, ...)")},
        _POSITION_REQUIRED,
    ),
    ns_fields=(GPS_TIME,),
)
SCHEMA_BESTVEL = SchemaSpec(
    "vsc_rig.gnss.BestVel",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.gnss.BestVel",
        "NovAtel BESTVEL of one receiver",
        {
            "gps_time": _GPS_TIME,
            "time_status": _str("NovAtel time status of the log header"),
            "sol_status": _SOL_STATUS,
            "vel_type": _POS_TYPE,
            "latency_s": _num("Velocity latency: the velocity is valid latency_s before gps_time (s)"),
            "diff_age_s": _num("Differential age (s)", True),
            "hor_speed_mps": _num("Horizontal speed over ground (m/s)"),
            "track_over_ground_deg": _num("Course over ground, azimuth clockwise from true north (deg)"),
            "vert_speed_mps": _num("Vertical speed, positive up (m/s)"),
        },
        (
            "gps_time",
            "sol_status",
            "vel_type",
            "latency_s",
            "hor_speed_mps",
            "track_over_ground_deg",
            "vert_speed_mps",
        ),
    ),
    ns_fields=(GPS_TIME,),
)
_CLOCK_PROPS: dict[str, Any] = {
    "gps_time": _GPS_TIME,
    "clock_status": _str("NovAtel clock model status (e.g. VALID)"),
    "clock_offset_s": _num("Receiver clock offset (s)", True),
    "clock_offset_std_s": _num("Receiver clock offset standard deviation (s)", True),
    "utc_offset_s": _num("UTC − GPS offset reported by the receiver (s, e.g. −18)", True),
}
SCHEMA_MARKTIME = SchemaSpec(
    "vsc_rig.gnss.MarkTime",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.gnss.MarkTime",
        "NovAtel MARKTIME: GPS time of the event-input (sync switch) edge",
        {**_CLOCK_PROPS, "event_input": _str("Event input (MARK1, MARK2, ...)")},
        ("gps_time", "clock_status"),
    ),
    ns_fields=(GPS_TIME,),
)
SCHEMA_TIME = SchemaSpec(
    "vsc_rig.gnss.Time",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.gnss.Time",
        "NovAtel TIME: receiver clock and UTC; leap_seconds is the GPS − UTC offset the time base uses",
        {
            **_CLOCK_PROPS,
            "leap_seconds": _int("GPS − UTC in whole seconds (e.g. 18), from utc_offset_s", True),
            "utc_status": _str("NovAtel UTC status (INVALID, VALID, WARNING)"),
            "utc_iso": _str("UTC date and time reported by the receiver (ISO 8601)"),
        },
        ("gps_time", "clock_status", "utc_status"),
    ),
    ns_fields=(GPS_TIME,),
)
SCHEMA_HEADING = SchemaSpec(
    "vsc_rig.gnss.Heading",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.gnss.Heading",
        "NovAtel HEADING2 / dual-antenna heading of the baseline from the main to the auxiliary antenna",
        {
            "gps_time": _GPS_TIME,
            "sol_status": _SOL_STATUS,
            "pos_type": _POS_TYPE,
            "length_m": _num("Baseline length (m)"),
            "heading_deg": _num("Baseline azimuth, clockwise from true north (deg)"),
            "pitch_deg": _num("Baseline pitch (deg)"),
            "heading_std_deg": _num("Heading standard deviation (deg)", True),
            "pitch_std_deg": _num("Pitch standard deviation (deg)", True),
            "num_svs": _int("Satellites tracked", True),
            "num_sol_svs": _int("Satellites used", True),
        },
        ("gps_time", "sol_status", "pos_type", "length_m", "heading_deg", "pitch_deg"),
    ),
    ns_fields=(GPS_TIME,),
)
# The official Foxglove schema (github.com/foxglove/schemas, LocationFix.json): same fields and types.
SCHEMA_LOCATION_FIX = SchemaSpec(
    "foxglove.LocationFix",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    {
        "title": "foxglove.LocationFix",
        "description": "A navigation satellite fix for any Global Navigation Satellite System",
        "type": "object",
        "properties": {
            "timestamp": {
                "type": "object",
                "title": "time",
                "properties": {
                    "sec": {"type": "integer", "minimum": 0},
                    "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
                },
                "description": "Timestamp of the message",
            },
            "frame_id": {
                "type": "string",
                "description": "Frame for the sensor. Latitude and longitude readings are at the origin of the frame.",
            },
            "latitude": {"type": "number", "description": "Latitude in degrees"},
            "longitude": {"type": "number", "description": "Longitude in degrees"},
            "altitude": {"type": "number", "description": "Altitude in meters"},
            "position_covariance": {
                "type": "array",
                "items": {"type": "number"},
                "minItems": 9,
                "maxItems": 9,
                "description": "Position covariance (m^2) defined relative to a tangential plane through the "
                "reported position. The components are East, North, and Up (ENU), in row-major order.",
            },
            "position_covariance_type": {
                "title": "foxglove.PositionCovarianceType",
                "description": "If `position_covariance` is available, `position_covariance_type` must be set "
                "to indicate the type of covariance.",
                "oneOf": [
                    {"title": "UNKNOWN", "const": 0},
                    {"title": "APPROXIMATED", "const": 1},
                    {"title": "DIAGONAL_KNOWN", "const": 2},
                    {"title": "KNOWN", "const": 3},
                ],
            },
        },
        # Foxglove's generated schema lists no "required"; vsc-rig always writes every field.
        "required": [
            "timestamp",
            "frame_id",
            "latitude",
            "longitude",
            "altitude",
            "position_covariance",
            "position_covariance_type",
        ],
    },
)
SCHEMA_CAN_ROLES = SchemaSpec(
    "vsc_rig.can.Roles",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.can.Roles",
        "One decoded CAN frame: the rig roles it carries, in SI units and ISO 8855 axes (plot roles.<name>)",
        {
            "can_id": _int("Arbitration id"),
            "message": _str("DBC message name"),
            "device_time": CAN_DEVICE_TIME.schema(
                "Interface timestamp on the interface's clock (python-can's seconds since the Unix epoch; not the "
                "common time base; absent when the interface gives none)"),
            "roles": _map(
                "role → SI value (only the roles this frame carries); other role names may appear",
                {"type": "number", "description": "SI value (absent when unknown)"},
                {role: _num(f"{role} ({unit})", True) for role, unit in ROLE_SI_UNITS.items()},
            ),
            "valid": _bool("False when the frame's quality bit, counter or checksum flags it"),
            "flags": {
                "type": "array",
                "items": {"type": "string"},
                "description": "Problems found (COUNTER_JUMP, CHECKSUM, INVALID, ...)",
            },
        },
        ("can_id", "message", "roles", "valid"),
    ),
    ns_fields=(CAN_DEVICE_TIME,),
)
SCHEMA_OPTICAL = SchemaSpec(
    "vsc_rig.optical.Sample",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.optical.Sample",
        "Scaled outputs of a Correvit-type optical sensor at its mounting point (SI, ISO 8855 axes)",
        {
            "sample_index": _int("DAQ sample index of this value (null when it came from CAN)", True),
            "vx_mps": _num("Longitudinal velocity (m/s)", True),
            "vy_mps": _num("Lateral velocity, positive left (m/s)", True),
            "speed_mps": _num("Speed over ground (m/s)", True),
            "slip_angle_rad": _num("Slip angle atan2(vy, vx) at the sensor (rad)", True),
            "valid": _bool("The sensor's validity output"),
        },
        ("valid",),
    ),
)
SCHEMA_RELAY_STATS = SchemaSpec(
    "vsc_rig.relay.Stats",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.relay.Stats",
        "RTK correction relay statistics since the start of the session",
        {
            "source": _str("Correction source (receiver:base, ntrip://..., a port)"),
            "format": _str("rtcmv3, rtca, cmr, novatel"),
            "bytes_in": _int("Bytes read from the source"),
            "frames_in": _int("Whole correction frames read"),
            "crc_errors": _int("Frames dropped for a bad CRC"),
            "frames_by_type": _map("frame type (e.g. RTCM 1077) → count", {"type": "integer"}),
            "sinks": _map(
                "sink → counters",
                {
                    "type": "object",
                    "properties": {
                        "bytes_out": _int("Bytes written to the sink"),
                        "frames_out": _int("Frames written to the sink"),
                        "dropped": _int("Frames dropped for this sink (queue full)"),
                    },
                },
            ),
            "age_s": _num("Age of the last correction frame (s)", True),
            "rate_bps": _num("Input rate over the last interval (bytes/s)", True),
        },
        ("bytes_in", "frames_in", "crc_errors"),
    ),
)
SCHEMA_TIMEBASE = SchemaSpec(
    "vsc_rig.TimebaseQuality",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.TimebaseQuality",
        "How well one device clock is mapped to the common time base (GPS-derived UTC)",
        {
            "clock": _str("Clock name (receiver, CAN bus, DAQ device, host)"),
            "method": _str("lower_envelope (device vs host receive times) or sync_pulse (DAQ edges vs MARKTIME)"),
            "reference": _str("What the clock is mapped to (host, gps)"),
            "status": _str("ok, converging, no_data, stale"),
            "n": _int("Pairs or matched pulses used"),
            "span_s": _num("Device-time span of the data used (s)"),
            "offset": TIMEBASE_OFFSET.schema("reference − device at the reference point (absent when unknown)"),
            "drift_ppm": _num("Rate of the reference relative to the device clock, minus 1, in ppm", True),
            "jitter_ns": _num("Standard deviation of the residuals above the envelope (ns)", True),
            "latency_p50_ns": _num("Median residual above the envelope (ns)", True),
            "latency_p95_ns": _num("95th percentile residual above the envelope (ns)", True),
            "rms_ns": _num("RMS of the sync-pulse residuals (ns)", True),
            "max_abs_ns": _num("Largest absolute sync-pulse residual (ns)", True),
            "leap_seconds": _int("GPS − UTC (s) used", True),
        },
        ("clock", "method", "reference", "status", "n"),
    ),
    ns_fields=(TIMEBASE_OFFSET,),
)


class EventKind(StrEnum):
    """What an entry of ``/rig/events`` is about."""

    SESSION_START = "session_start"
    SESSION_STOP = "session_stop"
    MARK = "mark"
    CONNECT = "connect"
    DISCONNECT = "disconnect"
    ERROR = "error"
    WARNING = "warning"
    GAP = "gap"
    OVERFLOW = "overflow"
    CALIBRATION = "calibration"
    DISK_SPACE = "disk_space"
    ROLLOVER = "rollover"
    TIMEBASE = "timebase"
    INFO = "info"


class Severity(StrEnum):
    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


SCHEMA_EVENT = SchemaSpec(
    "vsc_rig.Event",
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    _obj(
        "vsc_rig.Event",
        "Something that happened during the session: marks, device connect/disconnect, errors, gaps, "
        "queue overflows, calibration results",
        {
            "kind": {"type": "string", "enum": [k.value for k in EventKind], "description": "What happened"},
            "severity": {"type": "string", "enum": [s.value for s in Severity]},
            "source": _str("Device or component concerned"),
            "text": _str("One line for people"),
            "start": EVENT_START.schema("Start of the affected interval on the common time base, if any"),
            "end": EVENT_END.schema("End of the affected interval on the common time base, if any"),
            "details": _map("Machine-readable details (counts, topics, values; an integer beyond ±2^53, such as ns "
                            "since an epoch, as its decimal string, exact in JavaScript readers)", True),
        },
        ("kind", "severity", "source", "text"),
    ),
    ns_fields=(EVENT_START, EVENT_END),
)


def _layout(name: str, doc: str, **fields: Any) -> SchemaSpec:
    return SchemaSpec(
        name,
        BINARY_ENCODING,
        LAYOUT_SCHEMA_ENCODING,
        {"layout": name, "version": 1, "byte_order": "little", "description": doc, **fields},
    )


SCHEMA_RAW_BYTES = _layout(
    "vsc_rig.RawBytes",
    "The bytes exactly as read from the port, one read per message; publish_time is the host receive time",
    payload="bytes",
)

CAN_BLOCK_MAGIC = b"VCAN"
CAN_BLOCK_HEADER = struct.Struct("<4sHBBII")
"""CAN frame block header: magic b"VCAN", version u16 (1), data width u8 (8 or 64), reserved u8, frame count
u32, reserved u32 — 16 bytes, then ``count`` records of :func:`can_dtype` (width)."""


class CanFlag(IntFlag):
    """Per-frame flags of the CAN block layout (uint8)."""

    EXTENDED = 0x01
    ERROR = 0x02
    FD = 0x04
    REMOTE = 0x08
    RX = 0x10
    """Received from the bus (clear: an echo of a frame this host sent)."""
    BRS = 0x20
    """CAN FD bit-rate switch."""
    ESI = 0x40
    """CAN FD error-state indicator."""


_CAN_DTYPES: dict[int, np.dtype[Any]] = {}


def can_dtype(width: int = 64) -> np.dtype[Any]:
    """Record dtype of a CAN block with ``width`` data bytes per frame (8: classic only, 64: any)."""
    if width not in (8, 64):
        raise ValueError(f"CAN block data width must be 8 or 64, got {width}")
    dt = _CAN_DTYPES.get(width)
    if dt is None:
        dt = np.dtype(
            [
                ("device_ts_ns", "<i8"),
                ("host_ts_ns", "<i8"),
                ("can_id", "<u4"),
                ("flags", "u1"),
                ("dlc", "u1"),
                ("len", "u1"),
                ("reserved", "u1"),
                ("data", "u1", (width,)),
            ]
        )
        _CAN_DTYPES[width] = dt
    return dt


SCHEMA_CAN_FRAMES = _layout(
    "vsc_rig.can.FrameBlock",
    "A block of CAN frames as received: 16-byte header then fixed-size records. device_ts_ns is the interface "
    f"timestamp ({NO_TIME_NS} when the interface gives none), host_ts_ns the host receive time, dlc the code on "
    "the wire (0..15), len the number of data bytes (0 for remote frames), data zero-padded to the width.",
    header={
        "struct": CAN_BLOCK_HEADER.format,
        "fields": ["magic=VCAN", "version=1", "data_width (8|64)", "reserved", "count", "reserved"],
    },
    record_dtype={str(w): can_dtype(w).descr for w in (8, 64)},
    flags={f.name: int(f.value) for f in CanFlag if f.name},
)

DAQ_BLOCK_MAGIC = b"VDAQ"
DAQ_BLOCK_HEADER = struct.Struct("<4sHBBHHIqd")
"""DAQ block header (32 bytes): magic b"VDAQ", version u16 (1), sample type u8 (1 float32 volts, 2 int16
counts), reserved u8, channel count u16, reserved u16, samples per channel u32, first sample index i64,
sample rate f64 (Hz). Then per channel scale f64 and offset f64 (volts = raw·scale + offset), then per
channel a u16-length-prefixed UTF-8 name, zero padding to a multiple of 8, then the samples,
channel-major (n_channels × n_samples)."""
_DAQ_TYPES: dict[int, np.dtype[Any]] = {1: np.dtype("<f4"), 2: np.dtype("<i2")}

SCHEMA_DAQ_SAMPLES = _layout(
    "vsc_rig.daq.SampleBlock",
    "A block of analog samples, lossless as the DAQ delivered them (float32 volts or int16 counts with "
    "per-channel scale/offset); sample i of the block has index first_sample_index + i.",
    header={"struct": DAQ_BLOCK_HEADER.format},
    sample_types={"1": "<f4 volts", "2": "<i2 counts"},
)

TRUTH_MAGIC = b"VSIM"
TRUTH_HEADER = struct.Struct("<4sHHI4xddd")
"""Truth block header (40 bytes): magic b"VSIM", version u16 (1), reserved u16, count u32, 4 pad bytes,
origin latitude f64 (deg), longitude f64 (deg), height f64 (m); then ``count`` TRUTH_DTYPE records."""
_TRUTH_SCALARS = (
    "east",
    "north",
    "yaw",
    "vx",
    "vy",
    "yaw_rate",
    "ax",
    "ay",
    "ax_meas",
    "ay_meas",
    "roll",
    "roll_rate",
    "road_wheel_angle",
    "swa",
)
TRUTH_DTYPE: np.dtype[Any] = np.dtype(
    [("time_ns", "<i8"), ("t_s", "<f8")]
    + [(name, "<f8") for name in _TRUTH_SCALARS]
    + [("wheel_speed", "<f8", (4,)), ("wheel_load", "<f8", (4,)), ("ltr", "<f8")]
)
SCHEMA_SIM_TRUTH = _layout(
    "vsc_rig.sim.Truth",
    "SIMULATION ONLY: ground truth of the simulated vehicle (sim_devices.vehicle.truth.GroundTruth fields, SI, "
    "ISO 8855); time_ns on the common time base, t_s seconds since the start of the drive.",
    header={"struct": TRUTH_HEADER.format},
    record_dtype=TRUTH_DTYPE.descr,
)


def _spec(pattern: str, schema: SchemaSpec, description: str) -> TopicSpec:
    return TopicSpec(pattern, schema, schema.message_encoding == BINARY_ENCODING, description)


TOPICS: tuple[TopicSpec, ...] = (
    _spec("/gnss/{receiver}/raw", SCHEMA_RAW_BYTES, "Bytes from the receiver's port, as received"),
    _spec("/gnss/{receiver}/bestpos", SCHEMA_BESTPOS, "BESTPOS"),
    _spec("/gnss/{receiver}/bestvel", SCHEMA_BESTVEL, "BESTVEL"),
    _spec("/gnss/{receiver}/markpos", SCHEMA_MARKPOS, "MARKPOS (sync switch)"),
    _spec("/gnss/{receiver}/marktime", SCHEMA_MARKTIME, "MARKTIME (sync switch)"),
    _spec("/gnss/{receiver}/time", SCHEMA_TIME, "TIME (clock, UTC offset)"),
    _spec("/gnss/{receiver}/heading", SCHEMA_HEADING, "Dual-antenna heading"),
    _spec("/gnss/{receiver}/fix", SCHEMA_LOCATION_FIX, "Antenna position for maps"),
    _spec("/relay/raw", SCHEMA_RAW_BYTES, "Correction bytes relayed to the rovers, as received"),
    _spec("/relay/stats", SCHEMA_RELAY_STATS, "Correction relay statistics"),
    _spec("/can/{bus}/frames", SCHEMA_CAN_FRAMES, "Every CAN frame, in blocks"),
    _spec("/can/{bus}/roles", SCHEMA_CAN_ROLES, "Decoded CAN roles, one message per decoded frame"),
    _spec("/daq/{device}/samples", SCHEMA_DAQ_SAMPLES, "DAQ sample blocks"),
    _spec("/optical/{sensor}", SCHEMA_OPTICAL, "Scaled optical slip sensor outputs"),
    _spec("/rig/timebase", SCHEMA_TIMEBASE, "Time-base quality per clock"),
    _spec("/rig/events", SCHEMA_EVENT, "Session events"),
    _spec("/sim/truth", SCHEMA_SIM_TRUTH, "Simulator ground truth (simulated sessions only)"),
)

TOPIC_RELAY_RAW = "/relay/raw"
TOPIC_RELAY_STATS = "/relay/stats"
TOPIC_TIMEBASE = "/rig/timebase"
TOPIC_EVENTS = "/rig/events"
TOPIC_SIM_TRUTH = "/sim/truth"

_BY_PATTERN = {t.pattern: t for t in TOPICS}


def _family(pattern: str) -> TopicSpec:
    return _BY_PATTERN[pattern]


@dataclass(frozen=True, slots=True)
class LogField:
    """One field of a decoded GNSS topic record: ``key`` in the record, taken from attribute (or
    column) ``name`` of the NovAtel log's header or body; enums are recorded by name."""

    key: str
    """The column readers get (:mod:`rig.data`)."""
    name: str
    header: bool = False
    enum: type[Enum] | None = None
    ns: NsField | None = None
    """How the value is written in JSON when it is an integer-ns time (``key`` is then ``ns.column``)."""

    @property
    def json_key(self) -> str:
        """The member of the JSON record."""
        return self.key if self.ns is None else self.ns.key

    def to_json(self, value: Any) -> Any:
        """``value`` as written in the JSON record (enums by name: see :attr:`enum`, done by the caller)."""
        return value if self.ns is None else self.ns.to_json(value)


def _gnss_record_fields() -> dict[str, tuple[LogField, ...]]:
    from drivers.novatel.enums import ClockModelStatus, Datum, PositionType, SolutionStatus, TimeStatus, UTCStatus

    gps = LogField(GPS_TIME.column, "gps_ns", header=True, ns=GPS_TIME)
    sol = LogField("sol_status", "sol_status", enum=SolutionStatus)
    clock = (LogField("clock_status", "clock_status", enum=ClockModelStatus), LogField("clock_offset_s", "offset_s"),
             LogField("clock_offset_std_s", "offset_std_s"), LogField("utc_offset_s", "utc_offset_s"))
    return {
        "position": (
            gps, LogField("time_status", "time_status", header=True, enum=TimeStatus), sol,
            LogField("pos_type", "pos_type", enum=PositionType), LogField("lat_deg", "lat_deg"),
            LogField("lon_deg", "lon_deg"), LogField("height_msl_m", "hgt_m"), LogField("undulation_m", "undulation_m"),
            LogField("datum", "datum", enum=Datum), LogField("lat_std_m", "lat_sigma_m"),
            LogField("lon_std_m", "lon_sigma_m"), LogField("height_std_m", "hgt_sigma_m"),
            LogField("base_station_id", "stn_id"), LogField("diff_age_s", "diff_age_s"),
            LogField("sol_age_s", "sol_age_s"), LogField("num_svs", "num_svs"), LogField("num_sol_svs", "num_soln_svs"),
            LogField("ext_sol_status", "ext_sol_stat"),
        ),
        "velocity": (
            gps, LogField("time_status", "time_status", header=True, enum=TimeStatus), sol,
            LogField("vel_type", "vel_type", enum=PositionType), LogField("latency_s", "latency_s"),
            LogField("diff_age_s", "diff_age_s"), LogField("hor_speed_mps", "hor_spd_mps"),
            LogField("track_over_ground_deg", "trk_gnd_deg"), LogField("vert_speed_mps", "vert_spd_mps"),
        ),
        "heading": (
            gps, sol, LogField("pos_type", "pos_type", enum=PositionType), LogField("length_m", "length_m"),
            LogField("heading_deg", "heading_deg"), LogField("pitch_deg", "pitch_deg"),
            LogField("heading_std_deg", "heading_sigma_deg"), LogField("pitch_std_deg", "pitch_sigma_deg"),
            LogField("num_svs", "num_svs"), LogField("num_sol_svs", "num_soln_svs"),
        ),
        # the event's GPS time, not the log's; plus event_input (always MARK1)
        "marktime": (LogField(GPS_TIME.column, "event_gps_ns", ns=GPS_TIME), *clock),
        # plus utc_iso, formatted from the UTC fields
        "time": (gps, *clock, LogField("leap_seconds", "leap_seconds"),
                 LogField("utc_status", "utc_status", enum=UTCStatus)),
    }


if TYPE_CHECKING:
    GNSS_RECORD_FIELDS: Mapping[str, tuple[LogField, ...]]
    """The fields of the decoded GNSS records by kind (``position`` for BESTPOS and MARKPOS, ``velocity``,
    ``heading`` for HEADING and HEADING2, ``marktime``, ``time``): one table for the recorder, which
    builds them from each decoded log, and for :mod:`rig.data`, which builds them from raw bytes.
    Built on first use (:func:`__getattr__`): the NovAtel enums it names import the whole codec,
    which ``rig info`` and ``rig --help`` do not need."""


def __getattr__(name: str) -> Any:
    if name == "GNSS_RECORD_FIELDS":
        table = globals()["GNSS_RECORD_FIELDS"] = _gnss_record_fields()
        return table
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def gnss_raw(receiver: str) -> str:
    return _family("/gnss/{receiver}/raw").topic(receiver=receiver)


def gnss_bestpos(receiver: str) -> str:
    return _family("/gnss/{receiver}/bestpos").topic(receiver=receiver)


def gnss_bestvel(receiver: str) -> str:
    return _family("/gnss/{receiver}/bestvel").topic(receiver=receiver)


def gnss_markpos(receiver: str) -> str:
    return _family("/gnss/{receiver}/markpos").topic(receiver=receiver)


def gnss_marktime(receiver: str) -> str:
    return _family("/gnss/{receiver}/marktime").topic(receiver=receiver)


def gnss_time(receiver: str) -> str:
    return _family("/gnss/{receiver}/time").topic(receiver=receiver)


def gnss_heading(receiver: str) -> str:
    return _family("/gnss/{receiver}/heading").topic(receiver=receiver)


def gnss_fix(receiver: str) -> str:
    return _family("/gnss/{receiver}/fix").topic(receiver=receiver)


def can_frames(bus: str) -> str:
    return _family("/can/{bus}/frames").topic(bus=bus)


def can_roles(bus: str) -> str:
    return _family("/can/{bus}/roles").topic(bus=bus)


def daq_samples(device: str) -> str:
    return _family("/daq/{device}/samples").topic(device=device)


def optical(sensor: str) -> str:
    return _family("/optical/{sensor}").topic(sensor=sensor)


def topics_markdown() -> str:
    """The README's "Topics" table, generated from :data:`TOPICS` (a test keeps the README in step)."""
    lines = ["| topic | kind | schema | contents |", "|---|---|---|---|"]
    for t in TOPICS:
        kind = "raw" if t.raw else "decoded"
        lines.append(f"| `{t.pattern}` | {kind} | `{t.schema.name}` | {t.description} |")
    return "\n".join(lines) + "\n"


def spec_for_topic(topic: str) -> tuple[TopicSpec, dict[str, str]]:
    """The topic family of a concrete topic and its placeholder values.

    Raises ValueError for a topic that is not part of the session-file format.
    """
    for spec in TOPICS:
        params = spec.match(topic)
        if params is not None:
            return spec, params
    raise ValueError(f"{topic!r} is not a vsc-rig topic (see rig.core.topics.TOPICS)")


# ---------------------------------------------------------------------------------------------
# Decoded messages built here (the others are plain dicts following their schema)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Event:
    """One entry of ``/rig/events``. In JSON (:meth:`to_json`) the interval is ``start``/``end`` as
    ``foxglove.Time`` and a details integer beyond ±2^53 is its decimal string; :meth:`from_json` gives the
    int values back."""

    kind: EventKind
    source: str
    text: str
    severity: Severity = Severity.INFO
    start_ns: int | None = None
    end_ns: int | None = None
    details: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind.value,
            "severity": self.severity.value,
            "source": self.source,
            "text": self.text,
            "start": EVENT_START.to_json(self.start_ns),
            "end": EVENT_END.to_json(self.end_ns),
            "details": _big_ints_as_text(self.details),
        }

    @classmethod
    def from_json(cls, obj: Mapping[str, Any]) -> Event:
        """Inverse of :meth:`to_json`; also reads the plain-integer ``start_ns``/``end_ns`` of older files.

        Raises:
            ValueError: an unknown kind or severity, or a start/end of the wrong shape.
        """
        return cls(
            kind=EventKind(obj["kind"]),
            source=str(obj["source"]),
            text=str(obj["text"]),
            severity=Severity(obj["severity"]),
            start_ns=EVENT_START.read(obj),
            end_ns=EVENT_END.read(obj),
            details=_big_ints_from_text(dict(obj.get("details") or {})),
        )


def location_fix(
    time_ns: int,
    frame_id: str,
    lat_deg: float,
    lon_deg: float,
    height_m: float,
    lat_std_m: float | None = None,
    lon_std_m: float | None = None,
    height_std_m: float | None = None,
) -> dict[str, Any]:
    """A ``foxglove.LocationFix`` (timestamp = ``time_ns`` on the common time base, ns since the Unix epoch).

    With the three standard deviations the covariance is diagonal in ENU (east = longitude, north =
    latitude) and the type DIAGONAL_KNOWN (2); without them, zeros and UNKNOWN (0).
    """
    sec, nsec = divmod(int(time_ns), 1_000_000_000)
    cov = [0.0] * 9
    cov_type = 0
    if lat_std_m is not None and lon_std_m is not None and height_std_m is not None:
        cov[0], cov[4], cov[8] = lon_std_m**2, lat_std_m**2, height_std_m**2
        cov_type = 2
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": frame_id,
        "latitude": float(lat_deg),
        "longitude": float(lon_deg),
        "altitude": float(height_m),
        "position_covariance": cov,
        "position_covariance_type": cov_type,
    }


# ---------------------------------------------------------------------------------------------
# CAN frame blocks
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CanFrameRecord:
    """One CAN frame as stored in a ``/can/<bus>/frames`` block."""

    device_ts_ns: int | None
    host_ts_ns: int
    can_id: int
    flags: CanFlag
    dlc: int
    """Data length code on the wire (0..15)."""
    data: bytes

    def to_python_can(self) -> can.Message:
        import can as _can

        fd = bool(self.flags & CanFlag.FD)
        remote = bool(self.flags & CanFlag.REMOTE)
        return _can.Message(
            timestamp=0.0 if self.device_ts_ns is None else self.device_ts_ns / 1e9,
            arbitration_id=self.can_id,
            is_extended_id=bool(self.flags & CanFlag.EXTENDED),
            is_error_frame=bool(self.flags & CanFlag.ERROR),
            is_remote_frame=remote,
            is_fd=fd,
            is_rx=bool(self.flags & CanFlag.RX),
            bitrate_switch=bool(self.flags & CanFlag.BRS),
            error_state_indicator=bool(self.flags & CanFlag.ESI),
            dlc=_DLC_TO_LEN[self.dlc] if fd else self.dlc,
            data=None if remote else self.data,
        )


_DLC_TO_LEN = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def pack_can_columns(
    device_ts_ns: npt.ArrayLike,
    host_ts_ns: npt.ArrayLike,
    can_id: npt.ArrayLike,
    flags: npt.ArrayLike,
    dlc: npt.ArrayLike,
    length: npt.ArrayLike,
    data: npt.NDArray[np.uint8],
) -> bytes:
    """Pack frames given as columns (``data`` shape (n, w), w ≤ 64, zero padded) into one block."""
    n = int(np.shape(host_ts_ns)[0])
    lengths = np.asarray(length, dtype=np.int64)
    data_arr = np.asarray(data, dtype=np.uint8)
    if data_arr.ndim != 2 or data_arr.shape[0] != n or data_arr.shape[1] > 64:
        raise ValueError(f"CAN data must have shape (n, <=64) with n={n}, got {data_arr.shape}")
    if n and (lengths.min() < 0 or lengths.max() > data_arr.shape[1]):
        raise ValueError("CAN frame lengths must lie in [0, data width]")
    width = 8 if (n == 0 or lengths.max() <= 8) else 64
    rec = np.zeros(n, dtype=can_dtype(width))
    rec["device_ts_ns"] = device_ts_ns
    rec["host_ts_ns"] = host_ts_ns
    rec["can_id"] = can_id
    rec["flags"] = flags
    rec["dlc"] = dlc
    rec["len"] = lengths
    w = min(width, data_arr.shape[1])
    rec["data"][:, :w] = data_arr[:, :w]
    return CAN_BLOCK_HEADER.pack(CAN_BLOCK_MAGIC, 1, width, 0, n, 0) + rec.tobytes()


def pack_can_block(frames: Sequence[CanFrameRecord]) -> bytes:
    """Pack frames into one ``/can/<bus>/frames`` block (width 8 unless a frame has more than 8 bytes)."""
    n = len(frames)
    width = 8 if all(len(f.data) <= 8 for f in frames) else 64
    rec = np.zeros(n, dtype=can_dtype(width))
    for i, f in enumerate(frames):
        if len(f.data) > 64:
            raise ValueError(f"CAN frame {i}: {len(f.data)} data bytes > 64")
        if not 0 <= f.dlc <= 15:
            raise ValueError(f"CAN frame {i}: dlc {f.dlc} outside 0..15")
        r = rec[i]
        r["device_ts_ns"] = NO_TIME_NS if f.device_ts_ns is None else f.device_ts_ns
        r["host_ts_ns"] = f.host_ts_ns
        r["can_id"] = f.can_id
        r["flags"] = int(f.flags)
        r["dlc"] = f.dlc
        r["len"] = len(f.data)
        r["data"][: len(f.data)] = np.frombuffer(f.data, dtype=np.uint8)
    return CAN_BLOCK_HEADER.pack(CAN_BLOCK_MAGIC, 1, width, 0, n, 0) + rec.tobytes()


def unpack_can_block(payload: bytes | memoryview) -> npt.NDArray[Any]:
    """A block's frames as a structured array (:func:`can_dtype` of the block's width; zero copy).

    Raises :class:`~vsccore.errors.DecodeError` for a payload that is not a complete CAN block.
    """
    from vsccore.errors import DecodeError

    if len(payload) < CAN_BLOCK_HEADER.size:
        raise DecodeError(f"CAN block: {len(payload)} bytes is shorter than the {CAN_BLOCK_HEADER.size}-byte header")
    magic, version, width, _r, count, _r2 = CAN_BLOCK_HEADER.unpack_from(payload)
    if magic != CAN_BLOCK_MAGIC or version != 1 or width not in (8, 64):
        raise DecodeError(f"CAN block: bad header (magic {magic!r}, version {version}, width {width})")
    dt = can_dtype(width)
    expected = CAN_BLOCK_HEADER.size + count * dt.itemsize
    if len(payload) != expected:
        raise DecodeError(f"CAN block: {len(payload)} bytes, header says {count} frames = {expected} bytes")
    return np.frombuffer(payload, dtype=dt, count=count, offset=CAN_BLOCK_HEADER.size)


def unpack_can_blocks(payloads: Iterable[bytes | memoryview]) -> npt.NDArray[Any]:
    """All frames of many blocks as one structured array; width 64 if any block has FD frames."""
    arrays = [unpack_can_block(p) for p in payloads]
    if not arrays:
        return np.zeros(0, dtype=can_dtype(8))
    width = max(a.dtype["data"].shape[0] for a in arrays)
    out = np.zeros(sum(a.shape[0] for a in arrays), dtype=can_dtype(width))
    i = 0
    for a in arrays:
        n = a.shape[0]
        seg = out[i : i + n]
        for name in ("device_ts_ns", "host_ts_ns", "can_id", "flags", "dlc", "len"):
            seg[name] = a[name]
        seg["data"][:, : a.dtype["data"].shape[0]] = a["data"]
        i += n
    return out


def unpack_can_frames(payload: bytes | memoryview) -> list[CanFrameRecord]:
    """A block's frames as :class:`CanFrameRecord` objects (convenient, slower than the array)."""
    arr = unpack_can_block(payload)
    out: list[CanFrameRecord] = []
    for r in arr:
        dev = int(r["device_ts_ns"])
        n = int(r["len"])
        out.append(
            CanFrameRecord(
                device_ts_ns=None if dev == NO_TIME_NS else dev,
                host_ts_ns=int(r["host_ts_ns"]),
                can_id=int(r["can_id"]),
                flags=CanFlag(int(r["flags"])),
                dlc=int(r["dlc"]),
                data=bytes(r["data"][:n]),
            )
        )
    return out


# ---------------------------------------------------------------------------------------------
# DAQ sample blocks
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DaqBlock:
    """A block of DAQ samples: ``samples[c, i]`` is channel c at sample index ``first_sample_index + i``."""

    first_sample_index: int
    rate_hz: float
    channel_names: tuple[str, ...]
    samples: npt.NDArray[Any]
    """float32 volts or int16 counts, shape (n_channels, n_samples)."""
    scale: tuple[float, ...] = ()
    """Volts per count per channel (int16 blocks); empty means 1.0."""
    offset: tuple[float, ...] = ()
    """Volts at count zero per channel (int16 blocks); empty means 0.0."""

    def volts(self) -> npt.NDArray[np.float64]:
        """Samples in volts (float64), shape (n_channels, n_samples)."""
        n = len(self.channel_names)
        scale = np.asarray(self.scale or (1.0,) * n, dtype=np.float64)[:, None]
        offset = np.asarray(self.offset or (0.0,) * n, dtype=np.float64)[:, None]
        return np.asarray(self.samples, dtype=np.float64) * scale + offset


def pack_daq_block(block: DaqBlock) -> bytes:
    """Pack a :class:`DaqBlock` (float32 or int16 samples) into one ``/daq/<device>/samples`` payload."""
    samples = np.asarray(block.samples)
    if samples.dtype == np.float32:
        kind = 1
    elif samples.dtype == np.int16:
        kind = 2
    else:
        raise ValueError(f"DAQ samples must be float32 volts or int16 counts, got {samples.dtype}")
    n_ch = len(block.channel_names)
    if samples.ndim != 2 or samples.shape[0] != n_ch:
        raise ValueError(f"DAQ samples must have shape ({n_ch}, n), got {samples.shape}")
    scale = block.scale or (1.0,) * n_ch
    offset = block.offset or (0.0,) * n_ch
    if len(scale) != n_ch or len(offset) != n_ch:
        raise ValueError("DAQ block: scale and offset need one value per channel")
    parts = [
        DAQ_BLOCK_HEADER.pack(
            DAQ_BLOCK_MAGIC, 1, kind, 0, n_ch, 0, samples.shape[1], block.first_sample_index, block.rate_hz
        ),
        np.asarray([v for pair in zip(scale, offset, strict=True) for v in pair], dtype="<f8").tobytes(),
    ]
    names = b"".join(struct.pack("<H", len(b)) + b for b in (n.encode() for n in block.channel_names))
    parts.append(names + b"\0" * (-len(names) % 8))
    parts.append(np.ascontiguousarray(samples, dtype=_DAQ_TYPES[kind]).tobytes())
    return b"".join(parts)


def unpack_daq_block(payload: bytes | memoryview) -> DaqBlock:
    """Inverse of :func:`pack_daq_block` (samples are a zero-copy view of ``payload``)."""
    from vsccore.errors import DecodeError

    buf = memoryview(payload)
    if len(buf) < DAQ_BLOCK_HEADER.size:
        raise DecodeError(f"DAQ block: {len(buf)} bytes is shorter than the header")
    magic, version, kind, _r, n_ch, _r2, n, first, rate = DAQ_BLOCK_HEADER.unpack_from(buf)
    if magic != DAQ_BLOCK_MAGIC or version != 1 or kind not in _DAQ_TYPES:
        raise DecodeError(f"DAQ block: bad header (magic {bytes(magic)!r}, version {version}, type {kind})")
    pos = DAQ_BLOCK_HEADER.size
    try:
        so = np.frombuffer(buf, dtype="<f8", count=2 * n_ch, offset=pos)
        pos += 16 * n_ch
        names: list[str] = []
        start = pos
        for _ in range(n_ch):
            (ln,) = struct.unpack_from("<H", buf, pos)
            names.append(bytes(buf[pos + 2 : pos + 2 + ln]).decode())
            pos += 2 + ln
        pos += -(pos - start) % 8
        dt = _DAQ_TYPES[kind]
        if len(buf) - pos != n_ch * n * dt.itemsize:
            raise DecodeError(f"DAQ block: {len(buf) - pos} sample bytes, header says {n_ch}×{n} {dt}")
        samples = np.frombuffer(buf, dtype=dt, count=n_ch * n, offset=pos).reshape(n_ch, n)
    except (struct.error, ValueError, UnicodeDecodeError) as exc:
        if isinstance(exc, DecodeError):
            raise
        raise DecodeError(f"DAQ block: truncated or corrupt ({exc})") from exc
    return DaqBlock(
        first_sample_index=int(first),
        rate_hz=float(rate),
        channel_names=tuple(names),
        samples=samples,
        scale=tuple(float(v) for v in so[0::2]),
        offset=tuple(float(v) for v in so[1::2]),
    )


# ---------------------------------------------------------------------------------------------
# Simulator truth blocks
# ---------------------------------------------------------------------------------------------


def pack_truth_block(truth: GroundTruth, start: int, stop: int, t0_ns: int) -> bytes:
    """Pack samples ``start:stop`` of a simulated ground truth; ``time_ns = t0_ns + t·1e9``."""
    sl = slice(start, stop)
    t = np.asarray(truth.t[sl], dtype=np.float64)
    rec = np.zeros(t.shape[0], dtype=TRUTH_DTYPE)
    rec["time_ns"] = t0_ns + np.round(t * 1e9).astype(np.int64)
    rec["t_s"] = t
    for name in _TRUTH_SCALARS:
        rec[name] = getattr(truth, name)[sl]
    rec["wheel_speed"] = truth.wheel_speed[sl]
    rec["wheel_load"] = truth.wheel_load[sl]
    rec["ltr"] = truth.ltr[sl]
    header = TRUTH_HEADER.pack(TRUTH_MAGIC, 1, 0, rec.shape[0], truth.lat0_deg, truth.lon0_deg, truth.h0_m)
    return header + rec.tobytes()


def unpack_truth_block(payload: bytes | memoryview) -> tuple[npt.NDArray[Any], tuple[float, float, float]]:
    """Truth records (TRUTH_DTYPE) and the local origin (lat_deg, lon_deg, h_m) of one block."""
    from vsccore.errors import DecodeError

    if len(payload) < TRUTH_HEADER.size:
        raise DecodeError(f"truth block: {len(payload)} bytes is shorter than the header")
    magic, version, _r, count, lat0, lon0, h0 = TRUTH_HEADER.unpack_from(payload)
    if magic != TRUTH_MAGIC or version != 1:
        raise DecodeError(f"truth block: bad header (magic {magic!r}, version {version})")
    if len(payload) != TRUTH_HEADER.size + count * TRUTH_DTYPE.itemsize:
        raise DecodeError(f"truth block: {len(payload)} bytes does not hold {count} records")
    rec = np.frombuffer(payload, dtype=TRUTH_DTYPE, count=count, offset=TRUTH_HEADER.size)
    return rec, (float(lat0), float(lon0), float(h0))
