"""Declarative field layouts of the typed NovAtel logs, and the generic body codecs built from them.

Each typed body is described once, in wire order, by a tuple of :class:`FieldSpec` (binary type
code, ASCII form, enum). From that table this module builds, per message, a precompiled
``struct.Struct`` and per-field converter lists for binary and ASCII in both directions, so
decoding is one ``unpack_from`` plus a few dict look-ups, and no message has hand-written
parsing code except PSRDOP's variable-length PRN list.

ASCII number formats follow what OEM7 receivers print (e.g. latitude with 11 decimals, heights
with 4, ages with 3); a field printed as ``repr`` round-trips any double exactly.
"""

from __future__ import annotations

import csv
import operator
import re
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from enum import Enum
from typing import Any, cast

from drivers.novatel.enums import ClockModelStatus, Datum, PositionType, SolutionStatus, UTCStatus, _OpenIntEnum
from drivers.novatel.messages import (
    BestPos,
    BestVel,
    BestXyz,
    BodyFormat,
    ComponentType,
    Heading,
    Heading2,
    Mark1Time,
    Mark2Pos,
    Mark2Time,
    MarkPos,
    MarkTime,
    Message,
    PsrDop,
    RawBody,
    RecordEmitter,
    Time,
    Version,
    VersionComponent,
    compile_function,
)
from vsccore.errors import DecodeError, EncodeError


class Kind(Enum):
    """How a field is written in ASCII."""

    FLOAT = "float"
    INT = "int"
    HEX = "hex"
    ENUM = "enum"
    STR = "str"


@dataclass(frozen=True, slots=True)
class FieldSpec:
    """One body field: name (the dataclass field), struct code, ASCII kind and format."""

    name: str
    code: str
    kind: Kind
    fmt: str = ""  # float: format spec ("" = repr); hex: width spec such as "02x"
    enum: type[_OpenIntEnum] | None = None


def _f64(name: str, fmt: str = "") -> FieldSpec:
    return FieldSpec(name, "d", Kind.FLOAT, fmt)


def _f32(name: str, fmt: str = "") -> FieldSpec:
    return FieldSpec(name, "f", Kind.FLOAT, fmt)


def _u8(name: str) -> FieldSpec:
    return FieldSpec(name, "B", Kind.INT)


def _u32(name: str) -> FieldSpec:
    return FieldSpec(name, "I", Kind.INT)


def _i32(name: str) -> FieldSpec:
    return FieldSpec(name, "i", Kind.INT)


def _hex8(name: str) -> FieldSpec:
    return FieldSpec(name, "B", Kind.HEX, "02x")


def _enum(name: str, enum: type[_OpenIntEnum]) -> FieldSpec:
    return FieldSpec(name, "I", Kind.ENUM, enum=enum)


def _str4(name: str) -> FieldSpec:
    return FieldSpec(name, "4s", Kind.STR)


def _chars(name: str, size: int) -> FieldSpec:
    """A fixed-length NUL-padded character field (``Char[size]``), quoted in ASCII."""
    return FieldSpec(name, f"{size}s", Kind.STR)


_SIGNAL_TAIL = (
    _hex8("reserved"),
    _hex8("ext_sol_stat"),
    _hex8("galileo_beidou_sig_mask"),
    _hex8("gps_glonass_sig_mask"),
)

POSITION_FIELDS: tuple[FieldSpec, ...] = (
    _enum("sol_status", SolutionStatus),
    _enum("pos_type", PositionType),
    _f64("lat_deg", ".11f"),
    _f64("lon_deg", ".11f"),
    _f64("hgt_m", ".4f"),
    _f32("undulation_m", ".4f"),
    _enum("datum", Datum),
    _f32("lat_sigma_m", ".4f"),
    _f32("lon_sigma_m", ".4f"),
    _f32("hgt_sigma_m", ".4f"),
    _str4("stn_id"),
    _f32("diff_age_s", ".3f"),
    _f32("sol_age_s", ".3f"),
    _u8("num_svs"),
    _u8("num_soln_svs"),
    _u8("num_soln_l1_svs"),
    _u8("num_soln_multi_svs"),
    *_SIGNAL_TAIL,
)

