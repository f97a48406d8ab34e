"""Synthetic sessions with damaged timing: a clean truth session (``tests.calib_cli.synth``) rewritten
through the real recorder with its CAN frames late, cut short, stalled, or with log times running back."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

import rig.core.topics as T  # noqa: N812 - short alias
from rig.core.config import load_session as load_config
from rig.store import Attachment, Recorder, RecorderOptions, find_parts, scan_part
from tests.calib_cli.synth import SIM_TOML, simulate_truth, straights, write_truth_session

FrameEdit = Callable[[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]],
                     tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.bool_]]]
"""(host ns from the first frame, host ns, device ns or NO_TIME) → (device ns or NO_TIME, host ns, keep mask)
of the frames."""

NS = 1_000_000_000


def clean_session(out: Path, name: str = "clean") -> Path:
    """A clean truth session: 20 Hz GNSS on two rovers, 50 Hz host-stamped CAN (yaw rate, a_y, SWA)."""
    cfg = load_config(SIM_TOML)
    truth = simulate_truth(cfg, straights(duration_s=6.0))
    return write_truth_session(out, name, cfg, truth, offset_deg=0.5)


def rewrite(src: Path, out: Path, name: str, edit: FrameEdit | None = None, *,
            log_time: Callable[[str, int, int], int] | None = None) -> Path:
    """Copy the session ``src`` into ``out/name`` with the real recorder, ``edit`` applied to every CAN frame
    (as one array over the whole session) and ``log_time(topic, index, log_ns)`` to the log times."""
    scans = [scan_part(p) for p in find_parts(src)]
    meta: dict[str, dict[str, str]] = {}
    atts: list[Attachment] = []
    for m, _ref in scans[0].metadata:
        if m.name in (T.METADATA_SESSION, T.METADATA_VEHICLE, T.METADATA_CALIBRATION):
            meta[m.name] = dict(m.metadata)
    for a, _ref in scans[0].attachments:
        atts.append(Attachment(a.name, a.media_type, bytes(a.data)))
    msgs: dict[str, list[tuple[int, int, bytes]]] = {}
    for s in scans:
        for topic, tm in s.topics.items():
            if topic != T.TOPIC_EVENTS:
                msgs.setdefault(topic, []).extend(zip(tm.log_time, tm.publish_time, tm.data, strict=True))
    can_topics = [t for t in msgs if t.startswith("/can/") and t.endswith("/frames")]
    for topic in can_topics:
        log0 = msgs[topic][0][0]
        rec = T.unpack_can_blocks([d for _l, _p, d in msgs[topic]])
        host = rec["host_ts_ns"].astype(np.int64)
        host0 = int(host[0])
        dev = rec["device_ts_ns"].astype(np.int64)
        keep = np.ones(host.size, dtype=bool)
        if edit is not None:
            dev, host, keep = edit(host - host[0], host, dev)
        blocks = []
        idx = np.flatnonzero(keep)
        for b in range(0, idx.size, 50):
            sel = idx[b: b + 50]
            r = rec[sel]
            blk = T.pack_can_columns(dev[sel], host[sel], r["can_id"], r["flags"], r["dlc"], r["len"], r["data"])
            # as a live recorder: the block's log time is its first frame's host time on the common base
            blocks.append((log0 + int(host[sel[0]]) - host0, int(host[sel[-1]]), blk))
        msgs[topic] = blocks
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0)
    with Recorder(out, name, meta, attachments=atts, options=opts) as rec_out:
        for topic, rows in msgs.items():
            src = rec_out.source(f"copy:{topic}", maxsize=len(rows) + 1)
            for i, (log_ns, pub_ns, data) in enumerate(rows):
                t = log_time(topic, i, log_ns) if log_time is not None else log_ns
                assert src.put(topic, t, pub_ns, data)
    return out / name
