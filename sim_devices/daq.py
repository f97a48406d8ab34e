"""Simulated DAQ: a full :class:`~drivers.daq.base.DaqBackend` whose inputs are wired to a simulated world.

Each physical input channel (``sim/ai0`` …) is wired to a *source*: an output of a simulated
Correvit (:class:`OpticalOutput`), the sync switch (:class:`SyncPulseOutput`), a brake-pressure
transducer (:class:`BrakePressureOutput`), any function of the ground truth
(:class:`FunctionOutput`), a fixed voltage (:class:`ConstantInput`) or nothing
(:class:`FloatingInput`, also what an unwired input reads). The signal chain, in order:

1. Optical sensor (per sensor, on its internal update grid ``u / internal_rate_hz`` of truth
   time): true velocity of the mount point (wheel axes for a wheel sensor) from the
   :class:`~sim_devices.vehicle.truth.GroundTruth`, delayed by ``delay_s``, rotated by the head's
   physical misalignment ``zero_offset_rad`` (the simulation's truth, separate from the
   calibration value in force in the driver's spec), first-order lag ``lag_s``, white velocity
   noise, angle = atan2 (+ optional angle noise), angle forced to 0 V and status to "invalid"
   below the minimum speed; each output is held until the next update (zero-order hold), signs
   flipped for roles the spec marks ``invert``, and turned into volts with the inverse of the
   spec's scaling.
2. DAQ input: white noise ``adc_noise_v`` (plus the source's own ``noise_v``), then an ideal
   ``adc_bits`` converter over the channel's configured range: step ``(max_v − min_v) / 2**bits``
   (20 V / 65536 for ±10 V), saturating at the range ends.

Time. Sample ``k`` is taken at truth time ``t_k = t_start + clock_offset_s + k / (rate · (1 +
clock_ppm·1e−6))``: the DAQ's sample clock runs ``clock_ppm`` fast and its first sample is
``clock_offset_s`` late against true time, so a time-base estimator has a drift and an offset
to find (through the sync-pulse edges, which sit at their true times). Live, ``t_start`` is the
truth time when :meth:`SimDaqBackend.start` is called (the injected clock's ``now_ns`` minus
``truth_start_ns``), and sample ``k`` becomes available when the clock reaches ``t_k``;
:meth:`SimDaqBackend.read` waits on the clock for it or times out. Offline,
:meth:`SimDaqBackend.generate` renders ``[t0, t1)`` with ``t_start = t0`` without waiting.

Buffer. The acquisition buffer holds ``buffer_size`` samples per channel. Samples are rendered
only when read (the world is deterministic, so this is the same as rendering them when acquired),
but if more than ``buffer_size`` samples are unread when a read begins, the oldest are lost
exactly as in a ring buffer: the next block starts at ``acquired − buffer_size`` and names the
lost index range. Random streams advance over lost samples, so every sample that is delivered
equals the one :meth:`generate` gives for the same index.

GPS time. ``truth_epoch_gps_ns`` is the GPS time (ns since the GPS epoch) of truth ``t = 0``,
the same epoch the simulated receivers use (pass their ``SimTimeBase`` as ``timebase=``).
:meth:`SimDaqBackend.sample_gps_ns` gives the true GPS time of any sample, so a time-base
estimator can be scored. The sync switch shared with the
simulated receivers is the GNSS simulator's ``SyncSchedule`` of pulse GPS times (or any list of
them): :meth:`SyncPulseOutput.from_gps` puts its rising edges at those instants.

Disconnection. A shared :class:`SimDaqLink` (pass the same one to every backend a session's
factory makes) can be unplugged and replugged: reads and starts then fail with DeviceError.

CAN output. A Correvit with a CAN interface is simulated by :func:`correvit_can_frames`: the same
sensor model (noise, lag, hold, zero offset) sampled at the CAN cycle, encoded with cantools
through the CAN role map into the messages of ``sim_devices/data/correvit.dbc``.
"""

from __future__ import annotations

import importlib.resources
import logging
import math
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from cantools.database.can import Database
from scipy.signal import lfilter

from drivers.analog import AnalogChannelSpec, Scaling
from drivers.can.roles import RoleMap, encode_role_frame
from drivers.daq.base import DaqBackend, DaqChannelConfig, LostSamples
from drivers.optical import WHEEL_IDS, OpticalRole, OpticalSensorSpec, SensorKind
from sim_devices.vehicle.truth import GroundTruth
from vsccore.angles import sideslip_from_velocity, transfer_velocity
from vsccore.clock import UNBOUNDED_NS, Clock, Participant, participant
from vsccore.errors import ConfigError, DeviceError, DeviceTimeoutError, SimulationError

if TYPE_CHECKING:  # the GNSS simulator's time base; duck-typed at run time (see SyncPulseOutput.from_gps)
    from sim_devices.gnss.timebase import SimTimeBase, SyncSchedule

FloatArray = npt.NDArray[np.float64]

log = logging.getLogger(__name__)

_STEERED_WHEELS = frozenset(WHEEL_IDS[:2])
"""Front wheels steer with the road-wheel angle of the ground truth."""


