"""The live feed: recorded messages in (from the recorder's writer thread), phone-sized channels out.

:meth:`LiveFeed.offer` is the recorder's tap: an append to a bounded deque (the oldest message
goes when it is full, and is counted), nothing else. The feed's own thread drains the deque,
decimates, derives the live-only channels and publishes through a :class:`LiveSink`.

Live-only channels (not recorded topics; :data:`LIVE_TOPICS`):

- ``/live/sideslip``: β reference at antenna A from the latest A/B RTK position pair and A's
  course (heading of the baseline B → A less the mounting offset in force, minus the course), its
  ± band and the VSC's own estimate (CAN role ``vsc_beta_estimate``);
- ``/live/ltr``: the live load-transfer ratio, its prediction and the warning state (the session's
  :class:`~rig.analysis.live_ltr.LiveLtr`, as on the dashboard);
- ``/live/status``: the status page's document (fix type per rover, correction age, baseline, β,
  LTR, recording time, free disk);
- ``/live/log``: ``/rig/events`` as ``foxglove.Log`` for Foxglove's Log panel.

Times in the live channels are ``foxglove.Time`` objects (``stamp``: ``{sec, nsec}``), not integer
nanoseconds, which JavaScript readers round to a multiple of up to 128 ns.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import pymap3d

import rig.core.topics as T  # noqa: N812 - topics used as a namespace
from drivers.relay.endpoints import Secret
from rig.core.topics import foxglove_time
from rig.record.status import DeviceState, RecordingStatus
from vsccore.angles import sideslip_from_azimuths
from vsccore.errors import ConfigError

__all__ = [
    "LIVE_TOPICS",
    "TOKEN_ENV",
    "TOPIC_LIVE_LOG",
    "TOPIC_LIVE_LTR",
    "TOPIC_LIVE_SIDESLIP",
    "TOPIC_LIVE_STATUS",
    "LiveFeed",
    "LiveOptions",
    "LiveSink",
    "LiveStats",
    "foxglove_time",
    "is_loopback",
]

log = logging.getLogger(__name__)

TOKEN_ENV = "RIG_LIVE_TOKEN"
"""Environment variable holding the live view's token (``--live-token`` wins)."""
MIN_TOKEN_CHARS = 12

TOPIC_LIVE_SIDESLIP = "/live/sideslip"
TOPIC_LIVE_LTR = "/live/ltr"
TOPIC_LIVE_STATUS = "/live/status"
TOPIC_LIVE_LOG = "/live/log"

COURSE_SPEED_STD_MPS = 0.03
"""1-σ horizontal velocity error of an RTK receiver (NovAtel OEM7 spec, 0.03 m/s RMS): the course's
share of the live β band (BESTVEL carries no standard deviation)."""
MIN_SPEED_MPS = 2.0
"""Below this the course over ground is noise: no live β reference (as on the dashboard)."""


_TIME_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "description": "foxglove.Time on the common time base (UTC)",
    "properties": {"sec": {"type": "integer", "minimum": 0},
                   "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
    "required": ["sec", "nsec"],
}


def _num(desc: str) -> dict[str, Any]:
    return {"type": "number", "description": desc}


def _live_schema(name: str, desc: str, props: Mapping[str, Any], required: tuple[str, ...]) -> T.SchemaSpec:
    return T.SchemaSpec(name, T.JSON_ENCODING, T.JSON_SCHEMA_ENCODING, {
        "title": name, "description": desc, "type": "object",
        "properties": {"stamp": _TIME_SCHEMA, **props}, "required": ["stamp", *required],
    })


