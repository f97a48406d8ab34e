"""NovAtel codec: pure bytes in / typed messages out, and back. No I/O, no threads.

Decoding a stream::

    framer = Framer()
    for frame in framer.feed(chunk):          # any chunking; frames are reassembled
        if frame.log and isinstance(frame.log.body, BestPos):
            ...
    framer.finish()                            # end of stream
    framer.stats                               # frames by kind, skipped bytes by reason, CRC failures

or ``for frame in FrameReader(fileobj): ...`` for anything with ``read(n)``.

Encoding (the simulated receiver)::

    header = make_header(body, week=2300, seconds=345600.0, port="COM1")
    encode_binary(header, body)   # AA 44 12 … CRC
    encode_ascii(header, body)    # #BESTPOSA,…*xxxxxxxx\\r\\n
    encode_ok(); encode_error("Invalid Message ID"); encode_prompt("COM1")

Modules: ``crc`` (checksums), ``enums``, ``messages`` (dataclasses), ``layouts`` (declarative
field tables and body codecs), ``binary`` / ``ascii`` (one frame each way), ``framer`` (stream),
``encode`` (all encoders), ``jsonview`` (JSON-able dicts), ``columns`` (a whole buffer decoded in bulk
into numpy columns per log, for post-processing: ``decode_columns(data).log("BESTPOS")``).
"""

from typing import TYPE_CHECKING, Any

from drivers.novatel.ascii import decode_abbreviated, decode_ascii, parse_prompt, parse_response
from drivers.novatel.binary import decode_binary
from drivers.novatel.crc import crc24q, novatel_crc32, xor_checksum
from drivers.novatel.encode import (
    encode_abbreviated,
    encode_ascii,
    encode_binary,
    encode_error,
    encode_ok,
    encode_prompt,
    encode_response,
)
from drivers.novatel.enums import (
    ClockModelStatus,
    Datum,
    PositionType,
    SolutionStatus,
    TimeStatus,
    UTCStatus,
    VelocityType,
)
from drivers.novatel.framer import Frame, FrameKind, Framer, FrameReader, FramerStats, SkipReason, iter_frames
from drivers.novatel.jsonview import frame_to_dict, log_to_dict
from drivers.novatel.layouts import decode_version, encode_version
from drivers.novatel.messages import (
    LOG_IDS,
    MESSAGE_TYPES,
    BestPos,
    BestVel,
    BestXyz,
    Body,
    BodyFormat,
    ComponentType,
    Header,
    Heading,
    Heading2,
    Log,
    Mark1Time,
    Mark2Pos,
    Mark2Time,
    MarkPos,
    MarkTime,
    Message,
    Prompt,
    PsrDop,
    RawBody,
    Response,
    ShortHeader,
    Time,
    Version,
    VersionComponent,
    make_header,
    make_short_header,
)

if TYPE_CHECKING:
    from drivers.novatel.columns import ColumnBatch, LogColumns, RejectReason, decode_columns

#: Exported from :mod:`drivers.novatel.columns` on first use, so that importing the codec does not load numpy.
_COLUMNS_EXPORTS = frozenset({"ColumnBatch", "LogColumns", "RejectReason", "decode_columns"})


def __getattr__(name: str) -> Any:
    if name in _COLUMNS_EXPORTS:
        from drivers.novatel import columns

        return getattr(columns, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "LOG_IDS",
    "MESSAGE_TYPES",
    "BestPos",
    "BestVel",
    "BestXyz",
    "Body",
    "BodyFormat",
    "ClockModelStatus",
    "ColumnBatch",
    "ComponentType",
    "Datum",
    "Frame",
    "FrameKind",
    "FrameReader",
    "Framer",
    "FramerStats",
    "Header",
    "Heading",
    "Heading2",
    "Log",
    "LogColumns",
    "Mark1Time",
    "Mark2Pos",
    "Mark2Time",
    "MarkPos",
    "MarkTime",
    "Message",
    "PositionType",
    "Prompt",
    "PsrDop",
    "RawBody",
    "RejectReason",
    "Response",
    "ShortHeader",
    "SkipReason",
    "SolutionStatus",
    "Time",
    "TimeStatus",
    "UTCStatus",
    "VelocityType",
    "Version",
    "VersionComponent",
    "crc24q",
    "decode_abbreviated",
    "decode_ascii",
    "decode_binary",
    "decode_columns",
    "decode_version",
    "encode_abbreviated",
    "encode_ascii",
    "encode_binary",
    "encode_error",
    "encode_ok",
    "encode_prompt",
    "encode_response",
    "encode_version",
    "frame_to_dict",
    "iter_frames",
    "log_to_dict",
    "make_header",
    "make_short_header",
    "novatel_crc32",
    "parse_prompt",
    "parse_response",
    "xor_checksum",
]
