"""The session recorder: per-device bounded sources, one MCAP writer thread, parts, recovery.

Public API::

    from rig.store import Recorder, RecorderOptions, Attachment, session_metadata

    rec = Recorder(out_dir, "run1", session_metadata(session=..., vehicle=..., calibration=...),
                   attachments=[Attachment.from_file(dbc_path)], options=RecorderOptions(...))
    rec.start()
    src = rec.source("rover_a", maxsize=10_000)   # one per device, from any thread
    src.put(topics.gnss_raw("rover_a"), log_time_ns, host_ns, data)
    summary = rec.stop()                           # drained, finalized

Reading back: :func:`find_parts`, :func:`scan_part` (tolerates a truncated part);
:func:`recover` writes a finalized copy of a crashed part.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

from rig.store.reader import PartScan, ProblemKind, find_parts, part_path, scan_part, session_base

# eager: the function shares its name with its module, which would otherwise shadow it once imported
from rig.store.recover import RecoverReport, finalize_in_place, recover

if TYPE_CHECKING:
    from rig.store.sources import Source, SourceStats
    from rig.store.writer import (
        Attachment,
        Compression,
        FileSummary,
        Recorder,
        RecorderOptions,
        session_metadata,
    )

_LAZY = {
    **dict.fromkeys(("Source", "SourceStats"), "rig.store.sources"),
    **dict.fromkeys(("Attachment", "Compression", "Recorder", "RecorderOptions", "FileSummary",
                     "session_metadata"), "rig.store.writer"),
}
"""The writing side, imported on first use: reading a session (``rig info``) needs only the reader."""


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = globals()[name] = getattr(import_module(module), name)
    return value

__all__ = [
    "Attachment",
    "Compression",
    "FileSummary",
    "PartScan",
    "ProblemKind",
    "Recorder",
    "RecorderOptions",
    "RecoverReport",
    "Source",
    "SourceStats",
    "finalize_in_place",
    "find_parts",
    "part_path",
    "recover",
    "scan_part",
    "session_base",
    "session_metadata",
]
