"""Encoders of the NovAtel codec, in one place (used by the simulated receiver and by tests).

- :func:`encode_binary` — long-header (``Header``) or short-header (``ShortHeader``) binary log.
- :func:`encode_ascii` — ``#`` ASCII log (``%`` short ASCII for a ``ShortHeader``), CR LF ended.
- :func:`encode_abbreviated` — abbreviated-ASCII log lines.
- :func:`encode_ok`, :func:`encode_error`, :func:`encode_response`, :func:`encode_prompt` —
  command responses (``<OK``, ``<ERROR:…``) and the port prompt (``[COM1]``).

Each raises :class:`vsccore.errors.EncodeError` when a value does not fit its wire field.
"""

from __future__ import annotations

from drivers.novatel.ascii import (
    encode_abbreviated,
    encode_ascii,
    encode_error,
    encode_ok,
    encode_prompt,
    encode_response,
)
from drivers.novatel.binary import encode_binary

__all__ = [
    "encode_abbreviated",
    "encode_ascii",
    "encode_binary",
    "encode_error",
    "encode_ok",
    "encode_prompt",
    "encode_response",
]