BESTVEL_FIELDS: tuple[FieldSpec, ...] = (
    _enum("sol_status", SolutionStatus),
    _enum("vel_type", PositionType),
    _f32("latency_s", ".3f"),
    _f32("diff_age_s", ".3f"),
    _f64("hor_spd_mps", ".4f"),
    _f64("trk_gnd_deg", ".6f"),
    _f64("vert_spd_mps", ".4f"),
    _f32("reserved"),
)

BESTXYZ_FIELDS: tuple[FieldSpec, ...] = (
    _enum("p_sol_status", SolutionStatus),
    _enum("pos_type", PositionType),
    _f64("p_x_m", ".4f"),
    _f64("p_y_m", ".4f"),
    _f64("p_z_m", ".4f"),
    _f32("p_x_sigma_m", ".4f"),
    _f32("p_y_sigma_m", ".4f"),
    _f32("p_z_sigma_m", ".4f"),
    _enum("v_sol_status", SolutionStatus),
    _enum("vel_type", PositionType),
    _f64("v_x_mps", ".4f"),
    _f64("v_y_mps", ".4f"),
    _f64("v_z_mps", ".4f"),
    _f32("v_x_sigma_mps", ".4f"),
    _f32("v_y_sigma_mps", ".4f"),
    _f32("v_z_sigma_mps", ".4f"),
    _str4("stn_id"),
    _f32("v_latency_s", ".3f"),
    _f32("diff_age_s", ".3f"),
    _f32("sol_age_s", ".3f"),
    _u8("num_svs"),
    _u8("num_soln_svs"),
    _u8("num_soln_l1_svs"),
    _u8("num_soln_multi_svs"),
    *_SIGNAL_TAIL,
)

EVENT_TIME_FIELDS: tuple[FieldSpec, ...] = (
    _i32("week"),
    _f64("seconds", ".9f"),
    _f64("offset_s", ".9e"),
    _f64("offset_std_s", ".9e"),
    _f64("utc_offset_s", ".11f"),
    _enum("clock_status", ClockModelStatus),
)

TIME_FIELDS: tuple[FieldSpec, ...] = (
    _enum("clock_status", ClockModelStatus),
    _f64("offset_s", ".9e"),
    _f64("offset_std_s", ".9e"),
    _f64("utc_offset_s", ".11f"),
    _u32("utc_year"),
    _u8("utc_month"),
    _u8("utc_day"),
    _u8("utc_hour"),
    _u8("utc_min"),
    _u32("utc_ms"),
    _enum("utc_status", UTCStatus),
)

_HEADING_HEAD = (
    _enum("sol_status", SolutionStatus),
    _enum("pos_type", PositionType),
    _f32("length_m", ".9f"),
    _f32("heading_deg", ".9f"),
    _f32("pitch_deg", ".9f"),
    _f32("reserved"),
    _f32("heading_sigma_deg", ".9f"),
    _f32("pitch_sigma_deg", ".9f"),
)
_HEADING_TAIL = (
    _u8("num_svs"),
    _u8("num_soln_svs"),
    _u8("num_obs"),
    _u8("num_multi"),
    _hex8("sol_source"),
    _hex8("ext_sol_stat"),
    _hex8("galileo_beidou_sig_mask"),
    _hex8("gps_glonass_sig_mask"),
)

HEADING_FIELDS: tuple[FieldSpec, ...] = (*_HEADING_HEAD, _str4("stn_id"), *_HEADING_TAIL)
HEADING2_FIELDS: tuple[FieldSpec, ...] = (
    *_HEADING_HEAD,
    _str4("rover_stn_id"),
    _str4("master_stn_id"),
    *_HEADING_TAIL,
)

#: PSRDOP fixed part; a signed count and that many ulong PRNs follow.
PSRDOP_FIELDS: tuple[FieldSpec, ...] = (
    _f32("gdop", ".4f"),
    _f32("pdop", ".4f"),
    _f32("hdop", ".4f"),
    _f32("htdop", ".4f"),
    _f32("tdop", ".4f"),
    _f32("cutoff_deg", ".1f"),
)

# --- ASCII token helpers ---------------------------------------------------------------------


def _parse_hex(token: str) -> int:
    return int(token, 16)


def _parse_str(token: str) -> str:
    if len(token) >= 2 and token[0] == '"' and token[-1] == '"':
        return token[1:-1]
    return token


