"""Volts → SI scaling of analog DAQ channels (brake-pressure transducers, optical-sensor outputs, …).

A scaling is a small pure conversion with a forward (:meth:`to_value`) and an inverse
(:meth:`to_volts`) direction, in the spirit of cantools' ``raw_to_scaled`` / ``scaled_to_raw``:

- :class:`LinearScaling`: ``value = scale · V + offset``;
- :class:`TableScaling`: piecewise-linear through (volts, value) points, volts strictly increasing
  and values strictly monotonic (so the inverse exists).

Scalings hold SI numbers only. Configuration files speak bar, km/h or deg: the ``from_unit`` /
``unit=`` constructors and :func:`scaling_from_dict` convert at that edge with :func:`si_factor`.
:func:`scaling_to_dict` gives the SI form that the recorder stores beside the raw volts, so a
session can be decoded again from raw alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from vsccore.errors import ConfigError

from .daq.base import DaqBlock

FloatArray = npt.NDArray[np.float64]

# unit → (factor to SI, SI unit). Purely multiplicative units only: an offset unit (°C) would make
# "V per unit" scale factors ambiguous.
_UNITS: dict[str, tuple[float, str]] = {
    "": (1.0, ""),
    "1": (1.0, ""),
    "V": (1.0, "V"),
    "Pa": (1.0, "Pa"),
    "kPa": (1e3, "Pa"),
    "MPa": (1e6, "Pa"),
    "mbar": (1e2, "Pa"),
    "bar": (1e5, "Pa"),
    "psi": (6894.757293168361, "Pa"),
    "m/s": (1.0, "m/s"),
    "km/h": (1.0 / 3.6, "m/s"),
    "mph": (0.44704, "m/s"),
    "rad": (1.0, "rad"),
    "deg": (math.pi / 180.0, "rad"),
    "rad/s": (1.0, "rad/s"),
    "deg/s": (math.pi / 180.0, "rad/s"),
    "m/s^2": (1.0, "m/s^2"),
    "g": (9.80665, "m/s^2"),
    "m": (1.0, "m"),
    "mm": (1e-3, "m"),
    "N": (1.0, "N"),
    "kN": (1e3, "N"),
    "Nm": (1.0, "Nm"),
}


def known_units() -> tuple[str, ...]:
    """Unit names accepted by :func:`si_factor`."""
    return tuple(u for u in _UNITS if u)


def si_factor(unit: str, where: str = "unit") -> tuple[float, str]:
    """Return ``(factor, si_unit)`` so that ``value_si = factor · value_in_unit``.

    Raises:
        ConfigError: the unit is unknown (the message names ``where`` and the known units).
    """
    try:
        return _UNITS[unit.strip()]
    except KeyError:
        raise ConfigError(f"{where}: unknown unit {unit!r}; known units: {', '.join(known_units())}") from None


def _as_float_array(x: npt.ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class LinearScaling:
    """``value = scale · volts + offset`` (SI units per volt, SI units at 0 V)."""

    scale: float
    offset: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale) and math.isfinite(self.offset)):
            raise ConfigError(f"linear scaling needs finite scale and offset, got {self.scale}, {self.offset}")
        if self.scale == 0.0:
            raise ConfigError("linear scaling scale must not be zero (the inverse would not exist)")

    @classmethod
    def from_unit(
        cls, scale_per_volt: float, offset: float = 0.0, unit: str = "", where: str = "scaling"
    ) -> LinearScaling:
        """Scale in ``unit`` per volt and offset in ``unit`` (e.g. 25 bar/V), converted to SI."""
        factor, _ = si_factor(unit, where)
        try:
            return cls(scale=scale_per_volt * factor, offset=offset * factor)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    @classmethod
    def from_points(
        cls, v0: float, value0: float, v1: float, value1: float, unit: str = "", where: str = "scaling"
    ) -> LinearScaling:
        """The line through (v0, value0) and (v1, value1), values in ``unit`` (e.g. −10 V ↔ −40 deg)."""
        if v0 == v1:
            raise ConfigError(f"{where}: the two voltage points must differ, got {v0} V twice")
        factor, _ = si_factor(unit, where)
        scale = (value1 - value0) / (v1 - v0)
        try:
            return cls(scale=scale * factor, offset=(value0 - scale * v0) * factor)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    def to_value(self, volts: npt.ArrayLike) -> FloatArray:
        """Volts → SI value."""
        return self.scale * _as_float_array(volts) + self.offset

    def to_volts(self, value: npt.ArrayLike) -> FloatArray:
        """SI value → volts (the inverse, used by the simulator)."""
        return (_as_float_array(value) - self.offset) / self.scale


@dataclass(frozen=True, slots=True)
class TableScaling:
    """Piecewise-linear volts → SI value through the points ``(volts[i], values[i])``.

    ``volts`` must be strictly increasing and ``values`` strictly monotonic (increasing or
    decreasing) so that the inverse is unique. Outside the table the end segments are extended
    linearly: a transducer driven past its calibrated span still reads a value, and saturation of
    the input itself is :class:`drivers.daq.health.ChannelHealth`'s business.
    """

    volts: tuple[float, ...]
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        v = np.asarray(self.volts, dtype=float)
        x = np.asarray(self.values, dtype=float)
        if v.ndim != 1 or v.shape != x.shape:
            raise ConfigError(
                f"table scaling needs equally long 1-D volts and values, got {len(self.volts)} and {len(self.values)}"
            )
        if v.size < 2:
            raise ConfigError(f"table scaling needs at least 2 points, got {v.size}")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(x))):
            raise ConfigError("table scaling points must be finite numbers")
        dv = np.diff(v)
        if np.any(dv <= 0):
            i = int(np.argmax(dv <= 0))
            raise ConfigError(
                f"table scaling volts must be strictly increasing: point {i + 1} ({v[i + 1]} V) "
                f"does not exceed point {i} ({v[i]} V)"
            )
        dx = np.diff(x)
        if not (np.all(dx > 0) or np.all(dx < 0)):
            raise ConfigError(f"table scaling values must be strictly monotonic, got {list(self.values)}")

    @classmethod
    def from_unit(
        cls, volts: Sequence[float], values: Sequence[float], unit: str = "", where: str = "scaling"
    ) -> TableScaling:
        """Table with values in ``unit`` (e.g. bar), converted to SI."""
        factor, _ = si_factor(unit, where)
        try:
            return cls(tuple(float(v) for v in volts), tuple(float(x) * factor for x in values))
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    def _increasing(self) -> tuple[FloatArray, FloatArray]:
        return np.asarray(self.volts, dtype=float), np.asarray(self.values, dtype=float)

    def to_value(self, volts: npt.ArrayLike) -> FloatArray:
        """Volts → SI value (linear extrapolation beyond the table)."""
        return _interp_extrapolate(_as_float_array(volts), *self._increasing())

    def to_volts(self, value: npt.ArrayLike) -> FloatArray:
        """SI value → volts (the inverse; linear extrapolation beyond the table)."""
        v, x = self._increasing()
        if x[0] > x[-1]:
            x, v = x[::-1], v[::-1]
        return _interp_extrapolate(_as_float_array(value), x, v)


def _interp_extrapolate(q: FloatArray, xp: FloatArray, fp: FloatArray) -> FloatArray:
    """np.interp with the first and last segments extended instead of clamped."""
    out = np.interp(q, xp, fp)
    lo = q < xp[0]
    hi = q > xp[-1]
    if np.any(lo):
        slope = (fp[1] - fp[0]) / (xp[1] - xp[0])
        out = np.where(lo, fp[0] + slope * (q - xp[0]), out)
    if np.any(hi):
        slope = (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
        out = np.where(hi, fp[-1] + slope * (q - xp[-1]), out)
    return np.asarray(out, dtype=np.float64)


Scaling = LinearScaling | TableScaling


def scaling_to_dict(scaling: Scaling) -> dict[str, Any]:
    """SI form of a scaling for the session metadata (read back with :func:`scaling_from_dict`)."""
    if isinstance(scaling, LinearScaling):
        return {"kind": "linear", "scale": scaling.scale, "offset": scaling.offset}
    return {"kind": "table", "volts": list(scaling.volts), "values": list(scaling.values)}


def scaling_from_dict(d: Mapping[str, Any], where: str = "scaling") -> Scaling:
    """Build a scaling from a configuration mapping; values are in ``d["unit"]`` (SI when absent).

    Accepted forms::

        {"kind": "linear", "scale": 25.0, "offset": 0.0, "unit": "bar"}      # 25 bar per volt
        {"kind": "linear", "points": [[-10, -40], [10, 40]], "unit": "deg"}  # two (V, value) points
        {"kind": "table", "volts": [0.5, 4.5], "values": [0, 250], "unit": "bar"}

    Raises:
        ConfigError: a key is missing or invalid (the message names ``where`` and the key).
    """
    unit = str(d.get("unit", ""))
    kind = d.get("kind", "linear")
    try:
        if kind == "linear":
            if "points" in d:
                (v0, x0), (v1, x1) = d["points"]
                return LinearScaling.from_points(float(v0), float(x0), float(v1), float(x1), unit, where)
            return LinearScaling.from_unit(float(d["scale"]), float(d.get("offset", 0.0)), unit, where)
        if kind == "table":
            return TableScaling.from_unit([float(v) for v in d["volts"]], [float(x) for x in d["values"]], unit, where)
    except ConfigError:
        raise
    except KeyError as exc:
        raise ConfigError(f"{where}: missing key {exc.args[0]!r} for a {kind} scaling") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: invalid {kind} scaling {dict(d)!r}: {exc}") from None
    raise ConfigError(f"{where}.kind: unknown scaling kind {kind!r}; expected 'linear' or 'table'")


@dataclass(frozen=True, slots=True)
class AnalogChannelSpec:
    """One scaled analog quantity: which DAQ channel (by its logical name) and how to scale it.

    ``unit`` is the SI unit of the scaled value, for display and the recorded schema.
    """

    name: str
    channel: str
    scaling: Scaling
    unit: str = ""
    description: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            raise ConfigError("analog channel spec needs a name")
        if not self.channel:
            raise ConfigError(f"analog channel {self.name!r}: DAQ channel name is empty")

    def decode(self, volts: npt.ArrayLike) -> FloatArray:
        """Volts of this channel → SI values."""
        return self.scaling.to_value(volts)

    def to_dict(self) -> dict[str, Any]:
        """SI form for the session metadata."""
        return {
            "name": self.name,
            "channel": self.channel,
            "unit": self.unit,
            "description": self.description,
            "scaling": scaling_to_dict(self.scaling),
        }

    @classmethod
    def from_config(cls, d: Mapping[str, Any], where: str = "daq.analog") -> AnalogChannelSpec:
        """From a session configuration ``[[daq.analog]]`` entry (``AnalogChannelConfig.model_dump()``).

        Linear: ``value = (volts − offset_v) · scale_per_v`` in ``unit``; table: ``table_v`` (volts,
        increasing) ↔ ``table_value`` (in ``unit``), piecewise linear. Values are converted to SI
        (bar → Pa, …) and :attr:`unit` is the SI unit.

        Raises:
            ConfigError: a missing key, an unknown unit or a bad table (names ``where`` and the channel).
        """
        try:
            name = str(d["name"])
            channel = str(d["daq_channel"])
        except KeyError as exc:
            raise ConfigError(f"{where}: missing key {exc.args[0]!r}") from None
        w = f"{where}.{name}"
        unit = str(d.get("unit", ""))
        _, si_unit = si_factor(unit, f"{w}.unit")
        scaling: Scaling
        try:
            if d.get("scale_per_v") is not None:
                scale = float(d["scale_per_v"])
                offset = -float(d.get("offset_v", 0.0)) * scale
                scaling = LinearScaling.from_unit(scale, offset, unit, f"{w}.scale_per_v")
            else:
                tv, tx = d.get("table_v"), d.get("table_value")
                if tv is None or tx is None:
                    raise ConfigError(f"{w}: give scale_per_v (linear) or table_v + table_value (table)")
                scaling = TableScaling.from_unit([float(v) for v in tv], [float(x) for x in tx], unit, f"{w}.table")
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"{w}: invalid scaling: {exc}") from None
        return cls(name=name, channel=channel, scaling=scaling, unit=si_unit, description=str(d.get("description", "")))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "analog") -> AnalogChannelSpec:
        """Build from a configuration mapping (``scaling`` as in :func:`scaling_from_dict`)."""
        try:
            name = str(d["name"])
            channel = str(d.get("channel", name))
            scaling_d = d["scaling"]
        except KeyError as exc:
            raise ConfigError(f"{where}: missing key {exc.args[0]!r}") from None
        scaling = scaling_from_dict(scaling_d, f"{where}.{name}.scaling")
        unit_in = str(scaling_d.get("unit", ""))
        si_unit = si_factor(unit_in, f"{where}.{name}.scaling.unit")[1] if unit_in else str(d.get("unit", ""))
        return cls(name=name, channel=channel, scaling=scaling, unit=si_unit, description=str(d.get("description", "")))


class AnalogDecoder:
    """Decodes DAQ blocks into named SI arrays for a fixed set of :class:`AnalogChannelSpec`."""

    def __init__(self, specs: Sequence[AnalogChannelSpec]) -> None:
        names = [s.name for s in specs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ConfigError(f"analog channel names must be unique, repeated: {dup}")
        self._specs = tuple(specs)

    @property
    def specs(self) -> tuple[AnalogChannelSpec, ...]:
        return self._specs

    def decode(self, block: DaqBlock) -> dict[str, FloatArray]:
        """Return ``{spec.name: SI values}`` for every spec, from the block's volts.

        Raises:
            ConfigError: a spec names a DAQ channel that the block does not carry.
        """
        return {s.name: s.decode(block.channel(s.channel)) for s in self._specs}


def brake_pressure_spec(
    name: str, channel: str, *, volts: tuple[float, float] = (0.5, 4.5), bar: tuple[float, float] = (0.0, 250.0)
) -> AnalogChannelSpec:
    """A ratiometric brake-pressure transducer (default 0.5–4.5 V ↔ 0–250 bar), scaled to Pa."""
    return AnalogChannelSpec(
        name=name,
        channel=channel,
        scaling=LinearScaling.from_points(volts[0], bar[0], volts[1], bar[1], "bar", f"{name}.scaling"),
        unit="Pa",
        description=f"brake pressure {name}",
    )
