"""A Correvit with CAN output: frames encoded with cantools, decoded through the CAN role map, live and offline."""

from __future__ import annotations

import math
import threading

import can
import numpy as np
import pytest

from drivers.can import FrameBatch, RoleDecoder, RoleMap, VectorRoleDecoder, load_dbc
from drivers.can.bus import CanBusConfig, CanBusLink, CanFrame
from drivers.optical import (
    OpticalCanAssembler,
    OpticalChannel,
    OpticalRole,
    OpticalSample,
    OpticalSensorSpec,
    SensorKind,
    concatenate,
    from_role_series,
    transfer_to_point,
)
from sim_devices.daq import (
    SimOpticalSensor,
    correvit_can_frames,
    correvit_dbc_path,
    correvit_role_table,
)
from tests.daq.helpers import T0_NS, ramp, slalom
from vsccore.clock import ScaledClock
from vsccore.errors import ConfigError

MOUNT = (1.6, 0.5, 0.4)
LATENCY_S = 0.0005
ZERO = math.radians(0.6)


@pytest.fixture(scope="module")
def db():
    return load_dbc(correvit_dbc_path(), strict=True)


@pytest.fixture(scope="module")
def rolemap(db) -> RoleMap:
    return RoleMap.from_mapping(correvit_role_table("correvit"), db, source="correvit_role_table")


def can_spec(roles=(OpticalRole.VX, OpticalRole.VY, OpticalRole.SLIP_ANGLE, OpticalRole.SPEED)) -> OpticalSensorSpec:
    chans = tuple(OpticalChannel(r, can_role=f"correvit_{r.value}") for r in roles)
    return OpticalSensorSpec("correvit", SensorKind.BODY, MOUNT, chans, zero_offset_rad=ZERO)


def truth_times(sample: OpticalSample) -> np.ndarray:
    """Truth time of each sample: the primary (Correvit_Vel) frame goes out latency_s after the cycle."""
    assert sample.time_ns is not None
    return (sample.time_ns - T0_NS) / 1e9 - LATENCY_S


def test_dbc_and_role_map(db, rolemap) -> None:
    assert {m.name: m.frame_id for m in db.messages} == {"Correvit_Vel": 0x7C0, "Correvit_Angle": 0x7C1}
    text = correvit_dbc_path().read_text()
    assert "Provenance" in text and "NOT the vendor's file" in text
    vx = rolemap.role("correvit_vx")
    assert (vx.message, vx.signal, vx.si_unit, vx.valid_signal) == ("Correvit_Vel", "Vel_X", "m/s", "Vel_Status")
    assert rolemap.role("correvit_slip_angle").si_unit == "rad"


@pytest.fixture(scope="module")
def slalom_frames(db, rolemap):
    truth = slalom(duration=8.0)
    spec = can_spec()
    sensor = SimOpticalSensor(spec, internal_rate_hz=1000.0, velocity_noise_mps=0.0, zero_offset_rad=ZERO)
    frames = correvit_can_frames(
        sensor, truth, db, rolemap, t1_s=7.5, latency_s=LATENCY_S, truth_start_ns=T0_NS
    )
    return truth, spec, frames


def test_offline_decode_matches_truth_within_0_05_deg(db, rolemap, slalom_frames) -> None:
    truth, spec, frames = slalom_frames
    assert len(frames) == 2 * 751  # two messages per 10 ms cycle over 7.5 s (both ends included)
    batch = VectorRoleDecoder(db, rolemap).decode(FrameBatch.from_frames(frames))
    s = from_role_series(spec, batch.roles)
    assert len(s) == 751 and s.valid.all()
    assert s.zero_offset_applied_rad == ZERO
    t = truth_times(s)
    beta_mount = np.interp(t, truth.t, truth.point_sideslip(*spec.mount_xy))
    # the CAN signals are 0.01 km/h and 0.01°: a few thousandths of a degree
    assert np.max(np.abs(np.degrees(s.slip_angle - beta_mount))) < 0.01
    cg = transfer_to_point(s, spec, np.interp(t, truth.t, truth.yaw_rate))
    assert np.max(np.abs(np.degrees(cg.sideslip - np.interp(t, truth.t, truth.beta_cg)))) < 0.05
    speed_true = np.hypot(*truth.point_velocity(*spec.mount_xy))
    np.testing.assert_allclose(s.speed, np.interp(t, truth.t, speed_true), atol=0.01 / 3.6)


def test_below_min_speed_the_quality_bits_make_samples_invalid(db, rolemap) -> None:
    truth = ramp(v0=0.0, accel=1.0, duration=1.0)  # 0.5 km/h is reached at 0.139 s
    spec = can_spec()
    sensor = SimOpticalSensor(spec, internal_rate_hz=1000.0, velocity_noise_mps=0.0, zero_offset_rad=ZERO)
    frames = correvit_can_frames(sensor, truth, db, rolemap, t1_s=0.5, latency_s=LATENCY_S, truth_start_ns=T0_NS)
    batch = VectorRoleDecoder(db, rolemap).decode(FrameBatch.from_frames(frames))
    assert np.any(batch.roles["correvit_vx"].flags != 0)  # INVALID from Vel_Status = 0
    s = from_role_series(spec, batch.roles)
    t = truth_times(s)
    slow, fast = t < 0.5 / 3.6 - 0.002, t > 0.5 / 3.6 + 0.002
    assert slow.sum() == 14 and not s.valid[slow].any() and s.valid[fast].all()
    for arr in (s.vx, s.vy, s.slip_angle, s.speed):
        assert np.isnan(arr[slow]).all()  # invalid is NaN, never zero