def _enum_parser(enum: type[_OpenIntEnum]) -> Callable[[str], Any]:
    members = dict(enum._member_map_)
    get = members.get
    from_token = enum.from_token

    def parse(token: str) -> Any:
        member = get(token)
        return member if member is not None else from_token(token)

    return parse


def _enum_by_value(enum: type[_OpenIntEnum]) -> Callable[[int], Any]:
    members = dict(enum._value2member_map_)
    get = members.get

    def convert(value: int) -> Any:
        member = get(value)
        return member if member is not None else enum(value)

    return convert


def _float_formatter(fmt: str) -> Callable[[Any], str]:
    if not fmt:
        return lambda v: repr(float(v))
    spec = "{:" + fmt + "}"
    return spec.format


def _hex_formatter(fmt: str) -> Callable[[Any], str]:
    spec = "{:" + fmt + "}"
    return spec.format


def _enum_formatter(value: Any) -> str:
    name = value.name
    return str(int(value)) if name.startswith("UNKNOWN_") else str(name)


def _str_formatter(value: Any) -> str:
    return f'"{value}"'


def split_ascii_fields(text: str) -> list[str]:
    """Split a comma-separated ASCII body; a comma inside a quoted string does not split."""
    if '"' in text and any("," in quoted for quoted in text.split('"')[1::2]):
        return next(csv.reader([text]))
    return text.split(",")


_ABBREV_TOKEN = re.compile(r'"[^"]*"|\S+')


def split_abbreviated_fields(text: str) -> list[str]:
    """Split abbreviated-ASCII body text on whitespace; a quoted string is one token."""
    return _ABBREV_TOKEN.findall(text)



# --- Generated fast decoders -----------------------------------------------------------------
# Decoding is the hot path (20-50 Hz per receiver, and whole captures offline). For each layout
# the table is turned once into straight-line Python: one unpack (binary) or one tuple unpack
# (ASCII), each value converted in place (enums by dict subscript, no call) and stored into a
# slot twin of the dataclass (see ``messages.RecordEmitter``), with no per-field loop, function
# dispatch or dataclass ``__init__``. A value the fast code does not take (an enum value missing
# from the table, a quoted token, a number that does not parse) raises KeyError / ValueError /
# IndexError and the caller decodes the same input again through the generic, table-walking
# methods of BodyCodec, which create UNKNOWN_ enum members, split quoted text, and name the
# failing field. Tests check that both paths agree.

_STR_CACHE: dict[bytes, str] = {}


def _decode_str4(raw: bytes) -> str:
    text = raw.rstrip(b"\0").decode("latin-1")
    if len(_STR_CACHE) < 4096:  # station IDs repeat; bound the cache against garbage
        _STR_CACHE[raw] = text
    return text


def _token_str(token: str) -> str:
    """A STR token for the fast path: a plain token, or one quoted string without inner quotes.

    Raises:
        ValueError: any other use of ``"`` (the generic splitter must handle that line).
    """
    if '"' not in token:
        return token
    if len(token) >= 2 and token[0] == '"' and token[-1] == '"' and '"' not in token[1:-1]:
        return token[1:-1]
    raise ValueError(f"token {token!r} needs the generic ASCII splitter")


#: Exceptions by which generated decoders hand an input back to the generic path.
FAST_PATH_MISSES = (KeyError, ValueError, IndexError)


def emit_binary_body(
    specs: Sequence[FieldSpec], emit: RecordEmitter, values: Sequence[str], ns: dict[str, Any]
) -> list[str]:
    """Lines that build a body from unpacked binary values (names in ``values``)."""
    ns.setdefault("_str_get", _STR_CACHE.get)
    ns.setdefault("_str_dec", _decode_str4)
    lines = [emit.begin()]
    for i, (spec, value) in enumerate(zip(specs, values, strict=True)):
        if spec.kind is Kind.ENUM:
            assert spec.enum is not None
            table = f"_by_value_{emit.var}{i}"
            ns[table] = dict(spec.enum._value2member_map_)
            expr = f"{table}[{value}]"
        elif spec.kind is Kind.STR:
            expr = f"(_str_get({value}) or _str_dec({value}))"
        else:
            expr = value
        lines.append(emit.store(spec.name, expr))
    lines.append(emit.end())
    return lines


