"""Error model of a simulated GNSS receiver: solution noise by solution type, and the RTK state machine.

Pure numpy, seeded, no I/O.

Position error. Each axis (east, north, up) is the sum of a first-order Gauss–Markov process
(time constant ``correlation_time_s``; the slowly wandering multipath-like part real RTK solutions
show) and white noise. Both are kept as unit-variance states and scaled by the 1σ of the current
solution type (:class:`SolutionNoise`), so a change of solution type changes the error amplitude
at once, like the jump a real receiver shows when it fixes or loses its ambiguities. The
correlated share of the variance is ``correlated_fraction``. Velocity errors are white
(Doppler-derived velocity is nearly so).

Common-mode error. Two rovers on one roof, corrected by the same base, share most of their
position error (base coordinates, atmospheric residuals, the same satellites): their *relative*
position, and so the baseline heading, is far better than either absolute position (dual-antenna
systems quote ~0.1° heading at 1 m, i.e. a few mm of relative error). ``common_fraction`` of the
position variance is therefore a process shared by every receiver built with the same
``common_seed``: a sum of sinusoids with seeded random frequencies (Gauss–Markov-like spectrum
with the same ``correlation_time_s``) and phases, a deterministic function of GPS time, so each
receiver evaluates it at its own epochs without sharing state. The remaining variance is the
receiver's own (multipath, noise) as above.

RTK state. :class:`RtkStateMachine` is fed every valid correction frame a rover receives (message
number, station ID, receive time, and for GPS observation messages the base epoch). From that
history it says which solution type a rover has at a given GPS time:

- no observations from a base whose station message (1005/1006) has been seen → SINGLE;
- corrections younger than ``max_correction_age_s`` for less than ``time_to_float_s`` → PSRDIFF,
  then NARROW_FLOAT, and NARROW_INT after ``time_to_fix_s`` of uninterrupted corrections;
- when corrections stop: RTK (fixed or float) degrades to NARROW_FLOAT until the age reaches
  ``float_hold_s``, then PSRDIFF until ``psrdiff_timeout_s``, then SINGLE;
- a gap longer than ``max_correction_age_s`` restarts the time to fix.

The differential age is the solution time minus the epoch of the newest base observations
(GPS MSM / legacy GPS messages carry it), else minus the receive time of the newest observation
message; 0 for SINGLE.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from drivers.novatel.enums import PositionType
from vsccore.errors import SimulationError
from vsccore.gpstime import NS_PER_S

__all__ = [
    "DEFAULT_SOLUTION_NOISE",
    "CommonModeError",
    "GnssErrorModel",
    "GnssErrorParams",
    "RtkParams",
    "RtkState",
    "RtkStateMachine",
    "SolutionError",
    "SolutionNoise",
    "is_observation_message",
    "is_station_message",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SolutionNoise:
    """1σ errors of one solution type.

    ``horizontal_rms_m`` is the 2-D RMS (drms) of the horizontal position error; each horizontal
    axis has σ = drms/√2. Velocity sigmas are per axis.
    """

    horizontal_rms_m: float
    vertical_sigma_m: float
    velocity_sigma_mps: float
    vertical_velocity_sigma_mps: float

    def __post_init__(self) -> None:
        values = (
            self.horizontal_rms_m,
            self.vertical_sigma_m,
            self.velocity_sigma_mps,
            self.vertical_velocity_sigma_mps,
        )
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise SimulationError(f"GNSS solution noise must be finite and >= 0, got {values}")

    @property
    def position_sigma_enu(self) -> FloatArray:
        """Per-axis position σ (east, north, up) in m."""
        h = self.horizontal_rms_m / math.sqrt(2.0)
        return np.array([h, h, self.vertical_sigma_m])

    @property
    def velocity_sigma_enu(self) -> FloatArray:
        """Per-axis velocity σ (east, north, up) in m/s."""
        v = self.velocity_sigma_mps
        return np.array([v, v, self.vertical_velocity_sigma_mps])


def _default_noise() -> dict[PositionType, SolutionNoise]:
    return dict(DEFAULT_SOLUTION_NOISE)


#: Default 1σ by solution type (typical OEM7 figures; RTK fixed ≈ 1 cm + 1 ppm).
DEFAULT_SOLUTION_NOISE: Mapping[PositionType, SolutionNoise] = {
    PositionType.NARROW_INT: SolutionNoise(0.015, 0.020, 0.02, 0.03),
    PositionType.NARROW_FLOAT: SolutionNoise(0.35, 0.50, 0.02, 0.03),
    PositionType.PSRDIFF: SolutionNoise(0.50, 0.90, 0.03, 0.05),
    PositionType.SINGLE: SolutionNoise(1.50, 2.50, 0.05, 0.08),
    PositionType.FIXEDPOS: SolutionNoise(0.0, 0.0, 0.0, 0.0),
}


@dataclass(frozen=True, slots=True)
class GnssErrorParams:
    """Parameters of :class:`GnssErrorModel`."""

    noise: Mapping[PositionType, SolutionNoise] = field(default_factory=_default_noise)
    correlated_fraction: float = 0.7
    correlation_time_s: float = 10.0
    common_fraction: float = 0.0
    """Share of the position variance common to all receivers with the same ``common_seed``."""
    common_seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.common_fraction <= 1.0:
            raise SimulationError(f"common_fraction must be in [0, 1], got {self.common_fraction}")
        if not 0.0 <= self.correlated_fraction <= 1.0:
            raise SimulationError(f"correlated_fraction must be in [0, 1], got {self.correlated_fraction}")
        if not (math.isfinite(self.correlation_time_s) and self.correlation_time_s > 0.0):
            raise SimulationError(f"correlation_time_s must be > 0, got {self.correlation_time_s}")

    def noise_for(self, pos_type: PositionType) -> SolutionNoise:
        """1σ of a solution type (SINGLE's for types without an entry)."""
        found = self.noise.get(pos_type)
        if found is not None:
            return found
        single = self.noise.get(PositionType.SINGLE)
        return single if single is not None else DEFAULT_SOLUTION_NOISE[PositionType.SINGLE]


@dataclass(frozen=True, slots=True)
class SolutionError:
    """Errors of one solution epoch (ENU, added to the truth) and the 1σ the receiver reports."""

    position_enu_m: FloatArray
    position_sigma_enu_m: FloatArray
    velocity_enu_mps: FloatArray
    velocity_sigma_enu_mps: FloatArray


class CommonModeError:
    """A smooth zero-mean unit-variance random process per ENU axis, a deterministic function of time.

    Sum of ``n`` sinusoids per axis with frequencies drawn from the Lorentzian spectrum of a
    first-order Gauss–Markov process with time constant ``tau_s`` (so its autocorrelation is
    close to exp(−|Δt|/τ)) and uniform random phases; amplitude √(2/n) each gives unit variance.
    """

    def __init__(self, seed: int, tau_s: float, n: int = 48) -> None:
        rng = np.random.default_rng([0x5EED, seed])
        # Lorentzian (Cauchy) angular frequencies with half-width 1/τ: the spectrum of exp(−|t|/τ)
        self._omega = np.abs(rng.standard_cauchy((3, n))) / tau_s
        self._phase = rng.uniform(0.0, 2.0 * math.pi, (3, n))
        self._amp = math.sqrt(2.0 / n)

    def at(self, t_s: float) -> FloatArray:
        """The process value (3,) at time ``t_s`` (any origin; seconds)."""
        return self._amp * np.cos(self._omega * t_s + self._phase).sum(axis=1)


class GnssErrorModel:
    """Seeded position/velocity error generator (see module docstring).

    Draws must come in non-decreasing time order for the Gauss–Markov part to be right; an
    earlier time reuses the current state.
    """

    def __init__(self, params: GnssErrorParams | None = None, seed: int | None = 0) -> None:
        self.params = params if params is not None else GnssErrorParams()
        self._rng = np.random.default_rng(seed)
        self._gm = self._rng.standard_normal(3)  # stationary start
        self._t_ns: int | None = None
        p = self.params
        self._common = CommonModeError(p.common_seed, p.correlation_time_s) if p.common_fraction > 0.0 else None
        self._sigmas: dict[PositionType, tuple[FloatArray, FloatArray]] = {}
        self._sigmas_of = self.params

    def _sigma(self, pos_type: PositionType) -> tuple[FloatArray, FloatArray]:
        """Position and velocity 1σ (ENU) of a solution type, built once (read-only: every epoch shares them)."""
        if self._sigmas_of is not self.params:  # the parameters were replaced
            self._sigmas.clear()
            self._sigmas_of = self.params
        found = self._sigmas.get(pos_type)
        if found is None:
            noise = self.params.noise_for(pos_type)
            found = (noise.position_sigma_enu, noise.velocity_sigma_enu)
            for a in found:
                a.flags.writeable = False
            self._sigmas[pos_type] = found
        return found

    def sample(self, t_gps_ns: int, pos_type: PositionType) -> SolutionError:
        """Errors of the solution at GPS time ``t_gps_ns`` (ns) of type ``pos_type``."""
        p = self.params
        if self._t_ns is not None and t_gps_ns > self._t_ns:
            dt = (t_gps_ns - self._t_ns) / NS_PER_S
            phi = math.exp(-dt / p.correlation_time_s)
            self._gm = phi * self._gm + math.sqrt(max(0.0, 1.0 - phi * phi)) * self._rng.standard_normal(3)
        if self._t_ns is None or t_gps_ns > self._t_ns:
            self._t_ns = t_gps_ns
        white = self._rng.standard_normal(3)
        vel_white = self._rng.standard_normal(3)
        sigma, vsigma = self._sigma(pos_type)
        unit = math.sqrt(p.correlated_fraction) * self._gm + math.sqrt(1.0 - p.correlated_fraction) * white
        if self._common is not None:
            # one week of GPS time keeps the float argument accurate (ω·t ≲ 1e6 rad)
            common = self._common.at((t_gps_ns % (7 * 86400 * NS_PER_S)) / NS_PER_S)
            unit = math.sqrt(1.0 - p.common_fraction) * unit + math.sqrt(p.common_fraction) * common
        return SolutionError(sigma * unit, sigma, vsigma * vel_white, vsigma)


# --- RTK state -----------------------------------------------------------------------------------

_OBSERVATION_RANGES = ((1001, 1004), (1009, 1012), (1071, 1077), (1081, 1087), (1091, 1097), (1111, 1117),
                       (1121, 1127))
_GPS_EPOCH_MESSAGES = ((1001, 1004), (1071, 1077))


def is_observation_message(number: int) -> bool:
    """True for RTCM3 observation messages (legacy GPS/GLONASS and MSM of every system)."""
    return any(a <= number <= b for a, b in _OBSERVATION_RANGES)


def is_station_message(number: int) -> bool:
    """True for RTCM3 station (antenna reference point) messages 1005/1006."""
    return number in (1005, 1006)


def carries_gps_epoch(number: int) -> bool:
    """True for messages whose header holds the GPS epoch time (DF004)."""
    return any(a <= number <= b for a, b in _GPS_EPOCH_MESSAGES)


@dataclass(frozen=True, slots=True)
class RtkParams:
    """Timing of the simulated RTK engine (seconds; see the module docstring)."""

    max_correction_age_s: float = 5.0
    float_hold_s: float = 10.0
    psrdiff_timeout_s: float = 30.0
    time_to_float_s: float = 2.0
    time_to_fix_s: float = 10.0

    def __post_init__(self) -> None:
        values = (self.max_correction_age_s, self.float_hold_s, self.psrdiff_timeout_s)
        if not (0.0 < values[0] <= values[1] <= values[2]):
            raise SimulationError(
                f"RTK timeouts must satisfy 0 < max_correction_age_s <= float_hold_s <= psrdiff_timeout_s, got {values}"
            )
        if not (0.0 <= self.time_to_float_s <= self.time_to_fix_s):
            raise SimulationError(
                f"RTK needs 0 <= time_to_float_s <= time_to_fix_s, got {self.time_to_float_s}, {self.time_to_fix_s}"
            )


@dataclass(frozen=True, slots=True)
class RtkState:
    """What the RTK engine gives at one instant."""

    pos_type: PositionType
    diff_age_s: float
    station_id: str


class RtkStateMachine:
    """Solution type of a rover from the history of the corrections it received."""

    def __init__(self, params: RtkParams | None = None) -> None:
        self.params = params if params is not None else RtkParams()
        self._station_id: int | None = None
        self._last_obs_ns: int | None = None
        self._last_epoch_ns: int | None = None
        self._run_start_ns: int | None = None
        self.frames_seen = 0

    @property
    def station_id(self) -> int | None:
        """Station ID from the last station message (None before the first)."""
        return self._station_id

    def on_frame(self, rx_gps_ns: int, number: int, station_id: int, epoch_gps_ns: int | None = None) -> None:
        """Account for one valid correction frame received at GPS time ``rx_gps_ns``."""
        self.frames_seen += 1
        if is_station_message(number):
            self._station_id = station_id
            return
        if not is_observation_message(number):
            return
        max_age_ns = round(self.params.max_correction_age_s * NS_PER_S)
        if self._last_obs_ns is None or rx_gps_ns - self._last_obs_ns > max_age_ns or self._run_start_ns is None:
            self._run_start_ns = rx_gps_ns
        self._last_obs_ns = max(rx_gps_ns, self._last_obs_ns or rx_gps_ns)
        if epoch_gps_ns is not None:
            self._last_epoch_ns = epoch_gps_ns

    def state(self, t_gps_ns: int) -> RtkState:
        """Solution type and differential age at GPS time ``t_gps_ns``."""
        p = self.params
        if self._station_id is None or self._last_obs_ns is None or self._run_start_ns is None:
            return RtkState(PositionType.SINGLE, 0.0, "")
        age = max(0.0, (t_gps_ns - self._last_obs_ns) / NS_PER_S)
        station = str(self._station_id)
        if self._last_epoch_ns is not None and self._last_epoch_ns <= self._last_obs_ns:
            diff_age = max(0.0, (t_gps_ns - self._last_epoch_ns) / NS_PER_S)
        else:
            diff_age = age
        if age <= p.max_correction_age_s:
            run = (t_gps_ns - self._run_start_ns) / NS_PER_S
            if run >= p.time_to_fix_s:
                return RtkState(PositionType.NARROW_INT, diff_age, station)
            if run >= p.time_to_float_s:
                return RtkState(PositionType.NARROW_FLOAT, diff_age, station)
            return RtkState(PositionType.PSRDIFF, diff_age, station)
        run_at_last = (self._last_obs_ns - self._run_start_ns) / NS_PER_S
        if age <= p.float_hold_s and run_at_last >= p.time_to_float_s:
            return RtkState(PositionType.NARROW_FLOAT, diff_age, station)
        if age <= p.psrdiff_timeout_s:
            return RtkState(PositionType.PSRDIFF, diff_age, station)
        return RtkState(PositionType.SINGLE, 0.0, "")