def _send_and_assemble(db, rolemap, spec, frames, channel: str) -> tuple[OpticalSample, list[tuple[int, int, bytes]]]:
    """Send frames over a python-can virtual bus; a CanBusLink receives them and the live path decodes."""
    decoder = RoleDecoder(db, rolemap)
    assembler = OpticalCanAssembler(spec, rolemap)
    parts: list[OpticalSample] = []
    received: list[tuple[int, int, bytes]] = []
    done = threading.Event()

    def on_frame(f: CanFrame) -> None:
        assert f.device_ts_ns is not None
        received.append((f.device_ts_ns, f.arbitration_id, f.data))
        out = assembler.add(decoder.decode(f.arbitration_id, f.data, f.device_ts_ns))
        if out is not None:
            parts.append(out)
        if len(received) == len(frames):
            done.set()

    config = CanBusConfig(interface="virtual", channel=channel, bitrate=None, name="correvit")
    session = CanBusLink(config, on_frame, clock=ScaledClock(T0_NS), stats_period_s=None)
    with session, can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx:
        for ts, fid, data in frames:
            tx.send(can.Message(timestamp=ts / 1e9, arbitration_id=fid, data=data, is_extended_id=False))
        assert done.wait(20.0)
    assert session.failure is None
    tail = assembler.flush()
    if tail is not None:
        parts.append(tail)
    return concatenate(parts), received


def test_live_over_a_virtual_bus_equals_offline(db, rolemap, slalom_frames) -> None:
    truth, spec, frames = slalom_frames
    frames = frames[:400]
    live, received = _send_and_assemble(db, rolemap, spec, frames, "daq-correvit-live")
    assert len(received) == len(frames)
    offline = from_role_series(spec, VectorRoleDecoder(db, rolemap).decode(FrameBatch.from_frames(received)).roles)
    assert len(live) == len(offline) == 200
    assert live.time_ns is not None and offline.time_ns is not None
    np.testing.assert_array_equal(live.time_ns, offline.time_ns)
    for name in ("vx", "vy", "slip_angle", "speed", "valid"):
        np.testing.assert_array_equal(getattr(live, name), getattr(offline, name))
    t = truth_times(live)
    err = np.degrees(live.slip_angle - np.interp(t, truth.t, truth.point_sideslip(*spec.mount_xy)))
    assert np.max(np.abs(err)) < 0.01


def test_lost_and_corrupt_frames_invalidate_only_their_cycle(db, rolemap, slalom_frames) -> None:
    _, spec, frames = slalom_frames
    frames = list(frames[:200])
    angle_id, vel_id = 0x7C1, 0x7C0
    drop = [i for i, f in enumerate(frames) if f[1] == angle_id][30]  # cycle 30 loses its angle frame
    short = [i for i, f in enumerate(frames) if f[1] == vel_id][50]  # cycle 50's velocity frame is truncated
    frames[short] = (frames[short][0], vel_id, frames[short][2][:5])
    del frames[drop]
    live, received = _send_and_assemble(db, rolemap, spec, frames, "daq-correvit-faults")
    offline = from_role_series(spec, VectorRoleDecoder(db, rolemap).decode(FrameBatch.from_frames(received)).roles)
    for s in (live, offline):
        # the truncated primary frame still clocks a sample (its time is known), with no values
        assert len(s) == 100
        assert np.flatnonzero(~s.valid).tolist() == [30, 50]
        assert np.isnan(s.slip_angle[[30, 50]]).all()
    np.testing.assert_array_equal(live.slip_angle, offline.slip_angle)


def test_roles_derive_the_same_way_as_on_the_analog_path(db, rolemap, slalom_frames) -> None:
    """A sensor mapped with slip_angle + speed only gives the same velocities as with vx + vy."""
    _, full_spec, frames = slalom_frames
    batch = VectorRoleDecoder(db, rolemap).decode(FrameBatch.from_frames(frames))
    full = from_role_series(full_spec, batch.roles)
    polar = from_role_series(can_spec((OpticalRole.SLIP_ANGLE, OpticalRole.SPEED)), batch.roles)
    np.testing.assert_allclose(polar.vx, full.vx, atol=0.01)  # 0.01 km/h, 0.01° quantisation
    np.testing.assert_allclose(polar.vy, full.vy, atol=0.01)
    with pytest.raises(ConfigError, match=r"CAN roles \['correvit_vx'\] not decoded"):
        from_role_series(full_spec, {k: v for k, v in batch.roles.items() if k != "correvit_vx"})
    chans = (OpticalChannel(OpticalRole.VX, can_role="vx2"), OpticalChannel(OpticalRole.VY, can_role="correvit_vy"))
    other = OpticalSensorSpec("x", SensorKind.BODY, MOUNT, chans)
    with pytest.raises(ConfigError, match=r"CAN roles \['vx2'\] are not in the CAN role map"):
        OpticalCanAssembler(other, rolemap)
    with pytest.raises(ConfigError, match="exactly one of a DAQ channel or a CAN role"):
        OpticalChannel(OpticalRole.VX, channel="ai0", can_role="correvit_vx")