def emit_ascii_body(
    specs: Sequence[FieldSpec], emit: RecordEmitter, tokens: Sequence[str], ns: dict[str, Any]
) -> list[str]:
    """Lines that build a body from ASCII tokens (names in ``tokens``)."""
    ns.setdefault("_float", float)
    ns.setdefault("_int", int)
    ns.setdefault("_token_str", _token_str)
    lines = [emit.begin()]
    for i, (spec, token) in enumerate(zip(specs, tokens, strict=True)):
        if spec.kind is Kind.ENUM:
            assert spec.enum is not None
            table = f"_by_name_{emit.var}{i}"
            ns[table] = dict(spec.enum._member_map_)
            expr = f"{table}[{token}]"
        elif spec.kind is Kind.STR:
            expr = f"_token_str({token})"
        elif spec.kind is Kind.FLOAT:
            expr = f"_float({token})"
        elif spec.kind is Kind.INT:
            expr = f"_int({token})"
        else:
            expr = f"_int({token}, 16)"
        lines.append(emit.store(spec.name, expr))
    lines.append(emit.end())
    return lines


def _compile_decoders(
    cls: type[Message], specs: Sequence[FieldSpec], unpack: Callable[..., tuple[Any, ...]]
) -> tuple[Callable[[bytes], Any], Callable[[Sequence[str]], Any]]:
    n = len(specs)
    values = [f"a{i}" for i in range(n)]
    tokens = [f"t{i}" for i in range(n)]
    ns: dict[str, Any] = {"_unpack": unpack}
    binary = [f"def decode_binary_{cls.__name__}(body):", "    " + ", ".join(values) + ", = _unpack(body)"]
    binary += ["    " + line for line in emit_binary_body(specs, RecordEmitter(cls, "obj", ns), values, ns)]
    binary.append("    return obj")
    ascii_ = [f"def decode_ascii_{cls.__name__}(tokens):", "    " + ", ".join(tokens) + f", = tokens[:{n}]"]
    ascii_ += ["    " + line for line in emit_ascii_body(specs, RecordEmitter(cls, "obj", ns), tokens, ns)]
    ascii_.append("    return obj")
    decode_binary = compile_function(f"decode_binary_{cls.__name__}", binary, ns)
    decode_ascii = compile_function(f"decode_ascii_{cls.__name__}", ascii_, ns)
    return decode_binary, decode_ascii


# --- Per-message codecs ----------------------------------------------------------------------


