"""NTRIP 1.0 / 2.0 protocol pieces, without I/O: requests, responses, chunked transfer, GGA.

- :func:`build_request` makes the GET request of a client (v1: ``HTTP/1.0``; v2: ``HTTP/1.1``
  with ``Ntrip-Version: Ntrip/2.0`` and, when a position is known, ``Ntrip-GGA``).
- :func:`parse_response_head` reads a caster's answer: ``ICY 200 OK`` (v1 data),
  ``HTTP/1.x 200`` with ``gnss/data`` (v2 data, maybe chunked), ``SOURCETABLE 200 OK`` or
  ``gnss/sourcetable`` (the mountpoint is unknown), ``401``/``403`` (credentials refused; decided
  at the status line, which may be all a caster sends).
- :class:`ChunkedDecoder` undoes HTTP/1.1 chunked transfer coding incrementally.
- :func:`build_gga` makes the NMEA GGA sentence a client uploads to a network (VRS) caster,
  with pynmea2.
- :func:`parse_sourcetable` lists the ``STR`` records of a source table.

The Authorization header is built here and nowhere else; nothing in this module logs.
"""

from __future__ import annotations

import base64
import math
from dataclasses import dataclass
from enum import Enum

import pynmea2

from vsccore.errors import DecodeError

__all__ = [
    "ChunkedDecoder",
    "NtripResponse",
    "ResponseKind",
    "SourcetableEntry",
    "build_gga",
    "build_request",
    "encode_chunk",
    "parse_response_head",
    "parse_sourcetable",
]

USER_AGENT = "NTRIP vsc-rig"
MAX_HEAD = 16384


def build_request(
    host: str,
    port: int,
    mountpoint: str,
    *,
    user: str | None,
    password: str | None,
    version: int = 2,
    gga: str | None = None,
    agent_version: str = "",
) -> bytes:
    """The client's GET request for ``mountpoint`` (``""`` asks for the source table)."""
    agent = f"{USER_AGENT}/{agent_version}" if agent_version else USER_AGENT
    lines = [f"GET /{mountpoint} HTTP/1.1" if version == 2 else f"GET /{mountpoint} HTTP/1.0"]
    if version == 2:
        lines += [f"Host: {host}:{port}", "Ntrip-Version: Ntrip/2.0"]
    lines += [f"User-Agent: {agent}", "Accept: */*"]
    if user is not None:
        token = base64.b64encode(f"{user}:{password or ''}".encode()).decode("ascii")
        lines.append(f"Authorization: Basic {token}")
    if version == 2 and gga:
        lines.append(f"Ntrip-GGA: {gga.strip()}")
    lines += ["Connection: close", "", ""]
    return "\r\n".join(lines).encode("latin-1")


class ResponseKind(Enum):
    """What a caster answered."""

    DATA = "data"
    SOURCETABLE = "sourcetable"
    UNAUTHORIZED = "unauthorized"
    FORBIDDEN = "forbidden"
    NOT_FOUND = "not_found"
    ERROR = "error"


@dataclass(frozen=True, slots=True)
class NtripResponse:
    """A parsed response head; ``body_start`` is the index of the first byte after it."""

    kind: ResponseKind
    status_line: str
    status: int
    version: int
    """1 for an ``ICY``/``SOURCETABLE`` answer, 2 for an ``HTTP/1.1`` answer with ``Ntrip-Version``."""
    headers: dict[str, str]
    body_start: int

    @property
    def chunked(self) -> bool:
        return "chunked" in self.headers.get("transfer-encoding", "").lower()


def parse_response_head(buf: bytes, *, eof: bool = False) -> NtripResponse | None:
    """Parse a caster's response head; None while more bytes are needed.

    ``ICY 200 OK`` is complete at its line end (an empty line after it, if any, is skipped); an
    HTTP answer other than 200 is complete at its status line: RTKLIB's ``str2str`` answers a
    wrong password with the bare line ``HTTP/1.0 401 Unauthorized`` and closes, so nothing more
    may come (headers already there are read). A 200 answer and ``SOURCETABLE 200 OK`` are
    complete at the empty line that ends their headers, or at ``eof`` (the caster closed).

    Raises:
        DecodeError: the bytes are not an NTRIP/HTTP response.
    """
    eol = buf.find(b"\n")
    if eol < 0:
        if len(buf) > MAX_HEAD:
            raise DecodeError(f"NTRIP response: no status line in the first {MAX_HEAD} bytes")
        if not (eof and buf.strip()):
            return None
        eol = len(buf)
    status_line = buf[:eol].rstrip(b"\r").decode("latin-1")
    upper = status_line.upper()
    if upper.startswith("ICY 200"):
        start = eol + 1
        if buf[start : start + 2] == b"\r\n":
            start += 2
        return NtripResponse(ResponseKind.DATA, status_line, 200, 1, {}, start)
    if upper.startswith("SOURCETABLE 200"):
        head_end = _head_end(buf) or (len(buf) if eof else None)
        if head_end is None:
            return None
        return NtripResponse(ResponseKind.SOURCETABLE, status_line, 200, 1, _headers(buf, eol, head_end), head_end)
    if not upper.startswith("HTTP/"):
        raise DecodeError(f"NTRIP response: unexpected status line {status_line[:80]!r}")
    parts = status_line.split(None, 2)
    try:
        status = int(parts[1])
    except (IndexError, ValueError):
        raise DecodeError(f"NTRIP response: bad status line {status_line[:80]!r}") from None
    head_end = _head_end(buf)
    if head_end is None:
        if status != 200 or eof:
            head_end = len(buf)  # the status decides; the headers may never come
        elif len(buf) > MAX_HEAD:
            raise DecodeError(f"NTRIP response: head longer than {MAX_HEAD} bytes")
        else:
            return None
    headers = _headers(buf, eol, head_end)
    version = 2 if headers.get("ntrip-version", "").lower().startswith("ntrip/2") else 1
    content_type = headers.get("content-type", "").lower()
    if status == 401:
        kind = ResponseKind.UNAUTHORIZED
    elif status == 403:
        kind = ResponseKind.FORBIDDEN
    elif status == 404:
        kind = ResponseKind.NOT_FOUND
    elif status == 200 and "sourcetable" in content_type:
        kind = ResponseKind.SOURCETABLE
    elif status == 200:
        kind = ResponseKind.DATA
    else:
        kind = ResponseKind.ERROR
    return NtripResponse(kind, status_line, status, version, headers, head_end)