# --- sources -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SimOpticalSensor:
    """A simulated Correvit (S350/SFII) configured by the driver-side spec it is read with.

    ``spec`` gives the mount, the channel roles, the output scaling (the sim applies its inverse),
    the ``invert`` flags (the sensor's own sign convention) and the minimum speed.
    """

    spec: OpticalSensorSpec
    internal_rate_hz: float = 250.0
    lag_s: float = 0.0
    delay_s: float = 0.0
    velocity_noise_mps: float = 0.02
    angle_noise_rad: float = 0.0
    zero_offset_rad: float = 0.0
    status_valid_v: float = 5.0
    status_invalid_v: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("internal_rate_hz",):
            if not getattr(self, name) > 0:
                raise SimulationError(f"sim optical sensor {self.spec.name!r}: {name} must be > 0")
        for name in ("lag_s", "delay_s", "velocity_noise_mps", "angle_noise_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise SimulationError(f"sim optical sensor {self.spec.name!r}: {name} must be >= 0, got {v}")


@dataclass(frozen=True, slots=True)
class OpticalOutput:
    """One analog output (role) of a simulated optical sensor."""

    sensor: SimOpticalSensor
    role: OpticalRole
    noise_v: float = 0.0


@dataclass(frozen=True, slots=True)
class SyncPulseOutput:
    """The sync switch: pulses whose rising edges cross mid-level at ``edge_times_s`` (truth time).

    Each transition is a raised-cosine ramp lasting ``rise_time_s`` centred on its nominal time
    (cable capacitance and the input filter round a real edge); pulses last ``width_s``.
    """

    edge_times_s: tuple[float, ...]
    width_s: float = 0.1
    rise_time_s: float = 0.004
    low_v: float = 0.0
    high_v: float = 5.0
    noise_v: float = 0.0

    def __post_init__(self) -> None:
        if not (self.rise_time_s >= 0 and self.width_s > self.rise_time_s):
            raise SimulationError(
                f"sync pulse needs 0 <= rise_time_s < width_s, got {self.rise_time_s}, {self.width_s}"
            )
        t = np.asarray(self.edge_times_s, dtype=float)
        if t.size > 1 and np.any(np.diff(t) <= self.width_s + self.rise_time_s):
            raise SimulationError("sync pulse edges must be increasing and further apart than width_s + rise_time_s")

    @classmethod
    def from_gps(
        cls, pulses: SyncSchedule | Iterable[int], truth_epoch: SimTimeBase | int, **kwargs: Any
    ) -> SyncPulseOutput:
        """Pulses whose rising edges cross mid-level at the given GPS times (ns since the GPS epoch).

        ``pulses`` is the sync schedule shared with the simulated receivers, whose MARKTIME/MARKPOS
        events fire at the same instants: a :class:`sim_devices.gnss.timebase.SyncSchedule` (its
        ``pulse_gps_ns``) or any sequence of int GPS ns. ``truth_epoch`` is the session's
        :class:`~sim_devices.gnss.timebase.SimTimeBase` (its ``truth_start_gps_ns``) or the GPS
        time (ns) of truth ``t = 0``. Other keyword arguments are the fields of this class.
        """
        times: Iterable[int] = pulses if isinstance(pulses, Iterable) else pulses.pulse_gps_ns
        epoch = truth_epoch if isinstance(truth_epoch, int) else int(truth_epoch.truth_start_gps_ns)
        # Subtract in integers first: float64 cannot hold GPS ns (~1.4e18) to the nanosecond.
        edges = tuple((int(g) - epoch) / 1e9 for g in times)
        return cls(edges, **kwargs)


@dataclass(frozen=True, slots=True)
class BrakePressureOutput:
    """A brake-pressure transducer; pressure from the truth's braking deceleration (a crude model).

    ``p_master = pa_per_mps2 · max(0, −ax − threshold_mps2)`` (the threshold stands for the drag
    and rolling resistance that decelerate the car without braking); front wheel cylinders see
    ``p_master``, rear ones ``rear_fraction · p_master``. ``scaling`` is the transducer's
    volts → Pa scaling (its inverse gives the volts).
    """

    circuit: str
    scaling: Scaling
    pa_per_mps2: float = 1.0e6
    threshold_mps2: float = 0.3
    rear_fraction: float = 0.7
    noise_v: float = 0.0

    def __post_init__(self) -> None:
        if self.circuit not in ("master", *WHEEL_IDS):
            raise SimulationError(
                f"brake pressure circuit must be 'master' or one of {WHEEL_IDS}, got {self.circuit!r}"
            )


@dataclass(frozen=True, slots=True)
class FunctionOutput:
    """Any SI quantity computed from the truth at truth times ``t`` (s), turned into volts by ``scaling``."""

    fn: Callable[[GroundTruth, FloatArray], FloatArray]
    scaling: Scaling
    noise_v: float = 0.0


@dataclass(frozen=True, slots=True)
class ConstantInput:
    """A fixed voltage (a channel pulled to a rail, or stuck)."""

    volts: float
    noise_v: float = 0.0


@dataclass(frozen=True, slots=True)
class FloatingInput:
    """An open input: wide-band noise plus mains hum around an offset."""

    noise_v: float = 0.3
    hum_v: float = 0.5
    hum_hz: float = 50.0
    offset_v: float = 0.0


SimSource = OpticalOutput | SyncPulseOutput | BrakePressureOutput | FunctionOutput | ConstantInput | FloatingInput


class SimDaqLink:
    """The cable between the simulated DAQ and the host: unplug it to make the device disappear."""

    def __init__(self) -> None:
        self._unplugged = threading.Event()

    @property
    def connected(self) -> bool:
        return not self._unplugged.is_set()

    @property
    def unplugged_event(self) -> threading.Event:
        return self._unplugged

    def unplug(self) -> None:
        self._unplugged.set()

    def replug(self) -> None:
        self._unplugged.clear()


# --- signal rendering --------------------------------------------------------------------------


class _OpticalRenderer:
    """State of one simulated optical sensor across blocks (lag filter, noise stream, held output)."""

    def __init__(self, sensor: SimOpticalSensor, truth: GroundTruth) -> None:
        self._s = sensor
        self._truth = truth
        self._rng = np.random.default_rng(sensor.seed)
        self._next_u: int | None = None
        self._y: FloatArray | None = None  # lag-filter state (vx, vy) after update next_u − 1
        self._last: dict[OpticalRole, float] = {}
        spec = sensor.spec
        self._sign = {c.role: (-1.0 if c.invert else 1.0) for c in spec.channels}
        self._alpha = 1.0 if sensor.lag_s == 0 else -math.expm1(-1.0 / (sensor.internal_rate_hz * sensor.lag_s))

    def _true_velocity(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Velocity of the mount point at truth times t, in sensor axes before misalignment."""
        tr = self._truth
        vx = np.interp(t, tr.t, tr.vx)
        vy = np.interp(t, tr.t, tr.vy)
        r = np.interp(t, tr.t, tr.yaw_rate)
        spec = self._s.spec
        px, py = transfer_velocity(vx, vy, r, (0.0, 0.0), spec.mount_xy)
        if spec.kind is SensorKind.WHEEL and spec.wheel in _STEERED_WHEELS:
            d = np.interp(t, tr.t, tr.road_wheel_angle)
            c, s = np.cos(d), np.sin(d)
            px, py = c * px + s * py, -s * px + c * py
        return px, py

    def _updates(self, u0: int, u1: int) -> dict[OpticalRole, FloatArray]:
        """Outputs (sensor convention, SI / status volts) of internal updates u0 … u1 − 1."""
        s = self._s
        u = np.arange(u0, u1, dtype=np.float64)
        vx, vy = self._true_velocity(u / s.internal_rate_hz - s.delay_s)
        z = s.zero_offset_rad
        if z:
            c, sn = math.cos(z), math.sin(z)
            vx, vy = c * vx - sn * vy, sn * vx + c * vy
        if self._y is None:
            self._y = np.array([vx[0], vy[0]])  # start in steady state
        a = self._alpha
        b, den = [a], [1.0, a - 1.0]
        fx, _ = lfilter(b, den, vx, zi=[(1.0 - a) * self._y[0]])
        fy, _ = lfilter(b, den, vy, zi=[(1.0 - a) * self._y[1]])
        self._y = np.array([fx[-1], fy[-1]])
        noise = self._rng.standard_normal((u.size, 3))
        mx = fx + s.velocity_noise_mps * noise[:, 0]
        my = fy + s.velocity_noise_mps * noise[:, 1]
        speed = np.hypot(mx, my)
        valid = speed >= s.spec.min_speed_mps
        angle = np.where(valid, sideslip_from_velocity(mx, my) + s.angle_noise_rad * noise[:, 2], 0.0)
        sg = self._sign
        return {
            OpticalRole.VX: sg.get(OpticalRole.VX, 1.0) * mx,
            OpticalRole.VY: sg.get(OpticalRole.VY, 1.0) * my,
            OpticalRole.SPEED: sg.get(OpticalRole.SPEED, 1.0) * speed,
            OpticalRole.SLIP_ANGLE: sg.get(OpticalRole.SLIP_ANGLE, 1.0) * angle,
            OpticalRole.VALID: np.where(valid, s.status_valid_v, s.status_invalid_v),
        }

    def values(self, t: FloatArray) -> dict[OpticalRole, FloatArray]:
        """Held outputs at DAQ sample truth times ``t`` (increasing, continuing earlier calls)."""
        # A sample taken at an update instant sees the new value; the tolerance keeps rounding
        # errors of k / rate from deciding that instead.
        u = np.floor(t * self._s.internal_rate_hz + 1e-6).astype(np.int64)
        u_min, u_max = int(u[0]), int(u[-1])
        start = u_min if self._next_u is None else self._next_u
        if u_min < start - 1:
            raise SimulationError("sim optical sensor: samples requested out of order")
        new = self._updates(start, u_max + 1) if u_max + 1 > start else None
        out: dict[OpticalRole, FloatArray] = {}
        had_last = bool(self._last)
        for role in OpticalRole:
            if new is not None and had_last:
                series = np.concatenate(([self._last[role]], new[role]))
                base = start - 1
            elif new is not None:
                series, base = new[role], start
            else:
                series, base = np.array([self._last[role]]), start - 1
            out[role] = series[u - base]
            self._last[role] = float(series[-1])
        self._next_u = max(start, u_max + 1)
        return out


def _raised_cosine_pulses(t: FloatArray, src: SyncPulseOutput) -> FloatArray:
    """Pulse train of raised-cosine edges (see :class:`SyncPulseOutput`)."""
    edges = np.asarray(src.edge_times_s, dtype=np.float64)
    out = np.full(t.shape, src.low_v, dtype=np.float64)
    if edges.size == 0:
        return out
    half = 0.5 * src.rise_time_s
    i = np.searchsorted(edges - half, t, side="right") - 1
    has = i >= 0
    tau = np.where(has, t - edges[np.clip(i, 0, None)], -np.inf)

    def ramp(x: FloatArray) -> FloatArray:
        if half == 0:
            return (x >= 0).astype(np.float64)
        xc = np.clip(x, -half, half)  # the ramp is flat at 0 and 1 outside ±half (and tau may be −inf)
        return 0.5 * (1.0 + np.sin(np.pi * xc / src.rise_time_s))

    h = ramp(tau) - ramp(tau - src.width_s)
    return out + (src.high_v - src.low_v) * h


def _brake_pressure(truth: GroundTruth, t: FloatArray, src: BrakePressureOutput) -> FloatArray:
    ax = np.interp(t, truth.t, truth.ax)
    p = src.pa_per_mps2 * np.maximum(0.0, -ax - src.threshold_mps2)
    if src.circuit in ("rl", "rr"):
        p = src.rear_fraction * p
    return p


class _Renderer:
    """Renders DAQ samples k0 … k0+n−1 of one acquisition (all stateful parts of the chain)."""

    def __init__(self, backend: SimDaqBackend, t_start_s: float, rate_hz: float) -> None:
        self._b = backend
        self._t_start_s = t_start_s
        self._rate_hz = rate_hz
        self._adc_rng = np.random.default_rng(backend.seed)
        self._optical: dict[int, _OpticalRenderer] = {}
        chans = backend.channels
        self._sources = [backend.source_for(c) for c in chans]
        for src in self._sources:
            if isinstance(src, OpticalOutput) and id(src.sensor) not in self._optical:
                assert backend.truth is not None
                self._optical[id(src.sensor)] = _OpticalRenderer(src.sensor, backend.truth)
        sig = []
        for src in self._sources:
            extra = src.noise_v
            sig.append(math.hypot(backend.adc_noise_v, extra))
        self._sigma = np.asarray(sig, dtype=np.float64)
        self._lo = np.array([c.min_v for c in chans])
        self._hi = np.array([c.max_v for c in chans])
        self._step = (self._hi - self._lo) / float(2**backend.adc_bits)

    def sample_times(self, k0: int, n: int) -> FloatArray:
        k = np.arange(k0, k0 + n, dtype=np.float64)
        return np.asarray(self._b.sample_time_s(k, self._t_start_s, self._rate_hz), dtype=np.float64)

    def skip(self, n: int) -> None:
        """Advance the sample-level noise stream over ``n`` lost samples."""
        n_ch = len(self._sources)
        while n > 0:
            m = min(n, 1_000_000)
            self._adc_rng.standard_normal((m, n_ch))
            n -= m

    def render(self, k0: int, n: int) -> FloatArray:
        t = self.sample_times(k0, n)
        b = self._b
        truth = b.truth
        n_ch = len(self._sources)
        v = np.empty((n_ch, n), dtype=np.float64)
        optical_vals: dict[int, dict[OpticalRole, FloatArray]] = {
            key: r.values(t) for key, r in self._optical.items()
        }
        for i, src in enumerate(self._sources):
            if isinstance(src, OpticalOutput):
                x = optical_vals[id(src.sensor)][src.role]
                if src.role is OpticalRole.VALID:
                    v[i] = x
                else:
                    ch = src.sensor.spec.channel_for(src.role)
                    assert ch is not None
                    assert ch.scaling is not None
                    v[i] = ch.scaling.to_volts(x)
            elif isinstance(src, SyncPulseOutput):
                v[i] = _raised_cosine_pulses(t, src)
            elif isinstance(src, BrakePressureOutput):
                assert truth is not None
                v[i] = src.scaling.to_volts(_brake_pressure(truth, t, src))
            elif isinstance(src, FunctionOutput):
                assert truth is not None
                v[i] = src.scaling.to_volts(np.asarray(src.fn(truth, t), dtype=np.float64))
            elif isinstance(src, ConstantInput):
                v[i] = src.volts
            else:
                v[i] = src.offset_v + src.hum_v * np.sin(2.0 * np.pi * src.hum_hz * t)
        # (n, n_ch) then transpose: the stream order is per sample, so block sizes do not change it.
        z = self._adc_rng.standard_normal((n, n_ch)).T
        v += self._sigma[:, None] * z
        v = np.nan_to_num(v, nan=0.0, posinf=1e9, neginf=-1e9)
        code = np.clip(np.floor((v - self._lo[:, None]) / self._step[:, None] + 0.5), 0, 2**b.adc_bits - 1)
        return self._lo[:, None] + code * self._step[:, None]


# --- the backend -------------------------------------------------------------------------------


class SimDaqBackend(DaqBackend):
    """The simulated DAQ (registry name ``sim``); see the module docstring for the signal chain.

    Args:
        clock: host clock; sample ``k`` is available when it reaches the sample's time.
        truth: ground truth feeding optical, brake-pressure and function sources.
        sources: physical channel name → source. Unwired inputs float.
        truth_start_ns: clock time (ns) of truth ``t = 0`` (default: the clock at construction).
        adc_bits, adc_noise_v: converter resolution and input noise (σ, volts).
        clock_ppm, clock_offset_s: sample-clock error against true time (see module docstring).
        link: a shared :class:`SimDaqLink` to simulate unplugging.
        truth_epoch_gps_ns: GPS time (ns) of truth ``t = 0`` (for :meth:`sample_gps_ns`).
        timebase: the session's :class:`~sim_devices.gnss.timebase.SimTimeBase`, shared with the
            simulated receivers; gives ``truth_start_ns`` and ``truth_epoch_gps_ns`` when those are not given.
    """

    name = "sim"

    def __init__(
        self,
        *,
        clock: Clock | None = None,
        truth: GroundTruth | None = None,
        sources: Mapping[str, SimSource] | None = None,
        truth_start_ns: int | None = None,
        adc_bits: int = 16,
        adc_noise_v: float = 0.0003,
        clock_ppm: float = 0.0,
        clock_offset_s: float = 0.0,
        seed: int = 0,
        link: SimDaqLink | None = None,
        device: str = "sim",
        truth_epoch_gps_ns: int | None = None,
        timebase: SimTimeBase | None = None,
    ) -> None:
        super().__init__(clock=clock, device=device)
        if not (1 <= adc_bits <= 32):
            raise SimulationError(f"sim DAQ: adc_bits must be in 1..32, got {adc_bits}")
        if not (math.isfinite(adc_noise_v) and adc_noise_v >= 0):
            raise SimulationError(f"sim DAQ: adc_noise_v must be >= 0, got {adc_noise_v}")
        if not (math.isfinite(clock_ppm) and abs(clock_ppm) < 1e5 and math.isfinite(clock_offset_s)):
            raise SimulationError(f"sim DAQ: invalid clock error ppm={clock_ppm}, offset={clock_offset_s}")
        self.truth = truth
        self._sources: dict[str, SimSource] = dict(sources or {})
        if timebase is not None:
            truth_start_ns = timebase.truth_start_ns if truth_start_ns is None else truth_start_ns
            truth_epoch_gps_ns = timebase.truth_start_gps_ns if truth_epoch_gps_ns is None else truth_epoch_gps_ns
        self.truth_start_ns = truth_start_ns if truth_start_ns is not None else self.clock.now_ns()
        self.adc_bits = adc_bits
        self.adc_noise_v = adc_noise_v
        self.clock_ppm = clock_ppm
        self.clock_offset_s = clock_offset_s
        self.seed = seed
        self.link = link if link is not None else SimDaqLink()
        self.truth_epoch_gps_ns = truth_epoch_gps_ns
        self._renderer: _Renderer | None = None
        self._t_start_s = 0.0
        self._next = 0
        self._pending_lost: LostSamples | None = None
        self._reader: Participant | None = None

    # -- wiring and timing -----------------------------------------------------------------------

    @property
    def true_rate_hz(self) -> float:
        """The sample clock's actual rate against true time (nominal × (1 + ppm·1e−6))."""
        assert self.rate_hz is not None
        return self.rate_hz * (1.0 + self.clock_ppm * 1e-6)

    def source_for(self, channel: DaqChannelConfig) -> SimSource:
        """The source wired to a configured channel (an open input if none is)."""
        return self._sources.get(channel.physical_channel, FloatingInput())

    def sample_time_s(
        self, k: npt.ArrayLike, t_start_s: float | None = None, rate_hz: float | None = None
    ) -> FloatArray | float:
        """Truth time (s) of sample index ``k`` of an acquisition started at truth time ``t_start_s``."""
        rate = rate_hz if rate_hz is not None else self.rate_hz
        if rate is None:
            raise ConfigError("sim DAQ: no sample rate (start() or pass rate_hz)")
        t0 = self._t_start_s if t_start_s is None else t_start_s
        true_rate = rate * (1.0 + self.clock_ppm * 1e-6)
        t = t0 + self.clock_offset_s + np.asarray(k, dtype=np.float64) / true_rate
        return float(t) if np.ndim(t) == 0 else np.asarray(t, dtype=np.float64)

    def sample_gps_ns(
        self, k: npt.ArrayLike, t_start_s: float | None = None, rate_hz: float | None = None
    ) -> npt.NDArray[np.int64]:
        """True GPS time (ns since the GPS epoch, rounded) of sample index ``k`` — the answer a time base must find.

        Raises:
            ConfigError: the backend was made without ``truth_epoch_gps_ns``.
        """
        if self.truth_epoch_gps_ns is None:
            raise ConfigError(f"DAQ {self.device}: sample_gps_ns needs truth_epoch_gps_ns")
        t = np.asarray(self.sample_time_s(k, t_start_s, rate_hz), dtype=np.float64)
        return self.truth_epoch_gps_ns + np.round(t * 1e9).astype(np.int64)

    def _sample_clock_ns(self, k: int) -> int:
        return self.truth_start_ns + round(float(self.sample_time_s(k)) * 1e9)

    def _acquired(self, now_ns: int) -> int:
        """Samples acquired by host time ``now_ns`` (sample k counts once its instant has passed)."""
        t = (now_ns - self.truth_start_ns) / 1e9 - self._t_start_s - self.clock_offset_s
        # (the tolerance makes a sample count as acquired at its own instant despite rounding)
        return max(0, math.floor(t * self.true_rate_hz + 1e-6) + 1)

    # -- hooks ---------------------------------------------------------------------------------

    def _configure(self, channels: tuple[DaqChannelConfig, ...]) -> None:
        physical = {c.physical_channel for c in channels}
        for c in channels:
            src = self._sources.get(c.physical_channel)
            if src is None:
                log.info("sim DAQ: %s (%s) is not wired: it will float", c.physical_channel, c.name)
            elif isinstance(src, OpticalOutput | BrakePressureOutput | FunctionOutput) and self.truth is None:
                raise ConfigError(f"sim DAQ: {c.physical_channel} ({c.name}) needs ground truth; pass truth=")
            elif isinstance(src, OpticalOutput) and src.role is not OpticalRole.VALID:
                ch = src.sensor.spec.channel_for(src.role)
                if ch is None or ch.scaling is None:
                    raise ConfigError(
                        f"sim DAQ: {c.physical_channel} wired to {src.sensor.spec.name}.{src.role.value}, "
                        "which the sensor spec has no scaling for"
                    )
        unused = sorted(set(self._sources) - physical)
        if unused:
            log.info("sim DAQ: wired inputs not acquired: %s", unused)

    def _start(self, rate_hz: float, buffer_size: int) -> None:
        if not self.link.connected:
            raise DeviceError(f"DAQ {self.device}: device not found (unplugged)")
        self._t_start_s = (self.clock.now_ns() - self.truth_start_ns) / 1e9
        if self._reader is None:
            # on a governed clock simulated time waits for whoever reads this DAQ
            self._reader = participant(self.clock, f"daq:{self.device}", progress_ns=UNBOUNDED_NS, reuse=True)
        self._next = 0
        self._pending_lost = None
        self._renderer = _Renderer(self, self._t_start_s, rate_hz)

    def _read(self, n_samples: int, timeout_s: float) -> tuple[int, npt.NDArray[np.float64], LostSamples | None]:
        assert self._renderer is not None
        if n_samples > self.buffer_size:
            raise ConfigError(
                f"DAQ {self.device}: cannot read {n_samples} samples at once from a {self.buffer_size}-sample buffer"
            )
        if not self.link.connected:
            raise DeviceError(f"DAQ {self.device}: device disappeared (unplugged)")
        now = self.clock.now_ns()
        acquired = self._acquired(now)
        if acquired - self._next > self.buffer_size:
            first_kept = acquired - self.buffer_size
            prev = self._pending_lost
            start = prev.start_index if prev is not None else self._next
            self._pending_lost = LostSamples(start, first_kept)
            self._renderer.skip(first_kept - self._next)
            self._next = first_kept
        ready_ns = self._sample_clock_ns(self._next + n_samples - 1)
        deadline = now + int(timeout_s * 1e9)
        if ready_ns > deadline:
            self.clock.sleep_until_ns(deadline, self.link.unplugged_event)
            if not self.link.connected:
                raise DeviceError(f"DAQ {self.device}: device disappeared (unplugged)")
            raise DeviceTimeoutError(f"DAQ {self.device}: {n_samples} samples not acquired within {timeout_s} s")
        reader = self._reader
        if reader is not None:
            reader.at(ready_ns)
        if not self.clock.sleep_until_ns(ready_ns, self.link.unplugged_event):
            raise DeviceError(f"DAQ {self.device}: device disappeared (unplugged)")
        first = self._next
        data = self._renderer.render(first, n_samples)
        self._next += n_samples
        if reader is not None:  # the reader owes the next block once it is complete
            reader.at(self._sample_clock_ns(self._next + n_samples - 1))
        lost, self._pending_lost = self._pending_lost, None
        return first, data, lost

    def _available(self) -> int:
        if self._renderer is None or not self.link.connected:
            return 0
        return self._acquired(self.clock.now_ns()) - self._next

    def _stop(self) -> None:
        self._renderer = None
        if self._reader is not None:
            self._reader.idle()

    # -- offline -------------------------------------------------------------------------------

    def generate(
        self, truth: GroundTruth | None = None, t0_s: float = 0.0, t1_s: float | None = None, rate_hz: float = 1000.0
    ) -> npt.NDArray[np.float64]:
        """Render an acquisition started at truth time ``t0_s`` up to ``t1_s`` without waiting.

        Returns volts of shape (n_channels, n) for samples ``k = 0 … n−1`` with truth times
        :meth:`sample_time_s` ``(k, t0_s, rate_hz) < t1_s`` (``t1_s`` defaults to the truth's end).
        Uses the configured channels and a fresh copy of every random stream, so it gives exactly
        the samples a live acquisition started at ``t0_s`` delivers.
        """
        if not self.channels:
            raise ConfigError(f"DAQ {self.device}: configure channels before generate()")
        if truth is not None:
            self.truth = truth
        if t1_s is None:
            if self.truth is None:
                raise ConfigError("sim DAQ generate(): give t1_s or a truth to end at")
            t1_s = float(self.truth.t[-1])
        true_rate = rate_hz * (1.0 + self.clock_ppm * 1e-6)
        n = max(0, math.ceil((t1_s - t0_s - self.clock_offset_s) * true_rate))
        if n == 0:
            return np.empty((len(self.channels), 0))
        return _Renderer(self, t0_s, rate_hz).render(0, n)


def wire_by_name(channels: Mapping[str, SimSource], configs: Sequence[DaqChannelConfig]) -> dict[str, SimSource]:
    """Turn ``{logical channel name: source}`` into the ``{physical channel: source}`` wiring."""
    by_name = {c.name: c.physical_channel for c in configs}
    missing = sorted(set(channels) - set(by_name))
    if missing:
        raise ConfigError(f"sim DAQ wiring names channels that are not configured: {missing}")
    return {by_name[name]: src for name, src in channels.items()}


def wire_optical(
    sensor: SimOpticalSensor, configs: Sequence[DaqChannelConfig], *, require_all: bool = True
) -> dict[str, OpticalOutput]:
    """Wire each analog output of a simulated sensor to the input its spec names (``{physical: source}``).

    The sensor's spec says which logical DAQ channel carries each role; ``configs`` say which
    physical input each logical channel is. With ``require_all=False`` roles whose channel is not
    acquired are left unwired (an output that nobody reads).

    Raises:
        ConfigError: a role's DAQ channel is not among ``configs`` (and ``require_all``).
    """
    by_name = {c.name: c.physical_channel for c in configs}
    out: dict[str, OpticalOutput] = {}
    for ch in sensor.spec.channels:
        if ch.channel is None:
            continue
        if ch.channel not in by_name:
            if require_all:
                raise ConfigError(
                    f"sim DAQ: optical sensor {sensor.spec.name!r} role {ch.role.value!r} is on DAQ channel "
                    f"{ch.channel!r}, which is not configured; channels: {sorted(by_name)}"
                )
            continue
        out[by_name[ch.channel]] = OpticalOutput(sensor, ch.role)
    return out


BRAKE_CIRCUITS: Mapping[str, str] = {
    "mc_pressure": "master",
    "wheel_pressure_fl": "fl",
    "wheel_pressure_fr": "fr",
    "wheel_pressure_rl": "rl",
    "wheel_pressure_rr": "rr",
}
"""Analog channel names (the CAN role names of the same quantities) that :func:`sim_daq_sources`
wires to a simulated brake-pressure transducer, and their circuit."""


def sim_daq_sources(
    channels: Sequence[DaqChannelConfig],
    *,
    optical: Sequence[SimOpticalSensor] = (),
    analog: Sequence[AnalogChannelSpec] = (),
    sync_channel: str | None = None,
    sync: SyncPulseOutput | None = None,
    extra: Mapping[str, SimSource] | None = None,
) -> dict[str, SimSource]:
    """The ``sources=`` wiring of a :class:`SimDaqBackend` for a session's DAQ configuration.

    - every DAQ-channel role of each simulated optical sensor (:func:`wire_optical`);
    - analog channels named as in :data:`BRAKE_CIRCUITS` (``mc_pressure``, ``wheel_pressure_fl`` …)
      to a brake-pressure transducer with the channel's own scaling;
    - ``sync_channel`` to the sync pulse ``sync`` (e.g. :meth:`SyncPulseOutput.from_gps`);
    - ``extra``: any other source by logical channel name (wins over the above).

    Channels left unwired float (and the health checker reports them).

    Raises:
        ConfigError: a sensor, analog spec or extra source names a channel that is not configured.
    """
    by_name = {c.name: c.physical_channel for c in channels}
    out: dict[str, SimSource] = {}
    for sensor in optical:
        out.update(wire_optical(sensor, channels))
    for spec in analog:
        circuit = BRAKE_CIRCUITS.get(spec.name)
        if circuit is None:
            continue
        if spec.channel not in by_name:
            raise ConfigError(f"sim DAQ: analog channel {spec.name!r} is on {spec.channel!r}, which is not configured")
        out[by_name[spec.channel]] = BrakePressureOutput(circuit, spec.scaling)
    if sync_channel is not None and sync is not None:
        if sync_channel not in by_name:
            raise ConfigError(f"sim DAQ: sync channel {sync_channel!r} is not configured; channels: {sorted(by_name)}")
        out[by_name[sync_channel]] = sync
    out.update(wire_by_name(extra or {}, channels))
    return out


# --- Correvit CAN output -----------------------------------------------------------------------

CORREVIT_MESSAGES: Mapping[OpticalRole, tuple[str, str, str, str]] = {
    OpticalRole.VX: ("Correvit_Vel", "Vel_X", "km/h", "Vel_Status"),
    OpticalRole.VY: ("Correvit_Vel", "Vel_Y", "km/h", "Vel_Status"),
    OpticalRole.SPEED: ("Correvit_Vel", "Vel", "km/h", "Vel_Status"),
    OpticalRole.SLIP_ANGLE: ("Correvit_Angle", "Angle", "deg", "Angle_Status"),
}
"""Role → (message, signal, unit, status bit) in ``correvit.dbc``."""


def correvit_dbc_path() -> Path:
    """Path of the Correvit CAN-output DBC shipped as package data (provenance in the file's comment)."""
    return Path(str(importlib.resources.files("sim_devices").joinpath("data/correvit.dbc")))


def correvit_role_table(prefix: str = "correvit") -> dict[str, Any]:
    """The CAN role table (``{"roles": {...}}``, the form of a roles file) for ``correvit.dbc``.

    Roles are named ``{prefix}_{optical role}`` (``correvit_vx`` …); each carries the message's
    status bit as its quality bit (valid when 1), so a sample below the minimum speed is flagged
    INVALID by the CAN decoders. Build the map with ``RoleMap.from_mapping(table, db)``.
    """
    return {
        "roles": {
            f"{prefix}_{role.value}": {
                "message": msg,
                "signal": sig,
                "unit": unit,
                "valid_signal": status,
                "valid_when": 1,
            }
            for role, (msg, sig, unit, status) in CORREVIT_MESSAGES.items()
        }
    }


def correvit_can_frames(
    sensor: SimOpticalSensor,
    truth: GroundTruth,
    db: Database,
    rolemap: RoleMap,
    *,
    t0_s: float = 0.0,
    t1_s: float | None = None,
    period_s: float = 0.01,
    latency_s: float = 0.0005,
    message_gap_s: float = 0.0002,
    truth_start_ns: int = 0,
) -> list[tuple[int, int, bytes]]:
    """CAN frames of a simulated Correvit with CAN output: ``(timestamp_ns, arbitration_id, data)`` in time order.

    Every ``period_s`` from ``t0_s`` (truth time) until ``t1_s`` (default: the truth's end) the
    sensor's held outputs (the same model as the analog outputs: noise, lag, internal update
    rate, zero offset, minimum speed) are encoded into each message that carries one of the
    spec's CAN roles (``OpticalChannel.can_role``), via :func:`drivers.can.roles.encode_role_frame`.
    A message's frames are stamped ``truth_start_ns + (t + latency_s + j·message_gap_s)·1e9`` for
    its position ``j`` among the messages of a cycle. Below the minimum speed the quality bit of
    each role (its ``valid_signal``) is set to a value meaning "invalid", and a ``valid`` role, if
    mapped, to 0.

    Raises:
        ConfigError: the spec has no CAN roles, or one is not in the role map.
    """
    spec = sensor.spec
    by_can = spec.can_roles
    if not by_can:
        raise ConfigError(f"sim Correvit {spec.name!r}: the spec has no CAN roles")
    specs = {name: rolemap.role(name) for name in by_can}
    messages: list[str] = []
    for rs in specs.values():
        if rs.message not in messages:
            messages.append(rs.message)
    end = float(truth.t[-1]) if t1_s is None else t1_s
    n = max(0, math.floor((end - t0_s) / period_s + 1e-9) + 1)
    if n == 0:
        return []
    t = t0_s + period_s * np.arange(n, dtype=np.float64)
    outputs = _OpticalRenderer(sensor, truth).values(t)
    valid = outputs[OpticalRole.VALID] == sensor.status_valid_v
    frames: list[tuple[int, int, bytes]] = []
    for j, message in enumerate(messages):
        msg = db.get_message_by_name(message)
        roles_here = [(name, by_can[name], rs) for name, rs in specs.items() if rs.message == message]
        for i in range(n):
            values: dict[str, float] = {}
            overrides: dict[str, float] = {}
            for name, role, rs in roles_here:
                if role is OpticalRole.VALID:
                    values[name] = 1.0 if valid[i] else 0.0
                else:
                    values[name] = float(outputs[role][i])
                if rs.valid_signal is not None and not valid[i]:
                    bad = next(v for v in range(2 ** msg.get_signal_by_name(rs.valid_signal).length)
                               if v not in rs.valid_values)
                    overrides[rs.valid_signal] = float(bad)
            data = encode_role_frame(db, rolemap, message, values, counter=i, signals=overrides or None)
            ts = truth_start_ns + round((float(t[i]) + latency_s + j * message_gap_s) * 1e9)
            frames.append((ts, msg.frame_id, data))
    frames.sort(key=lambda f: f[0])
    return frames