class BodyCodec:
    """Binary and ASCII codec of one typed body, built from its field table."""

    __slots__ = (
        "_ascii_formatters",
        "_ascii_parsers",
        "_enum_slots",
        "_fast_ascii",
        "_fast_binary",
        "_getter",
        "_str_sizes",
        "_str_slots",
        "cls",
        "names",
        "size",
        "specs",
        "struct",
    )

    def __init__(self, cls: type[Message], specs: Sequence[FieldSpec], tail: tuple[str, ...] = ()) -> None:
        self.cls = cls
        self.specs = tuple(specs)
        self.names = tuple(s.name for s in self.specs)
        if (*self.names, *tail) != tuple(f.name for f in fields(cls)):
            raise TypeError(f"layout of {cls.__name__} does not follow its dataclass fields")
        self.struct = struct.Struct("<" + "".join(s.code for s in self.specs))
        self.size = self.struct.size
        self._getter = operator.attrgetter(*self.names)
        self._enum_slots = tuple(
            (i, _enum_by_value(s.enum)) for i, s in enumerate(self.specs) if s.kind is Kind.ENUM and s.enum
        )
        self._str_slots = tuple(i for i, s in enumerate(self.specs) if s.kind is Kind.STR)
        self._str_sizes = tuple(int(self.specs[i].code[:-1] or 1) for i in self._str_slots)
        parsers: list[Callable[[str], Any]] = []
        formatters: list[Callable[[Any], str]] = []
        for s in self.specs:
            if s.kind is Kind.FLOAT:
                parsers.append(float)
                formatters.append(_float_formatter(s.fmt))
            elif s.kind is Kind.INT:
                parsers.append(int)
                formatters.append(str)
            elif s.kind is Kind.HEX:
                parsers.append(_parse_hex)
                formatters.append(_hex_formatter(s.fmt))
            elif s.kind is Kind.ENUM:
                assert s.enum is not None
                parsers.append(_enum_parser(s.enum))
                formatters.append(_enum_formatter)
            else:
                parsers.append(_parse_str)
                formatters.append(_str_formatter)
        self._ascii_parsers = tuple(parsers)
        self._ascii_formatters = tuple(formatters)
        if tail:  # variable-length tail (PSRDOP): the subclass decodes with the generic methods
            self._fast_binary = self._fast_ascii = None
        else:
            self._fast_binary, self._fast_ascii = _compile_decoders(cls, self.specs, self.struct.unpack_from)

    # binary

    @property
    def fixed_layout(self) -> bool:
        """True when the body is exactly the field table (no variable-length tail)."""
        return self._fast_binary is not None

    def decode_binary_values(self, body: bytes, offset: int = 0) -> list[Any]:
        """Field values (enums and strings converted) from a binary body."""
        values = list(self.struct.unpack_from(body, offset))
        for i, convert in self._enum_slots:
            values[i] = convert(values[i])
        for i in self._str_slots:
            values[i] = values[i].rstrip(b"\0").decode("latin-1")
        return values

    def decode_binary(self, body: bytes) -> Message:
        """Typed body from binary bytes (trailing bytes beyond the layout are ignored).

        Raises:
            DecodeError: the body is shorter than the layout.
        """
        if len(body) < self.size:
            raise DecodeError(
                f"NovAtel {self.cls.MESSAGE_NAME} binary body has {len(body)} bytes, layout needs {self.size}"
            )
        if self._fast_binary is not None:
            try:
                return self._fast_binary(body)
            except KeyError:
                pass  # an enum value missing from the table: the generic path makes an UNKNOWN_ member
        return self.cls(*self.decode_binary_values(body))

    def decode_binary_reference(self, body: bytes) -> Message:
        """Same as :meth:`decode_binary` through the generic (table-walking) path."""
        return self.cls(*self.decode_binary_values(body))

    def encode_binary_values(self, msg: Any) -> bytes:
        values = list(self._getter(msg))
        try:
            for i, size in zip(self._str_slots, self._str_sizes, strict=True):
                raw = values[i].encode("latin-1")
                if len(raw) > size:
                    raise ValueError(f"{self.names[i]}={values[i]!r} is longer than {size} characters")
                values[i] = raw
            return self.struct.pack(*values)
        except (struct.error, ValueError, OverflowError, UnicodeEncodeError, AttributeError, TypeError) as exc:
            raise EncodeError(f"cannot encode NovAtel {self.cls.MESSAGE_NAME} body in binary: {exc}") from exc

    def encode_binary(self, msg: Any) -> bytes:
        """Binary body bytes of a typed body.

        Raises:
            EncodeError: a field does not fit its wire type.
        """
        return self.encode_binary_values(msg)

    # ASCII

    def decode_tokens(self, tokens: Sequence[str], start: int = 0) -> list[Any]:
        """Field values from ASCII tokens (extra trailing tokens are ignored).

        Raises:
            DecodeError: too few tokens, or a token that does not parse (names the field).
        """
        n = len(self.specs)
        if len(tokens) - start < n:
            raise DecodeError(
                f"NovAtel {self.cls.MESSAGE_NAME} ASCII body has {len(tokens) - start} fields, layout needs {n}"
            )
        try:
            return [parse(tok) for parse, tok in zip(self._ascii_parsers, tokens[start : start + n], strict=True)]
        except (ValueError, KeyError):
            for i, (parse, tok) in enumerate(zip(self._ascii_parsers, tokens[start : start + n], strict=True)):
                try:
                    parse(tok)
                except (ValueError, KeyError) as exc:
                    raise DecodeError(
                        f"NovAtel {self.cls.MESSAGE_NAME} field {i + 1} ({self.names[i]}): cannot parse {tok!r}"
                    ) from exc
            raise  # pragma: no cover - the loop above re-raises

    def decode_ascii(self, tokens: Sequence[str]) -> Message:
        """Typed body from ASCII tokens (extra trailing tokens are ignored).

        Raises:
            DecodeError: too few tokens, or a token that does not parse (names the field).
        """
        if self._fast_ascii is not None and len(tokens) >= len(self.specs):
            try:
                return self._fast_ascii(tokens)
            except FAST_PATH_MISSES:
                pass  # the generic path below takes it, or says which field failed
        return self.cls(*self.decode_tokens(tokens))

    def decode_ascii_reference(self, tokens: Sequence[str]) -> Message:
        """Same as :meth:`decode_ascii` through the generic (table-walking) path."""
        return self.cls(*self.decode_tokens(tokens))

    def format_tokens(self, msg: Any) -> list[str]:
        """ASCII tokens of a typed body.

        Raises:
            EncodeError: a field value cannot be written.
        """
        try:
            return [fmt(v) for fmt, v in zip(self._ascii_formatters, self._getter(msg), strict=True)]
        except (ValueError, TypeError, AttributeError) as exc:
            raise EncodeError(f"cannot encode NovAtel {self.cls.MESSAGE_NAME} body in ASCII: {exc}") from exc


