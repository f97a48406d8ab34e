"""Decoding a raw NovAtel port capture (any mix of ASCII, binary, responses, NMEA, RTCM3) into JSON lines and a
summary of frames and rejected bytes (``rig gnss decode``)."""

from __future__ import annotations

import json
from typing import IO, TYPE_CHECKING, Any

if TYPE_CHECKING:  # the NovAtel driver and rich are imported where used: ``rig --help`` stays fast

    from drivers.novatel import FramerStats


def decode_capture(source: IO[bytes], out: IO[str], *, summary_only: bool = False) -> FramerStats:
    """Write one JSON line per frame of ``source`` to ``out`` and then the summary line."""
    from drivers.novatel import Framer, FrameReader, frame_to_dict

    reader = FrameReader(source, framer=Framer())
    dumps = json.dumps
    for frame in reader:
        if not summary_only:
            out.write(dumps(frame_to_dict(frame), ensure_ascii=False, allow_nan=False))
            out.write("\n")
    stats = reader.stats
    summary: dict[str, Any] = {"kind": "summary", **stats.to_dict()}
    summary["total_frames"] = stats.total_frames
    summary["total_bytes_skipped"] = stats.total_skipped
    out.write(dumps(summary) + "\n")
    return stats

