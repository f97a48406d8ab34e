"""A synthetic session of known content, written by the real recorder, for ``rig info`` and ``rig export``.

Two NovAtel rovers at 20 Hz: their port bytes (BESTPOSB and BESTVELB binary logs, a BESTVELA ASCII log
once a second) cut into reads of random size, so frames straddle reads and part boundaries, plus
decoded BESTPOS; rover_b is silent for 2 s (disconnect and connect events). Corrections: a base's
RTCM3 epoch once a second in several reads, with relay statistics. Time-base records every 5 s,
events (mark, error, warning), calibration metadata, an attachment. Small chunks and a small
rollover size give several parts.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.novatel import (
    BestPos,
    BestVel,
    Datum,
    PositionType,
    SolutionStatus,
    encode_ascii,
    encode_binary,
    make_header,
)
from rig.store import Attachment, Recorder, RecorderOptions, session_metadata
from tests.relay.helpers import base_epoch
from vsccore.gpstime import gps_ns_to_unix_ns, gps_to_ns

LEAP = 18
WEEK = 2400
SOW0 = 345_600.0
G0 = gps_to_ns(WEEK, SOW0)
U0 = gps_ns_to_unix_ns(G0, LEAP)
"""UTC (ns since the Unix epoch) of epoch 0."""
DT = 50_000_000
RECEIVERS = ("rover_a", "rover_b")
GAP_EPOCHS = (200, 240)
"""rover_b delivers nothing for epochs [200, 240): 2 s."""
CALIBRATION = {"gnss": {"mount_offset_deg": 0.12, "baseline_m": 1.5}, "optical": {"zero_offset_deg": -0.3}}
CLOCKS = ("daq:daq1", "gnss:rover_a", "gnss:rover_b")


@dataclass
class Synth:
    base: Path
    epochs: int
    frames: dict[str, list[bytes]] = field(default_factory=dict)
    """Every NovAtel frame written by each receiver, as the framer returns it (ASCII without CR LF)."""
    reads: dict[str, list[bytes]] = field(default_factory=dict)
    """Every raw read per receiver, and of the relay (``relay``), in order."""
    read_times: dict[str, list[int]] = field(default_factory=dict)
    rtcm: list[bytes] = field(default_factory=list)
    bestpos_times: dict[str, list[int]] = field(default_factory=dict)
    timebase_last: dict[str, dict[str, Any]] = field(default_factory=dict)
    timebase_count: int = 0
    events: dict[str, int] = field(default_factory=dict)
    disconnect: tuple[int, int] = (0, 0)
    all_times: list[int] = field(default_factory=list)

    @property
    def gap_start_ns(self) -> int:
        """Log time of rover_b's last BESTPOS before its gap."""
        return U0 + (GAP_EPOCHS[0] - 1) * DT

    @property
    def gap_end_ns(self) -> int:
        return U0 + GAP_EPOCHS[1] * DT


def _bestpos(k: int, r: int) -> BestPos:
    return BestPos(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 48.7 + k * 1e-7, 9.18 + r * 1e-5, 300.0,
                   47.0, Datum.WGS84, 0.01, 0.01, 0.02, "7", 1.0, 0.0, 20, 18, 18, 16, 0, 0, 0, 0)


def _bestvel(k: int) -> BestVel:
    return BestVel(SolutionStatus.SOL_COMPUTED, PositionType.NARROW_INT, 0.05, 1.0, 20.0 + k * 1e-3, 90.0, 0.0, 0.0)


def _cut(stream: bytes, ends: list[int], t_of_end: list[int], rng: np.random.Generator, max_read: int
         ) -> list[tuple[int, bytes]]:
    """Cut ``stream`` into reads of 1..max_read bytes; a read's time is that of the frame its last byte is in."""
    out: list[tuple[int, bytes]] = []
    pos = 0
    j = 0
    while pos < len(stream):
        n = int(rng.integers(1, max_read + 1))
        chunk = stream[pos : pos + n]
        pos += len(chunk)
        while ends[j] < pos:
            j += 1
        out.append((t_of_end[j] + 2_000_000 + 100 * len(out), chunk))
    return out


