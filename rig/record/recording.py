"""A recording session: every device of a session configuration into one MCAP file (``rig record``).

:class:`Recording` builds the devices of a :class:`~rig.core.config.SessionConfig` and records them
through one :class:`~rig.store.Recorder`, one bounded source per device:

- each NovAtel receiver (:class:`~drivers.novatel.receiver.NovatelReceiver`): configured with
  its logs, the raw bytes of its port on ``/gnss/<rx>/raw``, the decoded BESTPOS / BESTVEL /
  MARKPOS / MARKTIME / TIME / HEADING logs, and a ``foxglove.LocationFix`` per BESTPOS on
  ``/gnss/<rx>/fix``; every synchronous log feeds the receiver's clock estimator in the
  :class:`~rig.core.timebase.Timebase` (after removing the receiver's output latency and the log's
  serial transmission time), and TIME gives the leap seconds;
- the correction relay (:class:`~drivers.relay.Relay`): ``receiver:NAME`` as source reads the
  corrections out of that receiver's own stream; ``receiver:NAME`` as sink writes to the device
  wired to that receiver's correction port (or through its command port); the relayed frames on
  ``/relay/raw`` and its statistics on ``/relay/stats`` once a second;
- each CAN bus (:class:`~drivers.can.bus.CanBusLink`): every frame in blocks on
  ``/can/<bus>/frames`` and, with a role map, one ``/can/<bus>/roles`` message per decoded frame;
- the DAQ (:class:`~drivers.daq.DaqLink`): sample blocks on ``/daq/<device>/samples`` and the
  optical sensors wired to it (decimated to ≤ 100 Hz) on ``/optical/<sensor>``; its sample clock
  is put on GPS time from the sync-switch edges and the MARKTIME/MARKPOS of the same edges;
- ``/rig/timebase`` quality records every ``timebase_period_s`` and at the end, and
  ``/rig/events`` for connects, disconnects, gaps, errors and warnings of every device;
- timing integrity: a channel silent for longer than its stall threshold
  (:func:`rig.core.quality.stall_threshold_ns`) turns its device DEGRADED on the status board while it
  lasts (a dashboard alarm) and is a ``gap`` event when it resumes (:mod:`rig.store.sources`); at
  the end, a channel that stopped before the session did is a ``gap`` event of kind ``ended_early``,
  a jump of the time base (the first TIME replacing the host estimate) is a ``timebase`` event, and
  the streams' live time-base verdicts (:func:`rig.core.quality.live_verdicts`) are a ``timebase`` event;
  :func:`summary_lines` reports late, stalled and clamped channels beside the drops.

Decoded messages carry ``log_time`` on the common time base (GNSS logs: their GPS time in UTC;
other devices: their device or host time mapped through the time base as known at that moment);
``publish_time`` is always the host receive time. A device that fails does not stop the others:
its callbacks never raise into its driver, its failure is an event and a line on the
:class:`~rig.record.status.StatusBoard`. :meth:`Recording.stop` stops the relay, receivers, CAN and
DAQ, writes the last records and finalizes the file. Simulated sessions pass the simulated world
as port resolver, DAQ and CAN factories and plug-in (see :mod:`rig.sim.world`). The device adapters
live in :mod:`rig.record.gnss`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import logging
import math
import shutil
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

import can
import pymap3d
import tomli_w

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.can.bus import CanBusConfig
from drivers.novatel import BestPos
from drivers.relay.endpoints import mask_credentials
from rig.analysis.live_ltr import LiveLtr
from rig.core.config import ReceiverConfig, SessionConfig
from rig.core.quality import (
    FLOOR_ALLOWANCE_MS,
    Gap,
    StreamQuality,
    ended_early,
    live_daq_causality_ns,
    live_verdicts,
    stream_of_topic,
)
from rig.core.timebase import OEM7_OUTPUT_LATENCY_S, Timebase
from rig.core.topics import EventKind, Severity
from rig.record.can import CAN_BLOCK_AGE_NS, CanDevice, roles_table
from rig.record.daq import DaqDevice, DaqFactory
from rig.record.device import Device, Reconnect
from rig.record.gnss import GnssDevice, receiver_commands
from rig.record.relay import RelayDevice
from rig.record.status import DeviceState, StatusBoard
from rig.store import Attachment, FileSummary, Recorder, RecorderOptions, Source, session_metadata
from vsccore.angles import sideslip_from_azimuths
from vsccore.clock import Clock, SystemClock
from vsccore.errors import SessionFileError
from vsccore.gpstime import NS_PER_S

__all__ = [
    "DaqFactory",
    "DirectPorts",
    "PortResolver",
    "Recording",
    "RecordingPlugin",
    "RecordingSummary",
    "default_session_name",
    "receiver_commands",
    "summary_lines",
]

log = logging.getLogger(__name__)



class PortResolver(Protocol):
    """Where a receiver's ports are on this host (real devices: the configuration as written)."""

    def port(self, receiver: ReceiverConfig) -> str:
        """Path or URL of the host port wired to the receiver's command port."""
        ...

    def correction_port(self, receiver: ReceiverConfig) -> str | None:
        """Path or URL wired to the receiver's correction port (None: send through the command port)."""
        ...


