"""NovAtel binary logs: long header (``AA 44 12``, 28 bytes) and short header (``AA 44 13``, 12 bytes).

Frame layout: header, body (little-endian, layout per message ID), CRC-32 over header + body
(little-endian). Decoding takes one complete frame; finding frames in a stream is the framer's
job (:mod:`drivers.novatel.framer`).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from drivers.novatel.crc import novatel_crc32, novatel_crc32_residue_ok
from drivers.novatel.enums import PORT_NAME_BY_BYTE, TimeStatus, port_byte_from_name, port_name_from_byte
from drivers.novatel.layouts import CODECS_BY_CLASS, CODECS_BY_ID, BodyCodec, emit_binary_body
from drivers.novatel.messages import (
    LOG_NAMES,
    Body,
    BodyFormat,
    Header,
    Log,
    RawBody,
    RecordEmitter,
    ShortHeader,
    compile_function,
    log_name_for_id,
    new_header,
    new_log,
    new_short_header,
)
from vsccore.errors import ChecksumError, DecodeError, EncodeError

SYNC_LONG = b"\xaa\x44\x12"
SYNC_SHORT = b"\xaa\x44\x13"
LONG_HEADER_LEN = 28
SHORT_HEADER_LEN = 12
CRC_LEN = 4

#: Long header after the 3 sync bytes: header length, message ID, message type, port, message
#: length, sequence, idle time (0.5 %), time status, week, milliseconds, receiver status,
#: reserved, software version.
LONG_HEADER = struct.Struct("<BHBBHHBBHIIHH")
#: Short header after the 3 sync bytes: message length, message ID, week, milliseconds.
SHORT_HEADER = struct.Struct("<BHHI")
_CRC = struct.Struct("<I")

_TIME_STATUS = dict(TimeStatus._value2member_map_)
_LOG_NAMES_GET = LOG_NAMES.get
_PORT_NAMES_GET = PORT_NAME_BY_BYTE.get


def _time_status(value: int) -> TimeStatus:
    member = _TIME_STATUS.get(value)
    return member if member is not None else TimeStatus(value)


def decode_long_header(frame: bytes) -> tuple[Header, int, int]:
    """Header, body offset and body length of a long-header binary frame (CRC not checked)."""
    (hdr_len, mid, mtype, port, msg_len, seq, idle, tstat, week, ms, rx_status, reserved, sw) = (
        LONG_HEADER.unpack_from(frame, 3)
    )
    header = new_header(
        _LOG_NAMES_GET(mid) or log_name_for_id(mid),
        mid,
        _PORT_NAMES_GET(port) or port_name_from_byte(port),
        seq,
        idle * 0.5,
        _TIME_STATUS.get(tstat) or _time_status(tstat),
        week,
        ms / 1000,
        rx_status,
        reserved,
        sw,
        mtype & 0x1F,
        mtype >= 0x80,
    )
    return header, hdr_len, msg_len


def decode_short_header(frame: bytes) -> tuple[ShortHeader, int, int]:
    """Header, body offset and body length of a short-header binary frame (CRC not checked)."""
    msg_len, mid, week, ms = SHORT_HEADER.unpack_from(frame, 3)
    return new_short_header(log_name_for_id(mid), mid, week, ms / 1000), SHORT_HEADER_LEN, msg_len


_CODECS_GET = CODECS_BY_ID.get


# --- Generated whole-frame decoders ------------------------------------------------------------
# For a verified frame with the standard header length, one generated function per message ID
# unpacks header and body with a single precompiled struct, converts enums and names by dict
# subscript and builds header, body and log through slot twins (see ``messages.RecordEmitter``).
# It returns None when its preconditions fail (body shorter than the layout, response bit set)
# and raises KeyError for a value outside its tables (unknown port, time status, enum value or
# message ID); :func:`decode_verified` then takes the generic path below, which handles those
# cases and says what is wrong. Tests check both paths give equal logs.

_HEADER_TABLES: dict[str, Any] = {
    "_ports": dict(PORT_NAME_BY_BYTE),
    "_time_status": dict(TimeStatus._value2member_map_),
    "_names": dict(LOG_NAMES),
    "_binary_fmt": BodyFormat.BINARY,
}


def _compile_frame_decoder(
    codec: BodyCodec | None, short: bool, wrap: tuple[type, object] | None = None
) -> Callable[[bytes], Any]:
    """Decoder of a whole verified binary frame for one typed layout (``codec``) or raw bodies (None).

    It returns the :class:`Log`, or with ``wrap = (record class, kind)`` the record
    ``cls(kind=kind, raw=raw, message=log, error=None)`` (the framer's frame, built in the same
    function).
    """
    ns: dict[str, Any] = dict(_HEADER_TABLES)
    typed = codec is not None and codec.fixed_layout
    n = len(codec.specs) if typed and codec is not None else 0
    values = [f"a{i}" for i in range(n)]
    name = f"decode_{'short' if short else 'long'}_{codec.cls.__name__ if typed and codec else 'raw'}"
    hdr_len = SHORT_HEADER_LEN if short else LONG_HEADER_LEN
    if short:
        head_fmt, head_vars = "<3x" + SHORT_HEADER.format[1:], "mlen, mid, week, ms"
        emit_h = RecordEmitter(ShortHeader, "hd", ns)
    else:
        head_fmt = "<3x" + LONG_HEADER.format[1:]
        head_vars = "_hl, mid, mtype, port, mlen, seq, idle, tstat, week, ms, rxs, res, sw"
        emit_h = RecordEmitter(Header, "hd", ns)
    lines = [f"def {name}(raw):"]
    if typed and codec is not None:
        ns["_unpack"] = struct.Struct(head_fmt + codec.struct.format[1:]).unpack_from
        # Frames come verified, so len(raw) = header + body + CRC; a response is kept raw.
        guard = f"len(raw) < {hdr_len + codec.size + CRC_LEN}" + ("" if short else " or raw[6] >= 0x80")
        lines += [f"    if {guard}:", "        return None"]
        lines.append(f"    {head_vars}, {', '.join(values)}, = _unpack(raw)")
        ns["_message_name"] = codec.cls.MESSAGE_NAME
        message_name = "_message_name"
    else:
        ns["_unpack"] = struct.Struct(head_fmt).unpack_from
        lines.append(f"    {head_vars}, = _unpack(raw)")
        message_name = "_names[mid]"
    header = [emit_h.begin(), emit_h.store("message_name", message_name), emit_h.store("message_id", "mid")]
    if not short:
        header += [
            emit_h.store("port", "_ports[port]"),
            emit_h.store("sequence", "seq"),
            emit_h.store("idle_time_pct", "idle * 0.5"),
            emit_h.store("time_status", "_time_status[tstat]"),
        ]
    header += [emit_h.store("week", "week"), emit_h.store("seconds", "ms / 1000")]
    if not short:
        header += [
            emit_h.store("receiver_status", "rxs"),
            emit_h.store("reserved", "res"),
            emit_h.store("sw_version", "sw"),
            emit_h.store("source", "mtype & 0x1F"),
            emit_h.store("response", "mtype >= 0x80" if not typed else "False"),
        ]
    header.append(emit_h.end())
    if typed and codec is not None:
        body = emit_binary_body(codec.specs, RecordEmitter(codec.cls, "bd", ns), values, ns)
    else:
        emit_b = RecordEmitter(RawBody, "bd", ns)
        body = [
            emit_b.begin(),
            emit_b.store("data", f"raw[{hdr_len}:{hdr_len} + mlen]"),
            emit_b.store("fmt", "_binary_fmt"),
            emit_b.end(),
        ]
    emit_log = RecordEmitter(Log, "lg", ns)
    tail = [emit_log.begin(), emit_log.store("header", "hd"), emit_log.store("body", "bd"), emit_log.end()]
    if wrap is not None:
        emit_f = RecordEmitter(wrap[0], "fr", ns)
        ns["_frame_kind"] = wrap[1]
        tail += [
            emit_f.begin(),
            emit_f.store("kind", "_frame_kind"),
            emit_f.store("raw", "raw"),
            emit_f.store("message", "lg"),
            emit_f.store("error", "None"),
            emit_f.end(),
        ]
    lines += ["    " + line for line in (*header, *body, *tail)]
    lines.append("    return lg" if wrap is None else "    return fr")
    return compile_function(name, lines, ns)


def _no_fast_path(raw: bytes) -> None:
    """Layouts with a variable-length tail (PSRDOP) go through the generic path."""
    return


def compile_long_frame_decoders(
    wrap: tuple[type, object] | None = None,
) -> tuple[dict[int, Callable[[bytes], Any]], Callable[[bytes], Any]]:
    """Generated decoders of verified long-header frames with the standard 28-byte header.

    Returns ``(by message ID, decoder for IDs not in the map)``. Each decoder takes the complete
    frame and returns the :class:`Log` (or the ``wrap`` record, see ``_compile_frame_decoder``),
    None when the frame needs the generic path (body shorter than its layout, response bit,
    variable-length layout), or raises KeyError for a value outside its tables.
    """
    by_id: dict[int, Callable[[bytes], Any]] = {
        mid: _compile_frame_decoder(codec, False, wrap) if codec.fixed_layout else _no_fast_path
        for mid, codec in CODECS_BY_ID.items()
    }
    return by_id, _compile_frame_decoder(None, False, wrap)


_FAST_LONG, _fast_long_raw = compile_long_frame_decoders()
_FAST_SHORT: dict[int, Callable[[bytes], Log | None]] = {
    mid: _compile_frame_decoder(codec, short=True) if codec.fixed_layout else _no_fast_path
    for mid, codec in CODECS_BY_ID.items()
}
_FAST_LONG_GET = _FAST_LONG.get
_FAST_SHORT_GET = _FAST_SHORT.get
_fast_short_raw = _compile_frame_decoder(None, short=True)


def decode_verified(frame: bytes, short: bool) -> tuple[Log, str | None]:
    """Decode a binary frame whose CRC (and so its length) is already verified.

    A body that does not decode is kept as :class:`RawBody` and the reason returned as the second
    item (None when the body decoded or is a raw pass-through log).
    """
    # Fast path: generated decoder for the message ID (raw-body decoder for other IDs).
    try:
        if short:
            log = _FAST_SHORT_GET(frame[4] | frame[5] << 8, _fast_short_raw)(frame)
        elif frame[3] == LONG_HEADER_LEN:
            log = _FAST_LONG_GET(frame[4] | frame[5] << 8, _fast_long_raw)(frame)
        else:
            log = None
    except KeyError:
        log = None  # a value outside the fast tables: the generic path below handles it
    if log is not None:
        return log, None
    return decode_verified_reference(frame, short)


def decode_verified_reference(frame: bytes, short: bool) -> tuple[Log, str | None]:
    """Same as :func:`decode_verified` through the generic path (header, then body codec)."""
    if short:
        header: Header | ShortHeader
        header, offset, length = decode_short_header(frame)
        response = False
    else:
        header, offset, length = decode_long_header(frame)
        response = header.response
    body_bytes = frame[offset : offset + length]
    codec = _CODECS_GET(header.message_id)
    if codec is None or response:
        return new_log(header, RawBody(body_bytes, BodyFormat.BINARY)), None
    try:
        return new_log(header, codec.decode_binary(body_bytes)), None
    except DecodeError as exc:
        return new_log(header, RawBody(body_bytes, BodyFormat.BINARY)), str(exc)


def decode_binary(frame: bytes) -> Log:
    """Decode one complete binary frame (long or short header), checking its length and CRC.

    Raises:
        ChecksumError: the CRC does not verify.
        DecodeError: not a NovAtel binary frame, wrong length, or a body that does not decode.
    """
    frame = bytes(frame)
    sync = frame[:3]
    if sync == SYNC_LONG:
        if len(frame) < LONG_HEADER_LEN + CRC_LEN:
            raise DecodeError(f"NovAtel binary frame of {len(frame)} bytes is shorter than a long header")
        hdr_len = frame[3]
        (msg_len,) = struct.unpack_from("<H", frame, 8)
        if hdr_len < LONG_HEADER_LEN:
            raise DecodeError(f"NovAtel binary header length {hdr_len} is below {LONG_HEADER_LEN}")
        expected = hdr_len + msg_len + CRC_LEN
        short = False
    elif sync == SYNC_SHORT:
        if len(frame) < SHORT_HEADER_LEN + CRC_LEN:
            raise DecodeError(f"NovAtel short binary frame of {len(frame)} bytes is shorter than its header")
        expected = SHORT_HEADER_LEN + frame[3] + CRC_LEN
        short = True
    else:
        raise DecodeError(f"not a NovAtel binary frame: starts with {frame[:3].hex()}")
    if len(frame) != expected:
        raise DecodeError(f"NovAtel binary frame is {len(frame)} bytes, its header says {expected}")
    if not novatel_crc32_residue_ok(frame):
        (got,) = _CRC.unpack_from(frame, expected - CRC_LEN)
        raise ChecksumError(
            f"NovAtel binary frame CRC {got:08x} does not match {novatel_crc32(frame[:-CRC_LEN]):08x}"
        )
    log, error = decode_verified(frame, short)
    if error is not None:
        raise DecodeError(error)
    return log


def _body_bytes(header: Header | ShortHeader, body: Body) -> bytes:
    if isinstance(body, RawBody):
        if body.fmt is not BodyFormat.BINARY:
            raise EncodeError(f"NovAtel {header.message_name}: a raw {body.fmt.value} body cannot be sent in binary")
        return body.data
    codec = CODECS_BY_CLASS.get(type(body))
    if codec is None:
        raise EncodeError(f"no NovAtel binary layout for {type(body).__name__}")
    if header.message_id != codec.cls.MESSAGE_ID:
        raise EncodeError(
            f"header names message {header.message_name} ({header.message_id}) but the body is "
            f"{codec.cls.MESSAGE_NAME} ({codec.cls.MESSAGE_ID})"
        )
    return codec.encode_binary(body)


def _milliseconds(seconds: float, what: str) -> int:
    ms = round(seconds * 1000)
    if not 0 <= ms <= 0xFFFFFFFF:
        raise EncodeError(f"NovAtel {what}: seconds of week {seconds} out of range")
    return ms


def encode_binary(header: Header | ShortHeader, body: Body) -> bytes:
    """Binary frame (sync, header, body, CRC-32) of a log.

    A :class:`Header` gives a long-header frame, a :class:`ShortHeader` a short-header one. The
    port is written as the low byte of its address (see :mod:`drivers.novatel.enums`).

    Raises:
        EncodeError: a header or body value does not fit its wire field, the header's message ID
            is not the body's, or a raw body is not binary.
    """
    payload = _body_bytes(header, body)
    try:
        if isinstance(header, ShortHeader):
            if len(payload) > 0xFF:
                raise EncodeError(
                    f"NovAtel {header.message_name}: body of {len(payload)} bytes too long for short header"
                )
            head = SYNC_SHORT + SHORT_HEADER.pack(
                len(payload), header.message_id, header.week, _milliseconds(header.seconds, header.message_name)
            )
        else:
            if len(payload) > 0xFFFF:
                raise EncodeError(f"NovAtel {header.message_name}: body of {len(payload)} bytes is too long")
            try:
                port = port_byte_from_name(header.port)
            except KeyError:
                raise EncodeError(f"NovAtel {header.message_name}: unknown port name {header.port!r}") from None
            mtype = (header.source & 0x1F) | (0x80 if header.response else 0)
            head = SYNC_LONG + LONG_HEADER.pack(
                LONG_HEADER_LEN,
                header.message_id,
                mtype,
                port,
                len(payload),
                header.sequence,
                round(header.idle_time_pct * 2),
                int(header.time_status),
                header.week,
                _milliseconds(header.seconds, header.message_name),
                header.receiver_status,
                header.reserved,
                header.sw_version,
            )
    except struct.error as exc:
        raise EncodeError(f"NovAtel {header.message_name}: header value out of range: {exc}") from exc
    frame = head + payload
    return frame + _CRC.pack(novatel_crc32(frame))
