"""Relay endpoints named by strings: serial ports, NTRIP casters, TCP peers and files.

Syntax (the same for ``rig relay --from/--to`` and the session configuration):

- ``/dev/ttyUSB0`` or ``/dev/ttyUSB0@115200`` (also ``COM3@38400``): a serial port, optional baud;
- ``ntrip://user:password@host:port/MOUNTPOINT`` (source only); ``?version=1`` asks for NTRIP 1.0
  (2.0 by default; a caster that answers ``ICY 200 OK`` is understood either way). User and
  password left out of the URL come from the environment (``VSC_RIG_NTRIP_USER``,
  ``VSC_RIG_NTRIP_PASSWORD`` unless other names are given);
- ``tcp://host:port``;
- ``file:PATH`` or ``file:PATH@BAUD``: a capture file (as a source, ``@BAUD`` replays it at that
  line rate, 10 bits a byte); as a sink, the file is appended to.

A password is held in a :class:`Secret`, whose ``str``/``repr`` never show it; every spec's
``display`` and ``repr`` mask it, and parse errors quote the text with the password masked.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from urllib.parse import unquote, urlsplit

from vsccore.errors import ConfigError

__all__ = [
    "DEFAULT_NTRIP_PASSWORD_ENV",
    "DEFAULT_NTRIP_PORT",
    "DEFAULT_NTRIP_USER_ENV",
    "Endpoint",
    "FileEndpoint",
    "NtripEndpoint",
    "RedactedEndpoint",
    "Secret",
    "SerialEndpoint",
    "TcpEndpoint",
    "mask_credentials",
    "parse_endpoint",
    "redact_endpoint",
]

DEFAULT_NTRIP_PORT = 2101
DEFAULT_NTRIP_USER_ENV = "VSC_RIG_NTRIP_USER"
DEFAULT_NTRIP_PASSWORD_ENV = "VSC_RIG_NTRIP_PASSWORD"
MASK = "***"

# in free text: the password runs to the last '@' of the URL token
_URL_PASSWORD = re.compile(r"(?P<head>[A-Za-z][A-Za-z0-9+.-]*://[^:/@\s\"']*:)[^\s\"']*@")
# one endpoint string: the password runs to its last '@' (it may hold '/', '?', '#', '@' or spaces)
_ENDPOINT_PASSWORD = re.compile(r"(?P<head>[A-Za-z][A-Za-z0-9+.-]*://[^:/@\s]*:)(?P<password>.*)@(?P<rest>[^@]*)", re.S)


# A key/value line whose key names a password (TOML/INI ``source_password = "..."``, ``password: x``).
_KEY_PASSWORD = re.compile(
    r"(?im)^(?P<head>[ \t]*[\"']?[A-Za-z0-9_.-]*(?:password|passwd|secret)[A-Za-z0-9_.-]*[\"']?[ \t]*[=:][ \t]*)"
    r"(?P<value>\S.*?)[ \t]*$"
)


def mask_credentials(text: str) -> str:
    """``text`` with every password it spells out replaced by ``***``.

    Covers the password of any ``scheme://user:password@`` URL and the value of any key/value line
    whose key names a password (a configuration file's ``relay.source_password = "..."``).
    """
    text = _URL_PASSWORD.sub(lambda m: f"{m.group('head')}{MASK}@", text)
    return _KEY_PASSWORD.sub(lambda m: f'{m.group("head")}"{MASK}"', text)


class Secret:
    """A credential that never shows itself in ``str``, ``repr``, logs or tracebacks."""

    __slots__ = ("_value",)

    def __init__(self, value: str) -> None:
        self._value = value

    def reveal(self) -> str:
        """The secret value (only for building the request that needs it)."""
        return self._value

    def __repr__(self) -> str:
        return f"Secret({MASK!r})"

    def __str__(self) -> str:
        return MASK

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Secret) and other._value == self._value

    def __hash__(self) -> int:
        return hash(("Secret", self._value))

    def __bool__(self) -> bool:
        return bool(self._value)

    def __reduce__(self) -> tuple[object, ...]:
        raise TypeError("Secret values are not pickled")


@dataclass(frozen=True, slots=True)
class RedactedEndpoint:
    """An endpoint string as it enters the program, split at once into the ``text`` with the URL
    password replaced by ``***`` (safe for metadata, events, logs, status lines and errors) and the
    ``password`` (a :class:`Secret`, None when the URL has none). ``str`` is the redacted text."""

    text: str
    password: Secret | None = field(default=None, repr=False, compare=False)

    def __str__(self) -> str:
        return self.text


def redact_endpoint(text: str) -> RedactedEndpoint:
    """Split the password out of an endpoint string (``ntrip://user:password@host/MOUNT``)."""
    m = _ENDPOINT_PASSWORD.fullmatch(text.strip())
    if m is None:
        return RedactedEndpoint(text.strip())
    password = unquote(m.group("password"))
    return RedactedEndpoint(f"{m.group('head')}{MASK}@{m.group('rest')}", Secret(password) if password else None)


@dataclass(frozen=True, slots=True)
class SerialEndpoint:
    """A serial port (``path``; ``baud`` None keeps the port's setting, which a pty ignores)."""

    path: str
    baud: int | None = None

    @property
    def display(self) -> str:
        return self.path if self.baud is None else f"{self.path}@{self.baud}"


@dataclass(frozen=True, slots=True)
class TcpEndpoint:
    """A TCP peer (the relay connects to it)."""

    host: str
    port: int

    @property
    def display(self) -> str:
        return f"tcp://{self.host}:{self.port}"


@dataclass(frozen=True, slots=True)
class FileEndpoint:
    """A capture file; ``baud`` paces a replay (10 bits a byte), None reads it as fast as it goes."""

    path: str
    baud: int | None = None

    @property
    def display(self) -> str:
        return f"file:{self.path}" if self.baud is None else f"file:{self.path}@{self.baud}"


@dataclass(frozen=True, slots=True)
class NtripEndpoint:
    """An NTRIP caster mountpoint; the password is a :class:`Secret` and is left out of ``repr``."""

    host: str
    port: int
    mountpoint: str
    user: str | None = None
    password: Secret | None = field(default=None, repr=False, compare=False)
    version: int = 2

    @property
    def display(self) -> str:
        cred = "" if self.user is None else f"{self.user}:{MASK}@" if self.password else f"{self.user}@"
        suffix = "" if self.version == 2 else f"?version={self.version}"
        return f"ntrip://{cred}{self.host}:{self.port}/{self.mountpoint}{suffix}"


Endpoint = SerialEndpoint | TcpEndpoint | FileEndpoint | NtripEndpoint

_BAUD = re.compile(r"^(?P<path>.+)@(?P<baud>\d+)$")


def _split_baud(text: str, what: str) -> tuple[str, int | None]:
    m = _BAUD.match(text)
    if m is None:
        return text, None
    baud = int(m.group("baud"))
    if baud <= 0:
        raise ConfigError(f"relay endpoint {what!r}: baud rate must be positive")
    return m.group("path"), baud


def parse_endpoint(
    text: str | RedactedEndpoint,
    *,
    env: Mapping[str, str] | None = None,
    user_env: str = DEFAULT_NTRIP_USER_ENV,
    password_env: str = DEFAULT_NTRIP_PASSWORD_ENV,
) -> Endpoint:
    """Parse an endpoint string (see the module doc).

    Raises:
        ConfigError: the text is not a valid endpoint (the message quotes it, password masked).
    """
    redacted = text if isinstance(text, RedactedEndpoint) else redact_endpoint(text)
    text = shown = redacted.text  # from here on, no code sees the password but through the Secret
    if not text:
        raise ConfigError("relay endpoint is empty")
    lower = text.lower()
    if lower.startswith("ntrip://"):
        return _parse_ntrip(text, shown, redacted.password, os.environ if env is None else env, user_env, password_env)
    if lower.startswith("tcp://"):
        parts = urlsplit(text)
        try:
            port = parts.port
        except ValueError:
            port = None
        if not parts.hostname or port is None:
            raise ConfigError(f"relay endpoint {shown!r}: expected tcp://host:port")
        return TcpEndpoint(parts.hostname, port)
    if lower.startswith("file:"):
        path, baud = _split_baud(text[5:], shown)
        if path.startswith("//"):
            path = path[2:]
        if not path:
            raise ConfigError(f"relay endpoint {shown!r}: expected file:PATH")
        return FileEndpoint(path, baud)
    if "://" in text:
        raise ConfigError(
            f"relay endpoint {shown!r}: unknown scheme (expected a serial port, ntrip://, tcp:// or file:)"
        )
    path, baud = _split_baud(text, shown)
    return SerialEndpoint(path, baud)


def _parse_ntrip(
    text: str, shown: str, url_password: Secret | None, env: Mapping[str, str], user_env: str, password_env: str
) -> NtripEndpoint:
    # ``text`` is redacted: a password given in the URL stands there as '***' and comes in ``url_password``.
    rest = text[len("ntrip://") :]
    user: str | None = None
    password: str | None = None
    at = rest.rfind("@")
    if at >= 0:
        cred, rest = rest[:at], rest[at + 1 :]
        if ":" in cred:
            user = unquote(cred.split(":", 1)[0])
            password = url_password.reveal() if url_password is not None else ""
        else:
            user = unquote(cred)
    parts = urlsplit("ntrip://" + rest)
    try:
        port = parts.port or DEFAULT_NTRIP_PORT
    except ValueError:
        raise ConfigError(f"relay endpoint {shown!r}: bad port") from None
    if not parts.hostname:
        raise ConfigError(f"relay endpoint {shown!r}: expected ntrip://user:password@host:port/MOUNTPOINT")
    mountpoint = unquote(parts.path.lstrip("/"))
    if not mountpoint or "/" in mountpoint:
        raise ConfigError(f"relay endpoint {shown!r}: expected one mountpoint after the host")
    version = 2
    for item in filter(None, parts.query.split("&")):
        key, _, value = item.partition("=")
        if key.lower() in ("version", "v") and value in ("1", "2"):
            version = int(value)
        else:
            raise ConfigError(f"relay endpoint {shown!r}: unknown option {key!r} (only version=1|2)")
    if not user:
        user = env.get(user_env) or None
    if password is None and user is not None:
        password = env.get(password_env)
    return NtripEndpoint(
        parts.hostname,
        port,
        mountpoint,
        user,
        Secret(password) if password else None,
        version,
    )
