"""A simulated recording scored against the simulator's truth: each stream's timing error."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from rig.core.config import SessionConfig
from rig.data import Session
from vsccore.errors import ConfigError
from vsccore.gpstime import gps_ns_to_unix_ns

__all__ = ["StreamTiming", "timing_vs_truth", "true_output_latency_ns"]





def true_output_latency_ns(ds: Session) -> dict[str, int]:
    """The simulated receivers' true output latency (ns) by receiver, from the simulator's truth event."""
    for _t, e in ds.events:
        if e.source == "sim" and isinstance(e.details.get("gnss_output_latency_ns"), dict):
            return {str(k): int(v) for k, v in e.details["gnss_output_latency_ns"].items()}
    raise ConfigError(f"{ds.path}: no simulated receivers' latency recorded (not a simulated session?)")


@dataclass(frozen=True, slots=True)
class StreamTiming:
    """Time-stamp error of one stream of a simulated recording against the simulator's true times."""

    stream: str
    n: int
    mean_ns: float
    rms_ns: float
    max_abs_ns: float


def _timing(stream: str, err: Any) -> StreamTiming:
    e = np.asarray(err, dtype=np.float64)
    if e.size == 0:
        return StreamTiming(stream, 0, math.nan, math.nan, math.nan)
    return StreamTiming(stream, int(e.size), float(e.mean()), float(np.sqrt(np.mean(e * e))), float(np.abs(e).max()))


def timing_vs_truth(ds: Session, cfg: SessionConfig) -> list[StreamTiming]:
    """How far each stream's times on the common base are from the truth, in a file recorded from a
    :class:`SimWorld` (whose host clock is true UTC):

    - CAN: the simulated ECU stamps each frame with its true transmit time (the interface clock);
    - DAQ: sample times from the sync pulse against the simulated sample clock (the ``sim`` event);
    - GNSS: MARKTIME against the sync schedule's true edge times is exact by construction, so the
      GNSS streams are scored through the DAQ and CAN (their alignment rests on GNSS time).
    """
    out: list[StreamTiming] = []
    for bus in ds.can_buses():
        fr = ds.can_frames(bus)
        dev = fr.records["device_ts_ns"].astype(np.int64)
        ok = dev != T.NO_TIME_NS
        out.append(_timing(f"can:{bus} ({fr.time_source})", fr.time_ns[ok] - dev[ok]))
    daq = cfg.daq
    marks = [r.name for r in cfg.receivers if {_base(lr.name) for lr in r.logs} & {"MARKTIME", "MARK1TIME", "MARKPOS"}]
    if daq is not None and daq.sync_channel is not None and marks and ds.leap_seconds is not None:
        d = ds.daq(daq.device, sync_channel=daq.sync_channel, receiver=marks[0])
        sim = [e for _t, e in ds.events if e.source == "sim" and "sample0_gps_ns" in e.details]
        if len(sim) == 1:
            g0 = gps_ns_to_unix_ns(int(sim[0].details["sample0_gps_ns"]), ds.leap_seconds)
            true = g0 + d.sample_index.astype(np.float64) * (1e9 / float(sim[0].details["true_rate_hz"]))
            out.append(_timing(f"daq:{daq.device} ({d.time_source})", d.time_ns - true))
    return out


def _base(name: str) -> str:
    return name[:-1] if name[-1:] in ("A", "B") else name