def _psrdop(values: Sequence[Any], prns: tuple[int, ...]) -> PsrDop:
    gdop, pdop, hdop, htdop, tdop, cutoff_deg = values
    return PsrDop(gdop, pdop, hdop, htdop, tdop, cutoff_deg, prns)


class PsrDopCodec(BodyCodec):
    """PSRDOP: the fixed DOP fields, then a signed count and that many ulong PRNs."""

    __slots__ = ()

    _COUNT = struct.Struct("<i")

    def decode_binary(self, body: bytes) -> Message:
        fixed = self.size
        if len(body) < fixed + 4:
            raise DecodeError(f"NovAtel PSRDOP binary body has {len(body)} bytes, needs at least {fixed + 4}")
        values = self.decode_binary_values(body)
        (count,) = self._COUNT.unpack_from(body, fixed)
        if count < 0 or len(body) < fixed + 4 + 4 * count:
            raise DecodeError(f"NovAtel PSRDOP binary body of {len(body)} bytes cannot hold {count} PRNs")
        prns = struct.unpack_from(f"<{count}I", body, fixed + 4)
        return _psrdop(values, prns)

    def encode_binary(self, msg: Any) -> bytes:
        head = self.encode_binary_values(msg)
        try:
            prns = tuple(msg.prns)
            return head + self._COUNT.pack(len(prns)) + struct.pack(f"<{len(prns)}I", *prns)
        except (struct.error, TypeError) as exc:
            raise EncodeError(f"cannot encode NovAtel PSRDOP PRN list: {exc}") from exc

    def decode_ascii(self, tokens: Sequence[str]) -> Message:
        values = self.decode_tokens(tokens)
        n = len(self.specs)
        try:
            count = int(tokens[n])
            prns = tuple(int(t) for t in tokens[n + 1 : n + 1 + count])
        except (IndexError, ValueError) as exc:
            raise DecodeError(f"NovAtel PSRDOP ASCII PRN list does not parse: {exc}") from exc
        if count < 0 or len(prns) != count:
            raise DecodeError(f"NovAtel PSRDOP ASCII says {count} PRNs but carries {len(prns)}")
        return _psrdop(values, prns)

    def format_tokens(self, msg: Any) -> list[str]:
        tokens = super().format_tokens(msg)
        prns = tuple(msg.prns)
        return [*tokens, str(len(prns)), *(str(int(p)) for p in prns)]


def _build_codecs() -> dict[int, BodyCodec]:
    table: list[tuple[type[Message], tuple[FieldSpec, ...]]] = [
        (BestPos, POSITION_FIELDS),
        (MarkPos, POSITION_FIELDS),
        (Mark2Pos, POSITION_FIELDS),
        (BestVel, BESTVEL_FIELDS),
        (BestXyz, BESTXYZ_FIELDS),
        (MarkTime, EVENT_TIME_FIELDS),
        (Mark1Time, EVENT_TIME_FIELDS),
        (Mark2Time, EVENT_TIME_FIELDS),
        (Time, TIME_FIELDS),
        (Heading, HEADING_FIELDS),
        (Heading2, HEADING2_FIELDS),
    ]
    codecs: dict[int, BodyCodec] = {cls.MESSAGE_ID: BodyCodec(cls, specs) for cls, specs in table}
    codecs[PsrDop.MESSAGE_ID] = PsrDopCodec(PsrDop, PSRDOP_FIELDS, tail=("prns",))
    return codecs


