"""``rig gnss decode``: decode a raw capture from a NovAtel receiver port into JSON lines.

The capture may hold any mix of what such a port carries (NovAtel ASCII / abbreviated / binary /
short-binary logs, command responses, prompts, NMEA, RTCM3). Output, one JSON object per line:

- one per frame: ``{"kind": "novatel_binary", "type": "BESTPOS", "header": {...}, "body": {...}}``
  (field names carry their units, enums their names; see :mod:`drivers.novatel.jsonview`),
- a final ``{"kind": "summary", "frames": {kind: n}, "bytes_skipped": {reason: n}, "crc_failures":
  {kind: n}, …}`` with the frames by kind and the rejected bytes by reason.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import IO, Annotated, Any

import typer

from drivers.novatel import Framer, FrameReader, FramerStats, frame_to_dict
from vsccore.errors import SessionFileError

app = typer.Typer(help="GNSS receivers (NovAtel): decode raw captures.", no_args_is_help=True)


def decode_capture(source: IO[bytes], out: IO[str], *, summary_only: bool = False) -> FramerStats:
    """Write one JSON line per frame of ``source`` to ``out`` and then the summary line."""
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


@app.command("decode")
def decode(
    file: Annotated[str, typer.Argument(help="Raw capture file, or '-' for standard input.")],
    summary_only: Annotated[bool, typer.Option("--summary-only", help="Print only the summary line.")] = False,
) -> None:
    """Decode FILE (any mix of NovAtel logs, responses, NMEA, RTCM3) and print one JSON object per message."""
    try:
        if file == "-":
            decode_capture(sys.stdin.buffer, sys.stdout, summary_only=summary_only)
            return
        path = Path(file)
        try:
            handle = path.open("rb")
        except OSError as exc:
            raise SessionFileError(f"{path}: cannot read capture: {exc.strerror or exc}") from None
        with handle:
            decode_capture(handle, sys.stdout, summary_only=summary_only)
    except BrokenPipeError:  # output piped into head & co.: stop quietly (Python docs' recipe)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        raise typer.Exit(0) from None
