"""NovAtel ASCII forms: ``#`` logs, ``%`` short logs, abbreviated ``<`` logs, responses and prompts.

- ASCII log: ``#NAMEA,port,seq,idle%,time status,week,seconds,rx status,reserved,sw version;``
  body fields ``*`` CRC-32 as 8 hex digits, computed over the characters between ``#`` and ``*``.
- Short ASCII log: ``%NAMEA,week,seconds;`` body ``*`` CRC.
- Abbreviated ASCII (no CRC): a header line ``<NAME port seq idle status week seconds rxstatus
  reserved swversion`` followed by continuation lines ``<     field field …``.
- Command responses ``<OK`` and ``<ERROR:reason``; port prompts ``[COM1]``, ``[USB1]``, ``[ICOM1]``.

Real receivers vary a little and this module accepts what they send when the CRC is right: port
names such as ICOM1/USB1, a bare ``0`` in a hex field, extra trailing fields (old firmware),
numbers in place of enum names. Decoding takes one frame; finding frames is the framer's job.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.novatel.crc import novatel_crc32
from drivers.novatel.enums import TimeStatus
from drivers.novatel.layouts import (
    CODECS_BY_CLASS,
    CODECS_BY_NAME,
    FAST_PATH_MISSES,
    BodyCodec,
    emit_ascii_body,
    split_abbreviated_fields,
    split_ascii_fields,
)
from drivers.novatel.messages import (
    LOG_IDS,
    Body,
    BodyFormat,
    Header,
    Log,
    Prompt,
    RawBody,
    RecordEmitter,
    Response,
    ShortHeader,
    compile_function,
    log_id_for_name,
    new_header,
    new_log,
    new_short_header,
)
from vsccore.errors import ChecksumError, DecodeError, EncodeError

_TIME_STATUS_BY_NAME = dict(TimeStatus._member_map_)
_LOG_IDS_GET = LOG_IDS.get


def _time_status(token: str) -> TimeStatus:
    member = _TIME_STATUS_BY_NAME.get(token)
    return member if member is not None else TimeStatus.from_token(token)  # type: ignore[return-value]


def _split_name(token: str, format_suffix: bool) -> tuple[str, int]:
    """Log name without the ``A`` format suffix and the ``_n`` measurement-source suffix."""
    source = 0
    if "_" in token:
        base, _, suffix = token.rpartition("_")
        if suffix.isdigit():
            token, source = base, int(suffix)
    if format_suffix and token.endswith("A"):
        token = token[:-1]
    return token, source


def _long_header(fields: list[str], format_suffix: bool, where: str) -> Header:
    if len(fields) != 10:
        raise DecodeError(f"NovAtel {where} header has {len(fields)} fields, expected 10")
    name, port, seq, idle, tstat, week, seconds, rx_status, reserved, sw = fields
    if "_" in name or not format_suffix:
        name, source = _split_name(name, format_suffix)
    else:
        name, source = (name[:-1] if name.endswith("A") else name), 0
    try:
        return new_header(
            name,
            _LOG_IDS_GET(name) or log_id_for_name(name),
            port,
            int(seq),
            float(idle),
            _TIME_STATUS_BY_NAME.get(tstat) or _time_status(tstat),
            int(week),
            float(seconds),
            int(rx_status, 16),
            int(reserved, 16),
            int(sw),
            source,
            False,
        )
    except (ValueError, KeyError) as exc:
        raise DecodeError(f"NovAtel {where} header of {name} does not parse: {exc}") from exc


def _short_header(fields: list[str], where: str) -> ShortHeader:
    if len(fields) != 3:
        raise DecodeError(f"NovAtel {where} short header has {len(fields)} fields, expected 3")
    name, _ = _split_name(fields[0], True)
    try:
        return new_short_header(name, log_id_for_name(name), int(fields[1]), float(fields[2]))
    except ValueError as exc:
        raise DecodeError(f"NovAtel {where} short header of {name} does not parse: {exc}") from exc


_CODECS_BY_NAME_GET = CODECS_BY_NAME.get


# --- Generated whole-log decoders ---------------------------------------------------------------
# One generated function per typed log with a fixed layout, keyed by its ASCII name token
# (``BESTPOSA``): from the split header and body tokens it builds header, body and log through
# slot twins (see ``messages.RecordEmitter``). Anything outside its tables (a source suffix, an
# unknown time status or enum name, a quoted token with a comma, too few fields, a number that
# does not parse) raises one of ``FAST_PATH_MISSES`` and :func:`decode_ascii_verified` decodes the
# line again through the generic path, which handles it or says what is wrong.


def _compile_log_decoder(codec: BodyCodec) -> Callable[[list[str], list[str]], Log]:
    ns: dict[str, Any] = {
        "_time_status": dict(TimeStatus._member_map_),
        "_message_name": codec.cls.MESSAGE_NAME,
        "_message_id": codec.cls.MESSAGE_ID,
        "_int": int,
        "_float": float,
    }
    n = len(codec.specs)
    tokens = [f"t{i}" for i in range(n)]
    name = f"decode_ascii_log_{codec.cls.__name__}"
    emit_h = RecordEmitter(Header, "hd", ns)
    header = [
        emit_h.begin(),
        emit_h.store("message_name", "_message_name"),
        emit_h.store("message_id", "_message_id"),
        emit_h.store("port", "port"),
        emit_h.store("sequence", "_int(seq)"),
        emit_h.store("idle_time_pct", "_float(idle)"),
        emit_h.store("time_status", "_time_status[tstat]"),
        emit_h.store("week", "_int(week)"),
        emit_h.store("seconds", "_float(seconds)"),
        emit_h.store("receiver_status", "_int(rxs, 16)"),
        emit_h.store("reserved", "_int(res, 16)"),
        emit_h.store("sw_version", "_int(sw)"),
        emit_h.store("source", "0"),
        emit_h.store("response", "False"),
        emit_h.end(),
    ]
    body = emit_ascii_body(codec.specs, RecordEmitter(codec.cls, "bd", ns), tokens, ns)
    emit_log = RecordEmitter(Log, "lg", ns)
    tail = [emit_log.begin(), emit_log.store("header", "hd"), emit_log.store("body", "bd"), emit_log.end()]
    lines = [
        f"def {name}(head, body):",
        "    _name, port, seq, idle, tstat, week, seconds, rxs, res, sw = head",
        f"    {', '.join(tokens)}, = body[:{n}]",
        *("    " + line for line in (*header, *body, *tail)),
        "    return lg",
    ]
    function: Callable[[list[str], list[str]], Log] = compile_function(name, lines, ns)
    return function


FAST_ASCII_DECODERS: dict[str, Callable[[list[str], list[str]], Log]] = {
    codec.cls.MESSAGE_NAME + "A": _compile_log_decoder(codec) for codec in CODECS_BY_NAME.values() if codec.fixed_layout
}
_FAST_ASCII_GET = FAST_ASCII_DECODERS.get


def decode_ascii_verified(frame: bytes) -> tuple[Log, str | None]:
    """Decode a ``#``/``%`` ASCII frame (``#…*xxxxxxxx``) whose CRC is already verified.

    Returns the log and, when the body did not decode (kept as :class:`RawBody`), the reason.

    Raises:
        DecodeError: the header does not parse.
    """
    star = frame.rfind(b"*")
    return decode_ascii_text(frame[0], frame[1 : star if star > 0 else len(frame)].decode("latin-1"))


def decode_ascii_text(sync: int, text: str) -> tuple[Log, str | None]:
    """Same as :func:`decode_ascii_verified`, given the sync byte and the text between it and ``*``."""
    if sync == 0x23:  # '#': try the generated decoder of the log name
        head_text, sep, body_text = text.partition(";")
        head = head_text.split(",")
        fast = _FAST_ASCII_GET(head[0])
        if fast is not None and sep:
            try:
                return fast(head, body_text.split(",")), None
            except FAST_PATH_MISSES:
                pass
    return _decode_ascii_text(sync, text)


def decode_ascii_verified_reference(frame: bytes) -> tuple[Log, str | None]:
    """Same as :func:`decode_ascii_verified` through the generic path only."""
    star = frame.rfind(b"*")
    return _decode_ascii_text(frame[0], frame[1 : star if star > 0 else len(frame)].decode("latin-1"))


def _decode_ascii_text(sync: int, text: str) -> tuple[Log, str | None]:
    head_text, sep, body_text = text.partition(";")
    if not sep:
        raise DecodeError("NovAtel ASCII log has no ';' between header and body")
    header: Header | ShortHeader
    if sync == 0x25:  # '%'
        header = _short_header(head_text.split(","), "short ASCII")
    else:
        header = _long_header(head_text.split(","), True, "ASCII")
    codec = _CODECS_BY_NAME_GET(header.message_name)
    if codec is None:
        return new_log(header, RawBody(body_text.encode("latin-1"), BodyFormat.ASCII)), None
    try:
        return new_log(header, codec.decode_ascii(split_ascii_fields(body_text))), None
    except DecodeError as exc:
        return new_log(header, RawBody(body_text.encode("latin-1"), BodyFormat.ASCII)), str(exc)


def decode_ascii(frame: bytes | str) -> Log:
    """Decode one ASCII or short-ASCII log line (trailing CR/LF allowed), checking its CRC.

    Raises:
        ChecksumError: the CRC does not verify.
        DecodeError: not a NovAtel ASCII log, or a header or body that does not decode.
    """
    data = frame.encode("latin-1") if isinstance(frame, str) else bytes(frame)
    data = data.rstrip(b"\r\n")
    if data[:1] not in (b"#", b"%"):
        raise DecodeError(f"not a NovAtel ASCII log: starts with {data[:1]!r}")
    star = data.rfind(b"*")
    if star < 0 or len(data) != star + 9:
        raise DecodeError("NovAtel ASCII log does not end with '*' and 8 hex CRC digits")
    try:
        want = int(data[star + 1 :], 16)
    except ValueError:
        raise DecodeError(f"NovAtel ASCII log CRC {data[star + 1:]!r} is not hex") from None
    got = novatel_crc32(data[1:star])
    if got != want:
        raise ChecksumError(f"NovAtel ASCII log CRC {want:08x} does not match {got:08x}")
    log, error = decode_ascii_verified(data)
    if error is not None:
        raise DecodeError(error)
    return log


def decode_abbreviated_lines(frame: bytes) -> tuple[Log, str | None]:
    """Decode an abbreviated-ASCII log: header line plus ``<`` continuation lines (no CRC).

    Returns the log and, when the body did not decode (kept as :class:`RawBody`), the reason.

    Raises:
        DecodeError: the header line does not parse.
    """
    first_end = frame.find(b"\n")
    if first_end < 0:
        head_line, rest = frame, b""
    else:
        head_line, rest = frame[:first_end], frame[first_end + 1 :]
    head_text = head_line.decode("latin-1").strip()
    if not head_text.startswith("<"):
        raise DecodeError("abbreviated NovAtel log does not start with '<'")
    header = _long_header(head_text[1:].split(), False, "abbreviated ASCII")
    body_text = " ".join(
        line[1:] if line.startswith("<") else line for line in rest.decode("latin-1").splitlines()
    )
    codec = CODECS_BY_NAME.get(header.message_name)
    if codec is None:
        return new_log(header, RawBody(rest, BodyFormat.ABBREVIATED)), None
    try:
        return new_log(header, codec.decode_ascii(split_abbreviated_fields(body_text))), None
    except DecodeError as exc:
        return new_log(header, RawBody(rest, BodyFormat.ABBREVIATED)), str(exc)


def decode_abbreviated(text: bytes | str) -> Log:
    """Decode an abbreviated-ASCII log given as its lines (CR/LF line ends).

    Raises:
        DecodeError: the header or body does not decode.
    """
    data = text.encode("latin-1") if isinstance(text, str) else bytes(text)
    log, error = decode_abbreviated_lines(data.strip(b"\r\n"))
    if error is not None:
        raise DecodeError(error)
    return log


def parse_response(line: bytes | str) -> Response:
    """``<OK`` → Response(ok=True, "OK"); ``<ERROR:reason`` → Response(ok=False, "reason").

    Raises:
        DecodeError: the line is neither.
    """
    text = (line.decode("latin-1") if isinstance(line, bytes | bytearray) else line).strip()
    if text == "<OK":
        return Response(True, "OK")
    if text.startswith("<ERROR:"):
        return Response(False, text[7:])
    raise DecodeError(f"not a NovAtel command response: {text[:40]!r}")


def parse_prompt(text: bytes | str) -> Prompt:
    """``[COM1]`` → Prompt("COM1").

    Raises:
        DecodeError: not a prompt.
    """
    s = (text.decode("latin-1") if isinstance(text, bytes | bytearray) else text).strip()
    if len(s) >= 3 and s[0] == "[" and s[-1] == "]" and s[1:-1].replace("_", "").isalnum():
        return Prompt(s[1:-1])
    raise DecodeError(f"not a NovAtel port prompt: {s[:40]!r}")


# --- Encoding --------------------------------------------------------------------------------


def _seconds_text(seconds: float, what: str) -> str:
    ms = round(seconds * 1000)
    if ms < 0:
        raise EncodeError(f"NovAtel {what}: negative seconds of week {seconds}")
    return f"{ms // 1000}.{ms % 1000:03d}"


def _body_tokens(header: Header | ShortHeader, body: Body, sep: str) -> str:
    if isinstance(body, RawBody):
        if body.fmt is BodyFormat.BINARY:
            raise EncodeError(f"NovAtel {header.message_name}: a raw binary body cannot be sent as ASCII")
        text = body.data.decode("latin-1")
        if body.fmt is BodyFormat.ABBREVIATED and sep == ",":
            raise EncodeError(f"NovAtel {header.message_name}: a raw abbreviated body cannot be sent as ASCII")
        return text
    codec = CODECS_BY_CLASS.get(type(body))
    if codec is None:
        raise EncodeError(f"no NovAtel ASCII layout for {type(body).__name__}")
    if header.message_id != codec.cls.MESSAGE_ID:
        raise EncodeError(
            f"header names message {header.message_name} ({header.message_id}) but the body is "
            f"{codec.cls.MESSAGE_NAME} ({codec.cls.MESSAGE_ID})"
        )
    return sep.join(codec.format_tokens(body))


def _header_fields(header: Header, suffix: str) -> list[str]:
    source = f"_{header.source}" if header.source else ""
    ts = header.time_status
    ts_text = str(int(ts)) if ts.name.startswith("UNKNOWN_") else ts.name
    return [
        f"{header.message_name}{suffix}{source}",
        header.port,
        str(header.sequence),
        f"{header.idle_time_pct:.1f}",
        ts_text,
        str(header.week),
        _seconds_text(header.seconds, header.message_name),
        f"{header.receiver_status:08x}",
        f"{header.reserved:04x}",
        str(header.sw_version),
    ]


def encode_ascii(header: Header | ShortHeader, body: Body) -> bytes:
    """ASCII log line ``#…;…*xxxxxxxx\\r\\n`` (``%`` short form for a :class:`ShortHeader`).

    Raises:
        EncodeError: a value cannot be written, the header's message ID is not the body's, or the
            text would contain a character that breaks framing (``*``, ``;`` in the header, CR, LF).
    """
    body_text = _body_tokens(header, body, ",")
    if isinstance(header, ShortHeader):
        sync = b"%"
        head_text = f"{header.message_name}A,{header.week},{_seconds_text(header.seconds, header.message_name)}"
    else:
        sync = b"#"
        head_text = ",".join(_header_fields(header, "A"))
    if ";" in head_text:
        raise EncodeError(f"NovAtel {header.message_name}: ';' in an ASCII header field")
    text = f"{head_text};{body_text}"
    if "*" in text or "\r" in text or "\n" in text:
        raise EncodeError(f"NovAtel {header.message_name}: '*' or a line break in an ASCII field")
    try:
        data = text.encode("latin-1")
    except UnicodeEncodeError as exc:
        raise EncodeError(f"NovAtel {header.message_name}: non-latin-1 text in an ASCII field") from exc
    return sync + data + b"*" + f"{novatel_crc32(data):08x}".encode() + b"\r\n"


def encode_abbreviated(header: Header, body: Body) -> bytes:
    """Abbreviated-ASCII log: header line and one continuation line, each ending in CR LF.

    Raises:
        EncodeError: as :func:`encode_ascii`.
    """
    head_text = " ".join(_header_fields(header, ""))
    body_text = _body_tokens(header, body, " ")
    if isinstance(body, RawBody) and body.fmt is BodyFormat.ABBREVIATED:
        text = f"<{head_text}\r\n{body_text}"
        return text.encode("latin-1") + (b"" if text.endswith("\n") else b"\r\n")
    if "\r" in body_text or "\n" in body_text:
        raise EncodeError(f"NovAtel {header.message_name}: line break in an abbreviated field")
    return f"<{head_text}\r\n<     {body_text}\r\n".encode("latin-1")


def encode_response(response: Response) -> bytes:
    """``<OK\\r\\n`` or ``<ERROR:reason\\r\\n``."""
    if response.ok:
        return b"<OK\r\n"
    return encode_error(response.text)


def encode_ok() -> bytes:
    """The abbreviated-ASCII success response ``<OK\\r\\n``."""
    return b"<OK\r\n"


def encode_error(reason: str) -> bytes:
    """The abbreviated-ASCII error response ``<ERROR:reason\\r\\n``.

    Raises:
        EncodeError: the reason contains a line break.
    """
    if "\r" in reason or "\n" in reason:
        raise EncodeError("NovAtel error response text contains a line break")
    return f"<ERROR:{reason}\r\n".encode("latin-1")


def encode_prompt(port: str) -> bytes:
    """Port prompt such as ``[COM1]`` (no line end, as the receiver sends it).

    Raises:
        EncodeError: the port name is not alphanumeric (with ``_``).
    """
    if not port or not port.replace("_", "").isalnum():
        raise EncodeError(f"NovAtel prompt port name {port!r} is not alphanumeric")
    return f"[{port}]".encode("ascii")