def _head_end(buf: bytes) -> int | None:
    i = buf.find(b"\r\n\r\n")
    if i >= 0:
        return i + 4
    j = buf.find(b"\n\n")
    return None if j < 0 else j + 2


def _headers(buf: bytes, eol: int, head_end: int) -> dict[str, str]:
    headers: dict[str, str] = {}
    for line in buf[eol + 1 : head_end].decode("latin-1").splitlines():
        name, sep, value = line.partition(":")
        if sep:
            headers[name.strip().lower()] = value.strip()
    return headers


class ChunkedDecoder:
    """Incremental decoder of HTTP/1.1 chunked transfer coding."""

    def __init__(self) -> None:
        self._buf = b""
        self._remaining = 0  # data bytes left in the current chunk
        self._need_crlf = False
        self.done = False

    def feed(self, data: bytes) -> bytes:
        """Add coded bytes; return the payload bytes they complete.

        Raises:
            DecodeError: a chunk-size line is malformed.
        """
        buf = self._buf + data if self._buf else data
        out: list[bytes] = []
        pos = 0
        n = len(buf)
        while pos < n and not self.done:
            if self._remaining:
                take = min(self._remaining, n - pos)
                out.append(buf[pos : pos + take])
                pos += take
                self._remaining -= take
                if self._remaining == 0:
                    self._need_crlf = True
                continue
            if self._need_crlf:
                if n - pos < 2:
                    break
                if buf[pos : pos + 2] != b"\r\n":
                    raise DecodeError("NTRIP chunked stream: missing CR LF after a chunk")
                pos += 2
                self._need_crlf = False
                continue
            eol = buf.find(b"\r\n", pos)
            if eol < 0:
                if n - pos > 64:
                    raise DecodeError("NTRIP chunked stream: chunk-size line too long")
                break
            size_text = buf[pos:eol].split(b";", 1)[0].strip()
            try:
                size = int(size_text, 16)
            except ValueError:
                raise DecodeError(f"NTRIP chunked stream: bad chunk size {size_text[:16]!r}") from None
            pos = eol + 2
            if size == 0:
                self.done = True
                break
            self._remaining = size
        self._buf = buf[pos:]
        return b"".join(out)


def encode_chunk(data: bytes) -> bytes:
    """One HTTP/1.1 chunk (``b""`` gives the last-chunk marker)."""
    return f"{len(data):X}\r\n".encode("ascii") + data + b"\r\n"


def build_gga(
    lat_deg: float,
    lon_deg: float,
    height_m: float,
    *,
    utc_seconds_of_day: float,
    quality: int = 1,
    satellites: int = 12,
    hdop: float = 1.0,
) -> str:
    """An NMEA GGA sentence (talker GP) for the given position, with checksum, without CR LF.

    ``height_m`` is written as the altitude above mean sea level with a zero geoid separation;
    a VRS caster only needs an approximate position.
    """
    if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0) or not math.isfinite(height_m):
        raise ValueError(f"GGA position out of range: lat {lat_deg}, lon {lon_deg}, height {height_m}")
    sod = utc_seconds_of_day % 86400.0
    hh = int(sod // 3600)
    mm = int(sod % 3600 // 60)
    ss = sod - hh * 3600 - mm * 60
    alat, alon = abs(lat_deg), abs(lon_deg)
    lat_text = f"{int(alat):02d}{(alat - int(alat)) * 60:09.6f}"
    lon_text = f"{int(alon):03d}{(alon - int(alon)) * 60:09.6f}"
    fields = (
        f"{hh:02d}{mm:02d}{ss:05.2f}",
        lat_text,
        "N" if lat_deg >= 0 else "S",
        lon_text,
        "E" if lon_deg >= 0 else "W",
        str(quality),
        f"{satellites:02d}",
        f"{hdop:.1f}",
        f"{height_m:.3f}",
        "M",
        "0.000",
        "M",
        "",
        "",
    )
    return str(pynmea2.GGA("GP", "GGA", fields))


@dataclass(frozen=True, slots=True)
class SourcetableEntry:
    """One ``STR`` record of a source table (the fields the relay shows)."""

    mountpoint: str
    identifier: str
    format: str
    details: str


def parse_sourcetable(text: str) -> list[SourcetableEntry]:
    """The ``STR`` records of a source table."""
    entries = []
    for line in text.splitlines():
        if line.startswith("STR;"):
            f = line.split(";")
            f += [""] * (5 - len(f))
            entries.append(SourcetableEntry(f[1], f[2], f[3], f[4]))
    return entries
