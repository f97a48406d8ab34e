"""A copy of a recorded session with chosen NovAtel logs removed from receivers' raw streams (an older recording,
or a configuration that did not log them), for the PPK tests."""

from __future__ import annotations

import io
import shutil
from collections.abc import Mapping
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

from drivers.novatel import FrameReader
from rig.core.topics import gnss_raw
from rig.store import find_parts


def _drop_spans(stream: bytes, names: set[str]) -> list[tuple[int, int]]:
    """Byte spans [start, end) of the frames of the logs ``names`` (message names without the B/A suffix)."""
    spans: list[tuple[int, int]] = []
    cursor = 0
    for fr in FrameReader(io.BytesIO(stream)):
        at = stream.find(fr.raw, cursor)
        assert at >= 0, "a frame the framer found is not in the stream"
        cursor = at + len(fr.raw)
        if fr.log is not None and fr.log.header.message_name in names:
            spans.append((at, cursor))
    return spans


def _cut(data: bytes, offset: int, spans: list[tuple[int, int]]) -> bytes:
    """``data`` (at ``offset`` in its stream) without the bytes inside ``spans``."""
    end = offset + len(data)
    keep = bytearray()
    pos = offset
    for a, b in spans:
        if b <= pos or a >= end:
            continue
        keep += data[pos - offset:max(a, pos) - offset]
        pos = min(b, end)
    keep += data[pos - offset:]
    return bytes(keep)


def copy_without_logs(session: Path, dest: Path, drop: Mapping[str, set[str]]) -> tuple[Path, dict[str, int]]:
    """Copy ``session`` (every part) into ``dest``, removing from ``/gnss/<receiver>/raw`` the frames of the logs
    ``drop[receiver]`` (e.g. ``{"rover_a": {"GLOEPHEMERIS"}}``); every other record is copied as it is.

    Returns the copy's session base and the bytes removed per receiver (each must be > 0: a filter that removes
    nothing would test nothing).
    """
    parts = find_parts(session)
    wanted = {gnss_raw(r): names for r, names in drop.items()}
    streams: dict[str, bytearray] = {t: bytearray() for t in wanted}
    for part in parts:
        with part.open("rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
                if channel.topic in streams:
                    streams[channel.topic] += message.data
    spans = {t: _drop_spans(bytes(streams[t]), wanted[t]) for t in wanted}
    removed = {r: sum(b - a for a, b in spans[gnss_raw(r)]) for r in drop}
    dest.mkdir(parents=True, exist_ok=True)
    offsets = dict.fromkeys(wanted, 0)
    for part in parts:
        with part.open("rb") as fin, (dest / part.name).open("wb") as fout:
            reader = make_reader(fin)
            summary = reader.get_summary()
            assert summary is not None
            writer = Writer(fout)
            writer.start(profile="", library="tests.ppk.filtered")
            schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
            channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0),
                                                        c.metadata)
                           for cid, c in summary.channels.items()}
            for meta in reader.iter_metadata():
                writer.add_metadata(meta.name, meta.metadata)
            for att in reader.iter_attachments():
                writer.add_attachment(att.create_time, att.log_time, att.name, att.media_type, att.data)
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                data = message.data
                if channel.topic in wanted:
                    data = _cut(data, offsets[channel.topic], spans[channel.topic])
                    offsets[channel.topic] += len(message.data)
                writer.add_message(channel_ids[channel.id], message.log_time, data, message.publish_time,
                                   message.sequence)
            writer.finish()
    for other in session.parent.glob(session.name + ".*"):
        if other.suffix != ".mcap" and not other.name.endswith(".ppk.parquet") and other.is_file():
            shutil.copy(other, dest / other.name)
    return dest / session.name, removed
