"""Optical slip sensor: scaling, sign, validity, zero offset, CAN path, and transfer to the CG vs ground truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.analog import LinearScaling
from drivers.daq import DaqBlock
from drivers.optical import (
    OpticalChannel,
    OpticalRole,
    OpticalSensorSpec,
    SensorKind,
    convert_block,
    convert_volts,
    correvit_channels,
    from_can,
    transfer_to_point,
)
from sim_devices.daq import SimDaqBackend, SimOpticalSensor
from tests.daq.helpers import T0_NS, ManualClock, optical_channels, optical_wiring, slalom, steady_circle
from vsccore.errors import ConfigError

KMH = 1.0 / 3.6


def body_spec(**kw: object) -> OpticalSensorSpec:
    invert = kw.pop("invert", ())
    return OpticalSensorSpec(
        name="body", kind=SensorKind.BODY, mount_xyz_m=(1.6, 0.5, 0.4),
        channels=correvit_channels("body", invert=invert),  # type: ignore[arg-type]
        **kw,  # type: ignore[arg-type]
    )


def test_known_volts_give_known_values() -> None:
    spec = body_spec()
    # 0.04 V per km/h, 4 deg per V
    s = convert_volts(
        spec,
        {"body_vx": [4.0, 2.0], "body_vy": [-0.2, 0.1], "body_slip_angle": [0.5, -2.5], "body_speed": [4.0, 2.0],
         "body_valid": [5.0, 5.0]},
    )
    np.testing.assert_allclose(s.vx, [100 * KMH, 50 * KMH])
    np.testing.assert_allclose(s.vy, [-5 * KMH, 2.5 * KMH])
    np.testing.assert_allclose(s.slip_angle, np.radians([2.0, -10.0]))
    np.testing.assert_allclose(s.speed, [100 * KMH, 50 * KMH])
    assert s.valid.tolist() == [True, True]
    assert s.zero_offset_applied_rad == 0.0


def test_invert_per_role_flips_the_sensor_sign_convention() -> None:
    spec = body_spec(invert=(OpticalRole.VY, OpticalRole.SLIP_ANGLE))
    s = convert_volts(spec, {"body_vx": [4.0], "body_vy": [0.2], "body_slip_angle": [0.5], "body_speed": [4.0],
                             "body_valid": [5.0]})
    assert s.vy[0] == pytest.approx(-5 * KMH)
    assert s.slip_angle[0] == pytest.approx(math.radians(-2.0))
    assert s.vx[0] == pytest.approx(100 * KMH)


def test_below_min_speed_or_status_invalid_is_nan_not_zero() -> None:
    spec = body_spec(min_speed_mps=0.5 * KMH)
    v = np.array([0.3, 0.6, 30.0, 30.0]) * 0.04  # km/h → volts
    s = convert_volts(spec, {"body_vx": v, "body_vy": np.zeros(4), "body_slip_angle": np.zeros(4), "body_speed": v,
                             "body_valid": [5.0, 5.0, 5.0, 0.0]})
    assert s.valid.tolist() == [False, True, True, False]
    for arr in (s.vx, s.vy, s.slip_angle, s.speed):
        assert np.isnan(arr[0]) and np.isnan(arr[3])
        assert np.isfinite(arr[1]) and np.isfinite(arr[2])
    # inverted status logic (valid when low)
    spec_low = body_spec(status_valid_high=False)
    s2 = convert_volts(spec_low, {"body_vx": v, "body_vy": np.zeros(4), "body_slip_angle": np.zeros(4), "body_speed": v,
                                  "body_valid": [0.0, 0.0, 0.0, 5.0]})
    assert s2.valid.tolist() == [False, True, True, False]


def test_zero_offset_is_removed_and_reported() -> None:
    z = math.radians(1.0)
    spec = body_spec(zero_offset_rad=z)
    beta_meas = math.radians(3.0)
    v_kmh = 72.0
    volts = {
        "body_vx": [v_kmh * math.cos(beta_meas) * 0.04],
        "body_vy": [v_kmh * math.sin(beta_meas) * 0.04],
        "body_slip_angle": [3.0 / 4.0],
        "body_speed": [v_kmh * 0.04],
        "body_valid": [5.0],
    }
    s = convert_volts(spec, volts)
    assert s.slip_angle[0] == pytest.approx(math.radians(2.0))
    # the velocity vector is rotated back by the same misalignment
    assert math.atan2(s.vy[0], s.vx[0]) == pytest.approx(math.radians(2.0))
    assert math.hypot(s.vx[0], s.vy[0]) == pytest.approx(v_kmh * KMH)
    assert s.zero_offset_applied_rad == z


def test_missing_roles_are_derived() -> None:
    spec = OpticalSensorSpec(
        "sf2", SensorKind.BODY, (0.0, 0.0, 0.0),
        (OpticalChannel(OpticalRole.SLIP_ANGLE, "a", LinearScaling.from_unit(4.0, 0.0, "deg")),
         OpticalChannel(OpticalRole.SPEED, "v", LinearScaling.from_unit(25.0, 0.0, "km/h"))),
    )
    s = convert_volts(spec, {"a": [1.0], "v": [2.0]})  # 4 deg, 50 km/h
    assert s.vx[0] == pytest.approx(50 * KMH * math.cos(math.radians(4.0)))
    assert s.vy[0] == pytest.approx(50 * KMH * math.sin(math.radians(4.0)))
    with pytest.raises(ConfigError, match=r"channel 'v' \(speed\) not in the data"):
        convert_volts(spec, {"a": [1.0]})


def test_can_path_gives_the_same_sample_as_the_analog_path() -> None:
    spec = body_spec(invert=(OpticalRole.VY,), zero_offset_rad=math.radians(0.5), min_speed_mps=0.5 * KMH)
    vx = np.array([20.0, 0.05, 15.0])
    vy_sensor = np.array([0.7, 0.0, -0.3])  # in the sensor's (inverted) convention
    angle = np.arctan2(-vy_sensor, vx)
    vel = np.hypot(vx, vy_sensor)
    status = np.array([1, 1, 0])
    can = from_can(spec, {"vx": vx, "vy": vy_sensor, "slip_angle": angle, "speed": vel, "valid": status},
                   time_ns=[1, 2, 3])
    volts = convert_volts(
        spec,
        {"body_vx": vx / KMH * 0.04, "body_vy": vy_sensor / KMH * 0.04, "body_slip_angle": np.degrees(angle) / 4.0,
         "body_speed": vel / KMH * 0.04, "body_valid": status * 5.0},
    )
    for name in ("vx", "vy", "slip_angle", "speed"):
        np.testing.assert_allclose(getattr(can, name), getattr(volts, name), rtol=1e-12, equal_nan=True)
    assert can.valid.tolist() == [True, False, False]
    assert can.time_ns is not None and can.time_ns.tolist() == [1, 2, 3]
    # ISO sign restored: the lateral velocity of sample 0 is −0.7 m/s before the zero-offset rotation
    z = math.radians(0.5)
    assert can.vy[0] == pytest.approx(-math.sin(z) * 20.0 + math.cos(z) * -0.7)
    with pytest.raises(ConfigError, match="unknown optical role 'yaw'"):
        from_can(spec, {"yaw": [0.0], "vx": [1.0], "vy": [0.0]})


def _sim_read(truth, specs_and_sensors, seconds: float, rate: float = 1000.0):
    channels, sources = [], {}
    for i, sensor in enumerate(specs_and_sensors):
        ch = optical_channels(sensor.spec.name, 8 * i)
        channels += ch
        sources.update(optical_wiring(sensor, ch))
    clock = ManualClock()
    b = SimDaqBackend(clock=clock, truth=truth, sources=sources, truth_start_ns=T0_NS)
    b.configure(channels)
    b.start(rate)
    blk = b.read(int(seconds * rate), timeout_s=seconds + 1)
    t = np.asarray(b.sample_time_s(blk.sample_indices()))
    b.close()
    return blk, t


@pytest.mark.parametrize("make_truth", [steady_circle, slalom])
def test_body_slip_transferred_to_cg_matches_ground_truth(make_truth) -> None:
    truth = make_truth()
    spec = body_spec()
    sensor = SimOpticalSensor(spec, internal_rate_hz=1000.0, velocity_noise_mps=0.01)
    blk, t = _sim_read(truth, [sensor], 8.0)
    s = convert_block(spec, blk)
    assert s.valid.all()
    r = np.interp(t, truth.t, truth.yaw_rate)
    cg = transfer_to_point(s, spec, r)
    beta_true = np.interp(t, truth.t, truth.beta_cg)
    # at the mount the slip differs clearly from the CG's (the transfer matters)…
    beta_mount_true = np.interp(t, truth.t, truth.point_sideslip(1.6, 0.5))
    assert np.max(np.abs(beta_mount_true - beta_true)) > 0.01
    # …and after the transfer the optical estimate matches the truth to the sensor's noise
    err = cg.sideslip - beta_true
    assert np.sqrt(np.mean(err**2)) < 1.0e-3
    assert abs(np.mean(err)) < 2.0e-4
    # any other body point too, e.g. the rear axle
    rear = transfer_to_point(s, spec, r, to_xy=(-1.4, 0.0))
    err_rear = rear.sideslip - np.interp(t, truth.t, truth.point_sideslip(-1.4, 0.0))
    assert np.sqrt(np.mean(err_rear**2)) < 1.0e-3


def test_wheel_sensor_measures_tyre_slip_angle_and_transfers_to_cg() -> None:
    truth = slalom()
    wheel_xy = (1.4, 0.8)
    wspec = OpticalSensorSpec("wheel_fl", SensorKind.WHEEL, (*wheel_xy, 0.3), correvit_channels("wheel_fl"),
                              wheel="fl")
    bspec = body_spec()
    sensors = [SimOpticalSensor(bspec, velocity_noise_mps=0.01, seed=1),
               SimOpticalSensor(wspec, velocity_noise_mps=0.01, seed=2, internal_rate_hz=1000.0)]
    blk, t = _sim_read(truth, sensors, 6.0)
    w = convert_block(wspec, blk)
    b = convert_block(bspec, blk)
    assert w.sensor == "wheel_fl" and b.sensor == "body"
    # independent expectation: wheel-point velocity from the rigid-body formula, rotated by −δ
    vx_p = np.interp(t, truth.t, truth.vx) - np.interp(t, truth.t, truth.yaw_rate) * wheel_xy[1]
    vy_p = np.interp(t, truth.t, truth.vy) + np.interp(t, truth.t, truth.yaw_rate) * wheel_xy[0]
    d = np.interp(t, truth.t, truth.road_wheel_angle)
    alpha = np.arctan2(-np.sin(d) * vx_p + np.cos(d) * vy_p, np.cos(d) * vx_p + np.sin(d) * vy_p)
    assert np.sqrt(np.mean((w.slip_angle - alpha) ** 2)) < 1.0e-3
    # the tyre slip angle is not the sideslip at that point: they differ by the steer angle
    assert np.max(np.abs(np.arctan2(vy_p, vx_p) - alpha)) > 0.04
    cg = transfer_to_point(w, wspec, np.interp(t, truth.t, truth.yaw_rate), steer_angle=d)
    assert np.sqrt(np.mean((cg.sideslip - np.interp(t, truth.t, truth.beta_cg)) ** 2)) < 1.0e-3
    with pytest.raises(ConfigError, match="steering angle"):
        transfer_to_point(w, wspec, np.zeros(len(w)))


def test_sim_zero_offset_is_recovered_by_the_calibration_in_force() -> None:
    truth = steady_circle()
    z = math.radians(0.8)
    sensor = SimOpticalSensor(body_spec(), velocity_noise_mps=0.0, zero_offset_rad=z)
    blk, t = _sim_read(truth, [sensor], 2.0)
    beta_mount = np.interp(t, truth.t, truth.point_sideslip(1.6, 0.5))
    uncal = convert_block(body_spec(), blk)
    cal = convert_block(body_spec(zero_offset_rad=z), blk)
    assert np.mean(uncal.slip_angle - beta_mount) == pytest.approx(z, abs=1e-4)
    assert np.mean(cal.slip_angle - beta_mount) == pytest.approx(0.0, abs=1e-4)
    assert cal.zero_offset_applied_rad == z


def test_spec_validation_and_dict_round_trip() -> None:
    with pytest.raises(ConfigError, match="wheel sensor needs wheel"):
        OpticalSensorSpec("w", SensorKind.WHEEL, (1.0, 0.8, 0.3), correvit_channels("w"))
    with pytest.raises(ConfigError, match="needs roles"):
        OpticalSensorSpec("b", SensorKind.BODY, (0.0, 0.0, 0.0),
                          correvit_channels("b", roles=(OpticalRole.VY, OpticalRole.SPEED)))
    with pytest.raises(ConfigError, match="more than once"):
        OpticalSensorSpec("b", SensorKind.BODY, (0.0, 0.0, 0.0),
                          correvit_channels("b") + (OpticalChannel(OpticalRole.VX, "x2", LinearScaling(1.0)),))
    spec = body_spec(invert=(OpticalRole.SLIP_ANGLE,), zero_offset_rad=0.01)
    again = OpticalSensorSpec.from_dict(spec.to_dict())
    assert again == spec
    cfg = {
        "name": "s350", "kind": "wheel", "wheel": "rr", "mount_xyz_m": [-1.3, -0.8, 0.3], "min_speed_kmh": 0.5,
        "zero_offset_deg": 0.25,
        "channels": {"slip_angle": {"channel": "ai2", "invert": True, "scaling": {"points": [[-10, -40], [10, 40]],
                                                                           "unit": "deg"}},
                     "speed": {"channel": "ai3", "scaling": {"scale": 25.0, "unit": "km/h"}}},
    }
    s = OpticalSensorSpec.from_dict(cfg, "optical")
    assert s.min_speed_mps == pytest.approx(0.5 * KMH)
    assert s.zero_offset_rad == pytest.approx(math.radians(0.25))
    out = convert_volts(s, {"ai2": [1.0], "ai3": [2.0]})
    assert out.slip_angle[0] == pytest.approx(math.radians(-4.0 - 0.25))
    with pytest.raises(ConfigError, match=r"optical: missing key 'channels'"):
        OpticalSensorSpec.from_dict({"name": "x"}, "optical")


def test_records_fit_the_optical_topic_schema_and_blocks_pack_for_the_recorder() -> None:
    """What the recorder writes: /optical/<sensor> JSON records and /daq/<device>/samples blocks."""
    from rig.core import topics

    truth = slalom(duration=3.0)
    spec = body_spec()
    sensor = SimOpticalSensor(spec, velocity_noise_mps=0.01)
    blk, _ = _sim_read(truth, [sensor], 0.2)
    data = blk.data.copy()
    data[blk.channels.index("body_valid"), 5] = 0.0  # the sensor flags one sample invalid
    blk = DaqBlock(blk.first_sample_index, blk.rate_hz, data, blk.host_time_ns, blk.channels)
    s = convert_block(spec, blk)
    recs = s.records()
    schema = topics.spec_for_topic(topics.optical("body"))[0].schema.document
    assert all(topics.validate_json(schema, r) == [] for r in recs)
    assert [r["sample_index"] for r in recs[:3]] == [0, 1, 2]
    assert recs[5]["valid"] is False and recs[5]["slip_angle_rad"] is None
    decoded = topics.decode_json(topics.encode_json(recs[6]))
    assert decoded["slip_angle_rad"] == pytest.approx(float(s.slip_angle[6]))
    # the DAQ block as float32 volts: a 16-bit ±10 V code survives exactly
    packed = topics.pack_daq_block(topics.DaqBlock(blk.first_sample_index, blk.rate_hz, blk.channels,
                                                   blk.data.astype(np.float32)))
    back = topics.unpack_daq_block(packed)
    np.testing.assert_array_equal(back.volts(), blk.data)
    again = convert_volts(spec, {c: back.volts()[back.channel_names.index(c)] for c in spec.daq_channels})
    np.testing.assert_array_equal(again.slip_angle, s.slip_angle)