SCHEMA_LIVE_SIDESLIP = _live_schema(
    "vsc_rig.live.Sideslip",
    "Live β reference at antenna A (± band, 2σ) against the VSC's estimate; fields absent while unknown",
    {
        "beta_ref_deg": _num("β reference: heading of the baseline B→A less the mount offset, minus the course (deg)"),
        "band_deg": _num("± band of the reference (2σ from the position and velocity errors, deg)"),
        "beta_ref_low_deg": _num("β reference − band (deg)"),
        "beta_ref_high_deg": _num("β reference + band (deg)"),
        "beta_vsc_deg": _num("The VSC's sideslip estimate (CAN role vsc_beta_estimate, deg)"),
        "speed_kmh": _num("Horizontal speed of antenna A (km/h)"),
    },
    (),
)
SCHEMA_LIVE_LTR = _live_schema(
    "vsc_rig.live.Ltr",
    "Live load-transfer ratio from the CAN lateral acceleration and the roll model, and its prediction",
    {
        "ltr": _num("Load-transfer ratio (−1 … 1)"),
        "ltr_predicted": _num("Largest predicted |LTR| over the horizon, signed"),
        "warning": {"type": "boolean", "description": "Rollover warning"},
        "warning_level": {"type": "integer", "description": "1 while the warning is on, else 0 (for plots)"},
    },
    ("warning", "warning_level"),
)
SCHEMA_LIVE_STATUS = _live_schema(
    "vsc_rig.live.Status",
    "The status page's document: fix type per rover, corrections, baseline, β, LTR, recording and disk",
    {
        "session": {"type": "string"},
        "recording_s": _num("Time since the session started (s)"),
        "free_disk_mb": _num("Free space on the output disk (MB)"),
        "file": {"type": "string"},
        "megabytes": _num("Bytes written (MB)"),
        "dropped": {"type": "integer", "description": "Messages the recorder dropped"},
        "rovers": {"type": "array", "items": {"type": "object"}, "description": "name, antenna, fix_type, diff_age_s"},
        "correction_age_s": _num("Age of the last relayed correction (s)"),
        "baseline_m": _num("Measured antenna A–B distance (m)"),
        "baseline_nominal_m": _num("Configured A–B distance (m)"),
        "baseline_ok": {"type": "boolean"},
        "beta_ref_deg": _num("β reference (deg)"),
        "beta_vsc_deg": _num("VSC estimate (deg)"),
        "speed_kmh": _num("Speed (km/h)"),
        "ltr": _num("LTR"),
        "ltr_predicted": _num("Predicted LTR"),
        "ltr_warning": {"type": "boolean"},
        "alarms": {"type": "array", "items": {"type": "string"}},
        "live_dropped": {"type": "integer", "description": "Messages the live view dropped (never recorded ones)"},
    },
    ("session", "recording_s", "rovers", "ltr_warning", "alarms"),
)

LIVE_TOPICS: Mapping[str, T.SchemaSpec | None] = {
    TOPIC_LIVE_SIDESLIP: SCHEMA_LIVE_SIDESLIP,
    TOPIC_LIVE_LTR: SCHEMA_LIVE_LTR,
    TOPIC_LIVE_STATUS: SCHEMA_LIVE_STATUS,
    TOPIC_LIVE_LOG: None,  # foxglove.Log (the SDK's typed schema)
}
"""Channels that exist only live (not in the session file) → their JSON schema (None: a Foxglove type)."""


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True, slots=True)
class LiveOptions:
    """How the live view is served (``--live``, ``--live-bind``, ``--live-token``, ``--live-status-port``,
    ``--live-full-rate``)."""

    port: int = 8765
    """Foxglove WebSocket port (0: any free port)."""
    bind: str = "127.0.0.1"
    token: Secret | None = None
    """Needed on a non-loopback bind; with a token, the WebSocket and the status page both check it."""
    status_port: int | None = None
    """Status page port (default: ``port + 1``; 0: any free port)."""
    max_rate_hz: float = 50.0
    """Largest rate of one plot channel (per CAN message on the roles topics)."""
    full_rate: bool = False
    """Serve every message (no decimation)."""
    queue_size: int = 20_000
    status_period_s: float = 0.5

    def __post_init__(self) -> None:
        for key, port in (("--live", self.port), ("--live-status-port", self.status_port)):
            if port is not None and not 0 <= port <= 65535:
                raise ConfigError(f"{key} {port}: a TCP port is 0 … 65535")
        if not (self.max_rate_hz > 0 and math.isfinite(self.max_rate_hz)):
            raise ConfigError(f"--live-max-rate {self.max_rate_hz}: must be a positive number of Hz")
        if self.queue_size < 1:
            raise ConfigError(f"live queue size {self.queue_size}: must be >= 1")
        if isinstance(self.token, str):  # a plain string from a caller: held as a Secret all the same
            object.__setattr__(self, "token", Secret(self.token))
        if self.token is not None and not self.token:
            object.__setattr__(self, "token", None)
        if not is_loopback(self.bind):
            if not self.token:
                raise ConfigError(
                    f"--live-bind {self.bind}: not a loopback address, so the live view needs a token: "
                    f"give --live-token TOKEN or set {TOKEN_ENV}"
                )
            if len(self.token.reveal()) < MIN_TOKEN_CHARS:
                raise ConfigError(
                    f"--live-token: at least {MIN_TOKEN_CHARS} characters, got {len(self.token.reveal())}")

    @classmethod
    def from_cli(cls, port: int, bind: str, token: str | None, **kw: Any) -> LiveOptions:
        """Options of the command line; the token falls back to :data:`TOKEN_ENV`."""
        given = token or os.environ.get(TOKEN_ENV) or None
        return cls(port=port, bind=bind, token=Secret(given) if given else None, **kw)

    @property
    def page_port(self) -> int:
        if self.status_port is not None:
            return self.status_port
        return 0 if self.port == 0 else self.port + 1


