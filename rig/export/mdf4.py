"""One MDF4 file of a session (asammdf): CAN as ASAM bus logging, SI role channels, GNSS, optical, DAQ, truth."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rig.data.stream import GroupChunk, GroupKind, iter_groups
from rig.export.files import ExportedFile, ExportKind, ExportReport, progress_fn, single_file_export
from vsccore.errors import AnalysisError, ConfigError

MF4_EXTRA = "vsc-rig[mf4]"


_MDF_STRING_WIDTH = {"text": 256, "details": 512, "utc_iso": 40}


def _mdf_samples(chunk: GroupChunk, name: str) -> npt.NDArray[Any]:
    v = chunk.columns[name]
    if name in chunk.nullable_int:
        return chunk.numeric(name)
    if v.dtype == object:
        width = _MDF_STRING_WIDTH.get(name, 64)
        return np.asarray([s.encode("utf-8")[:width] for s in v.tolist()], dtype=f"S{width}")
    if v.dtype == bool:
        return v.astype(np.uint8)
    return v


def _can_dataframe(chunk: GroupChunk, width: int) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]:
    """ASAM MDF bus-logging records (``CAN_DataFrame`` with its ``CAN_DataFrame.*`` fields) of the data frames."""
    from can.util import len2dlc

    c = chunk.columns
    keep = ~(c["error_frame"] | c["remote_frame"])
    n = int(np.count_nonzero(keep))
    dt = np.dtype([("CAN_DataFrame.BusChannel", "<u1"), ("CAN_DataFrame.ID", "<u4"), ("CAN_DataFrame.IDE", "<u1"),
                   ("CAN_DataFrame.DLC", "<u1"), ("CAN_DataFrame.DataLength", "<u1"),
                   ("CAN_DataFrame.DataBytes", "<u1", (width,)), ("CAN_DataFrame.Dir", "<u1"),
                   ("CAN_DataFrame.EDL", "<u1"), ("CAN_DataFrame.BRS", "<u1"), ("CAN_DataFrame.ESI", "<u1")])
    rec = np.zeros(n, dtype=dt)
    rec["CAN_DataFrame.BusChannel"] = 1
    rec["CAN_DataFrame.ID"] = c["can_id"][keep]
    rec["CAN_DataFrame.IDE"] = c["extended"][keep]
    ln = c["len"][keep]
    rec["CAN_DataFrame.DataLength"] = ln
    rec["CAN_DataFrame.DLC"] = np.asarray([len2dlc(int(x)) for x in ln.tolist()], dtype=np.uint8) \
        if bool(np.any(ln > 8)) else ln
    data = c["data"][keep]
    w = min(width, data.shape[1])
    rec["CAN_DataFrame.DataBytes"][:, :w] = data[:, :w]
    rec["CAN_DataFrame.Dir"] = np.where(c["rx"][keep], 0, 1)
    rec["CAN_DataFrame.EDL"] = c["fd"][keep]
    return rec, keep


def export_mdf4(
    path: Path | str,
    out_dir: Path | str,
    *,
    topics: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int, int], None] | None = None,
) -> ExportReport:
    """Write a session as one ASAM MDF 4.10 file ``<out_dir>/<session>.mf4`` through asammdf, streaming.

    - every CAN bus as an ASAM bus-logging channel group (``CAN_DataFrame`` with ``CAN_DataFrame.ID``,
      ``.DataBytes``, … and a CAN bus source), so CANape and asammdf (``MDF.extract_bus_logging``) decode
      the raw frames with the DBC, which is attached to the file;
    - the rig roles decoded from those frames (``can_<bus>_roles``) as physical channels with SI units;
    - GNSS logs, optical sensors, DAQ channels (volts), the simulator's truth, events and time-base
      records as channel groups named after the group, channels ``<group>.<column>`` with their units.

    Every group's time is the session's common time base, in seconds from the file's start time (the
    session's first message, UTC). Appended data goes to asammdf's temporary file, not memory.
    Raises :class:`~vsccore.errors.ConfigError` naming the ``vsc-rig[mf4]`` extra when asammdf is missing.
    """
    try:
        from asammdf import MDF, Signal
        from asammdf.blocks.v4_blocks import SourceInformation
        from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS
    except ImportError:
        raise ConfigError(f"rig export --format mdf4 needs the asammdf package: install the {MF4_EXTRA} extra "
                          f"(pip install '{MF4_EXTRA}')") from None
    from datetime import UTC, datetime

    stream, final = single_file_export(path, out_dir, ".mf4", overwrite)
    mdf = MDF(version="4.10")
    mdf.header.start_time = datetime.fromtimestamp(stream.start_ns / 1e9, tz=UTC)
    attachment: Any = None
    if stream.dbc_name is not None:
        import hashlib

        dbc_bytes = stream.attachments[stream.dbc_name]
        attachment = (dbc_bytes, Path(stream.dbc_name), hashlib.md5(dbc_bytes).digest())
    groups: dict[str, tuple[int, int]] = {}  # group → (MDF group index, CAN data width or 0)
    rows: dict[str, int] = {}
    try:
        for chunk in iter_groups(stream, topics=topics, progress=progress_fn(progress, stream)):
            if not len(chunk):
                continue
            t_s = (chunk.time_ns - stream.start_ns) / 1e9
            if chunk.kind is GroupKind.CAN_FRAMES:
                known = groups.get(chunk.group)
                width = known[1] if known else int(chunk.columns["data"].shape[1])
                rec, keep = _can_dataframe(chunk, width)
                if known is None:
                    bus = chunk.group.removeprefix("can_").removesuffix("_frames")
                    source = SourceInformation(source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)
                    source.name = bus
                    source.path = bus
                    mdf.append(Signal(samples=rec, timestamps=t_s[keep], name="CAN_DataFrame", source=source,
                                      attachment=attachment, comment=f"CAN bus {bus}: every data frame"),
                               acq_name=chunk.group, comment=f"vsc-rig {chunk.group}")
                    groups[chunk.group] = (len(mdf.groups) - 1, width)
                else:
                    mdf.extend(known[0], [(t_s[keep], None), (rec, None)])
                rows[chunk.group] = rows.get(chunk.group, 0) + len(rec)
                continue
            names = list(chunk.columns)
            known = groups.get(chunk.group)
            if known is None:
                samples = {n: _mdf_samples(chunk, n) for n in names}
                sigs = [Signal(samples=v, timestamps=t_s, name=f"{chunk.group}.{n}", unit=chunk.units.get(n, ""),
                               comment=n, encoding="utf-8" if v.dtype.kind == "S" else None)
                        for n, v in samples.items()]
                mdf.append(sigs, acq_name=chunk.group, comment=f"vsc-rig {chunk.group} ({chunk.kind.value})")
                groups[chunk.group] = (len(mdf.groups) - 1, 0)
            else:
                mdf.extend(known[0], [(t_s, None)] + [(_mdf_samples(chunk, n), None) for n in names])
            rows[chunk.group] = rows.get(chunk.group, 0) + len(chunk)
        if not groups:
            raise AnalysisError(f"{path}: nothing to export as MDF4 (no table topics"
                                f"{' matching --topics' if topics else ''})")
        tmp = final.with_name(f".{final.stem}.partial.mf4")  # asammdf keeps a .mf4 suffix
        saved = Path(mdf.save(tmp, overwrite=True, compression=1))
        os.replace(saved, final)
    except BaseException:
        final.with_name(f".{final.stem}.partial.mf4").unlink(missing_ok=True)
        raise
    finally:
        mdf.close()
    files = [ExportedFile(final, ExportKind.TABLE, f"{len(groups)} channel groups: " + ", ".join(sorted(groups)),
                          final.stat().st_size, sum(rows.values()))]
    return ExportReport(tuple(files), tuple(stream.warnings))