class DirectPorts:
    """The ports as configured (``port``, ``correction_device``)."""

    def port(self, receiver: ReceiverConfig) -> str:
        return receiver.port

    def correction_port(self, receiver: ReceiverConfig) -> str | None:
        return receiver.correction_device


class RecordingPlugin(Protocol):
    """Something that records alongside the devices (the simulated world's ground truth)."""

    def attach(self, session: Recording) -> None:
        """Called once the recorder runs and the devices are started."""
        ...

    def detach(self, session: Recording) -> None:
        """Called after the devices stopped, before the file is finalized."""
        ...




@dataclass(frozen=True, slots=True)
class RecordingSummary:
    """What a finished session recorded."""

    name: str
    recording: FileSummary
    errors: tuple[str, ...]
    """Problems while stopping devices (the recording itself: ``recording.error``)."""
    device_errors: dict[str, int]
    """Error events per device during the session."""
    late: Mapping[str, float] = field(default_factory=dict)
    """Channels that stopped before the session did: seconds before its end, per topic."""
    stalled: Mapping[str, tuple[int, float]] = field(default_factory=dict)
    """Channels that stalled: (stalls, seconds silent in all), per topic."""
    clamped: Mapping[str, tuple[int, float]] = field(default_factory=dict)
    """Channels whose log_time ran back and was clamped: (messages, largest step back in ms), per topic."""
    verdicts: Mapping[str, StreamQuality] = field(default_factory=dict)
    """The streams' live time-base verdicts (:func:`rig.core.quality.live_verdicts`)."""

    @property
    def parts(self) -> tuple[Path, ...]:
        return self.recording.parts


LATENCY_STEP_NS = 300_000
"""The smallest output-latency excess the recording acts on (its own figure's scatter is tens of µs)."""


def default_session_name(now_ns: int) -> str:
    """``session-YYYYmmdd-HHMMSS`` (UTC) of a host time."""
    return datetime.fromtimestamp(now_ns / 1e9, tz=UTC).strftime("session-%Y%m%d-%H%M%S")


# ---------------------------------------------------------------------------------------------
# The session
# ---------------------------------------------------------------------------------------------


