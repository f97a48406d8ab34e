"""Session configuration and vehicle profile: TOML files validated with pydantic.

A *vehicle profile* describes the car (geometry, mass properties, tyres, steering ratio), where
the antennas and optical sensors sit, and the calibration values in force. A *session
configuration* says which devices to drive (receivers, correction relay, CAN, DAQ), where to
write, how to simulate (for simulated sessions) and the validation tolerances. A session file
either embeds the profile as ``[vehicle]``/``[antennas]``/… tables or names a profile file with
``vehicle_profile = "car.toml"``.

Units follow the key names: SI unless the name carries another unit (``_deg``, ``_kmh``,
``_bar``). Every problem is reported with its key path and, where possible, the line in the file.

Plausibility bounds, where physics or the hardware gives them (a value outside is a typing or
unit mistake, never a real set-up):

- mounting offsets (``mount_offset_deg``, ``true_mount_offset_deg``) and optical-sensor zeros
  within ±10°: the antenna baseline and the sensor are aligned with the car's axis by eye and
  tape measure to well under a degree; 10° off is a bracket on the wrong way round, and the
  small-angle calibrations (straight-run mean, circle fit) are not valid that far out;
- lever arms (``x_m``, ``y_m``, ``z_m`` of antennas and optical sensors, from the CG): within the
  envelope of a road vehicle that carries this rig, a car or van at most 7 m long, 2.55 m wide
  (the EU and US width limit) and 3 m tall, with the CG inside it: |x| ≤ 6 m, |y| ≤ 1.5 m
  (half the width plus a bracket), −1.5 m ≤ z ≤ 3 m (the ground is at −CG height, ≤ 1 m below);
- receiver baud rates from the set a NovAtel OEM7 port accepts (``SERIALCONFIG``), and ``ONTIME``
  log periods from the rates the receiver schedules: 50, 20, 10, 5, 4 and 2 Hz, or a whole number
  of seconds.
"""

from __future__ import annotations

import difflib
import importlib.resources
import re
import tomllib
from collections.abc import Mapping
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal, Self

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    SecretStr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from vsccore.errors import ConfigError

__all__ = [
    "AnalogChannelConfig",
    "AntennaConfig",
    "CalibrationConfig",
    "CanConfig",
    "ConfigProblem",
    "DaqChannelConfig",
    "DaqConfig",
    "OpticalSensorConfig",
    "ReceiverConfig",
    "RelayConfig",
    "SessionConfig",
    "VehicleConfig",
    "VehicleProfile",
    "load_profile",
    "load_session",
]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]