class LiveSink(Protocol):
    """Where the live channels go (the Foxglove server; a list in tests)."""

    def publish(self, topic: str, schema: T.SchemaSpec, data: bytes, log_time_ns: int) -> None:
        """One JSON message on ``topic`` (channel created on first use with ``schema``)."""
        ...

    def log(self, log_time_ns: int, severity: str, text: str, source: str) -> None:
        """One ``foxglove.Log`` entry on :data:`TOPIC_LIVE_LOG`."""
        ...


@dataclass(slots=True)
class LiveStats:
    """What the live feed did (for the status page and the benchmark)."""

    offered: int = 0
    dropped: int = 0
    """Messages the live queue dropped (oldest first) because the feed thread fell behind."""
    published: int = 0
    decimated: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)


_NOT_DECIMATED = frozenset({T.TOPIC_EVENTS, T.TOPIC_TIMEBASE, T.TOPIC_RELAY_STATS})
_VSC_ROLES = ("vsc_beta_estimate",)


class LiveFeed:
    """The live view's queue and thread (see the module docstring).

    Args:
        sink: where the channels go.
        options: rates and queue size.
        antenna_a, antenna_b: receivers of the main and auxiliary antennas (β reference and baseline).
        rovers: rover receiver → antenna letter (fix type per rover).
        mount_offset_deg: mounting offset of the baseline in force (removed from the heading).
        baseline_nominal_m: configured A–B distance.
        status: a snapshot of the session's :class:`~rig.record.status.StatusBoard` (recording, disk, LTR).
        now_ns: the session clock.
    """

    def __init__(
        self,
        sink: LiveSink,
        options: LiveOptions,
        *,
        antenna_a: str | None,
        antenna_b: str | None,
        rovers: Mapping[str, str],
        mount_offset_deg: float = 0.0,
        baseline_nominal_m: float = math.nan,
        status: Callable[[], RecordingStatus] | None = None,
        now_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        self.sink = sink
        self.options = options
        self._a, self._b = antenna_a, antenna_b
        self._rovers = dict(rovers)
        self._mount_rad = math.radians(mount_offset_deg)
        self._baseline_nominal = baseline_nominal_m
        self._status_fn = status
        self._now_ns = now_ns
        self._q: deque[tuple[str, int, int, bytes]] = deque(maxlen=options.queue_size)
        self._min_dt_ns = 0 if options.full_rate else round(1e9 / options.max_rate_hz)
        self._last_sent: dict[tuple[str, int], int] = {}
        self._kinds: dict[str, str | None] = {}
        self.stats = LiveStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._doc: dict[str, Any] = {}
        # live state (feed thread only)
        self._pos: dict[str, dict[str, Any]] = {}
        self._vel_a: dict[str, Any] | None = None
        self._beta_ref: tuple[float, float] | None = None
        """(β reference, band) in rad, of the latest A/B pair."""
        self._baseline_m = math.nan
        self._beta_vsc: float | None = None
        self._last_stamp = 0

    # --- the recorder's side -------------------------------------------------------------------

    def offer(self, topic: str, log_time_ns: int, publish_time_ns: int, data: bytes) -> None:
        """The recorder's tap (writer thread): queue one written message; never blocks, never raises."""
        q = self._q
        if len(q) == q.maxlen:
            self.stats.dropped += 1
        q.append((topic, log_time_ns, publish_time_ns, data))
        self.stats.offered += 1

    # --- lifecycle -----------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("live feed already started")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="rig-live-feed")
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread (what is queued is published first) and join it."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("live feed thread did not stop within %.1f s", timeout_s)
            self._thread = None

    def status_document(self) -> dict[str, Any]:
        """The latest status document (what ``/live/status`` and the status page show)."""
        with self._lock:
            return dict(self._doc)

    # --- the feed thread -----------------------------------------------------------------------

    def _run(self) -> None:
        next_status = 0.0
        period = self.options.status_period_s
        while True:
            stopping = self._stop.wait(0.02)
            try:
                self.drain()
                mono = time.monotonic()
                if mono >= next_status or stopping:
                    next_status = mono + period
                    self.publish_status()
            except Exception:  # the live view must go on; the recording does not depend on it
                log.exception("live feed failed on a message")
            if stopping:
                return

    def drain(self) -> int:
        """Publish everything queued (feed thread; tests call it directly). Returns the messages handled."""
        q = self._q
        n = 0
        while True:
            try:
                topic, log_ns, _pub_ns, data = q.popleft()
            except IndexError:
                return n
            n += 1
            self._handle(topic, log_ns, data)

    def _kind(self, topic: str) -> str | None:
        k = self._kinds.get(topic, "?")
        if k != "?":
            return k
        try:
            spec, _params = T.spec_for_topic(topic)
        except ValueError:
            kind = None
        else:
            if not spec.schema.is_json:
                kind = None  # raw bytes, CAN and DAQ blocks, truth: not for a phone
            else:
                leaf = topic.rsplit("/", 1)[-1]
                kind = leaf if topic.startswith("/gnss/") or leaf == "roles" else "json"
                if topic == T.TOPIC_EVENTS:
                    kind = "events"
        self._kinds[topic] = kind
        return kind

    def _handle(self, topic: str, log_ns: int, data: bytes) -> None:
        kind = self._kind(topic)
        if kind is None:
            return
        self._last_stamp = max(self._last_stamp, log_ns)
        key = 0
        if kind == "roles":
            msg = json.loads(data)
            key = int(msg.get("can_id", 0))
            roles = msg.get("roles") or {}
            for r in _VSC_ROLES:
                v = roles.get(r)
                if isinstance(v, int | float):
                    self._beta_vsc = float(v)
                    self._publish_sideslip(log_ns)
        elif kind in ("bestpos", "bestvel"):
            rx = topic.split("/")[2]
            msg = json.loads(data)
            if kind == "bestpos":
                self._pos[rx] = msg
                if rx in (self._a, self._b):
                    self._pair(log_ns)
            elif rx == self._a:
                self._vel_a = msg
        elif kind == "events":
            ev = json.loads(data)
            self.sink.log(log_ns, str(ev.get("severity", "info")), str(ev.get("text", "")), str(ev.get("source", "")))
        if topic not in _NOT_DECIMATED and self._min_dt_ns:
            last = self._last_sent.get((topic, key))
            if last is not None and 0 <= log_ns - last < self._min_dt_ns:
                self.stats.decimated += 1
                return
            self._last_sent[(topic, key)] = log_ns
        spec, _params = T.spec_for_topic(topic)
        self._send(topic, spec.schema, data, log_ns)

    def _send(self, topic: str, schema: T.SchemaSpec, data: bytes, log_ns: int) -> None:
        self.sink.publish(topic, schema, data, log_ns)
        self.stats.published += 1
        self.stats.per_topic[topic] = self.stats.per_topic.get(topic, 0) + 1

    def _pair(self, log_ns: int) -> None:
        """A new position of A or B: the baseline and, with A's course, the β reference of the pair."""
        a, b = self._pos.get(self._a or ""), self._pos.get(self._b or "")
        if a is None or b is None or a.get(T.GPS_TIME.key) is None or a[T.GPS_TIME.key] != b.get(T.GPS_TIME.key):
            return  # not the same epoch ({week, tow_ns}) of both
        try:
            e, n, u = pymap3d.geodetic2enu(a["lat_deg"], a["lon_deg"], a["height_msl_m"],
                                           b["lat_deg"], b["lon_deg"], b["height_msl_m"])
        except (KeyError, TypeError):
            return
        length = math.sqrt(e * e + n * n + u * u)
        self._baseline_m = length
        vel = self._vel_a
        speed = vel.get("hor_speed_mps") if vel is not None else None
        track = vel.get("track_over_ground_deg") if vel is not None else None
        if not isinstance(speed, int | float) or not isinstance(track, int | float) or speed <= MIN_SPEED_MPS:
            self._beta_ref = None
        else:
            heading = math.atan2(e, n) - self._mount_rad
            beta = float(sideslip_from_azimuths(heading, math.radians(track)))
            # position errors across the baseline turn the heading; velocity errors turn the course
            sig_pos = [math.hypot(p.get("lat_std_m") or 0.0, p.get("lon_std_m") or 0.0) / math.sqrt(2) for p in (a, b)]
            sig_heading = math.hypot(*sig_pos) / max(math.hypot(e, n), 1e-3)
            sig_course = COURSE_SPEED_STD_MPS / speed
            self._beta_ref = (beta, 2.0 * math.hypot(sig_heading, sig_course))
        self._publish_sideslip(log_ns)

    def _publish_sideslip(self, log_ns: int) -> None:
        key = (TOPIC_LIVE_SIDESLIP, 0)
        last = self._last_sent.get(key)
        if self._min_dt_ns and last is not None and 0 <= log_ns - last < self._min_dt_ns:
            self.stats.decimated += 1
            return
        self._last_sent[key] = log_ns
        msg: dict[str, Any] = {"stamp": foxglove_time(log_ns)}
        if self._beta_ref is not None:
            beta, band = (math.degrees(x) for x in self._beta_ref)
            msg |= {"beta_ref_deg": beta, "band_deg": band, "beta_ref_low_deg": beta - band,
                    "beta_ref_high_deg": beta + band}
        if self._beta_vsc is not None:
            msg["beta_vsc_deg"] = math.degrees(self._beta_vsc)
        speed = self._vel_a.get("hor_speed_mps") if self._vel_a is not None else None
        if isinstance(speed, int | float):
            msg["speed_kmh"] = speed * 3.6
        self._send(TOPIC_LIVE_SIDESLIP, SCHEMA_LIVE_SIDESLIP, T.encode_record(msg), log_ns)

    def publish_status(self) -> None:
        """Build the status document from the live state and the session's board; publish /live/status
        and /live/ltr."""
        snap = self._status_fn() if self._status_fn is not None else None
        stamp = self._last_stamp or self._now_ns()
        rovers = []
        for name, antenna in self._rovers.items():
            p = self._pos.get(name) or {}
            rovers.append({"name": name, "antenna": antenna, "fix_type": p.get("pos_type", "NONE"),
                           "sol_status": p.get("sol_status", "-"), "diff_age_s": p.get("diff_age_s"),
                           "satellites": p.get("num_sol_svs")})
        doc: dict[str, Any] = {"stamp": foxglove_time(stamp), "rovers": rovers,
                               "baseline_m": self._baseline_m, "baseline_nominal_m": self._baseline_nominal,
                               "live_dropped": self.stats.dropped}
        if self._beta_ref is not None:
            doc["beta_ref_deg"] = math.degrees(self._beta_ref[0])
        if self._beta_vsc is not None:
            doc["beta_vsc_deg"] = math.degrees(self._beta_vsc)
        ltr: dict[str, Any] = {"warning": False}
        if snap is not None:
            v = snap.vehicle
            doc |= {
                "session": snap.name, "recording_s": snap.elapsed_s, "free_disk_mb": snap.free_disk_mb,
                "file": snap.file, "megabytes": snap.bytes_written / 1e6, "dropped": snap.dropped,
                "correction_age_s": v.correction_age_s, "speed_kmh": v.speed_kmh,
                "ltr": v.ltr, "ltr_predicted": v.ltr_predicted, "ltr_warning": bool(v.ltr_warning),
                "baseline_tolerance_m": v.baseline_tolerance_m,
                "alarms": [f"{d.name} {d.state.value}" + (f": {d.detail}" if d.detail else "")
                           for d in snap.devices if d.state in (DeviceState.DEGRADED, DeviceState.LOST)],
            }
            if not math.isfinite(self._baseline_m):
                doc["baseline_m"] = v.baseline_m
            ltr = {"ltr": v.ltr, "ltr_predicted": v.ltr_predicted, "warning": bool(v.ltr_warning)}
        else:
            doc |= {"session": "", "recording_s": 0.0, "ltr_warning": False, "alarms": []}
        b, nom = doc["baseline_m"], doc["baseline_nominal_m"]
        tol = doc.get("baseline_tolerance_m", 0.03)
        doc["baseline_ok"] = bool(math.isfinite(b) and math.isfinite(nom) and abs(b - nom) <= tol)
        with self._lock:
            self._doc = doc
        self._send(TOPIC_LIVE_STATUS, SCHEMA_LIVE_STATUS, T.encode_record(doc), stamp)
        ltr_msg = {"stamp": foxglove_time(stamp), **ltr, "warning_level": int(ltr["warning"])}
        self._send(TOPIC_LIVE_LTR, SCHEMA_LIVE_LTR, T.encode_record(ltr_msg), stamp)