#: Body codec by message ID (dict dispatch for the decoders and encoders).
CODECS_BY_ID: dict[int, BodyCodec] = _build_codecs()
#: Body codec by log name.
CODECS_BY_NAME: dict[str, BodyCodec] = {c.cls.MESSAGE_NAME: c for c in CODECS_BY_ID.values()}
#: Body codec by body class.
CODECS_BY_CLASS: dict[type, BodyCodec] = {c.cls: c for c in CODECS_BY_ID.values()}


# --- VERSION (kept raw in the stream, decoded on demand) -------------------------------------

#: One VERSION component (OEM7 Commands and Logs Reference, VERSION): Enum type, Char[16] model, PSN,
#: hardware, software and boot versions, Char[12] compile date and time — 108 bytes, after a ulong count.
VERSION_COMPONENT_FIELDS: tuple[FieldSpec, ...] = (
    _enum("component_type", ComponentType),
    _chars("model", 16),
    _chars("psn", 16),
    _chars("hw_version", 16),
    _chars("sw_version", 16),
    _chars("boot_version", 16),
    _chars("compile_date", 12),
    _chars("compile_time", 12),
)
_VERSION_COMPONENT = BodyCodec(cast(Any, VersionComponent), VERSION_COMPONENT_FIELDS)
_COUNT = struct.Struct("<I")


def decode_version(body: RawBody | bytes, fmt: BodyFormat = BodyFormat.BINARY) -> Version:
    """VERSION body (binary bytes, or the ASCII / abbreviated text after the header) into :class:`Version`.

    Raises:
        DecodeError: the count does not match the components the body carries, or a field does not parse.
    """
    if isinstance(body, RawBody):
        data, fmt = body.data, body.fmt
    else:
        data = body
    size = _VERSION_COMPONENT.size
    if fmt is BodyFormat.BINARY:
        if len(data) < 4:
            raise DecodeError(f"NovAtel VERSION binary body has {len(data)} bytes, needs at least 4")
        (count,) = _COUNT.unpack_from(data)
        if len(data) < 4 + count * size:
            raise DecodeError(f"NovAtel VERSION binary body of {len(data)} bytes cannot hold {count} components")
        comps = tuple(
            VersionComponent(*_VERSION_COMPONENT.decode_binary_values(data, 4 + k * size)) for k in range(count)
        )
        return Version(comps)
    text = data.decode("latin-1").replace("\r", " ").replace("\n", " ").replace("<", " ")
    tokens = split_ascii_fields(text) if fmt is BodyFormat.ASCII else split_abbreviated_fields(text)
    tokens = [t.strip() for t in tokens]
    try:
        count = int(tokens[0])
    except (IndexError, ValueError) as exc:
        raise DecodeError(f"NovAtel VERSION ASCII body does not start with a component count: {exc}") from exc
    n = len(VERSION_COMPONENT_FIELDS)
    if count < 0 or len(tokens) < 1 + count * n:
        raise DecodeError(f"NovAtel VERSION ASCII says {count} components but carries {len(tokens) - 1} fields")
    comps = tuple(VersionComponent(*_VERSION_COMPONENT.decode_tokens(tokens, 1 + k * n)) for k in range(count))
    return Version(comps)


def encode_version(version: Version, fmt: BodyFormat = BodyFormat.BINARY) -> RawBody:
    """VERSION body as a :class:`RawBody` ready for the frame encoders.

    Raises:
        EncodeError: a text is longer than its field.
    """
    comps = version.components
    if fmt is BodyFormat.BINARY:
        return RawBody(_COUNT.pack(len(comps)) + b"".join(_VERSION_COMPONENT.encode_binary(c) for c in comps), fmt)
    tokens = [str(len(comps))]
    for c in comps:
        tokens += _VERSION_COMPONENT.format_tokens(c)
    if fmt is BodyFormat.ASCII:
        return RawBody(",".join(tokens).encode("latin-1"), fmt)
    raise EncodeError("NovAtel VERSION: the abbreviated form is written by encode_abbreviated from the ASCII body")
