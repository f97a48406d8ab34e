"""Optical slip sensor (Kistler/Datron Correvit S350, SFII): volts or CAN values → velocities and slip angle.

The sensor measures the velocity of its mounting point over the ground, in its own axes. Its
outputs (*roles*, named as in the session configuration's ``[[optical]].channels``) are the
longitudinal velocity ``vx``, the lateral velocity ``vy``, the ``slip_angle`` ``atan2(vy, vx)``,
the total velocity ``speed`` and, on some models, a ``valid`` status output. Each role comes on
its own analog output with a configured scaling (e.g. ±10 V ↔ ±40° for the angle, 25 km/h per V
for velocities) read by the DAQ, or as a CAN signal decoded through the DBC and the CAN role map
(:mod:`drivers.can`). Either way this module gives :class:`OpticalSample` arrays:

- scaling per role to SI, then ``invert`` per role (the Correvit's sign convention for the
  lateral velocity and angle can be opposite to ISO 8855: y left, angle positive to the left);
- the zero (angle offset) calibration in force is removed, as a rotation of the velocity vector
  (a yaw misalignment of the head rotates vx/vy as well as the angle); the applied value is kept
  in the result (``zero_offset_applied_rad``) so the recorder records it with the data;
- samples below the sensor's minimum speed, marked invalid by its status output (or by the CAN
  quality bit / a flagged frame), or non-finite are invalid: NaN in every quantity and False in
  ``valid`` — never zero.

A ``body`` sensor measures the body velocity at its mount; :func:`transfer_to_point` moves it to
the CG (or any body point) with the yaw rate, through :func:`vsccore.angles.transfer_velocity`.
A ``wheel`` sensor sits on a wheel-hub bracket and steers with the wheel: its angle is the tyre
slip angle and its velocities are in wheel axes; :func:`transfer_to_point` rotates them by the
road-wheel angle into vehicle axes first.

Configuration: :meth:`OpticalSensorSpec.from_config` takes the session configuration's
``[[optical]]`` table (``OpticalSensorConfig.model_dump()``) and the zero offset in force
(``[calibration].optical_zero_deg[name]``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from vsccore.angles import sideslip_from_velocity, transfer_velocity, wrap_pi
from vsccore.errors import ConfigError

from .analog import LinearScaling, Scaling, scaling_from_dict, scaling_to_dict, si_factor
from .daq.base import DaqBlock

if TYPE_CHECKING:
    from .can.roles import DecodedFrame, RoleMap
    from .can.vector_decode import RoleSeries

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

WHEEL_IDS = ("fl", "fr", "rl", "rr")
"""Wheel identifiers, the same order as everywhere in the project."""

S350_MIN_SPEED_MPS = 0.5 / 3.6
"""Correvit S350 minimum speed (0.5 km/h) below which its outputs are not valid."""

_FRAME_LEVEL_FLAGS = 1 | 2 | 4 | 8 | 16
"""``drivers.can.checks.FrameFlag.frame_level()`` as an int (UNKNOWN_ID … DECODE_ERROR)."""


class OpticalRole(StrEnum):
    """What one output of the sensor carries (the names of the session configuration)."""

    VX = "vx"
    """Longitudinal velocity (m/s)."""
    VY = "vy"
    """Lateral velocity (m/s)."""
    SLIP_ANGLE = "slip_angle"
    """Slip angle (rad)."""
    SPEED = "speed"
    """Total velocity (m/s)."""
    VALID = "valid"
    """Validity/status output (volts on the DAQ, the quality bit or a truthy value on CAN)."""


class SensorKind(StrEnum):
    BODY = "body"
    WHEEL = "wheel"


@dataclass(frozen=True, slots=True)
class OpticalChannel:
    """One role of a sensor: where it comes from and how it is scaled.

    ``channel`` is the logical DAQ channel name (analog path) and ``scaling`` its volts → SI
    conversion (not needed for ``valid``); ``can_role`` is the CAN role name in the CAN role map
    (CAN path: already SI, ``scaling`` unused). ``invert`` flips the sign on either path.
    """

    role: OpticalRole
    channel: str | None = None
    scaling: Scaling | None = None
    invert: bool = False
    can_role: str | None = None

    def __post_init__(self) -> None:
        if (self.channel is None) == (self.can_role is None):
            raise ConfigError(
                f"optical role {self.role.value!r}: give exactly one of a DAQ channel or a CAN role, "
                f"got channel={self.channel!r}, can_role={self.can_role!r}"
            )


@dataclass(frozen=True, slots=True)
class OpticalSensorSpec:
    """One optical sensor: identity, mounting, per-role scaling and validity rules.

    ``mount_xyz_m`` is the measuring point from the CG in vehicle axes (x forward, y left, z up).
    ``zero_offset_rad`` is the angle-offset calibration in force (subtracted from the angle).
    ``status_threshold_v``: the ``valid`` output means "valid" at or above this voltage (below
    it when ``status_valid_high`` is False).
    """

    name: str
    kind: SensorKind
    mount_xyz_m: tuple[float, float, float]
    channels: tuple[OpticalChannel, ...]
    min_speed_mps: float = S350_MIN_SPEED_MPS
    zero_offset_rad: float = 0.0
    wheel: str | None = None
    status_threshold_v: float = 2.5
    status_valid_high: bool = True
    model: str = "S350"

    def __post_init__(self) -> None:
        where = f"optical sensor {self.name!r}"
        if not self.name:
            raise ConfigError("optical sensor needs a name")
        if len(self.mount_xyz_m) != 3 or not all(math.isfinite(float(v)) for v in self.mount_xyz_m):
            raise ConfigError(f"{where}: mount_xyz_m must be three finite numbers, got {self.mount_xyz_m!r}")
        if self.kind is SensorKind.WHEEL and self.wheel not in WHEEL_IDS:
            raise ConfigError(f"{where}: a wheel sensor needs wheel in {WHEEL_IDS}, got {self.wheel!r}")
        if self.kind is SensorKind.BODY and self.wheel is not None:
            raise ConfigError(f"{where}: a body sensor has no wheel, got {self.wheel!r}")
        if not (math.isfinite(self.min_speed_mps) and self.min_speed_mps >= 0):
            raise ConfigError(f"{where}: min_speed_mps must be >= 0, got {self.min_speed_mps}")
        if not math.isfinite(self.zero_offset_rad):
            raise ConfigError(f"{where}: zero_offset_rad must be finite, got {self.zero_offset_rad}")
        if not math.isfinite(self.status_threshold_v):
            raise ConfigError(f"{where}: status_threshold_v must be finite, got {self.status_threshold_v}")
        roles = [c.role for c in self.channels]
        dup = sorted({r.value for r in roles if roles.count(r) > 1})
        if dup:
            raise ConfigError(f"{where}: roles given more than once: {dup}")
        have = set(roles)
        if not (
            {OpticalRole.VX, OpticalRole.VY} <= have
            or {OpticalRole.SLIP_ANGLE, OpticalRole.SPEED} <= have
            or {OpticalRole.SLIP_ANGLE, OpticalRole.VX} <= have
        ):
            raise ConfigError(
                f"{where}: needs roles vx+vy, slip_angle+speed or slip_angle+vx to determine the velocity; "
                f"got {sorted(r.value for r in have)}"
            )
        for c in self.channels:
            if c.channel is not None and c.role is not OpticalRole.VALID and c.scaling is None:
                raise ConfigError(f"{where}: role {c.role.value!r} on DAQ channel {c.channel!r} has no scaling")

    @property
    def mount_xy(self) -> tuple[float, float]:
        return float(self.mount_xyz_m[0]), float(self.mount_xyz_m[1])

    @property
    def roles(self) -> frozenset[OpticalRole]:
        return frozenset(c.role for c in self.channels)

    @property
    def daq_channels(self) -> tuple[str, ...]:
        """Logical DAQ channel names this sensor reads (analog path)."""
        return tuple(c.channel for c in self.channels if c.channel is not None)

    @property
    def can_roles(self) -> dict[str, OpticalRole]:
        """CAN role name → optical role (CAN path)."""
        return {c.can_role: c.role for c in self.channels if c.can_role is not None}

    def channel_for(self, role: OpticalRole) -> OpticalChannel | None:
        for c in self.channels:
            if c.role is role:
                return c
        return None

    def to_dict(self) -> dict[str, Any]:
        """SI form for the session metadata (the recorder stores it with the raw volts)."""
        channels: dict[str, Any] = {}
        for c in self.channels:
            d: dict[str, Any] = {"invert": c.invert}
            if c.channel is not None:
                d["channel"] = c.channel
            if c.can_role is not None:
                d["can_role"] = c.can_role
            if c.scaling is not None:
                d["scaling"] = scaling_to_dict(c.scaling)
            channels[c.role.value] = d
        return {
            "name": self.name,
            "model": self.model,
            "kind": self.kind.value,
            "wheel": self.wheel,
            "mount_xyz_m": [float(v) for v in self.mount_xyz_m],
            "min_speed_mps": self.min_speed_mps,
            "zero_offset_rad": self.zero_offset_rad,
            "status_threshold_v": self.status_threshold_v,
            "status_valid_high": self.status_valid_high,
            "channels": channels,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "optical") -> OpticalSensorSpec:
        """Build from the SI mapping of :meth:`to_dict` (what a session file's metadata holds).

        Edge units are accepted too: ``min_speed_kmh`` instead of ``min_speed_mps`` and
        ``zero_offset_deg`` instead of ``zero_offset_rad``; channel scalings take a ``unit`` (see
        :func:`drivers.analog.scaling_from_dict`).
        """
        try:
            name = str(d["name"])
            w = f"{where}.{name}"
            channels = []
            for role_name, cd in d["channels"].items():
                role = _role(role_name, f"{w}.channels")
                scaling = (
                    scaling_from_dict(cd["scaling"], f"{w}.channels.{role_name}.scaling") if "scaling" in cd else None
                )
                channels.append(
                    OpticalChannel(
                        role,
                        _opt_str(cd.get("channel")),
                        scaling,
                        bool(cd.get("invert", False)),
                        _opt_str(cd.get("can_role")),
                    )
                )
            if "min_speed_kmh" in d:
                min_speed = float(d["min_speed_kmh"]) / 3.6
            else:
                min_speed = float(d.get("min_speed_mps", S350_MIN_SPEED_MPS))
            if "zero_offset_deg" in d:
                zero = math.radians(float(d["zero_offset_deg"]))
            else:
                zero = float(d.get("zero_offset_rad", 0.0))
            mx, my, mz = (float(v) for v in d.get("mount_xyz_m", (0.0, 0.0, 0.0)))
            return cls(
                name=name,
                kind=SensorKind(str(d.get("kind", "body"))),
                mount_xyz_m=(mx, my, mz),
                channels=tuple(channels),
                min_speed_mps=min_speed,
                zero_offset_rad=zero,
                wheel=d.get("wheel"),
                status_threshold_v=float(d.get("status_threshold_v", 2.5)),
                status_valid_high=bool(d.get("status_valid_high", True)),
                model=str(d.get("model", "S350")),
            )
        except ConfigError:
            raise
        except KeyError as exc:
            raise ConfigError(f"{where}: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"{where}: invalid optical sensor configuration: {exc}") from None

    @classmethod
    def from_config(
        cls, cfg: Mapping[str, Any], *, zero_offset_deg: float = 0.0, where: str = "optical"
    ) -> OpticalSensorSpec:
        """Build from a session configuration ``[[optical]]`` table (``OpticalSensorConfig.model_dump()``).

        Per channel: ``physical = (volts − offset_v) · scale_per_v`` in ``unit`` (km/h, m/s, deg,
        rad …), converted to SI; ``invert`` flips the sign; the ``valid`` channel is valid at or
        above ``valid_above_v`` (default 2.5 V). A channel gives ``daq_channel`` (analog) or
        ``can_role`` (a role of the CAN role map, already SI). ``mount`` is ``{x_m, y_m, z_m}``.
        ``zero_offset_deg`` is the calibration in force (``[calibration].optical_zero_deg[name]``).

        Raises:
            ConfigError: a missing key, an unknown role or unit, or an inconsistent sensor (the
                message names ``where``, the sensor and the key).
        """
        try:
            name = str(cfg["name"])
            w = f"{where}.{name}"
            channels: list[OpticalChannel] = []
            threshold = 2.5
            for role_name, cd in cfg["channels"].items():
                role = _role(role_name, f"{w}.channels")
                cw = f"{w}.channels.{role.value}"
                daq = _opt_str(cd.get("daq_channel"))
                can_role = _opt_str(cd.get("can_role"))
                invert = bool(cd.get("invert", False))
                scaling: Scaling | None = None
                if role is OpticalRole.VALID:
                    if cd.get("valid_above_v") is not None:
                        threshold = float(cd["valid_above_v"])
                elif daq is not None:
                    unit = str(cd.get("unit", "km/h"))
                    _, si_unit = si_factor(unit, f"{cw}.unit")
                    want = "rad" if role is OpticalRole.SLIP_ANGLE else "m/s"
                    if si_unit != want:
                        raise ConfigError(f"{cw}.unit: {unit!r} is not a unit of {want} (role {role.value!r})")
                    scale = float(cd.get("scale_per_v", 1.0))
                    offset_v = float(cd.get("offset_v", 0.0))
                    scaling = LinearScaling.from_unit(scale, -offset_v * scale, unit, f"{cw}.scale_per_v")
                channels.append(OpticalChannel(role, daq, scaling, invert, can_role))
            mount = cfg.get("mount") or {}
            mount_xyz = (float(mount.get("x_m", 0.0)), float(mount.get("y_m", 0.0)), float(mount.get("z_m", 0.0)))
            return cls(
                name=name,
                kind=SensorKind(str(cfg.get("kind", "body"))),
                mount_xyz_m=mount_xyz,
                channels=tuple(channels),
                min_speed_mps=float(cfg.get("min_speed_kmh", 0.5)) / 3.6,
                zero_offset_rad=math.radians(float(zero_offset_deg)),
                wheel=_opt_str(cfg.get("wheel")),
                status_threshold_v=threshold,
                status_valid_high=True,
                model=str(cfg.get("model", "S350")),
            )
        except ConfigError as exc:
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None
        except KeyError as exc:
            raise ConfigError(f"{where}: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"{where}: invalid optical sensor configuration: {exc}") from None


def _opt_str(v: Any) -> str | None:
    return None if v is None else str(v)


def _role(name: Any, where: str) -> OpticalRole:
    try:
        return OpticalRole(str(name))
    except ValueError:
        raise ConfigError(
            f"{where}: unknown optical role {name!r}; roles: {[r.value for r in OpticalRole]}"
        ) from None


def correvit_channels(
    prefix: str,
    *,
    v_per_kmh: float = 0.04,
    angle_deg_per_v: float = 4.0,
    roles: Sequence[OpticalRole] = (OpticalRole.VX, OpticalRole.VY, OpticalRole.SLIP_ANGLE, OpticalRole.SPEED),
    status: bool = True,
    invert: Sequence[OpticalRole] = (),
) -> tuple[OpticalChannel, ...]:
    """Channels of a Correvit with the usual analog output scaling, named ``{prefix}_{role}``.

    Velocities ``v_per_kmh`` volts per km/h (0.04 V per km/h: 10 V ↔ 250 km/h), angle
    ``angle_deg_per_v`` degrees per volt (4°/V: ±10 V ↔ ±40°).
    """
    out = []
    for role in roles:
        if role is OpticalRole.SLIP_ANGLE:
            scaling: Scaling = LinearScaling.from_unit(angle_deg_per_v, 0.0, "deg")
        elif role is OpticalRole.VALID:
            continue
        else:
            scaling = LinearScaling.from_unit(1.0 / v_per_kmh, 0.0, "km/h")
        out.append(OpticalChannel(role, f"{prefix}_{role.value}", scaling, role in invert))
    if status:
        out.append(OpticalChannel(OpticalRole.VALID, f"{prefix}_{OpticalRole.VALID.value}"))
    return tuple(out)


@dataclass(frozen=True, slots=True)
class OpticalSample:
    """Physical arrays of one sensor (SI, sensor axes after the zero-offset correction).

    For a wheel sensor, ``vx``/``vy`` are in wheel axes and ``slip_angle`` is the tyre slip angle.
    Invalid samples are NaN in every quantity and False in ``valid``. ``first_sample_index`` is
    the DAQ sample index of element 0 (analog path); ``time_ns`` the per-sample times (CAN path:
    the receive times of the frames).
    """

    sensor: str
    vx: FloatArray
    vy: FloatArray
    slip_angle: FloatArray
    speed: FloatArray
    valid: BoolArray
    zero_offset_applied_rad: float
    status_ok: BoolArray | None = None
    first_sample_index: int | None = None
    time_ns: IntArray | None = None

    def __len__(self) -> int:
        return int(self.valid.shape[0])

    def records(self) -> list[dict[str, Any]]:
        """One dict per sample in the fields of the ``/optical/<sensor>`` topic (NaN → None)."""

        def num(a: FloatArray) -> list[float | None]:
            return [None if not math.isfinite(x) else x for x in a.tolist()]

        n = len(self)
        k0 = self.first_sample_index
        idx: list[int | None] = [None] * n if k0 is None else list(range(k0, k0 + n))
        cols = (num(self.vx), num(self.vy), num(self.speed), num(self.slip_angle), self.valid.tolist())
        return [
            {"sample_index": i, "vx_mps": a, "vy_mps": b, "speed_mps": c, "slip_angle_rad": d, "valid": bool(e)}
            for i, a, b, c, d, e in zip(idx, *cols, strict=True)
        ]


def _status_ok(spec: OpticalSensorSpec, volts: FloatArray) -> BoolArray:
    with np.errstate(invalid="ignore"):
        high = volts >= spec.status_threshold_v
    ok = high if spec.status_valid_high else ~high
    return np.asarray(ok & np.isfinite(volts), dtype=np.bool_)


def _assemble(
    spec: OpticalSensorSpec,
    phys: Mapping[OpticalRole, FloatArray],
    status_ok: BoolArray | None,
    first_sample_index: int | None,
    time_ns: IntArray | None,
) -> OpticalSample:
    """Derive the missing roles, remove the zero offset, apply validity."""
    n = {a.shape for a in phys.values()}
    if status_ok is not None:
        n.add(status_ok.shape)
    if len(n) != 1 or len(next(iter(n))) != 1:
        raise ConfigError(f"optical sensor {spec.name!r}: role arrays must be 1-D of one length, got shapes {n}")
    angle_m = phys.get(OpticalRole.SLIP_ANGLE)
    vel_m = phys.get(OpticalRole.SPEED)
    if OpticalRole.VX in phys and OpticalRole.VY in phys:
        vx, vy = phys[OpticalRole.VX], phys[OpticalRole.VY]
    elif angle_m is not None and vel_m is not None:
        vx, vy = vel_m * np.cos(angle_m), vel_m * np.sin(angle_m)
    elif angle_m is not None and OpticalRole.VX in phys:
        vx = phys[OpticalRole.VX]
        vy = vx * np.tan(angle_m)
    else:
        raise ConfigError(
            f"optical sensor {spec.name!r}: got roles {sorted(r.value for r in phys)}, "
            "need vx+vy, slip_angle+speed or slip_angle+vx"
        )
    angle = angle_m if angle_m is not None else sideslip_from_velocity(vx, vy)
    speed = vel_m if vel_m is not None else np.hypot(vx, vy)

    z = spec.zero_offset_rad
    if z != 0.0:
        c, s = math.cos(z), math.sin(z)
        vx, vy = c * vx + s * vy, -s * vx + c * vy
        angle = wrap_pi(angle - z)

    with np.errstate(invalid="ignore"):
        valid = np.isfinite(vx) & np.isfinite(vy) & np.isfinite(angle) & np.isfinite(speed)
        valid &= speed >= spec.min_speed_mps
    if status_ok is not None:
        valid &= status_ok
    nan = np.float64(np.nan)
    return OpticalSample(
        sensor=spec.name,
        vx=np.where(valid, vx, nan),
        vy=np.where(valid, vy, nan),
        slip_angle=np.where(valid, angle, nan),
        speed=np.where(valid, speed, nan),
        valid=np.asarray(valid, dtype=np.bool_),
        zero_offset_applied_rad=z,
        status_ok=status_ok,
        first_sample_index=first_sample_index,
        time_ns=time_ns,
    )


# --- analog path ------------------------------------------------------------------------------


def convert_volts(
    spec: OpticalSensorSpec, volts: Mapping[str, npt.ArrayLike], *, first_sample_index: int | None = None
) -> OpticalSample:
    """Convert the sensor's DAQ channels (``{DAQ channel name: volts}``) to physical arrays.

    Raises:
        ConfigError: a DAQ channel of the spec is missing from ``volts``, or the sensor has no
            DAQ channels (it is read over CAN).
    """
    phys: dict[OpticalRole, FloatArray] = {}
    status_ok: BoolArray | None = None
    daq = [c for c in spec.channels if c.channel is not None]
    if not daq:
        raise ConfigError(f"optical sensor {spec.name!r} has no DAQ channels (it is read over CAN)")
    for ch in daq:
        assert ch.channel is not None
        if ch.channel not in volts:
            raise ConfigError(
                f"optical sensor {spec.name!r}: DAQ channel {ch.channel!r} ({ch.role.value}) not in the data; "
                f"channels: {sorted(volts)}"
            )
        v = np.asarray(volts[ch.channel], dtype=np.float64)
        if ch.role is OpticalRole.VALID:
            status_ok = _status_ok(spec, v)
            continue
        assert ch.scaling is not None  # checked by the spec
        x = ch.scaling.to_value(v)
        phys[ch.role] = -x if ch.invert else x
    return _assemble(spec, phys, status_ok, first_sample_index, None)


def convert_block(spec: OpticalSensorSpec, block: DaqBlock) -> OpticalSample:
    """Convert one DAQ block (vectorised over all samples); ``first_sample_index`` is the block's."""
    volts = {c: block.channel(c) for c in spec.daq_channels}
    return convert_volts(spec, volts, first_sample_index=block.first_sample_index)


# --- CAN path ---------------------------------------------------------------------------------


def from_can(
    spec: OpticalSensorSpec,
    values: Mapping[str, npt.ArrayLike],
    *,
    time_ns: npt.ArrayLike | None = None,
) -> OpticalSample:
    """Build :class:`OpticalSample` arrays from SI values of a Correvit's CAN outputs, keyed by optical role.

    ``values`` maps optical role names (``"vx"``, ``"vy"``, ``"slip_angle"``, ``"speed"``,
    ``"valid"``) to equally long arrays (m/s, rad; ``valid`` truthy when valid). The spec's
    ``invert`` flags, zero offset and minimum speed apply exactly as on the analog path.
    :func:`from_role_series` and :class:`OpticalCanAssembler` call this after the DBC decoding.

    Raises:
        ConfigError: an unknown role name, or not enough roles to determine the velocity.
    """
    phys: dict[OpticalRole, FloatArray] = {}
    status_ok: BoolArray | None = None
    for key, arr in values.items():
        role = _role(key, f"optical sensor {spec.name!r}: CAN values")
        a = np.atleast_1d(np.asarray(arr, dtype=np.float64))
        if role is OpticalRole.VALID:
            with np.errstate(invalid="ignore"):
                truthy = np.isfinite(a) & (a != 0)
            status_ok = np.asarray(truthy if spec.status_valid_high else ~truthy & np.isfinite(a), dtype=np.bool_)
            continue
        ch = spec.channel_for(role)
        phys[role] = -a if (ch is not None and ch.invert) else a
    t = None if time_ns is None else np.atleast_1d(np.asarray(time_ns, dtype=np.int64))
    return _assemble(spec, phys, status_ok, None, t)


def _primary_can_role(spec: OpticalSensorSpec) -> tuple[str, OpticalRole]:
    """The CAN role whose frames clock the samples: the first of vx, slip_angle, speed, vy."""
    by_role = {r: name for name, r in spec.can_roles.items()}
    for role in (OpticalRole.VX, OpticalRole.SLIP_ANGLE, OpticalRole.SPEED, OpticalRole.VY):
        if role in by_role:
            return by_role[role], role
    raise ConfigError(f"optical sensor {spec.name!r} has no CAN roles (it is read through the DAQ)")


def _nearest_within(t_ref: IntArray, t: IntArray, max_skew_ns: int) -> npt.NDArray[np.intp]:
    """Index into ``t`` (sorted) of the row nearest each ``t_ref`` within ±max_skew_ns (ties: the earlier), or −1."""
    if t.size == 0:
        return np.full(t_ref.shape, -1, dtype=np.intp)
    j = np.searchsorted(t, t_ref, side="left")
    before = np.clip(j - 1, 0, t.size - 1)
    after = np.clip(j, 0, t.size - 1)
    d_before = np.where(j > 0, t_ref - t[before], np.iinfo(np.int64).max)
    d_after = np.where(j < t.size, t[after] - t_ref, np.iinfo(np.int64).max)
    pick = np.where(d_after < d_before, after, before)
    best = np.minimum(d_before, d_after)
    return np.where(best <= max_skew_ns, pick, -1).astype(np.intp)


def from_role_series(
    spec: OpticalSensorSpec, series: Mapping[str, RoleSeries], *, max_skew_ns: int = 5_000_000
) -> OpticalSample:
    """Optical samples from the CAN roles decoded offline (:class:`drivers.can.VectorRoleDecoder`).

    ``series`` is ``RoleBatch.roles`` (CAN role name → :class:`~drivers.can.vector_decode.RoleSeries`).
    One sample per frame of the primary role (the first of vx, slip_angle, speed, vy the sensor
    has on CAN), at that frame's timestamp; the other roles (carried by other messages of the same
    output cycle) are taken from their frame nearest in time within ``max_skew_ns`` (default
    5 ms, half a 100 Hz cycle). A role with no frame that close, a flagged frame (counter,
    checksum …) or a quality bit saying "invalid" makes the sample invalid (NaN), never zero.

    Raises:
        ConfigError: the sensor has no CAN roles, or a CAN role of the spec is not in ``series``.
    """
    primary_name, _ = _primary_can_role(spec)
    missing = sorted(set(spec.can_roles) - set(series))
    if missing:
        raise ConfigError(
            f"optical sensor {spec.name!r}: CAN roles {missing} not decoded; roles present: {sorted(series)}"
        )
    prim = series[primary_name]
    t_ref = np.asarray(prim.timestamps_ns, dtype=np.int64)
    ok_all = np.ones(t_ref.shape, dtype=np.bool_)
    values: dict[str, FloatArray] = {}
    for can_role, role in spec.can_roles.items():
        s = series[can_role]
        ts = np.asarray(s.timestamps_ns, dtype=np.int64)
        order = np.argsort(ts, kind="stable")
        idx = _nearest_within(t_ref, ts[order], max_skew_ns)
        found = idx >= 0
        rows = order[np.where(found, idx, 0)] if ts.size else np.zeros(t_ref.shape, dtype=np.intp)
        vals = np.where(found, np.asarray(s.values, dtype=np.float64)[rows] if ts.size else np.nan, np.nan)
        flags = np.asarray(s.flags)[rows] if ts.size else np.zeros(t_ref.shape, dtype=np.uint16)
        ok = found & (flags == 0)
        ok_all &= ok
        if role is OpticalRole.VALID:
            vals = np.where(ok & np.isfinite(vals), vals, 0.0)
        values[role.value] = vals
    # Any flagged or missing contribution invalidates the sample (the status role does it too).
    sample = from_can(spec, values, time_ns=t_ref)
    return _invalidate(sample, ok_all)


def _invalidate(sample: OpticalSample, ok: BoolArray) -> OpticalSample:
    valid = sample.valid & ok
    nan = np.float64(np.nan)
    return OpticalSample(
        sensor=sample.sensor,
        vx=np.where(valid, sample.vx, nan),
        vy=np.where(valid, sample.vy, nan),
        slip_angle=np.where(valid, sample.slip_angle, nan),
        speed=np.where(valid, sample.speed, nan),
        valid=valid,
        zero_offset_applied_rad=sample.zero_offset_applied_rad,
        status_ok=sample.status_ok,
        first_sample_index=sample.first_sample_index,
        time_ns=sample.time_ns,
    )


@dataclass(frozen=True, slots=True)
class _Row:
    t_ns: int
    value: float
    ok: bool


@dataclass(slots=True)
class _Pending:
    """A primary-role frame waiting for the nearest frames of the other roles."""

    t_ns: int
    rows: dict[str, _Row | None] = field(default_factory=dict)
    """Resolved roles: the chosen row (None: none within the skew)."""


class OpticalCanAssembler:
    """Live counterpart of :func:`from_role_series`: decoded CAN frames in, optical samples out.

    Feed every :class:`~drivers.can.roles.DecodedFrame` of the bus (from
    :class:`~drivers.can.roles.RoleDecoder`) in receive order to :meth:`add`; it returns the
    samples that became complete (or None). A sample at a primary-role frame's time ``t`` is
    complete once, for every other role, a frame at or after ``t`` has been seen (so the nearest
    one is known) or the bus has moved past ``t + max_skew_ns``. Over the same frames the result
    equals :func:`from_role_series`. Call :meth:`flush` at the end of a stream.
    """

    def __init__(self, spec: OpticalSensorSpec, rolemap: RoleMap, *, max_skew_ns: int = 5_000_000) -> None:
        """``rolemap`` is the CAN role map the frames are decoded with (``RoleDecoder.rolemap``).

        Raises:
            ConfigError: the sensor has no CAN roles, or one is not in the role map.
        """
        self._spec = spec
        self._primary, _ = _primary_can_role(spec)
        self._roles = spec.can_roles
        missing = sorted(r for r in self._roles if r not in rolemap.role_names)
        if missing:
            raise ConfigError(
                f"optical sensor {spec.name!r}: CAN roles {missing} are not in the CAN role map; "
                f"mapped roles: {sorted(rolemap.role_names)}"
            )
        # roles of each message: a frame flagged as a whole (length, checksum, counter) still
        # counts as a row of each, with no value, exactly as the vectorised decoder keeps it
        self._by_message: dict[str, list[str]] = {}
        for r in self._roles:
            self._by_message.setdefault(rolemap.role(r).message, []).append(r)
        self._skew = max_skew_ns
        self._last: dict[str, _Row] = {}
        self._pending: list[_Pending] = []

    @property
    def waiting(self) -> int:
        """Samples waiting for frames of their other roles."""
        return len(self._pending)

    def add(self, frame: DecodedFrame) -> OpticalSample | None:
        """Take one decoded frame; return the samples it completed (None if none)."""
        frame_ok = (int(frame.flags) & _FRAME_LEVEL_FLAGS) == 0
        if frame_ok:
            rows = {
                s.role: _Row(s.timestamp_ns, float(s.value), int(s.flags) == 0)
                for s in frame.samples
                if s.role in self._roles
            }
        else:
            roles = self._by_message.get(frame.message or "", [])
            rows = {r: _Row(frame.timestamp_ns, math.nan, False) for r in roles}
        # The primary role first, so the other roles of the same frame resolve its new sample.
        prim = rows.get(self._primary)
        if prim is not None:
            self._take(self._primary, prim)
            p = _Pending(prim.t_ns, {self._primary: prim})
            for role, last in self._last.items():
                if role != self._primary and last.t_ns >= prim.t_ns:  # same-time frame already seen
                    p.rows[role] = last if last.t_ns - prim.t_ns <= self._skew else None
            self._pending.append(p)
        for role, row in rows.items():
            if role != self._primary:
                self._take(role, row)
        return self._emit(frame.timestamp_ns, final=False)

    def flush(self) -> OpticalSample | None:
        """Complete every waiting sample with what has been seen (call at the end of a stream)."""
        return self._emit(None, final=True)

    def _take(self, role: str, row: _Row) -> None:
        last = self._last.get(role)
        before = last if last is not None and last.t_ns < row.t_ns else None
        for p in self._pending:
            if role not in p.rows and row.t_ns >= p.t_ns:
                b = before if before is not None and before.t_ns < p.t_ns else None
                p.rows[role] = self._nearer(p.t_ns, b, row)
        self._last[role] = row

    def _nearer(self, t_ref: int, before: _Row | None, after: _Row | None) -> _Row | None:
        """The row nearest ``t_ref`` within the skew (ties: the earlier), as :func:`_nearest_within`."""
        best: _Row | None = None
        for r in (before, after):
            if r is not None and abs(r.t_ns - t_ref) <= self._skew and (
                best is None or abs(r.t_ns - t_ref) < abs(best.t_ns - t_ref)
            ):
                best = r
        return best

    def _emit(self, now_ns: int | None, *, final: bool) -> OpticalSample | None:
        done: list[dict[str, _Row | None]] = []
        times: list[int] = []
        keep: list[_Pending] = []
        for p in self._pending:
            expired = final or (now_ns is not None and now_ns > p.t_ns + self._skew)
            if len(p.rows) < len(self._roles) and not expired:
                keep.append(p)
                continue
            rows = dict(p.rows)
            for role in self._roles:
                if role not in rows:  # no frame at or after t: the last one before may be near enough
                    last = self._last.get(role)
                    rows[role] = self._nearer(p.t_ns, last if last is not None and last.t_ns < p.t_ns else None, None)
            done.append(rows)
            times.append(p.t_ns)
        self._pending = keep
        if not done:
            return None
        ok = np.ones(len(done), dtype=np.bool_)
        values: dict[str, list[float]] = {role.value: [] for role in self._roles.values()}
        for i, rows in enumerate(done):
            for can_role, role in self._roles.items():
                r = rows[can_role]
                good = r is not None and r.ok
                ok[i] &= good
                if role is OpticalRole.VALID:
                    values[role.value].append(r.value if (r is not None and good) else 0.0)
                else:
                    values[role.value].append(r.value if r is not None else math.nan)
        arrays = {k: np.asarray(v, dtype=np.float64) for k, v in values.items()}
        sample = from_can(self._spec, arrays, time_ns=np.asarray(times, dtype=np.int64))
        return _invalidate(sample, ok)


def concatenate(samples: Iterable[OpticalSample]) -> OpticalSample:
    """Join consecutive samples of one sensor (e.g. the results of :meth:`OpticalCanAssembler.add`)."""
    items = list(samples)
    if not items:
        raise ValueError("concatenate needs at least one OpticalSample")
    names = {s.sensor for s in items}
    if len(names) != 1:
        raise ConfigError(f"cannot concatenate samples of different sensors {sorted(names)}")

    def cat(name: str) -> Any:
        parts = [getattr(s, name) for s in items]
        if any(p is None for p in parts):
            return None
        return np.concatenate(parts)

    first = items[0]
    return OpticalSample(
        sensor=first.sensor,
        vx=cat("vx"),
        vy=cat("vy"),
        slip_angle=cat("slip_angle"),
        speed=cat("speed"),
        valid=cat("valid"),
        zero_offset_applied_rad=first.zero_offset_applied_rad,
        status_ok=cat("status_ok"),
        first_sample_index=first.first_sample_index,
        time_ns=cat("time_ns"),
    )


# --- transfer to other body points --------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PointVelocity:
    """Velocity of a body point in vehicle axes and its sideslip angle."""

    vx: FloatArray
    vy: FloatArray
    sideslip: FloatArray


def to_vehicle_axes(
    sample: OpticalSample, spec: OpticalSensorSpec, steer_angle: npt.ArrayLike | None = None
) -> tuple[FloatArray, FloatArray]:
    """The sensor's velocity in vehicle axes.

    A body sensor already measures in vehicle axes. A wheel sensor measures in wheel axes, rotated
    by the road-wheel steering angle ``steer_angle`` (rad, positive to the left; 0 for an unsteered
    wheel), which must then be given.
    """
    if spec.kind is SensorKind.BODY:
        return sample.vx, sample.vy
    if steer_angle is None:
        raise ConfigError(
            f"optical sensor {spec.name!r} is on wheel {spec.wheel}: pass its road-wheel steering angle "
            "(0 for an unsteered wheel) to move its velocity into vehicle axes"
        )
    d = np.asarray(steer_angle, dtype=np.float64)
    c, s = np.cos(d), np.sin(d)
    return c * sample.vx - s * sample.vy, s * sample.vx + c * sample.vy


def transfer_to_point(
    sample: OpticalSample,
    spec: OpticalSensorSpec,
    yaw_rate: npt.ArrayLike,
    to_xy: tuple[float, float] = (0.0, 0.0),
    steer_angle: npt.ArrayLike | None = None,
) -> PointVelocity:
    """Velocity and sideslip at the body point ``to_xy`` (m from the CG; default the CG itself).

    ``yaw_rate`` (rad/s, positive turning left) must be sampled at the same instants as
    ``sample``. Invalid optical samples stay NaN.
    """
    vx, vy = to_vehicle_axes(sample, spec, steer_angle)
    vx_p, vy_p = transfer_velocity(vx, vy, np.asarray(yaw_rate, dtype=np.float64), spec.mount_xy, to_xy)
    return PointVelocity(vx_p, vy_p, sideslip_from_velocity(vx_p, vy_p))
