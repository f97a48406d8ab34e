"""CAN decoding: DBC loading, signal roles, live and vectorised decoders, checks and log reading.

Public entry points:

- :func:`drivers.can.dbc.load_dbc` — load a DBC (errors name file and line).
- :class:`drivers.can.roles.RoleMap` — the validated role mapping (``[can.roles.*]``).
- :class:`drivers.can.roles.RoleDecoder` — live, per-frame decoding to SI role samples.
- :class:`drivers.can.vector_decode.VectorDecoder` / :class:`~drivers.can.vector_decode.VectorRoleDecoder`
  — offline, vectorised decoding of a :class:`~drivers.can.vector_decode.FrameBatch`.
- :mod:`drivers.can.checks` — frame flags, checksum registry (``vw_mqb_crc8``), counter checks.
- :mod:`drivers.can.logs` — reading CAN log files (anything python-can reads) into a batch.

The live bus transport lives in :mod:`drivers.can.bus` (separate module).
"""

from __future__ import annotations

from drivers.can.checks import FrameFlag, get_checksum, register_checksum
from drivers.can.dbc import load_dbc
from drivers.can.roles import (
    DecodedFrame,
    MessageCheck,
    RoleDecoder,
    RoleMap,
    RoleSample,
    RoleSpec,
    encode_role_frame,
)
from drivers.can.vector_decode import FrameBatch, RoleSeries, VectorDecoder, VectorRoleDecoder

__all__ = [
    "DecodedFrame",
    "FrameBatch",
    "FrameFlag",
    "MessageCheck",
    "RoleDecoder",
    "RoleMap",
    "RoleSample",
    "RoleSeries",
    "RoleSpec",
    "VectorDecoder",
    "VectorRoleDecoder",
    "encode_role_frame",
    "get_checksum",
    "load_dbc",
    "register_checksum",
]