MAX_MOUNT_OFFSET_DEG = 10.0
"""Largest plausible antenna-baseline mounting offset or optical-sensor zero (see the module docstring)."""
LEVER_ARM_X_M = 6.0
LEVER_ARM_Y_M = 1.5
LEVER_ARM_Z_M = (-1.5, 3.0)
"""Lever-arm bounds from the CG in vehicle axes: a car or van ≤ 7 m long, 2.55 m wide, 3 m tall."""
NOVATEL_BAUDS = (300, 600, 900, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
"""Baud rates a NovAtel OEM7 serial port accepts (``SERIALCONFIG``, OEM7 Commands and Logs Reference)."""
NOVATEL_HIGH_RATE_PERIODS_S = (0.02, 0.05, 0.1, 0.2, 0.25, 0.5)
"""``ONTIME`` periods below 1 s that a NovAtel receiver schedules (50 Hz needs the receiver's option);
from 1 s up, any whole number of seconds."""


def _within_mount_offset(value: float) -> float:
    if not abs(value) <= MAX_MOUNT_OFFSET_DEG:  # also rejects NaN
        raise ValueError(
            f"{value!r}° is outside ±{MAX_MOUNT_OFFSET_DEG:g}°: a mounting misalignment this large is a "
            "mounting or unit mistake, not something to calibrate away"
        )
    return value


def _offsets_within_bounds(values: dict[str, float]) -> dict[str, float]:
    for name, value in values.items():
        try:
            _within_mount_offset(value)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
    return values


MountOffsetDeg = Annotated[float, AfterValidator(_within_mount_offset)]


# --------------------------------------------------------------------------------------------
# Vehicle profile
# --------------------------------------------------------------------------------------------


class VehicleConfig(_Model):
    """Geometry, mass properties, tyres and steering of the car (names shared with the simulator)."""

    name: str = "C-class saloon"
    mass_kg: Positive = 1550.0
    yaw_inertia_kgm2: Positive = 2600.0
    roll_inertia_kgm2: Positive = 550.0
    wheelbase_m: Positive = 2.80
    cg_to_front_axle_m: Positive = 1.20
    cg_to_rear_axle_m: Positive = 1.60
    track_front_m: Positive = 1.56
    track_rear_m: Positive = 1.55
    cg_height_m: Positive = 0.55
    roll_axis_height_m: NonNegative = 0.10
    roll_stiffness_front_nm_per_rad: Positive = 55000.0
    roll_stiffness_rear_nm_per_rad: Positive = 40000.0
    roll_damping_nms_per_rad: Positive = 4000.0
    tyre_radius_m: Positive = 0.31
    cornering_stiffness_front_n_per_rad: Positive = 60000.0
    cornering_stiffness_rear_n_per_rad: Positive = 70000.0
    tyre_peak_mu: Positive = 1.0
    tyre_shape_c: Positive = 1.3
    tyre_curvature_e: float = -0.5
    steering_ratio_swa_deg: tuple[float, ...] = (-540.0, -360.0, -180.0, 0.0, 180.0, 360.0, 540.0)
    steering_ratio: tuple[Positive, ...] = (13.5, 14.6, 15.6, 16.0, 15.6, 14.6, 13.5)

    @model_validator(mode="after")
    def _check_geometry(self) -> Self:
        total = self.cg_to_front_axle_m + self.cg_to_rear_axle_m
        if abs(total - self.wheelbase_m) > 0.005:
            raise ValueError(
                f"cg_to_front_axle_m + cg_to_rear_axle_m = {total:.3f} m must equal wheelbase_m = "
                f"{self.wheelbase_m:.3f} m (within 5 mm)"
            )
        if len(self.steering_ratio_swa_deg) != len(self.steering_ratio):
            raise ValueError(
                f"steering_ratio_swa_deg has {len(self.steering_ratio_swa_deg)} entries but steering_ratio "
                f"has {len(self.steering_ratio)}"
            )
        if len(self.steering_ratio) < 1:
            raise ValueError("steering_ratio needs at least one value")
        if any(b <= a for a, b in zip(self.steering_ratio_swa_deg, self.steering_ratio_swa_deg[1:], strict=False)):
            raise ValueError("steering_ratio_swa_deg must be strictly increasing")
        return self


class LeverArm(_Model):
    """A body point relative to the CG in vehicle axes (x forward, y left, z up), metres."""

    x_m: float
    y_m: float = 0.0
    z_m: float = 0.0

    @field_validator("x_m", "y_m", "z_m")
    @classmethod
    def _inside_the_car(cls, value: float, info: ValidationInfo) -> float:
        low, high = {
            "x_m": (-LEVER_ARM_X_M, LEVER_ARM_X_M),
            "y_m": (-LEVER_ARM_Y_M, LEVER_ARM_Y_M),
            "z_m": LEVER_ARM_Z_M,
        }[str(info.field_name)]
        if not low <= value <= high:  # also rejects NaN
            raise ValueError(
                f"{value!r} m from the CG is outside the car ({low:g} … {high:g} m; a car or van is at most "
                "7 m long, 2.55 m wide and 3 m tall)"
            )
        return value

    @property
    def xy(self) -> tuple[float, float]:
        return (self.x_m, self.y_m)


class AntennaConfig(_Model):
    """Roof antennas: A (main, near the CG) and B (auxiliary, behind it) on the longitudinal axis."""

    a: LeverArm = LeverArm(x_m=0.60, y_m=0.0, z_m=1.00)
    b: LeverArm = LeverArm(x_m=-0.98, y_m=0.0, z_m=1.00)
    baseline_length_m: Positive = 1.58
    baseline_tolerance_m: Positive = 0.03

    @model_validator(mode="after")
    def _check_baseline(self) -> Self:
        geometric = ((self.a.x_m - self.b.x_m) ** 2 + (self.a.y_m - self.b.y_m) ** 2) ** 0.5
        if abs(geometric - self.baseline_length_m) > 0.05:
            raise ValueError(
                f"baseline_length_m = {self.baseline_length_m} m but the lever arms a and b are "
                f"{geometric:.3f} m apart"
            )
        return self


class OpticalRole(StrEnum):
    """Outputs of a Correvit-type optical slip sensor."""

    VX = "vx"
    VY = "vy"
    SLIP_ANGLE = "slip_angle"
    SPEED = "speed"
    VALID = "valid"


class OpticalChannelConfig(_Model):
    """One analog output of the optical sensor: physical = (volts − offset_v) × scale, in ``unit``."""

    daq_channel: str | None = None
    can_role: str | None = None
    scale_per_v: float = 1.0
    offset_v: float = 0.0
    unit: str = "km/h"
    invert: bool = False
    valid_above_v: float | None = None

    @model_validator(mode="after")
    def _one_source(self) -> Self:
        if (self.daq_channel is None) == (self.can_role is None):
            raise ValueError("give exactly one of daq_channel or can_role")
        return self


class OpticalSensorConfig(_Model):
    """A Kistler/Datron Correvit S350 or SFII, on the body or on a wheel rim."""

    name: str
    model: Literal["S350", "SFII", "other"] = "S350"
    kind: Literal["body", "wheel"] = "body"
    wheel: Literal["fl", "fr", "rl", "rr"] | None = None
    mount: LeverArm
    min_speed_kmh: NonNegative = 0.5
    channels: dict[OpticalRole, OpticalChannelConfig]

    @model_validator(mode="after")
    def _wheel(self) -> Self:
        if self.kind == "wheel" and self.wheel is None:
            raise ValueError("a wheel-mounted optical sensor needs wheel = 'fl' | 'fr' | 'rl' | 'rr'")
        roles = set(self.channels)
        if not (OpticalRole.SLIP_ANGLE in roles or {OpticalRole.VX, OpticalRole.VY} <= roles):
            raise ValueError("channels must include slip_angle, or both vx and vy")
        on_can = sorted(str(r) for r, ch in self.channels.items() if ch.can_role is not None)
        if on_can:
            # refused rather than accepted and dropped: the recorder and the analysis read an optical sensor
            # from the DAQ only (its CAN frames, on a [[can]] bus, are still recorded raw)
            raise ValueError(
                f"optical sensor {self.name!r}: channels {on_can} name a can_role, but a CAN-output Correvit is not "
                "decoded into /optical yet (its frames are recorded raw on its [[can]] bus): wire its analog "
                "outputs to the DAQ (daq_channel)")
        return self


class ImuCalibrationConfig(_Model):
    """Accelerometer/gyroscope bias, scale and misalignment: measured = matrix · true + bias."""

    accel_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_matrix: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    gyro_bias_rps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_matrix: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    date: str | None = None
    source: str | None = None

    @field_validator("accel_matrix", "gyro_matrix")
    @classmethod
    def _three_by_three(cls, v: tuple[tuple[float, ...], ...]) -> tuple[tuple[float, ...], ...]:
        if len(v) != 3:
            raise ValueError("must be a 3×3 matrix (three rows of three numbers)")
        return v


class CalibrationConfig(_Model):
    """Calibration values in force (written by the ``rig calibrate-*`` commands)."""

    mount_offset_deg: MountOffsetDeg = 0.0
    mount_offset_u95_deg: NonNegative | None = None
    mount_offset_date: str | None = None
    mount_offset_session: str | None = None
    steering_ratio_swa_deg: tuple[float, ...] | None = None
    steering_ratio: tuple[Positive, ...] | None = None
    steering_ratio_date: str | None = None
    swa_zero_offset_deg: float = 0.0
    """Steering-angle sensor zero offset (SWA_measured = SWA_true + this), from ``rig calibrate-steering-ratio``."""
    swa_zero_offset_u95_deg: NonNegative | None = None
    optical_zero_deg: Annotated[dict[str, float], AfterValidator(_offsets_within_bounds)] = Field(
        default_factory=dict
    )
    imu: ImuCalibrationConfig | None = None


class VehicleProfile(_Model):
    """Everything about one car: [vehicle], [antennas], [[optical]] and [calibration]."""

    vehicle: VehicleConfig = VehicleConfig()
    antennas: AntennaConfig = AntennaConfig()
    optical: tuple[OpticalSensorConfig, ...] = ()
    calibration: CalibrationConfig = CalibrationConfig()

    @model_validator(mode="after")
    def _unique_optical(self) -> Self:
        names = [o.name for o in self.optical]
        if len(names) != len(set(names)):
            raise ValueError(f"optical sensor names must be unique, got {names}")
        return self


# --------------------------------------------------------------------------------------------
# Session configuration
# --------------------------------------------------------------------------------------------


class LogTrigger(StrEnum):
    ONTIME = "ontime"
    ONCHANGED = "onchanged"
    ONNEW = "onnew"
    ONCE = "once"


class LogRequest(_Model):
    """One ``LOG`` command: message name (with its B/A suffix for binary/ASCII), trigger and period."""

    name: str
    trigger: LogTrigger = LogTrigger.ONTIME
    period_s: Positive | None = None
    raw_only: bool = False

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not re.fullmatch(r"[A-Z0-9]+[ABSa-z]?", v):
            raise ValueError(f"{v!r} is not a NovAtel log name (e.g. 'BESTPOSB', 'RANGECMPB')")
        return v.upper()

    @model_validator(mode="after")
    def _period(self) -> Self:
        if self.trigger is LogTrigger.ONTIME and self.period_s is None:
            raise ValueError(f"log {self.name}: trigger 'ontime' needs period_s")
        if self.period_s is not None and self.period_s < 0.02 - 1e-9:
            raise ValueError(f"log {self.name}: period_s {self.period_s} is faster than 50 Hz")
        if self.period_s is not None and not _receiver_schedules(self.period_s):
            rates = ", ".join(f"{p:g}" for p in NOVATEL_HIGH_RATE_PERIODS_S)
            raise ValueError(
                f"log {self.name}: period_s {self.period_s} is not a period the receiver schedules "
                f"({rates} s, or a whole number of seconds)"
            )
        return self


def _receiver_schedules(period_s: float) -> bool:
    if period_s >= 1.0 - 1e-9:
        return abs(period_s - round(period_s)) <= 1e-9
    return any(abs(period_s - p) <= 1e-9 for p in NOVATEL_HIGH_RATE_PERIODS_S)


def _novatel_baud(value: int) -> int:
    if value not in NOVATEL_BAUDS:
        raise ValueError(f"{value} is not a baud rate of a NovAtel port ({', '.join(map(str, NOVATEL_BAUDS))})")
    return value


NovatelBaud = Annotated[int, AfterValidator(_novatel_baud)]
ReceiverPort = Literal["COM1", "COM2", "COM3", "USB1", "USB2", "USB3", "ICOM1"]
"""An OEM7 receiver port by name (OEM7 Commands and Logs Reference, COM ports and the serial port table)."""


def _default_rover_logs() -> tuple[LogRequest, ...]:
    return (
        LogRequest(name="BESTPOSB", period_s=0.05),
        LogRequest(name="BESTVELB", period_s=0.05),
        LogRequest(name="TIMEB", period_s=1.0),
        LogRequest(name="MARKPOSB", trigger=LogTrigger.ONNEW),
        LogRequest(name="MARKTIMEB", trigger=LogTrigger.ONNEW),
    )


_RANGECMP_OBS = 60
"""Observations a RANGECMP epoch carries in the budget: GPS + GLONASS (+ Galileo), two frequencies, open sky."""
_BODY_BYTES = {"RANGECMP": 4 + 24 * _RANGECMP_OBS, "RTCM1077": 400, "RTCM1087": 300, "RTCM1006": 21, "RTCM1230": 10}
"""Bodies the binary layouts do not fix (a RANGECMP epoch, RTCM3 MSM7 epochs: typical sizes)."""
_ASCII_FACTOR = 2.5
"""An ASCII log's size against its binary one (text fields, separators, a longer header)."""
PORT_BUDGET_WARN = 0.7
"""Share of a port's byte rate above which a log set leaves little margin for an epoch's burst."""


def port_budget(rc: ReceiverConfig) -> tuple[float, float]:
    """(bytes per second the receiver's ONTIME logs need, bytes per second its port carries at ``baud``: 10 bits
    a byte). An OEM7 drops what its port cannot carry and flags it in RXSTATUS (OEM7 Commands and Logs
    Reference, RXSTATUS: COM port transmit buffer overrun)."""
    from drivers.novatel.layouts import CODECS_BY_NAME

    need = 0.0
    for lr in rc.logs:
        if lr.trigger is not LogTrigger.ONTIME or not lr.period_s:
            continue
        base = lr.name[:-1] if lr.name[-1:] in ("A", "B", "S") and len(lr.name) > 1 else lr.name
        codec = CODECS_BY_NAME.get(base)
        body = codec.size if codec is not None and codec.fixed_layout else _BODY_BYTES.get(base, 100)
        size = float(body if base.startswith("RTCM") else 28 + body + 4)
        if lr.name.endswith("A"):
            size *= _ASCII_FACTOR
        need += size / lr.period_s
    return need, rc.baud / 10.0


class ReceiverConfig(_Model):
    """A NovAtel receiver on a serial port (or a pyserial URL)."""

    name: str
    role: Literal["base", "rover"]
    antenna: Literal["a", "b"] | None = None
    port: str
    baud: NovatelBaud = 115200
    autobaud: bool = False
    command_port: ReceiverPort = "COM1"
    """The receiver port ``port`` is cabled to (COM1–3, or USB1–3 for a PwrPak7 on USB). Logs are requested
    on the port the commands come in on (``LOG`` without a port: THISPORT), never by this name: over USB,
    ``LOG COM1 …`` would go to the physical COM1, not to the laptop."""
    correction_port: ReceiverPort = "COM2"
    """The receiver port set to receive corrections (``INTERFACEMODE <port> RTCMV3 NONE``)."""
    correction_device: str | None = None
    """Host serial port (path or URL, ``sim://NAME/COM2`` when simulated) cabled to ``correction_port``. A
    relay sink ``receiver:NAME`` needs it: the command port stays in NOVATEL mode, which ignores raw RTCM3."""
    correction_baud: NovatelBaud = 115200
    """Baud rate of ``correction_port``; set on the receiver (``SERIALCONFIG``) and on ``correction_device``
    when the rig owns that cable (a relay sink). The factory setting of a COM port is 9600."""
    correction_format: Literal["rtcmv3", "rtca", "cmr", "novatel"] = "rtcmv3"
    logs: tuple[LogRequest, ...] = Field(default_factory=_default_rover_logs)
    fix_position: tuple[float, float, float] | None = None
    """A base's surveyed antenna position: latitude, longitude (degrees), height (m) on ``fix_height``."""
    fix_height: Literal["ellipsoidal", "msl"] = "ellipsoidal"
    """What ``fix_position``'s height is: above the WGS84 ellipsoid (the rig sends ``UNDULATION USER 0``
    before ``FIX``) or above mean sea level (``UNDULATION EGM96``, the factory setting). A height read the
    wrong way is 25–50 m off: the base flags INTEGRITY_WARNING and stops sending corrections."""
    serial_number: str | None = None
    """The receiver's PSN (``LOG VERSION``). Given, a receiver answering with another one is refused by name
    (two USB adapters swapped after a replug); the one found is recorded either way."""
    extra_commands: tuple[str, ...] = ()
    command_timeout_s: Positive = 2.0
    output_latency_s: NonNegative | None = None
    """Fixed delay from a log's data time to its first byte on the port (a property of the receiver
    and its firmware, which the time base cannot see and must be told). None: 0 for a real receiver,
    ``simulation.gnss.output_latency_s`` for the simulated ones. The serial transmission time of each
    log (its length at ``baud``) is removed on top of it."""

    @model_validator(mode="after")
    def _budget(self) -> Self:
        need, carry = port_budget(self)
        if need > carry:
            raise ValueError(
                f"receiver {self.name!r}: its logs need about {need / 1e3:.1f} kB/s but the port carries "
                f"{carry / 1e3:.1f} kB/s at {self.baud} Bd: the receiver would drop logs (RXSTATUS overrun); "
                "raise baud, log less often, or take the raw observations (RANGECMPB) at a lower rate")
        return self

    @model_validator(mode="after")
    def _roles(self) -> Self:
        if self.role == "rover" and self.antenna is None:
            raise ValueError(f"rover {self.name!r} needs antenna = 'a' or 'b'")
        if self.role == "base" and self.antenna is not None:
            raise ValueError(f"base {self.name!r} must not name a vehicle antenna")
        return self


class RelayConfig(_Model):
    """RTK correction relay: one source, one or more sinks (``receiver:NAME`` or a port/URL)."""

    enabled: bool = True
    source: str = "receiver:base"
    sinks: tuple[str, ...] = ("receiver:rover_a", "receiver:rover_b")
    queue_frames: Annotated[int, Field(gt=0)] = 256
    ntrip_user_env: str = "VSC_RIG_NTRIP_USER"
    ntrip_password_env: str = "VSC_RIG_NTRIP_PASSWORD"
    gga_period_s: Positive = 10.0
    source_password: SecretStr | None = Field(default=None, exclude=True, repr=False)
    """A password given in the ``source`` URL, split off on reading (``source`` keeps ``***``); never dumped."""

    @model_validator(mode="before")
    @classmethod
    def _split_source_password(cls, data: Any) -> Any:
        from drivers.relay.endpoints import redact_endpoint

        if isinstance(data, Mapping) and isinstance(data.get("source"), str):
            redacted = redact_endpoint(data["source"])
            if redacted.password is not None:
                data = {**data, "source": redacted.text, "source_password": redacted.password.reveal()}
        return data


class CanRoleConfig(_Model):
    """Ties a DBC signal to a rig role (see docs/can.md)."""

    message: str
    signal: str
    unit: str | None = None
    invert: bool = False
    sign_signal: str | None = None
    sign_negative_when: int = 1
    valid_signal: str | None = None
    valid_when: int | tuple[int, ...] = 1


class CanCheckConfig(_Model):
    """Counter and checksum of one message."""

    counter: str | None = None
    checksum_signal: str | None = None
    algorithm: str = "none"


SamplePoint = Annotated[float, Field(ge=0.5, lt=1.0)]


class CanConfig(_Model):
    """One CAN bus through python-can (docs/can.md: keys, listen-only rule, timestamp source)."""

    name: str = "vsc"
    interface: str = "virtual"
    channel: str = "vsc"
    bitrate: Annotated[int, Field(gt=0)] = 500_000
    fd: bool = False
    data_bitrate: Annotated[int, Field(gt=0)] | None = None
    host: str | None = None
    port: Annotated[int, Field(gt=0, lt=65536)] | None = None
    options: dict[str, Any] = Field(default_factory=dict)
    """Passed to ``can.Bus`` as keyword arguments, checked against what the interface takes."""
    listen_only: bool | None = None
    """Unset: the recorder and ``rig can monitor`` open the bus listen-only where the interface can be
    (they never transmit); ``rig replay`` opens it active. False: record from an acknowledging interface."""
    timestamp_source: Literal["interface", "host"] | None = None
    """Whether the interface's stamps or the host receive times place frames in time (unset: per interface)."""
    sample_point: SamplePoint | None = None
    """Nominal sample point (fraction) where the rig derives a timing (PCAN FD; default 0.80)."""
    data_sample_point: SamplePoint | None = None
    """Data-phase sample point (fraction) where the rig derives a timing (PCAN FD; default 0.75)."""
    dbc: Path
    roles_file: Path | None = None
    roles: dict[str, CanRoleConfig] = Field(default_factory=dict)
    checks: dict[str, CanCheckConfig] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _python_can(self) -> Self:
        if self.data_bitrate is not None and not self.fd:
            raise ValueError("data_bitrate given but fd is false")
        if self.options or (self.fd and self.interface.lower() == "pcan"):
            # python-can specifics: the options the interface takes, a PCAN FD timing (the drivers are
            # imported only for these tables, so that other configurations load fast)
            from drivers.can.bus import CanBusConfig

            CanBusConfig.from_mapping(self.model_dump(include={
                "name", "interface", "channel", "bitrate", "fd", "data_bitrate", "host", "port", "options",
                "listen_only", "timestamp_source", "sample_point", "data_sample_point"}))
        return self


class DaqChannelConfig(_Model):
    """One analog input."""

    name: str
    physical: str
    range_v: tuple[float, float] = (-10.0, 10.0)
    terminal: Literal["rse", "nrse", "diff", "pseudodiff"] = "diff"

    @model_validator(mode="after")
    def _range(self) -> Self:
        if self.range_v[0] >= self.range_v[1]:
            raise ValueError(f"range_v {self.range_v} must be (min, max) with min < max")
        return self


class AnalogChannelConfig(_Model):
    """A transducer on a DAQ channel (brake pressure, …): linear or table scaling to ``unit``."""

    name: str
    daq_channel: str
    unit: str = "bar"
    scale_per_v: float | None = None
    offset_v: float = 0.0
    table_v: tuple[float, ...] | None = None
    table_value: tuple[float, ...] | None = None

    @model_validator(mode="after")
    def _scaling(self) -> Self:
        has_table = self.table_v is not None or self.table_value is not None
        if (self.scale_per_v is None) == (not has_table):
            raise ValueError("give either scale_per_v (linear) or table_v + table_value (table)")
        if has_table:
            if self.table_v is None or self.table_value is None or len(self.table_v) != len(self.table_value):
                raise ValueError("table_v and table_value must both be given with the same length")
            if len(self.table_v) < 2 or any(b <= a for a, b in zip(self.table_v, self.table_v[1:], strict=False)):
                raise ValueError("table_v must have at least two strictly increasing entries")
        return self


class DaqConfig(_Model):
    """An analog DAQ (``sim`` or ``nidaqmx``, or a third-party backend by entry point)."""

    backend: str = "sim"
    device: str = "Dev1"
    rate_hz: Positive = 1000.0
    block_size: Annotated[int, Field(gt=0)] = 100
    buffer_samples: Annotated[int, Field(gt=0)] = 10_000
    channels: tuple[DaqChannelConfig, ...]
    sync_channel: str | None = None
    sync_threshold_v: float = 2.5
    analog: tuple[AnalogChannelConfig, ...] = ()

    @model_validator(mode="after")
    def _channels(self) -> Self:
        names = [c.name for c in self.channels]
        if len(names) != len(set(names)):
            raise ValueError(f"DAQ channel names must be unique, got {names}")
        known = set(names)
        if self.sync_channel is not None and self.sync_channel not in known:
            raise ValueError(f"sync_channel {self.sync_channel!r} is not one of the channels {sorted(known)}")
        for a in self.analog:
            if a.daq_channel not in known:
                raise ValueError(f"analog {a.name!r}: daq_channel {a.daq_channel!r} is not one of {sorted(known)}")
        return self


class OutputConfig(_Model):
    """Where and how the session file is written."""

    directory: Path = Path("sessions")
    name: str | None = None
    compression: Literal["zstd", "lz4", "none"] = "zstd"
    rollover_size_mb: Positive | None = 2000.0
    rollover_duration_s: Positive | None = None
    min_free_disk_mb: Positive = 500.0


class SimGnssConfig(_Model):
    """Error model of the simulated receivers (1σ)."""

    position_noise_m: NonNegative = 0.015
    """RTK-fixed horizontal 2-D RMS of each rover's position."""
    velocity_noise_mps: NonNegative = 0.02
    correlation_time_s: Positive = 1.0
    common_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.95
    """Share of the position error variance common to all rovers (same base, same sky); the rest is
    each antenna's own, so the relative A–B error is √(2·(1 − f))·σ (≈ 5 mm at the defaults)."""
    output_latency_s: NonNegative | None = None
    """The simulated receivers' output latency; unset: each draws its own from its seed in 15–50 ms (OEM7:
    20–30 ms typical, 50 ms at most). The recording is never told it: it measures it, as in a real car."""
    leap_seconds: int = 18


class SimulationConfig(_Model):
    """The simulated car's physical truths, apart from the calibration values in force."""

    drive: str = "demo"
    seed: int = 1
    speed: Positive = 1.0
    origin_lat_deg: float = 48.7758
    origin_lon_deg: float = 9.1829
    origin_h_m: float = 300.0
    initial_heading_deg: float = 0.0
    start_gps_week: Annotated[int, Field(ge=0)] = 2400
    start_gps_seconds: NonNegative = 345600.0
    true_mount_offset_deg: MountOffsetDeg = 0.0
    true_swa_offset_deg: Annotated[float, Field(ge=-10.0, le=10.0)] = 0.8
    """Zero error of the simulated steering-angle sensor (deg, ISO sign: added to the true angle)."""
    true_optical_zero_deg: Annotated[dict[str, float], AfterValidator(_offsets_within_bounds)] = Field(
        default_factory=dict
    )
    gnss: SimGnssConfig = SimGnssConfig()
    daq_clock_ppm: float = 30.0
    governed: bool = True
    """Simulated time waits for a device or reader that fell behind (false: the host's real latency shows)."""
    governor_budget_ms: Positive = 1.0
    """How far (ms of simulated time) a device or reader may fall behind before simulated time waits."""


class ValidationConfig(_Model):
    """Pass/fail tolerances for the VSC sideslip estimate."""

    rmse_deg: Positive = 0.5
    max_abs_deg: Positive = 1.5
    bias_deg: Positive = 0.3
    min_speed_kmh: NonNegative = 10.0


class SessionConfig(_Model):
    """A whole session: the car, its devices, where to write, and (simulated sessions) the truth."""

    vehicle_profile: Path | None = None
    vehicle: VehicleConfig | None = None
    antennas: AntennaConfig | None = None
    optical: tuple[OpticalSensorConfig, ...] | None = None
    calibration: CalibrationConfig | None = None
    receivers: tuple[ReceiverConfig, ...] = ()
    relay: RelayConfig | None = None
    can: tuple[CanConfig, ...] = ()
    daq: DaqConfig | None = None
    output: OutputConfig = OutputConfig()
    simulation: SimulationConfig | None = None
    validation: ValidationConfig = ValidationConfig()

    @model_validator(mode="after")
    def _consistency(self) -> Self:
        inline = any(x is not None for x in (self.vehicle, self.antennas, self.optical, self.calibration))
        if self.vehicle_profile is not None and inline:
            raise ValueError("give either vehicle_profile = 'file.toml' or inline [vehicle]/[antennas], not both")
        names = [r.name for r in self.receivers]
        if len(names) != len(set(names)):
            raise ValueError(f"receiver names must be unique, got {names}")
        antennas = [r.antenna for r in self.receivers if r.role == "rover"]
        if len(antennas) != len(set(antennas)):
            raise ValueError(f"each antenna may have one rover only, got {antennas}")
        if self.relay is not None and self.relay.enabled:
            for endpoint in (self.relay.source, *self.relay.sinks):
                if endpoint.startswith("receiver:") and endpoint.removeprefix("receiver:") not in names:
                    raise ValueError(f"relay endpoint {endpoint!r} names no receiver (receivers: {names})")
            by_name = {r.name: r for r in self.receivers}
            for endpoint in self.relay.sinks:
                rc = by_name.get(endpoint.removeprefix("receiver:")) if endpoint.startswith("receiver:") else None
                if rc is not None and rc.correction_device is None:
                    raise ValueError(
                        f"relay sink {endpoint!r}: receiver {rc.name!r} has no correction_device, the host port "
                        f"cabled to its {rc.correction_port}; its command port stays in NOVATEL mode, which ignores "
                        f"raw RTCM3 (give correction_device, e.g. '/dev/serial/by-id/…' or 'sim://{rc.name}/"
                        f"{rc.correction_port}', and correction_baud)")
        return self

    @property
    def profile(self) -> VehicleProfile:
        """The inline vehicle profile (after :func:`load_session` has resolved ``vehicle_profile``)."""
        return VehicleProfile(
            vehicle=self.vehicle or VehicleConfig(),
            antennas=self.antennas or AntennaConfig(),
            optical=self.optical or (),
            calibration=self.calibration or CalibrationConfig(),
        )


# --------------------------------------------------------------------------------------------
# Loading and error reporting
# --------------------------------------------------------------------------------------------


class ConfigProblem(BaseModel):
    """One problem in a configuration file."""

    model_config = ConfigDict(frozen=True)

    path: str
    message: str
    line: int | None = None

    def __str__(self) -> str:
        where = f"line {self.line}: " if self.line is not None else ""
        return f"{where}{self.path}: {self.message}"


class ConfigFileError(ConfigError):
    """A configuration file has one or more problems; ``problems`` lists them all."""

    def __init__(self, file: Path, problems: list[ConfigProblem]) -> None:
        self.file = file
        self.problems = problems
        lines = "\n".join(f"  {p}" for p in problems)
        noun = "problem" if len(problems) == 1 else "problems"
        super().__init__(f"{file}: {len(problems)} {noun}\n{lines}")


def _field_names(model: type[BaseModel], loc: tuple[int | str, ...]) -> list[str]:
    """Field names that would be valid at the location ``loc`` (for "did you mean")."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            continue
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            return []
        field = current.model_fields.get(str(part))
        if field is None:
            return []
        current = _model_in(field.annotation)
        if current is None:
            return []
    if isinstance(current, type) and issubclass(current, BaseModel):
        return list(current.model_fields)
    return []


def _model_in(annotation: Any) -> type[BaseModel] | None:
    """The pydantic model inside an annotation like ``X | None``, ``tuple[X, ...]`` or ``dict[K, X]``."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _locate(text: str) -> dict[str, int]:
    """Map dotted key paths to the line where they are written (TOML headers and ``key =`` lines)."""
    lines: dict[str, int] = {}
    table: list[str] = []
    array_counts: dict[str, int] = {}
    header = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
    keyline = re.compile(r"^\s*([A-Za-z0-9_\-\"'.]+)\s*=")
    for number, raw in enumerate(text.splitlines(), start=1):
        m = header.match(raw)
        if m:
            parts = [p.strip().strip("\"'") for p in m.group(2).split(".")]
            if m.group(1) == "[[":
                base = ".".join(parts)
                index = array_counts.get(base, 0)
                array_counts[base] = index + 1
                table = [*parts, str(index)]
            else:
                # a sub-table of the last array element: [receivers.x] after [[receivers]]
                resolved: list[str] = []
                for i, p in enumerate(parts):
                    resolved.append(p)
                    base = ".".join(parts[: i + 1])
                    if base in array_counts and i < len(parts) - 1:
                        resolved.append(str(array_counts[base] - 1))
                table = resolved
            lines.setdefault(".".join(table), number)
            continue
        k = keyline.match(raw)
        if k:
            key = [p.strip().strip("\"'") for p in k.group(1).split(".")]
            lines.setdefault(".".join([*table, *key]), number)
    return lines


def _problems(exc: ValidationError, model: type[BaseModel], text: str) -> list[ConfigProblem]:
    where = _locate(text)
    out: list[ConfigProblem] = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        path = ".".join(str(p) for p in loc) or "(top level)"
        line = None
        for n in range(len(loc), 0, -1):
            line = where.get(".".join(str(p) for p in loc[:n]))
            if line is not None:
                break
        kind = err["type"]
        if kind == "extra_forbidden":
            name = str(loc[-1])
            valid = _field_names(model, loc[:-1])
            close = difflib.get_close_matches(name, valid, n=1, cutoff=0.6)
            hint = f"; did you mean '{close[0]}'?" if close else (f"; known keys: {', '.join(valid)}" if valid else "")
            msg = f"unknown key '{name}'{hint}"
        elif kind == "missing":
            msg = "required key is missing"
        else:
            msg = str(err["msg"]).removeprefix("Value error, ")
            if "input" in err and kind not in {"model_type", "dict_type"} and not isinstance(err["input"], Mapping):
                msg += f" (got {err['input']!r})"
        out.append(ConfigProblem(path=path, message=msg, line=line))
    return out


def _read_toml(path: Path) -> tuple[dict[str, Any], str]:
    try:
        raw = path.read_bytes()
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: no such configuration file") from exc
    except IsADirectoryError as exc:
        raise ConfigError(f"{path}: is a directory, not a configuration file") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        # TOML is UTF-8 by definition; name the first bad byte so it can be found in an editor
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ConfigError(
            f"{path}: not UTF-8 text: byte 0x{raw[exc.start]:02x} at byte offset {exc.start} (line {line}, "
            f"column {column}) is {exc.reason}; TOML files must be UTF-8"
        ) from None
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise ConfigFileError(path, [ConfigProblem(path="(syntax)", message=str(exc), line=_toml_line(exc))]) from exc


def _toml_line(exc: tomllib.TOMLDecodeError) -> int | None:
    lineno = getattr(exc, "lineno", None)
    if isinstance(lineno, int):
        return lineno
    m = re.search(r"line (\d+)", str(exc))
    return int(m.group(1)) if m else None


def load_profile(path: Path | str) -> VehicleProfile:
    """Read and validate a vehicle profile TOML file.

    Raises:
        ConfigFileError: listing every problem with its key path and line.
        ConfigError: when the file cannot be read.
    """
    p = Path(path)
    data, text = _read_toml(p)
    try:
        return VehicleProfile.model_validate(data)
    except ValidationError as exc:
        raise ConfigFileError(p, _problems(exc, VehicleProfile, text)) from None


def load_session(path: Path | str, overrides: Mapping[str, Any] | None = None) -> SessionConfig:
    """Read and validate a session configuration; resolve relative paths and the vehicle profile.

    ``overrides`` maps dotted keys (``simulation.true_mount_offset_deg``) to values applied before
    validation (``rig sim record --set``).

    Raises:
        ConfigFileError: listing every problem with its key path and line.
        ConfigError: when the file (or its vehicle profile) cannot be read.
    """
    p = Path(path)
    data, text = _read_toml(p)
    for key, value in (overrides or {}).items():
        _set_dotted(data, key, value)
    try:
        cfg = SessionConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigFileError(p, _problems(exc, SessionConfig, text)) from None
    base = p.resolve().parent
    updates: dict[str, Any] = {"can": tuple(_resolve_can(base, i, c) for i, c in enumerate(cfg.can))}
    if cfg.vehicle_profile is not None:
        profile_path = _resolve(base, cfg.vehicle_profile)
        profile = load_profile(profile_path)
        updates.update(
            vehicle_profile=profile_path,
            vehicle=profile.vehicle,
            antennas=profile.antennas,
            optical=profile.optical,
            calibration=profile.calibration,
        )
    return cfg.model_copy(update=updates)


def _resolve(base: Path, p: Path) -> Path:
    """Resolve a path from a config file: absolute, relative to the file, or ``pkg:package/file`` data."""
    text = str(p)
    if text.startswith("pkg:"):
        package, _, name = text.removeprefix("pkg:").partition("/")
        resource = importlib.resources.files(package).joinpath(name)
        return Path(str(resource))
    return p if p.is_absolute() else (base / p)


def _resolve_can(base: Path, index: int, can: CanConfig) -> CanConfig:
    """Resolve the DBC path and merge the roles file (inline roles win) of one ``[[can]]`` table."""
    update: dict[str, Any] = {"dbc": _resolve(base, can.dbc)}
    if can.roles_file is not None:
        roles_path = _resolve(base, can.roles_file)
        data, text = _read_toml(roles_path)
        try:
            from_file = _RolesFile.model_validate(data)
        except ValidationError as exc:
            raise ConfigFileError(roles_path, _problems(exc, _RolesFile, text)) from None
        update["roles_file"] = roles_path
        update["roles"] = {**from_file.roles, **can.roles}
        update["checks"] = {**from_file.checks, **can.checks}
    return can.model_copy(update=update)


class _RolesFile(_Model):
    """A reusable role mapping for one DBC: ``[roles.<role>]`` and ``[checks.<MESSAGE>]`` tables."""

    dbc: str | None = None
    roles: dict[str, CanRoleConfig] = Field(default_factory=dict)
    checks: dict[str, CanCheckConfig] = Field(default_factory=dict)


def _set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            try:
                node = node[int(part)]
            except (ValueError, IndexError) as exc:
                raise ConfigError(f"override {key!r}: {'.'.join(parts[: i + 1])} is not a valid list index") from exc
            continue
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict | list):
            raise ConfigError(f"override {key!r}: {'.'.join(parts[: i + 1])} is not a table")
        node = nxt
    if isinstance(node, list):
        raise ConfigError(f"override {key!r}: cannot set a key on a list")
    node[parts[-1]] = value


def parse_override(item: str) -> tuple[str, Any]:
    """Parse ``KEY=VALUE`` where VALUE is a TOML value (bare words are taken as strings)."""
    if "=" not in item:
        raise ConfigError(f"override {item!r} must look like KEY=VALUE")
    key, raw = item.split("=", 1)
    key = key.strip()
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return key, value


def check_file(path: Path | str) -> SessionConfig | VehicleProfile:
    """Validate a session configuration or a vehicle profile (decided by its tables)."""
    p = Path(path)
    data, _ = _read_toml(p)
    session_keys = {"receivers", "relay", "can", "daq", "output", "simulation", "validation", "vehicle_profile"}
    if session_keys & set(data):
        return load_session(p)
    return load_profile(p)
