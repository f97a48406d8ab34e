"""The session recorder: per-device bounded sources, one MCAP writer thread, parts, recovery.

Public API::

    from rig.recorder import Recorder, RecorderOptions, Attachment, session_metadata

    rec = Recorder(out_dir, "run1", session_metadata(session=..., vehicle=..., calibration=...),
                   attachments=[Attachment.from_file(dbc_path)], options=RecorderOptions(...))
    rec.start()
    src = rec.source("rover_a", maxsize=10_000)   # one per device, from any thread
    src.put(topics.gnss_raw("rover_a"), log_time_ns, host_ns, data)
    summary = rec.stop()                           # drained, finalized

Reading back: :func:`find_parts`, :func:`scan_part` (tolerates a truncated part);
:func:`recover` writes a finalized copy of a crashed part.
"""

from rig.recorder.reader import PartScan, ProblemKind, find_parts, part_path, scan_part, session_base
from rig.recorder.recover import RecoverReport, finalize_in_place, recover
from rig.recorder.sources import Source, SourceStats
from rig.recorder.writer import (
    Attachment,
    Compression,
    Recorder,
    RecorderOptions,
    RecordingSummary,
    session_metadata,
)

__all__ = [
    "Attachment",
    "Compression",
    "PartScan",
    "ProblemKind",
    "Recorder",
    "RecorderOptions",
    "RecordingSummary",
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
