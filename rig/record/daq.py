"""The DAQ of a recording: sample blocks on the DAQ clock aligned to GPS time by the sync pulse; the optical sensors."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.daq import DaqBlock, DaqEvent, DaqEventKind, DaqLink
from drivers.optical import OpticalSensorSpec, convert_block
from rig.core.config import DaqConfig, VehicleProfile
from rig.core.timebase import FitStatus, SyncFit, align_sync_pulses
from rig.core.topics import EventKind, Severity
from rig.record.device import Device, DeviceContext
from rig.record.status import DeviceState
from vsccore.clock import Clock
from vsccore.errors import AnalysisError
from vsccore.gpstime import GPS_EPOCH_UNIX_NS, NS_PER_S

__all__ = ["DaqDevice", "DaqFactory", "DaqSegmentTiming"]

log = logging.getLogger(__name__)


DaqFactory = Callable[[DaqConfig, Clock, Callable[[DaqBlock], None], Callable[[DaqEvent], None]], DaqLink]
"""Makes the DAQ session for ``[daq]`` (default: :meth:`drivers.daq.DaqLink.from_config`)."""


_OPTICAL_MAX_HZ = 100.0


class DaqDevice(Device):
    """The DAQ and the optical sensors it reads."""

    def __init__(self, ctx: DeviceContext, dc: DaqConfig, profile: VehicleProfile,
                 daq_factory: DaqFactory | None = None) -> None:
        super().__init__(ctx, f"daq.{dc.device}", "daq", maxsize=20_000)
        self.dc = dc
        self.clock_name = f"daq:{dc.device}"
        self.topic_samples = T.daq_samples(dc.device)
        self.ns_per_sample = NS_PER_S / dc.rate_hz
        cal = profile.calibration
        names = {c.name for c in dc.channels}
        self.optical: list[OpticalSensorSpec] = []
        for o in profile.optical:
            chans = [ch.daq_channel for ch in o.channels.values() if ch.daq_channel is not None]
            if chans and all(c in names for c in chans):
                self.optical.append(OpticalSensorSpec.from_config(
                    o.model_dump(), zero_offset_deg=cal.optical_zero_deg.get(o.name, 0.0), where=f"optical.{o.name}"))
        self.step = max(1, round(dc.rate_hz / _OPTICAL_MAX_HZ))
        self._lock = threading.Lock()
        self._segment = 0
        self._base = 0
        self._next_index = 0
        self._last_host = 0
        self.segments: dict[int, DaqSegmentTiming] = {}
        """Per acquisition (the DAQ's segment number): its own sync fit or host mapping."""
        self._latency_ns = 0
        self.lost = 0
        if daq_factory is not None:
            self.daq = daq_factory(dc, ctx.clock, self._on_block, self._on_event)
        else:
            self.daq = DaqLink.from_config(dc.model_dump(), on_block=self._on_block, on_event=self._on_event,
                                              clock=ctx.clock)

    def start(self) -> None:
        self.daq.start()

    def stop(self) -> None:
        self.daq.stop()

    def _index_base(self, segment: int, host_ns: int) -> int:
        """File sample index of index 0 of ``segment``: indices stay unique across reconnects.

        A new segment starts after the last index seen plus the samples the host time says were
        missed (its true position comes from the sync pulse; the estimate only keeps the order).
        """
        with self._lock:
            if segment != self._segment:
                if self._segment:
                    gap = max(0, round((host_ns - self._last_host) / self.ns_per_sample))
                    self._base = self._next_index + gap
                self._segment = segment
                self.segments[segment] = DaqSegmentTiming(segment, self._base)
            return self._base

    def _on_block(self, block: DaqBlock) -> None:
        try:
            self._block(block)
        except Exception as exc:  # an exception here would end the DAQ session
            self.failed_callback("block handling", exc)

    def _block(self, block: DaqBlock) -> None:
        s = self.ctx
        host = block.host_time_ns
        base = self._index_base(block.segment, host)
        first = base + block.first_sample_index
        n = block.n_samples
        with self._lock:
            self._next_index = first + n
            self._last_host = host
            seg = self._segment_of(block.segment, base)
            # lower envelope of the receive times: host time of the segment's index 0, at the nominal rate
            off = host - round((first + n - 1 - base) * self.ns_per_sample)
            seg.host_offset_ns = off if seg.host_offset_ns is None else min(seg.host_offset_ns, off)
        if block.lost_before is not None:
            self.lost += block.lost_before.count
        s.timebase.clock(self.clock_name).add(round((first + n - 1) * self.ns_per_sample), host)
        payload = T.pack_daq_block(T.DaqBlock(first, block.rate_hz, block.channels,
                                              np.asarray(block.data, dtype=np.float32)))
        t = self.sample_utc(np.asarray([first], dtype=np.float64), seg)
        self.source.put(self.topic_samples, int(t[0]), host, payload)
        s.board.message(self.name, host)
        for spec in self.optical:
            sample = convert_block(spec, block)
            sel = np.arange((-first) % self.step, n, self.step)
            if sel.size == 0:
                continue
            times = self.sample_utc((first + sel).astype(np.float64), seg)
            records = sample.records()
            topic = T.optical(spec.name)
            for i, ti in zip(sel.tolist(), times.tolist(), strict=True):
                rec = records[i]
                rec["sample_index"] = first + i
                self.source.put(topic, ti, host, rec)

    def _segment_of(self, number: int, base: int) -> DaqSegmentTiming:
        seg = self.segments.get(number)
        if seg is None:  # the driver's first segment (or an index_base call raced us)
            seg = self.segments[number] = DaqSegmentTiming(number, base)
        return seg

    def current_segment(self) -> DaqSegmentTiming | None:
        with self._lock:
            return self.segments.get(self._segment)

    @property
    def fit(self) -> SyncFit | None:
        """The sync fit of the current acquisition (None until it has enough edges matched to marks)."""
        seg = self.current_segment()
        return None if seg is None else seg.fit

    def sample_utc(self, index: np.ndarray, seg: DaqSegmentTiming | None = None) -> np.ndarray:
        """Common-time-base times (int64 ns) of file sample indices of one acquisition (default: the current).

        Each acquisition is timed on its own (the sample index restarts with a reconnect and the
        file's index after one is only an estimate): from its own sync fit once two or more of its
        edges match marks; before that from the host mapping (:meth:`host_utc`), and marked so.
        """
        tb = self.ctx.timebase
        seg = seg if seg is not None else self.current_segment()
        if seg is None:
            return np.round(index * self.ns_per_sample).astype(np.int64)
        fit = seg.fit
        if fit is not None and tb.leap_seconds is not None:
            return fit.gps_ns(index) + (GPS_EPOCH_UNIX_NS - tb.leap_seconds * NS_PER_S)
        return self.host_utc(index, seg)

    def _period_ns(self) -> float:
        """Sample period: from a synchronised acquisition (one oscillator), else the host estimate, else nominal."""
        with self._lock:
            fits = [s.fit for s in self.segments.values() if s.fit is not None]
        if fits:
            return float(fits[-1].map.slope)
        f = self.ctx.timebase.clock(self.clock_name).fit()
        if f is not None and self.ctx.timebase.clock(self.clock_name).status() is FitStatus.OK:
            return self.ns_per_sample * f[2]
        return self.ns_per_sample

    def host_utc(self, index: np.ndarray, seg: DaqSegmentTiming) -> np.ndarray:
        """Host-clock times of ``seg``'s samples on the common base: the lower envelope of its blocks'
        receive times less the DAQ's delivery latency measured on a synchronised acquisition (as the
        offline reader, :meth:`rig.data.Session.daq`, does for a segment without sync edges)."""
        tb = self.ctx.timebase
        off = seg.host_offset_ns
        if off is None:
            return np.round(index * self.ns_per_sample).astype(np.int64)
        host = off + np.round((np.asarray(index, dtype=np.float64) - seg.base) * self._period_ns()).astype(np.int64)
        return np.asarray([tb.host_to_utc(int(h)) for h in host], dtype=np.int64) - self._latency_ns

    def _on_event(self, ev: DaqEvent) -> None:
        try:
            self._event(ev)
        except Exception as exc:
            self.failed_callback("event handling", exc)

    def _event(self, ev: DaqEvent) -> None:
        k = ev.kind
        board = self.ctx.board
        if k is DaqEventKind.SYNC_EDGE:
            if ev.edge_index is not None:
                base = self._index_base(ev.segment, ev.host_time_ns)
                with self._lock:
                    self._segment_of(ev.segment, base).edges.append(base + ev.edge_index)
            return
        details: dict[str, Any] = {"segment": ev.segment}
        if ev.channel is not None:
            details["channel"] = ev.channel
        if ev.sample_index is not None:
            details["sample_index"] = ev.sample_index
        if ev.count is not None:
            details["count"] = ev.count
        if k in (DaqEventKind.STARTED, DaqEventKind.RECONNECTED):
            board.update(self.name, state=DeviceState.OK)
            details["time_source"] = "host"  # until this acquisition's own sync edges are matched
            self.event(EventKind.CONNECT, ev.message, host_ns=ev.host_time_ns, **details)
        elif k is DaqEventKind.DISCONNECTED:
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.DISCONNECT, ev.message, severity=Severity.WARNING, host_ns=ev.host_time_ns,
                       **details)
        elif k in (DaqEventKind.CONNECT_FAILED, DaqEventKind.ERROR):
            board.update(self.name, state=DeviceState.LOST)
            self.event(EventKind.ERROR, ev.message, severity=Severity.ERROR, host_ns=ev.host_time_ns, **details)
        elif k is DaqEventKind.OVERFLOW:
            self.event(EventKind.OVERFLOW, ev.message, severity=Severity.WARNING, host_ns=ev.host_time_ns, **details)
        elif k in (DaqEventKind.SATURATION, DaqEventKind.STUCK, DaqEventKind.FLOATING):
            board.update(self.name, state=DeviceState.DEGRADED)
            self.event(EventKind.WARNING, ev.message, severity=Severity.WARNING, host_ns=ev.host_time_ns, **details)
        elif k in (DaqEventKind.SATURATION_CLEARED, DaqEventKind.STUCK_CLEARED, DaqEventKind.FLOATING_CLEARED):
            self.event(EventKind.INFO, ev.message, host_ns=ev.host_time_ns, **details)
        elif k is DaqEventKind.STOPPED:
            board.update(self.name, state=DeviceState.STOPPED)

    def refresh(self) -> None:
        """Status-board detail: rate, channels, lost samples, and the current acquisition's sync fit."""
        detail = f"{self.dc.rate_hz:g} Hz × {len(self.dc.channels)} ch, lost {self.lost}"
        seg = self.current_segment()
        if seg is not None and seg.fit is None and len(seg.edges) >= 2 and len(seg.edges) != seg.fit_counts[0]:
            # a fresh acquisition (start, reconnect) gets its own fit as soon as it has two edges,
            # not at the next time-base period
            self.ctx.align_daq()  # the recording owns the marks
            seg = self.current_segment()
        fit = None if seg is None else seg.fit
        if seg is not None and fit is not None:
            detail += (f", sync {fit.matched_edges.size} edges rms {fit.rms_ns / 1e3:.1f} µs "
                       f"drift {fit.drift_ppm:+.1f} ppm")
        else:
            n = 0 if seg is None else len(seg.edges)
            detail += f", {n} sync edges, not aligned yet (host clock)"
        if seg is not None and seg.number > 1:
            detail += f", acquisition {seg.number}"
        self.ctx.board.update(self.name, detail=detail)

    def align(self, marks: Sequence[int]) -> None:
        """Refit each acquisition's sample index → GPS time from its own sync edges and the marks (when
        there is something new). An acquisition without two matched edges yet keeps the host mapping."""
        tb = self.ctx.timebase
        marks_a = np.asarray(marks, dtype=np.int64)
        with self._lock:
            todo = [(seg, np.asarray(seg.edges, dtype=np.float64)) for seg in self.segments.values()]
        latest: SyncFit | None = None
        for seg, edges in todo:
            counts = (edges.size, marks_a.size)
            if edges.size >= 2 and marks_a.size >= 2 and counts != seg.fit_counts:
                self._align_segment(seg, edges, marks_a)
                seg.fit_counts = counts
            if seg.fit is not None:
                latest = seg.fit
        if latest is not None:
            tb.set_daq(latest)

    def _align_segment(self, seg: DaqSegmentTiming, edges: np.ndarray, marks: np.ndarray) -> None:
        tb = self.ctx.timebase
        approx: np.ndarray | None = None
        if seg.fit is not None:
            approx = seg.fit.gps_ns(edges)
        elif tb.leap_seconds is not None and seg.host_offset_ns is not None:
            approx = self.host_utc(edges, seg) - (GPS_EPOCH_UNIX_NS - tb.leap_seconds * NS_PER_S)
        # the fit's clock name says which acquisition it is (the first keeps the device's name)
        name = self.dc.device if seg.number <= 1 else f"{self.dc.device}#{seg.number}"
        try:
            fit = align_sync_pulses(name, edges, marks, self.dc.rate_hz, approx_gps_ns=approx)
        except AnalysisError as exc:
            log.debug("DAQ %s acquisition %d: no sync fit yet: %s", self.dc.device, seg.number, exc)
            return
        first = seg.fit is None
        if first and tb.leap_seconds is not None and seg.host_offset_ns is not None:
            # the DAQ's delivery latency (host receive − true time), for acquisitions without a fit
            utc0 = int(fit.gps_ns(np.asarray([seg.base], dtype=np.float64))[0]) + (
                GPS_EPOCH_UNIX_NS - tb.leap_seconds * NS_PER_S)
            self._latency_ns = tb.host_to_utc(seg.host_offset_ns) - utc0
        seg.fit = fit
        if first:
            self.event(EventKind.INFO, f"acquisition {seg.number} synchronised to the sync pulse "
                       f"({fit.matched_edges.size} edges, rms {fit.rms_ns / 1e3:.1f} µs); its times before this "
                       "were from the host clock", segment=seg.number, time_source="sync_pulse")


@dataclass(slots=True)
class DaqSegmentTiming:
    """Live timing state of one DAQ acquisition (a segment: the sample index restarts with a reconnect)."""

    number: int
    """The DAQ driver's segment number (1 for the first acquisition)."""
    base: int
    """File sample index of the segment's index 0."""
    edges: list[float] = field(default_factory=list)
    """File sample indices of its sync edges."""
    host_offset_ns: int | None = None
    """Lower envelope of the host receive times, as the host time of index ``base`` (nominal rate)."""
    fit: SyncFit | None = None
    """Its own sync fit (None: too few edges matched yet; times come from the host clock)."""
    fit_counts: tuple[int, int] = (0, 0)

    @property
    def time_source(self) -> str:
        """``sync_pulse`` or ``host`` (not synchronised yet)."""
        return "sync_pulse" if self.fit is not None else "host"

