"""Vehicle parameters of the simulated car (a C-class saloon by default) and their loading from TOML.

The field names are shared with the ``[vehicle]`` table of the rig's vehicle profile, so a profile
can drive the simulator unchanged (:meth:`VehicleParams.from_mapping`, :func:`load_vehicle_toml`).
Units are in the names; everything is SI except the steering-table angles (degrees of
steering-wheel angle, as engineers write them).
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from vsccore.errors import ConfigError

__all__ = ["GRAVITY", "VehicleParams", "load_vehicle_toml"]

GRAVITY = 9.80665
"""Standard gravity (m/s²)."""


@dataclass(frozen=True, slots=True)
class VehicleParams:
    """Mass, geometry, suspension, tyre and steering parameters (SI unless the name says otherwise).

    Cornering stiffnesses are per tyre at the tyre's static load. ``steering_ratio`` gives the
    steering-wheel-to-road-wheel ratio at the steering-wheel angles ``steering_ratio_swa_deg``
    (linear in between, held beyond the ends); a table with only non-negative breakpoints is
    mirrored to negative angles. The roll inertia is that of the body about the roll axis.
    """

    name: str = "C-class saloon"
    mass_kg: float = 1550.0
    yaw_inertia_kgm2: float = 2600.0
    roll_inertia_kgm2: float = 550.0
    wheelbase_m: float = 2.80
    cg_to_front_axle_m: float = 1.20
    cg_to_rear_axle_m: float = 1.60
    track_front_m: float = 1.56
    track_rear_m: float = 1.55
    cg_height_m: float = 0.55
    roll_axis_height_m: float = 0.10
    roll_stiffness_front_nm_per_rad: float = 55000.0
    roll_stiffness_rear_nm_per_rad: float = 40000.0
    roll_damping_nms_per_rad: float = 4000.0
    tyre_radius_m: float = 0.31
    cornering_stiffness_front_n_per_rad: float = 60000.0
    cornering_stiffness_rear_n_per_rad: float = 70000.0
    tyre_peak_mu: float = 1.0
    tyre_shape_c: float = 1.3
    tyre_curvature_e: float = -0.5
    steering_ratio_swa_deg: tuple[float, ...] = (-540.0, -360.0, -180.0, 0.0, 180.0, 360.0, 540.0)
    steering_ratio: tuple[float, ...] = (13.5, 14.6, 15.6, 16.0, 15.6, 14.6, 13.5)
    # Simulator-only parameters (not needed by calibration or analysis).
    swa_lock_deg: float = 540.0
    """Steering-wheel angle at full lock, either side (deg)."""
    body_width_m: float = 1.80
    """Body width without mirrors (sets the ISO 3888-1 lane widths and the cone check)."""
    front_overhang_m: float = 0.85
    """Body length ahead of the front axle (m)."""
    rear_overhang_m: float = 1.00
    """Body length behind the rear axle (m)."""
    drive_share_front: float = 0.0
    """Share of the drive force on the front axle (0 = rear-wheel drive, 1 = front-wheel drive)."""
    brake_share_front: float = 0.70
    """Share of the brake force on the front axle."""
    drag_area_m2: float = 0.62
    """Aerodynamic drag coefficient times frontal area (m²)."""
    rolling_resistance_coeff: float = 0.012
    """Rolling-resistance force per unit vertical load."""
    tyre_mu_load_sensitivity: float = 0.10
    """Fractional drop of the peak friction per unit of load above the static load (Pacejka pDy2 ≈ −0.1)."""
    tyre_stiffness_peak_load_ratio: float = 2.0
    """Load, as a multiple of the static load, at which the cornering stiffness peaks (C_α ∝ sin(2 atan(F_z/c)))."""
    tyre_long_slip_stiffness_per_load: float = 20.0
    """Longitudinal slip stiffness per unit load (N per unit slip per N), for the wheel-speed slip."""

    def __post_init__(self) -> None:
        self._validate()

    # ----------------------------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], *, section: str = "vehicle") -> VehicleParams:
        """Build parameters from a mapping such as the ``[vehicle]`` table of a TOML profile.

        Missing keys keep their defaults. Raises :class:`ConfigError` naming ``section.key`` for
        unknown keys (with a "did you mean" hint) and for values of the wrong type or range.
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"[{section}] must be a table, got {type(data).__name__}")
        known = {f.name: f for f in fields(cls)}
        unknown = [k for k in data if k not in known]
        if unknown:
            hints = []
            for key in unknown:
                close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.6)
                hints.append(f"{section}.{key}" + (f" (did you mean {close[0]!r}?)" if close else ""))
            raise ConfigError(f"unknown key(s) in [{section}]: " + ", ".join(hints))
        values: dict[str, Any] = {}
        for key, raw in data.items():
            values[key] = _coerce(section, key, raw)
        try:
            return cls(**values)
        except ConfigError as exc:
            if section == "vehicle":
                raise
            raise ConfigError(str(exc).replace("vehicle.", f"{section}.")) from None

    def replace(self, **changes: Any) -> VehicleParams:
        """Return a copy with some fields changed (validated like :meth:`from_mapping`)."""
        merged = {f.name: getattr(self, f.name) for f in fields(self)}
        merged.update(changes)
        return VehicleParams.from_mapping(merged)

    def as_dict(self) -> dict[str, Any]:
        """All fields as a plain dict (tuples kept as tuples)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    # ----------------------------------------------------------------------------------------
    @property
    def weight_n(self) -> float:
        """Weight m·g (N)."""
        return self.mass_kg * GRAVITY

    @property
    def static_axle_loads_n(self) -> tuple[float, float]:
        """Static (front, rear) axle loads (N)."""
        w = self.weight_n
        return w * self.cg_to_rear_axle_m / self.wheelbase_m, w * self.cg_to_front_axle_m / self.wheelbase_m

    @property
    def axle_cornering_stiffness_n_per_rad(self) -> tuple[float, float]:
        """(front, rear) axle cornering stiffness = 2 × per-tyre value (N/rad)."""
        return 2.0 * self.cornering_stiffness_front_n_per_rad, 2.0 * self.cornering_stiffness_rear_n_per_rad

    @property
    def understeer_gradient_rad_per_mps2(self) -> float:
        """Linear single-track understeer gradient K = m/L·(b/C_f − a/C_r) (rad per m/s²)."""
        cf, cr = self.axle_cornering_stiffness_n_per_rad
        a, b, L = self.cg_to_front_axle_m, self.cg_to_rear_axle_m, self.wheelbase_m
        return self.mass_kg / L * (b / cf - a / cr)

    # ----------------------------------------------------------------------------------------
    def _validate(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "name":
                if not isinstance(value, str):
                    raise ConfigError(f"vehicle.name must be a string, got {value!r}")
                continue
            if isinstance(value, tuple):
                if not all(_is_number(v) for v in value):
                    raise ConfigError(f"vehicle.{f.name} must be a list of numbers, got {value!r}")
                continue
            if not _is_number(value) or not math.isfinite(value):
                raise ConfigError(f"vehicle.{f.name} must be a finite number, got {value!r}")
            if f.name in _MAY_BE_ZERO_OR_NEGATIVE:
                continue
            if f.name in _NON_NEGATIVE:
                if value < 0.0:
                    raise ConfigError(f"vehicle.{f.name} must be >= 0, got {value!r}")
            elif value <= 0.0:
                raise ConfigError(f"vehicle.{f.name} must be > 0, got {value!r}")
        total = self.cg_to_front_axle_m + self.cg_to_rear_axle_m
        if abs(total - self.wheelbase_m) > 0.005:
            raise ConfigError(
                f"vehicle.cg_to_front_axle_m + vehicle.cg_to_rear_axle_m = {total:.3f} m must equal "
                f"vehicle.wheelbase_m = {self.wheelbase_m:.3f} m (within 5 mm)"
            )
        if self.roll_axis_height_m >= self.cg_height_m:
            raise ConfigError(
                f"vehicle.roll_axis_height_m ({self.roll_axis_height_m} m) must be below vehicle.cg_height_m "
                f"({self.cg_height_m} m)"
            )
        for share in ("drive_share_front", "brake_share_front"):
            if not 0.0 <= getattr(self, share) <= 1.0:
                raise ConfigError(f"vehicle.{share} must be within [0, 1], got {getattr(self, share)!r}")
        if not 0.0 < self.tyre_shape_c < 2.0:
            raise ConfigError(f"vehicle.tyre_shape_c must be within (0, 2), got {self.tyre_shape_c!r}")
        if self.tyre_curvature_e >= 1.0:
            raise ConfigError(f"vehicle.tyre_curvature_e must be < 1, got {self.tyre_curvature_e!r}")
        if self.tyre_mu_load_sensitivity >= 1.0:
            raise ConfigError(
                f"vehicle.tyre_mu_load_sensitivity must be < 1, got {self.tyre_mu_load_sensitivity!r}"
            )
        bp, ratio = self.steering_ratio_swa_deg, self.steering_ratio
        if len(bp) != len(ratio) or len(bp) == 0:
            raise ConfigError(
                f"vehicle.steering_ratio_swa_deg has {len(bp)} entries but vehicle.steering_ratio has "
                f"{len(ratio)}; they must have the same non-zero length"
            )
        if any(b2 <= b1 for b1, b2 in zip(bp, bp[1:], strict=False)):
            raise ConfigError(f"vehicle.steering_ratio_swa_deg must be strictly increasing, got {bp!r}")
        if any(not r > 1.0 for r in ratio):
            raise ConfigError(f"vehicle.steering_ratio values must be > 1, got {ratio!r}")
        # Moment of the suspended mass about the roll axis must not beat the roll springs, or the
        # body would fall over at rest.
        if self.roll_stiffness_front_nm_per_rad + self.roll_stiffness_rear_nm_per_rad <= (
            self.weight_n * (self.cg_height_m - self.roll_axis_height_m)
        ):
            raise ConfigError(
                "vehicle.roll_stiffness_front_nm_per_rad + vehicle.roll_stiffness_rear_nm_per_rad must exceed "
                "m·g·(cg_height_m − roll_axis_height_m), or the body is unstable in roll"
            )


_NON_NEGATIVE = frozenset(
    {
        "roll_axis_height_m",
        "front_overhang_m",
        "rear_overhang_m",
        "drag_area_m2",
        "rolling_resistance_coeff",
        "drive_share_front",
        "brake_share_front",
        "roll_damping_nms_per_rad",
    }
)
_MAY_BE_ZERO_OR_NEGATIVE = frozenset({"tyre_curvature_e", "tyre_mu_load_sensitivity"})
_TUPLE_FIELDS = frozenset({"steering_ratio_swa_deg", "steering_ratio"})


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _coerce(section: str, key: str, raw: Any) -> Any:
    """Turn a TOML/JSON value into the field's type, or raise ConfigError naming ``section.key``."""
    if key == "name":
        if not isinstance(raw, str):
            raise ConfigError(f"{section}.name must be a string, got {raw!r}")
        return raw
    if key in _TUPLE_FIELDS:
        if isinstance(raw, str | bytes) or not isinstance(raw, list | tuple):
            raise ConfigError(f"{section}.{key} must be a list of numbers, got {raw!r}")
        if not all(_is_number(v) for v in raw):
            raise ConfigError(f"{section}.{key} must be a list of numbers, got {raw!r}")
        return tuple(float(v) for v in raw)
    if not _is_number(raw):
        raise ConfigError(f"{section}.{key} must be a number, got {raw!r}")
    return float(raw)


def load_vehicle_toml(path: str | Path, *, section: str = "vehicle") -> VehicleParams:
    """Read ``[section]`` of a TOML file into :class:`VehicleParams`.

    Raises :class:`ConfigError` naming the file when it is missing, is not valid TOML, has no
    such table, or the table has unknown or invalid keys.
    """
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read vehicle file ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text ({exc.reason})") from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: {exc}") from exc
    table = doc.get(section)
    if table is None:
        raise ConfigError(f"{p}: no [{section}] table")
    try:
        return VehicleParams.from_mapping(table, section=section)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None
