"""NovAtel binary logs: long header (``AA 44 12``, 28 bytes) and short header (``AA 44 13``, 12 bytes).

Frame layout: header, body (little-endian, layout per message ID), CRC-32 over header + body
(little-endian). Decoding takes one complete frame; finding frames in a stream is the framer's
job (:mod:`drivers.novatel.framer`).
"""

from __future__ import annotations

import struct

from drivers.novatel.crc import novatel_crc32, novatel_crc32_residue_ok
from drivers.novatel.enums import PORT_NAME_BY_BYTE, TimeStatus, port_byte_from_name, port_name_from_byte
from drivers.novatel.layouts import CODECS_BY_CLASS, CODECS_BY_ID
from drivers.novatel.messages import (
    LOG_NAMES,
    Body,
    BodyFormat,
    Header,
    Log,
    RawBody,
    ShortHeader,
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


def decode_verified(frame: bytes, short: bool) -> tuple[Log, str | None]:
    """Decode a binary frame whose CRC is already verified.

    A body that does not decode is kept as :class:`RawBody` and the reason returned as the second
    item (None when the body decoded or is a raw pass-through log).
    """
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