class Recording:
    """Records every device of ``cfg`` into ``<out_dir>/<name>.NNN.mcap`` (see the module docstring).

    Args:
        cfg: the session configuration (resolved by :func:`rig.core.config.load_session`).
        out_dir: output folder (default ``[output].directory``; created).
        name: session name (default ``[output].name`` or ``session-<UTC time>``).
        clock: host clock (a simulated world's scaled clock; default the wall clock).
        ports: where the receivers' ports are (default: as configured).
        daq_factory: makes the DAQ session (default :meth:`~drivers.daq.DaqLink.from_config`).
        can_factory: opens a CAN interface (default :func:`drivers.can.bus.open_bus`).
        plugins: attached after the devices start, detached after they stop.
        config_path: the configuration file, attached to the recording.
        options: recorder options (default from ``[output]``).
        stats_period_s, timebase_period_s: how often relay statistics and time-base records are written
            (session clock).
        reconnect_first_s, reconnect_max_s: back-off of the receivers' and CAN buses' reconnects.
    """

    def __init__(
        self,
        cfg: SessionConfig,
        *,
        out_dir: Path | str | None = None,
        name: str | None = None,
        clock: Clock | None = None,
        ports: PortResolver | None = None,
        daq_factory: DaqFactory | None = None,
        can_factory: Callable[[CanBusConfig], can.BusABC] | None = None,
        plugins: Sequence[RecordingPlugin] = (),
        config_path: Path | str | None = None,
        options: RecorderOptions | None = None,
        stats_period_s: float = 1.0,
        timebase_period_s: float = 10.0,
        reconnect_first_s: float = 0.1,
        reconnect_max_s: float = 2.0,
    ) -> None:
        self.cfg = cfg
        self.clock: Clock = clock or SystemClock()
        self.name = name or cfg.output.name or default_session_name(self.clock.now_ns())
        self.out_dir = Path(out_dir if out_dir is not None else cfg.output.directory)
        self.ports: PortResolver = ports or DirectPorts()
        self.daq_factory = daq_factory
        self.can_factory = can_factory
        self.plugins = tuple(plugins)
        self.config_path = Path(config_path) if config_path is not None else None
        self.options = options or RecorderOptions.from_output(cfg.output)
        self.stats_period_ns = round(stats_period_s * NS_PER_S)
        self.timebase_period_ns = round(timebase_period_s * NS_PER_S)
        self.reconnect = Reconnect(reconnect_first_s, reconnect_max_s)
        # A receiver's output latency is its own (never the simulator's truth): configured per receiver, else
        # measured from the DAQ's sync pulse during the recording (from 0: the measurement sees only a map
        # that is early), else OEM7's typical figure.
        self._measure_latency = cfg.daq is not None and cfg.daq.sync_channel is not None
        self.gnss_output_latency_ns = 0 if self._measure_latency else round(OEM7_OUTPUT_LATENCY_S * NS_PER_S)
        self.measured_latency_ns = 0
        """Output latency of the reference receiver measured so far (added to its clock's known latency)."""
        rovers = [r for r in cfg.receivers if r.role == "rover"]
        rovers.sort(key=lambda r: r.antenna or "z")
        reference = rovers[0].name if rovers else (cfg.receivers[0].name if cfg.receivers else None)
        self.timebase = Timebase(reference_receiver=reference)
        self.board = StatusBoard(self.name, now_ns=self.clock.now_ns())
        self._recorder: Recorder | None = None
        self.gnss: dict[str, GnssDevice] = {}
        self.relay: RelayDevice | None = None
        self.can: list[CanDevice] = []
        self.daq: DaqDevice | None = None
        self._rig: Source | None = None
        self._marks: list[int] = []
        self._marks_from_time: dict[str, bool] = {}
        self._sync_receiver: str | None = None
        self._marks_lock = threading.Lock()
        self._hk_stop = threading.Event()
        self._hk: threading.Thread | None = None
        self._stop_lock = threading.Lock()
        self._summary: RecordingSummary | None = None
        self.failed = threading.Event()
        """Set when the recording itself failed (disk full, write error): the session should stop."""
        self.ltr = LiveLtr(cfg.profile.vehicle)
        self._pos_a: tuple[int, BestPos] | None = None
        self._pos_b: tuple[int, BestPos] | None = None
        self._stalled_now: dict[str, str] = {}
        """Devices whose channel is stalled right now → the alarm text (the dashboard shows them DEGRADED)."""
        self._steps_written = 0
        self._timing: tuple[dict[str, float], dict[str, tuple[int, float]], dict[str, tuple[int, float]],
                            dict[str, StreamQuality]] = ({}, {}, {}, {})

    # --- public --------------------------------------------------------------------------------

    @property
    def recorder(self) -> Recorder:
        if self._recorder is None:
            raise SessionFileError(f"session {self.name}: not started")
        return self._recorder

    @property
    def base(self) -> Path:
        """Base path of the session's parts (``<out_dir>/<name>``)."""
        return self.out_dir / self.name

    def start(self) -> None:
        """Open the file, start every device and the housekeeping thread.

        Raises:
            ConfigError: a device configuration the drivers refuse (nothing keeps running).
            SessionFileError: the file cannot be created.
        """
        if self._recorder is not None:
            raise SessionFileError(f"session {self.name}: already started")
        self.out_dir.mkdir(parents=True, exist_ok=True)
        cfg = self.cfg
        profile = cfg.profile
        meta = session_metadata(
            session=cfg.model_dump(mode="json"),
            vehicle={"vehicle": profile.vehicle.model_dump(mode="json"),
                     "antennas": profile.antennas.model_dump(mode="json"),
                     "optical": [o.model_dump(mode="json") for o in profile.optical]},
            calibration=profile.calibration.model_dump(mode="json"),
        )
        rec = Recorder(self.out_dir, self.name, meta, attachments=self._attachments(), options=self.options,
                       clock=self.clock, host_to_log_time=self.timebase.host_to_utc)
        rec.start()
        self._recorder = rec
        try:
            self._rig = rec.source("rig", maxsize=10_000)
            self._build_devices()
            self._start_devices()
            for plugin in self.plugins:
                plugin.attach(self)
        except BaseException:
            self._stop_devices([])
            rec.stop()
            raise
        self._hk_stop.clear()
        self._hk = threading.Thread(target=self._housekeeping, name=f"rig-session:{self.name}")
        self._hk.start()
        log.info("session %s recording to %s", self.name, rec.base)

    def stop(self) -> RecordingSummary:
        """Stop every device, write the last records, finalize the file (idempotent)."""
        with self._stop_lock:
            if self._summary is not None:
                return self._summary
            rec = self.recorder
            self._hk_stop.set()
            if self._hk is not None:
                self._hk.join(10.0)
            errors: list[str] = []
            self._stop_devices(errors)
            for plugin in self.plugins:
                _step(errors, f"plugin {type(plugin).__name__}", functools.partial(plugin.detach, self))
            _step(errors, "final records", self._final_records)
            summary = rec.stop()
            late, stalled, clamped, verdicts = self._timing
            self._summary = RecordingSummary(
                name=self.name, recording=summary, errors=tuple(errors),
                device_errors={d.name: d.errors for d in self._devices()},
                late=late, stalled=stalled, clamped=clamped, verdicts=verdicts,
            )
            for e in errors:
                log.error("session %s: %s", self.name, e)
            return self._summary

    def run(
        self,
        stop: threading.Event,
        *,
        duration_s: float | None = None,
        until: threading.Event | None = None,
        tick: Callable[[], None] | None = None,
        tick_period_s: float = 0.25,
    ) -> None:
        """Block until ``stop`` or ``until`` is set, ``duration_s`` of session-clock time passed, or
        the recording failed; ``tick`` is called every ``tick_period_s`` of real time (dashboard)."""
        end = None if duration_s is None else self.clock.now_ns() + round(duration_s * NS_PER_S)
        while not (stop.is_set() or self.failed.is_set() or (until is not None and until.is_set())):
            if end is not None and self.clock.now_ns() >= end:
                return
            if tick is not None:
                tick()
            stop.wait(tick_period_s)

    def mark(self, note: str, *, host_ns: int | None = None) -> None:
        """An operator mark on ``/rig/events`` at host time ``host_ns`` (the key press; default now)."""
        t = self.clock.now_ns() if host_ns is None else host_ns
        self.recorder.event(EventKind.MARK, note or "mark", source="operator",
                            log_time_ns=self.timebase.host_to_utc(t), note=note, host_ns=t)
        self.board.event(f"mark: {note or '(no note)'}")

    def gga_position(self) -> tuple[float, float, float] | None:
        """Latest position of the main antenna (for an NTRIP network caster's GGA)."""
        pos = self._pos_a
        if pos is None:
            return None
        b = pos[1]
        return b.lat_deg, b.lon_deg, b.hgt_m + b.undulation_m

    # --- called by the devices -----------------------------------------------------------------

    def source(self, name: str, maxsize: int) -> Source:
        """A device's own recorder source."""
        return self.recorder.source(name, maxsize=maxsize)

    def on_lateral_accel(self, t_ns: int, ay_mps2: float) -> None:
        """A valid CAN lateral acceleration: the live LTR."""
        self.ltr.add(t_ns, ay_mps2)

    def on_mark(self, receiver: str, gps_ns: int, *, from_marktime: bool) -> None:
        """A sync-switch event from a receiver (MARKTIME preferred; one receiver feeds the DAQ alignment)."""
        with self._marks_lock:
            if self._sync_receiver is None:
                self._sync_receiver = receiver
            if receiver != self._sync_receiver:
                return
            if from_marktime and not self._marks_from_time.get(receiver):
                self._marks_from_time[receiver] = True
                self._marks.clear()
            if from_marktime == self._marks_from_time.get(receiver, False):
                self._marks.append(gps_ns)

    def on_position(self, receiver: ReceiverConfig, gps_ns: int, pos: BestPos) -> None:
        """A BESTPOS from a receiver: the live baseline and the relay's view of the rovers' differential age."""
        if receiver.antenna == "a":
            self._pos_a = (gps_ns, pos)
        elif receiver.antenna == "b":
            self._pos_b = (gps_ns, pos)
        if self.relay is not None and receiver.role == "rover":
            self.relay.relay.note_rover_diff_age(receiver.name,
                                                 pos.diff_age_s if math.isfinite(pos.diff_age_s) else None)

    # --- internals -----------------------------------------------------------------------------

    def _attachments(self) -> list[Attachment]:
        out: list[Attachment] = []
        names: set[str] = set()
        for cc in self.cfg.can:
            att = Attachment.from_file(cc.dbc)
            if att.name not in names:
                out.append(att)
                names.add(att.name)
            if cc.roles or cc.checks:
                buf = io.BytesIO()
                tomli_w.dump(roles_table(cc), buf)
                out.append(Attachment(f"{cc.name}.roles.toml", "application/toml", buf.getvalue()))
        if self.config_path is not None:
            att = Attachment.from_file(self.config_path)
            # the file as written, but for passwords in endpoint URLs (relay.source)
            text = att.data.decode("utf-8", "replace")
            if mask_credentials(text) != text:
                att = dataclasses.replace(att, data=mask_credentials(text).encode())
            if att.name not in names:
                out.append(att)
        return out

    def _devices(self) -> list[Device]:
        devs: list[Device] = list(self.gnss.values())
        if self.relay is not None:
            devs.append(self.relay)
        devs.extend(self.can)
        if self.daq is not None:
            devs.append(self.daq)
        return devs

    def _build_devices(self) -> None:
        cfg = self.cfg
        for rc in cfg.receivers:
            self.gnss[rc.name] = GnssDevice(self, rc, self.ports.port(rc),
                                            output_latency_ns=self.gnss_output_latency_ns)
        if cfg.relay is not None and cfg.relay.enabled:
            self.relay = RelayDevice(self, cfg.relay, self.gnss, self.ports.correction_port, self.gga_position)
        for cc in cfg.can:
            self.can.append(CanDevice(self, cc, self.can_factory))
        if cfg.daq is not None:
            self.daq = DaqDevice(self, cfg.daq, cfg.profile, self.daq_factory)
        ant = cfg.profile.antennas
        self.board.vehicle(baseline_nominal_m=ant.baseline_length_m, baseline_tolerance_m=ant.baseline_tolerance_m)

    def _start_devices(self) -> None:
        for g in self.gnss.values():
            g.start()
        if self.relay is not None:
            self.relay.start()
        for c in self.can:
            c.start()
        if self.daq is not None:
            self.daq.start()

    def _stop_devices(self, errors: list[str]) -> None:
        if self.relay is not None:
            _step(errors, "relay", self.relay.stop)
        for g in self.gnss.values():
            _step(errors, f"receiver {g.name}", g.stop)
        for c in self.can:
            _step(errors, f"CAN bus {c.cc.name}", c.stop)
        if self.daq is not None:
            _step(errors, f"DAQ {self.daq.dc.device}", self.daq.stop)

    def _final_records(self) -> None:
        if self.relay is not None:
            self.relay.publish_stats()
        self.align_daq()
        self._timebase_records()
        self._timebase_steps()
        late, stalled, clamped, _verdicts = self._timing = self._timing_records()
        rig = self._rig
        assert rig is not None
        stats = self.recorder.stats()
        rig.event(
            EventKind.INFO, f"session {self.name}: devices stopped",
            log_time_ns=self.timebase.host_to_utc(self.clock.now_ns()),
            device_errors={d.name: d.errors for d in self._devices()},
            dropped={s.name: s.dropped for s in stats if s.dropped},
            daq_lost_samples=self.daq.lost if self.daq is not None else 0,
            late_s=late, stalled={k: list(v) for k, v in stalled.items()},
            clamped={k: list(v) for k, v in clamped.items()},
        )

    def _timing_records(self) -> tuple[dict[str, float], dict[str, tuple[int, float]], dict[str, tuple[int, float]],
                                       dict[str, StreamQuality]]:
        """Early ends as gap events, the stalls and clamps so far, and the live verdicts as an event."""
        timings = [t for t in self.recorder.channel_timings() if t.messages]
        periodic = [t for t in timings if t.period_ns is not None and t.last_log_ns is not None]
        late: dict[str, float] = {}
        gaps: list[Gap] = []
        if not periodic:
            return late, {}, {}, {}
        end = max(t.last_log_ns for t in periodic if t.last_log_ns is not None)
        start = min(t.first_log_ns for t in periodic if t.first_log_ns is not None)
        # per source: the early ends and the stalls its device did not report itself, merged into spans
        spans: dict[tuple[str, str], list[tuple[int, int, str]]] = {}
        for t in periodic:
            assert t.last_log_ns is not None
            stream = stream_of_topic(t.topic) or t.source
            if ended_early(t.last_log_ns, t.period_ns, end):
                late[t.topic] = (end - t.last_log_ns) / NS_PER_S
                gaps.append(Gap(stream, t.topic, "ended_early", t.last_log_ns, end))
                spans.setdefault((t.source, "ended_early"), []).append((t.last_log_ns, end, t.topic))
            for a, b in t.stall_spans:
                gaps.append(Gap(stream, t.topic, "stall", a, b))
                if not any(a < gb and b > ga for ga, gb in t.source_gaps):
                    spans.setdefault((t.source, "stall"), []).append((a, b, t.topic))
        for (source, kind), items in spans.items():
            for a, b, topics in _merge_spans(items):
                what = "stalled" if kind == "stall" else "ended before the session"
                self.recorder.event(
                    EventKind.GAP, f"{', '.join(topics)} {what}: no messages for {(b - a) / NS_PER_S:.3f} s",
                    source=source, severity=Severity.WARNING, log_time_ns=a, start_ns=a, end_ns=b,
                    topics=topics, gap=kind,
                )
        stalled = {t.topic: (t.stalls, t.stalled_ns / NS_PER_S) for t in timings if t.stalls}
        clamped = {t.topic: (t.clamped, t.clamp_max_ns / 1e6) for t in timings if t.clamped}
        tb = self.timebase
        ref = tb.reference_receiver
        host_err: dict[str, float] = {}
        if ref is not None:
            e = tb.gnss_clock(ref).map_error_ns()
            if e is not None:
                # plus how early the map puts the DAQ blocks' arrivals before their sync-timed last samples
                causal = None if self.daq is None else live_daq_causality_ns(
                    tb.clock(self.daq.clock_name).floor_pairs(), self.daq.ns_per_sample,
                    [(seg.base, seg.fit) for seg in list(self.daq.segments.values())], tb.gnss_clock(ref))
                host_err[f"gnss:{ref}"] = (e + (causal or 0.0)) / 1e6 + FLOOR_ALLOWANCE_MS
        add = next(iter(host_err.values()), FLOOR_ALLOWANCE_MS)
        timing_err: dict[str, float] = {}
        for c in self.can:
            e = tb.clock(c.clock_name).map_error_ns() if tb.clock(c.clock_name).n else None
            if e is not None:
                timing_err[f"can:{c.cc.name}"] = e / 1e6 + add
        verdicts = live_verdicts(timings, gaps, span_ns=end - start, timing_error_ms=timing_err,
                                 host_map_error_ms=host_err, simulated=self.cfg.simulation is not None)
        self.recorder.event(
            EventKind.TIMEBASE, "time-base verdicts at the end of the recording: " + ", ".join(
                f"{k} {q.verdict.value}" for k, q in verdicts.items()),
            log_time_ns=end, verdicts={k: q.to_json() for k, q in verdicts.items()},
        )
        return late, stalled, clamped, verdicts

    def _timebase_steps(self) -> None:
        """The time base's jumps (first TIME replacing the host estimate …) as ``timebase`` events."""
        steps = self.timebase.steps()
        for st in steps[self._steps_written:]:
            extra: dict[str, Any] = {}
            if st.slew_ns:  # no jump: the live map runs slow for a while (rig.core.timebase.Timebase)
                what, severity = f"slew {st.step_ns / 1e6:+.3f} ms over {st.slew_ns / 1e6:.3f} ms", Severity.INFO
                extra["slew_ns"] = st.slew_ns
            else:
                what = f"step {st.step_ns / 1e6:+.3f} ms"
                severity = Severity.INFO if abs(st.step_ns) < 1_000_000 else Severity.WARNING
            self.recorder.event(
                EventKind.TIMEBASE, f"time base {what}: {st.reason}", severity=severity,
                log_time_ns=st.at_ns, step_ns=st.step_ns, host_ns=st.host_ns, reason=st.reason, **extra,
            )
        self._steps_written = len(steps)

    def _stall_alarms(self) -> None:
        """A device whose channel is silent past its stall threshold is DEGRADED while it lasts (alarm)."""
        now_log = self.timebase.host_to_utc(self.clock.now_ns())
        devices = {d.name for d in self._devices()}
        now: dict[str, str] = {}
        for t in self.recorder.channel_timings():
            late = t.late_ns(now_log)
            if late is not None and t.source in devices and t.source not in now:
                now[t.source] = f"STALLED: no {t.topic} for {late / NS_PER_S:.1f} s"
        for dev, text in now.items():
            if dev not in self._stalled_now:
                self.board.update(dev, state=DeviceState.DEGRADED)
                self.board.event(f"{dev}: {text}")
        for dev in self._stalled_now:
            if dev not in now:
                self.board.update(dev, state=DeviceState.OK)
        self._stalled_now = now

    @property
    def alarms(self) -> dict[str, str]:
        """Devices stalled right now → alarm text."""
        return dict(self._stalled_now)

    def align_daq(self) -> None:
        """Align the DAQ to the sync-switch marks gathered so far."""
        if self.daq is not None:
            with self._marks_lock:
                marks = sorted(self._marks)
            self.daq.align(marks)

    def _timebase_records(self) -> None:
        rig = self._rig
        assert rig is not None
        now = self.clock.now_ns()
        t = self.timebase.host_to_utc(now)
        for rec in self.timebase.quality_json():
            # the offset (e.g. GPS − Unix epochs, ~3.2e17 ns) as foxglove.Duration: exact in JavaScript readers
            rec["offset"] = T.TIMEBASE_OFFSET.to_json(rec.pop(T.TIMEBASE_OFFSET.column, None))
            rig.put(T.TOPIC_TIMEBASE, t, now, rec)

    def _housekeeping(self) -> None:
        now = self.clock.now_ns()
        next_stats = now + self.stats_period_ns
        next_tb = now + self.timebase_period_ns
        next_latency = now + NS_PER_S
        next_board = 0.0
        while not self._hk_stop.wait(0.1):
            try:
                now = self.clock.now_ns()
                for c in self.can:
                    c.flush(older_than_ns=now - 2 * CAN_BLOCK_AGE_NS)
                    c.retry()
                if now >= next_stats:
                    next_stats = now + self.stats_period_ns
                    if self.relay is not None:
                        self.relay.publish_stats()
                if now >= next_tb:
                    next_tb = now + self.timebase_period_ns
                    self.align_daq()
                    self._timebase_records()
                if now >= next_latency:
                    next_latency = now + NS_PER_S
                    self._measure_output_latency()
                self._timebase_steps()
                mono = time.monotonic()
                if mono >= next_board:
                    next_board = mono + 0.5
                    self._refresh_board()
                    self._stall_alarms()
                if self.recorder.failed.is_set() and not self.failed.is_set():
                    log.error("session %s: recording failed: %s", self.name, self.recorder.error)
                    self.failed.set()
            except Exception:  # housekeeping must go on; the cause is in the log
                log.exception("session %s: housekeeping failed", self.name)

    def _measure_output_latency(self) -> None:
        """The reference receiver's output latency from the DAQ's causality (:func:`live_daq_causality_ns`): a
        block cannot reach the host before its last sample (on GPS time through the sync pulse), so where the
        host map puts it earlier, the receiver's logs left it later than the map assumed. The excess is taken
        off the reference clock's pairs, those seen included (a TIMEBASE event: log_time of host-timed data
        before it was early by up to that much)."""
        ref = self.timebase.reference_receiver
        if not self._measure_latency or self.daq is None or ref is None or ref not in self.gnss:
            return
        if self.gnss[ref].rc.output_latency_s is not None:
            return  # configured: taken as given
        segments = [(seg.base, seg.fit) for seg in list(self.daq.segments.values())]
        if not any(fit is not None for _b, fit in segments):
            return
        clock = self.timebase.gnss_clock(ref)
        if clock.n == 0:
            return
        excess = live_daq_causality_ns(self.timebase.clock(self.daq.clock_name).floor_pairs(),
                                       self.daq.ns_per_sample, segments, clock)
        if excess is None or excess < LATENCY_STEP_NS:
            return
        step = round(excess)
        clock.add_min_latency(step)
        self.measured_latency_ns += step
        now = self.clock.now_ns()
        self.recorder.event(
            EventKind.TIMEBASE,
            f"{ref}: output latency measured from the DAQ sync pulse: {self.measured_latency_ns / 1e6:.2f} ms "
            f"(+{step / 1e6:.2f} ms; host-timed log_time before this was early by up to that)",
            log_time_ns=self.timebase.host_to_utc(now), receiver=ref, output_latency_ns=self.measured_latency_ns,
            step_ns=step, method="daq_causality")

    def _refresh_board(self) -> None:
        rec = self.recorder
        stats = rec.stats()
        size = 0
        for p in rec.parts:
            with contextlib.suppress(OSError):
                size += p.stat().st_size
        try:
            free = float(shutil.disk_usage(self.out_dir).free)
        except OSError:
            free = math.nan
        self.board.recorder(
            file=rec.parts[-1].name if rec.parts else "-",
            bytes_written=size, messages_written=sum(s.written for s in stats), dropped=sum(s.dropped for s in stats),
        )
        self.board.free_disk(free / 1e6)
        for g in self.gnss.values():
            g.refresh()
        if self.daq is not None:
            self.daq.refresh()
        self._refresh_vehicle()

    def _refresh_vehicle(self) -> None:
        """The live figures of the car: speed, baseline A–B against the configured one, sideslip, corrections."""
        figures: dict[str, float] = {}
        if self.relay is not None:
            st = self.relay.relay.stats()
            figures["relay_bytes_per_s"] = st.bytes_per_s
            if st.last_correction_age_s is not None:
                figures["correction_age_s"] = st.last_correction_age_s
        ga = self.gnss.get(next((r.name for r in self.cfg.receivers if r.antenna == "a"), ""))
        vel = ga.last_vel[1] if ga is not None and ga.last_vel is not None else None
        if vel is not None:
            figures["speed_kmh"] = vel.hor_spd_mps * 3.6
        a, b = self._pos_a, self._pos_b
        if a is not None and b is not None and a[0] == b[0]:
            pa, pb = a[1], b[1]
            e, n, u = pymap3d.geodetic2enu(pa.lat_deg, pa.lon_deg, pa.hgt_m, pb.lat_deg, pb.lon_deg, pb.hgt_m)
            figures["baseline_m"] = math.sqrt(e * e + n * n + u * u)
            if vel is not None and vel.hor_spd_mps > 2.0:
                # heading of the baseline B → A, less the mounting offset in force, minus the course
                heading = math.atan2(e, n) - math.radians(self.cfg.profile.calibration.mount_offset_deg)
                beta = float(sideslip_from_azimuths(heading, math.radians(vel.trk_gnd_deg)))
                figures["beta_deg"] = math.degrees(beta)
            else:
                figures["beta_deg"] = math.nan
        figures.update(self.ltr.figures())
        if figures:
            self.board.vehicle(**figures)