def write_session(out: Path, name: str = "run", duration_s: float = 30.0, rollover_bytes: int | None = 40_000,
                  chunk_size: int = 8 * 1024) -> Synth:
    rng = np.random.default_rng(7)
    epochs = int(duration_s * 20)
    meta = session_metadata(session={"output": {"name": name}}, vehicle={"name": "test car"}, calibration=CALIBRATION)
    opts = RecorderOptions(min_free_bytes=0, warn_free_bytes=0, reserve_bytes=0, chunk_size=chunk_size,
                           rollover_size_bytes=rollover_bytes)
    att = Attachment("session.toml", "application/toml", b"[output]\nname = 'run'\n")
    syn = Synth(out / name, epochs)
    h0 = time.time_ns()

    def host_to_log_time(h: int) -> int:
        """The recorder's own events (start, rollover, stop) land near U0, inside the synthetic data."""
        return U0 + 1_000_000 + (h - h0)

    with Recorder(out, name, meta, attachments=[att], options=opts, host_to_log_time=host_to_log_time) as rec:
        # corrections: one base epoch a second, 3 to 8 reads per second a few ms apart
        relay = rec.source("relay", maxsize=100_000)
        rtcm: list[bytes] = []
        r_reads: list[bytes] = []
        r_times: list[int] = []
        for s in range(int(duration_s)):
            epoch_frames = base_epoch(epoch_ms=int(SOW0 * 1000) + s * 1000)
            rtcm.extend(epoch_frames)
            epoch = b"".join(epoch_frames)
            inner = rng.choice(np.arange(1, len(epoch)), size=int(rng.integers(2, 8)), replace=False)
            cuts = [0, *sorted(inner.tolist()), len(epoch)]
            for i, (c0, c1) in enumerate(zip(cuts[:-1], cuts[1:], strict=True)):
                t = U0 + s * 1_000_000_000 + 30_000_000 + i * 3_000_000
                relay.put(T.TOPIC_RELAY_RAW, t, t, epoch[c0:c1])
                r_reads.append(epoch[c0:c1])
                r_times.append(t)
            relay.put(T.TOPIC_RELAY_STATS, U0 + s * 1_000_000_000 + 40_000_000, U0 + s * 1_000_000_000,
                      {"source": "serial:/dev/ttyUSB0", "format": "rtcmv3", "bytes_in": sum(map(len, r_reads)),
                       "frames_in": len(rtcm), "crc_errors": 0})
        syn.rtcm = rtcm
        syn.reads["relay"] = r_reads
        syn.read_times["relay"] = r_times
        syn.all_times += r_times
        # time base quality every 5 s (one message per clock)
        tb = rec.source("timebase")
        for s in range(0, int(duration_s), 5):
            for c_i, clock in enumerate(CLOCKS):
                rec_ = {"clock": clock, "method": "sync_pulse" if clock.startswith("daq") else "lower_envelope",
                        "reference": "gps" if clock.startswith("daq") else "host", "status": "ok", "n": 10 * (s + 1),
                        "span_s": float(s), "offset_ns": 1000 * c_i, "drift_ppm": 10.0 + c_i + s,
                        "jitter_ns": 1e5 * (c_i + 1) + s, "latency_p50_ns": 2e6, "latency_p95_ns": 4e6 + s,
                        "rms_ns": 3e4 if clock.startswith("daq") else None,
                        "max_abs_ns": 8e4 if clock.startswith("daq") else None, "leap_seconds": LEAP}
                tb.put(T.TOPIC_TIMEBASE, U0 + s * 1_000_000_000 + c_i, U0 + s * 1_000_000_000, rec_)
                syn.timebase_last[clock] = rec_
                syn.timebase_count += 1
        # the receivers last, so that their raw streams run on into the last part
        srcs = {}
        for r, rx in enumerate(RECEIVERS):
            src = srcs[rx] = rec.source(rx, maxsize=100_000)
            frames: list[bytes] = []
            ends: list[int] = []
            t_end: list[int] = []
            stream = bytearray()
            times: list[int] = []
            for k in range(epochs):
                if rx == "rover_b" and GAP_EPOCHS[0] <= k < GAP_EPOCHS[1]:
                    continue
                sow = SOW0 + k * 0.05
                pos = _bestpos(k, r)
                vel = _bestvel(k)
                wire = [encode_binary(make_header(pos, week=WEEK, seconds=sow, sequence=k % 60000), pos),
                        encode_binary(make_header(vel, week=WEEK, seconds=sow), vel)]
                if k % 20 == 0:
                    wire.append(encode_ascii(make_header(vel, week=WEEK, seconds=sow, port="COM2"), vel))
                for w in wire:
                    stream += w
                    frames.append(w[:-2] if w.startswith(b"#") else w)  # ASCII: Frame.raw has no CR LF
                    ends.append(len(stream))
                    t_end.append(U0 + k * DT)
                t = U0 + k * DT
                times.append(t)
                src.put(T.gnss_bestpos(rx), t, t + 20_000_000,
                        {"gps_time_ns": G0 + k * DT, "time_status": "FINESTEERING", "sol_status": "SOL_COMPUTED",
                         "pos_type": "NARROW_INT", "lat_deg": pos.lat_deg, "lon_deg": pos.lon_deg,
                         "height_msl_m": 300.0, "lat_std_m": 0.01, "lon_std_m": 0.01, "height_std_m": 0.02})
            reads = _cut(bytes(stream), ends, t_end, rng, 300)
            for t, chunk in reads:
                src.put(T.gnss_raw(rx), t, t + 1000, chunk)
            syn.frames[rx] = frames
            syn.reads[rx] = [c for _t, c in reads]
            syn.read_times[rx] = [t for t, _c in reads]
            syn.bestpos_times[rx] = times
            syn.all_times += times + [t for t, _c in reads]
        # events: rover_b's disconnect, an error on rover_a, an operator mark (plus the recorder's rollovers)
        srcs["rover_b"].event(T.EventKind.DISCONNECT, "port lost: [Errno 5] Input/output error",
                              severity=T.Severity.WARNING, log_time_ns=syn.gap_start_ns + 10_000_000)
        srcs["rover_b"].event(T.EventKind.CONNECT, "port reopened", log_time_ns=syn.gap_end_ns - 10_000_000)
        syn.disconnect = (syn.gap_start_ns + 10_000_000, syn.gap_end_ns - 10_000_000)
        srcs["rover_a"].event(T.EventKind.ERROR, "checksum burst: 3 frames dropped", severity=T.Severity.ERROR,
                              log_time_ns=U0 + 5_000_000_000)
        rec.event(T.EventKind.MARK, "operator mark: start of circle", log_time_ns=U0 + 3_000_000_000)
        syn.events = {"disconnect": 1, "connect": 1, "error": 1, "mark": 1}
    return syn