def _merge_spans(items: Sequence[tuple[int, int, str]]) -> list[tuple[int, int, list[str]]]:
    """Overlapping (start, end, topic) spans of one source merged, with their topics."""
    out: list[tuple[int, int, list[str]]] = []
    for a, b, topic in sorted(items):
        if out and a <= out[-1][1]:
            pa, pb, topics = out[-1]
            out[-1] = (pa, max(pb, b), topics if topic in topics else [*topics, topic])
        else:
            out.append((a, b, [topic]))
    return out


def _step(errors: list[str], what: str, fn: Callable[[], object]) -> None:
    """Run one stop step; a failure is noted and the next steps still run."""
    try:
        fn()
    except Exception as exc:
        log.exception("stopping %s failed", what)
        errors.append(f"{what}: {exc}")


def summary_lines(summary: RecordingSummary) -> list[str]:
    """Human-readable lines about a finished session (for the CLI)."""
    rec = summary.recording
    head = (f"session {summary.name}: {rec.messages} messages in {len(rec.parts)} part(s), "
            f"{'finalized' if rec.finalized else 'NOT finalized'}, dropped {rec.dropped}, "
            f"late {len(summary.late)}, stalled {len(summary.stalled)}, clamped {len(summary.clamped)}")
    lines = [head]
    if summary.late:
        lines.append("  late (ended before the session): "
                     + ", ".join(f"{k} {v:.1f} s early" for k, v in sorted(summary.late.items())))
    if summary.stalled:
        lines.append("  stalled: "
                     + ", ".join(f"{k} {n}× ({s:.1f} s)" for k, (n, s) in sorted(summary.stalled.items())))
    if summary.clamped:
        lines.append("  log_time clamped (ran back): "
                     + ", ".join(f"{k} {n} (max {ms:.1f} ms)" for k, (n, ms) in sorted(summary.clamped.items())))
    bad_q = [q for q in summary.verdicts.values() if q.verdict.value != "good"]
    lines += [f"  time base {q.message()}" for q in bad_q]
    lines += [f"  {p}" for p in rec.parts]
    if rec.error is not None:
        lines.append(f"  recording error: {rec.error}")
    lines += [f"  {e}" for e in summary.errors]
    bad = {k: v for k, v in summary.device_errors.items() if v}
    if bad:
        lines.append("  device errors: " + ", ".join(f"{k} {v}" for k, v in bad.items()))
    return lines

