"""The simulated VSC ECU: periods, counters and checksums, sensor error statistics, its sideslip estimate."""

from __future__ import annotations

import math
import queue
import time
import tomllib
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from drivers.can.bus import CanBusConfig, CanBusLink, CanFrame
from drivers.can.checks import FrameFlag, get_checksum
from drivers.can.roles import RoleDecoder, RoleMap
from drivers.can.vector_decode import FrameBatch, VectorRoleDecoder
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from sim_devices.vsc_ecu import InertialSensorErrors, VscEcu, VscEcuConfig, frames, simulate_ecu, vsc_sim_dbc_path
from tests.can_live.truth_builders import standstill, steady_circle, steady_circle_state
from vsccore.clock import ScaledClock

REPO = Path(__file__).resolve().parents[2]
ROLES = REPO / "examples" / "roles" / "vsc_sim.toml"
DEG = math.pi / 180.0


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    # cantools' own loader, independent of the project's
    return cantools.database.load_file(vsc_sim_dbc_path())


@pytest.fixture(scope="module")
def rolemap(db: cantools.database.can.Database) -> RoleMap:
    with ROLES.open("rb") as fh:
        return RoleMap.from_mapping(tomllib.load(fh), db, source=str(ROLES))


def _by_message(frame_list: list[tuple[float, can.Message]], db) -> dict[str, list[tuple[float, can.Message]]]:
    out: dict[str, list[tuple[float, can.Message]]] = defaultdict(list)
    for t, m in frame_list:
        out[db.get_message_by_frame_id(m.arbitration_id).name].append((t, m))
    return out


def _role_series(frame_list, db, rolemap) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Decode frames with the vectorised role decoder: role → (t s, value SI, flags); no frame may be flagged."""
    batch = FrameBatch.from_frames([(round(t * 1e9), m.arbitration_id, bytes(m.data)) for t, m in frame_list])
    result = VectorRoleDecoder(db, rolemap).decode(batch)
    for decoded in result.messages.values():
        assert not (decoded.flags & int(FrameFlag.frame_level())).any(), decoded.name
    return {
        role: (series.timestamps_ns / 1e9, series.values, series.flags.astype(np.int64))
        for role, series in result.roles.items()
    }


def _live_flags(frame_list, db, rolemap) -> set[int]:
    """Frame-level flags the live (per-frame) decoder gives these frames."""
    decoder = RoleDecoder(db, rolemap)
    return {int(decoder.decode(m.arbitration_id, bytes(m.data), round(t * 1e9)).flags) for t, m in frame_list}


# --- the wire ------------------------------------------------------------------------------------


def test_messages_come_at_their_dbc_periods(db) -> None:
    truth = steady_circle(15.0, 100.0, 10.0)
    by_name = _by_message(list(frames(truth)), db)
    assert set(by_name) == {m.name for m in db.messages}
    for name, items in by_name.items():
        period = db.get_message_by_name(name).cycle_time / 1000.0
        t = np.array([x[0] for x in items])
        d = np.diff(t)
        assert len(items) == pytest.approx(10.0 / period, abs=1.5), name
        assert np.mean(d) == pytest.approx(period, rel=2e-3), name
        assert np.max(np.abs(d - period)) < 0.5e-3, name  # transmit jitter only
        assert all(m.timestamp == tt for tt, m in items)


def test_counters_increment_and_checksums_verify(db, rolemap) -> None:
    frame_list = list(frames(steady_circle(15.0, 100.0, 3.0)))
    by_name = _by_message(frame_list, db)
    crc = get_checksum("vw_mqb_crc8")
    protected = [c.message for c in rolemap.checks if c.verifies_checksum]
    assert set(protected) == {"ESC_SensorCluster", "SAS_Steering", "ESC_BrakePressure", "VSC_Status"}
    for name in protected:
        message = db.get_message_by_name(name)
        counters = []
        for _, m in by_name[name]:
            fields = message.decode(bytes(m.data), decode_choices=False)
            counters.append(int(fields["COUNTER"]))
            assert int(fields["CHECKSUM"]) == crc.compute(m.arbitration_id, bytes(m.data))
        assert np.all(np.diff(counters) % 16 == 1), name
    # and both role decoders flag nothing (counter and checksum checks included)
    _role_series(frame_list, db, rolemap)
    assert _live_flags(frame_list, db, rolemap) == {int(FrameFlag.OK)}
    # a corrupted payload is caught
    _t, m = by_name["ESC_SensorCluster"][10]
    bad = bytearray(m.data)
    bad[3] ^= 0x01
    decoder = RoleDecoder(db, rolemap)
    assert decoder.decode(m.arbitration_id, bytes(bad), 0).flags == FrameFlag.CHECKSUM


def test_frames_are_deterministic_given_the_seed() -> None:
    truth = steady_circle(15.0, 100.0, 1.0)
    a = [(t, bytes(m.data)) for t, m in frames(truth, VscEcuConfig(seed=7))]
    b = [(t, bytes(m.data)) for t, m in frames(truth, VscEcuConfig(seed=7))]
    c = [(t, bytes(m.data)) for t, m in frames(truth, VscEcuConfig(seed=8))]
    assert a == b
    assert a != c


def test_signs_on_the_wire_and_after_the_role_mapping(db, rolemap) -> None:
    """Left-hand circle: ISO yaw rate, lateral acceleration and steering angle all positive after the
    role mapping, while the car's own SAS_Angle is negative (clockwise positive, role `invert`)."""
    truth = steady_circle(15.0, 100.0, 2.0)
    frame_list = list(frames(truth))
    by_name = _by_message(frame_list, db)
    sas = db.get_message_by_name("SAS_Steering")
    raw_angle = np.array([sas.decode(bytes(m.data))["SAS_Angle"] for _, m in by_name["SAS_Steering"]])
    assert np.all(raw_angle < 0)
    roles = _role_series(frame_list, db, rolemap)
    cfg = VscEcuConfig()
    swa_expected = truth.swa[0] + cfg.swa_offset_rad
    assert np.all(np.abs(roles["swa"][1] - swa_expected) <= 0.05 * DEG + 1e-9)  # 0.1° resolution
    valid = roles["yaw_rate"][2] == 0
    assert np.mean(roles["yaw_rate"][1][valid]) == pytest.approx(truth.yaw_rate[0] + cfg.yaw_rate.bias, abs=0.02 * DEG)
    assert np.mean(roles["lat_accel"][1][valid]) == pytest.approx(truth.ay_meas[0] + cfg.lat_accel.bias, abs=0.01)
    # quality bits during warm-up become INVALID flags, values are the substitute 0
    warm = roles["yaw_rate"][0] < cfg.sensor_warmup_s
    assert np.all(roles["yaw_rate"][2][warm] == int(FrameFlag.INVALID))
    assert np.all(roles["yaw_rate"][1][warm] == 0)
    assert np.all(roles["yaw_rate"][2][~warm] == 0)


# --- sensor error statistics -----------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2])
def test_inertial_sensor_bias_and_noise_match_the_configuration(db, rolemap, seed: int) -> None:
    cfg = VscEcuConfig(
        seed=seed,
        yaw_rate=InertialSensorErrors(bias=0.4 * DEG, noise_std=0.1 * DEG),
        lat_accel=InertialSensorErrors(bias=-0.08, noise_std=0.05),
        long_accel=InertialSensorErrors(bias=0.03, noise_std=0.04),
    )
    truth = standstill(40.0)
    roles = _role_series(list(frames(truth, cfg)), db, rolemap)
    lsb = {  # DBC resolutions, in SI
        "yaw_rate": 0.01 * DEG,
        "lat_accel": 0.0001 * 9.80665,
        "long_accel": 0.001,
    }
    for role, err in (("yaw_rate", cfg.yaw_rate), ("lat_accel", cfg.lat_accel), ("long_accel", cfg.long_accel)):
        _t, x, flags = roles[role]
        x = x[flags == 0]
        n = x.size
        assert n > 3900
        expected_std = math.sqrt(err.noise_std**2 + lsb[role] ** 2 / 12)
        # mean: 4 standard errors; std: chi-square, 4 sigma of std/sqrt(2n)
        assert np.mean(x) == pytest.approx(err.bias, abs=4 * expected_std / math.sqrt(n)), role
        assert np.std(x) == pytest.approx(expected_std, rel=4 / math.sqrt(2 * n)), role
        # quantised to the DBC grid
        assert np.allclose(np.round(x / lsb[role]) * lsb[role], x, atol=1e-9 * abs(lsb[role]) + 1e-12)


def test_standstill_offset_learning_reaches_the_true_bias(db, rolemap) -> None:
    cfg = VscEcuConfig(seed=3, yaw_rate=InertialSensorErrors(bias=0.5 * DEG, noise_std=0.08 * DEG))
    roles = _role_series(list(frames(standstill(20.0), cfg)), db, rolemap)
    t, offset, _ = roles["vsc_yaw_rate_offset"]
    # learnt with a 2 s time constant: after 10 time constants within noise/sqrt(averaging) + 1 LSB
    assert np.all(np.abs(offset[t > 15.0] - 0.5 * DEG) < 0.02 * DEG)
    assert roles["vsc_beta_estimate"][2].max() == int(FrameFlag.INVALID)  # no estimate at standstill


def test_wheel_speeds_from_tooth_timing(db, rolemap) -> None:
    truth = steady_circle(20.0, 133.3, 4.0)
    # ideal encoder and tyres: only the 1 µs timer and the 0.01 km/h DBC step remain
    ideal = VscEcuConfig(tooth_pitch_error_std=0.0, tyre_radius_error=(0.0, 0.0, 0.0, 0.0))
    roles = _role_series(list(frames(truth, ideal)), db, rolemap)
    for w, wheel in enumerate(("fl", "fr", "rl", "rr")):
        t, v, _ = roles[f"wheel_speed_{wheel}"]
        v_true = truth.wheel_speed[0, w]
        arc = 2 * math.pi * ideal.wheel_radius_m / ideal.wheel_teeth
        span = (int(v_true * ideal.wheel_window_s / arc) - 1) * arc / v_true  # shortest edge span in the window
        bound = v_true * 2e-6 / span + 0.005 / 3.6 + 1e-9
        assert np.max(np.abs(v[t > 0.1] - v_true)) <= bound, wheel
    # real encoder and tyres: each wheel reads its speed over the ECU's nominal radius, ± pitch errors
    real = VscEcuConfig(seed=4)
    roles = _role_series(list(frames(truth, real)), db, rolemap)
    for w, wheel in enumerate(("fl", "fr", "rl", "rr")):
        t, v, _ = roles[f"wheel_speed_{wheel}"]
        scaled = truth.wheel_speed[0, w] / (1 + real.tyre_radius_error[w])
        assert np.mean(v[t > 0.1]) == pytest.approx(scaled, rel=3e-4), wheel
        assert np.std(v[t > 0.1]) > 0.002  # pitch errors show as noise


def test_wheel_speed_is_zero_below_the_lowest_measurable_speed(db) -> None:
    cfg = VscEcuConfig(seed=5)
    arc = 2 * math.pi * cfg.wheel_radius_m / cfg.wheel_teeth
    v_min = arc / cfg.wheel_timeout_s  # one tooth per timeout
    for v, moving in ((0.5 * v_min, False), (3.0 * v_min, True)):
        truth = replace(standstill(3.0), wheel_speed=np.full((3001, 4), v))
        out = simulate_ecu(truth, cfg, db)
        kmh = out.messages["ESC_WheelSpeeds"].signals["ESC_WheelSpeed_FL"]
        late = out.messages["ESC_WheelSpeeds"].t > 1.0
        if moving:
            assert np.all(kmh[late] > 0)
            assert np.mean(kmh[late]) == pytest.approx(v * 3.6, rel=0.05)
        else:
            assert np.all(kmh[late] == 0)


# --- the controller's sideslip estimate --------------------------------------------------------------


def _estimate_error_deg(
    v: float, radius: float, db, rolemap, duration: float = 15.0
) -> tuple[float, tuple[float, float]]:
    truth = steady_circle(v, radius, duration)
    roles = _role_series(list(frames(truth, VscEcuConfig(seed=11))), db, rolemap)
    t, beta, flags = roles["vsc_beta_estimate"]
    settled = (t > 8.0) & (flags == 0)
    beta_true = float(truth.beta_cg[0])
    err = (beta[settled] - beta_true) / DEG
    tk, beta_kin, _ = roles["vsc_beta_kinematic"]
    at = [float(beta_kin[np.searchsorted(tk, x)]) / DEG for x in (5.0, 10.0, 14.9)]
    return float(np.max(np.abs(err))), (at[1] - at[0], at[2] - at[1])


def test_estimate_tracks_true_sideslip_in_the_linear_range(db, rolemap) -> None:
    # a_y = 2.25 and 3 m/s²: linear tyres; stated tolerance 0.3°
    for v, radius in ((15.0, 100.0), (20.0, 133.3)):
        assert steady_circle_state(v, radius)["a"] < 0.35 * 9.81
        err, _ = _estimate_error_deg(v, radius, db, rolemap)
        assert err < 0.3, (v, radius, err)


def test_estimate_degrades_near_the_limit(db, rolemap) -> None:
    v, radius = 20.0, 47.06  # a_y = 8.5 m/s², 0.87 of the friction limit
    state = steady_circle_state(v, radius)
    # the true sideslip is far beyond what a linear model predicts: the observer cannot be right
    assert abs(state["beta"] - state["beta_linear"]) > 1.0 * DEG
    err_limit, kin_drift = _estimate_error_deg(v, radius, db, rolemap)
    err_linear, _ = _estimate_error_deg(20.0, 133.3, db, rolemap)
    assert err_limit > 1.0
    assert err_limit > 4 * err_linear
    # the pure kinematic integration drifts steadily (sensor biases, roll compensation error)
    first, second = kin_drift
    assert abs(first) > 0.25
    assert abs(second) > 0.25
    assert first * second > 0


# --- running on buses -------------------------------------------------------------------------------


def test_ecu_runs_in_scaled_time_on_a_virtual_bus(channel: str, db) -> None:
    truth = steady_circle(15.0, 100.0, 2.0)
    expected = [(t, m.arbitration_id, bytes(m.data)) for t, m in frames(truth)]
    outputs = simulate_ecu(truth)  # computed before the clock starts: the drive starts 0.3 s in
    t0_ns = 1_700_000_000_000_000_000
    clock = ScaledClock(t0_ns - 300_000_000, speed=10.0)
    received: queue.Queue[CanFrame] = queue.Queue()
    session = CanBusLink(CanBusConfig(interface="virtual", channel=channel), received.put, clock=clock)
    with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as ecu_bus, session:
        # a loaded machine may start the ECU late: it then catches up instead of skipping frames
        ecu = VscEcu(truth, ecu_bus, clock, t0_ns, outputs=outputs, max_lag_s=60.0)
        with ecu:
            assert ecu.finished.wait(10.0)
        got = [received.get(timeout=3.0) for _ in expected]
    assert ecu.failure is None
    assert ecu.frames_skipped == 0
    assert ecu.frames_sent == len(expected)
    assert [(f.arbitration_id, f.data) for f in got] == [(i, d) for _, i, d in expected]
    for f, (t, _, _) in zip(got, expected, strict=True):
        assert f.device_ts_ns == pytest.approx(t0_ns + t * 1e9, abs=1000)  # the ECU's transmit time
        assert f.host_ts_ns >= f.device_ts_ns - 1_000_000  # received after (on the shared scaled clock)


def test_ecu_stop_is_prompt(channel: str) -> None:
    truth = steady_circle(15.0, 100.0, 60.0)
    outputs = simulate_ecu(truth)
    total = sum(len(s.t) for s in outputs.messages.values())
    clock = ScaledClock(0)
    with can.Bus(interface="virtual", channel=channel) as bus, can.Bus(interface="virtual", channel=channel) as rx:
        ecu = VscEcu(truth, bus, clock, 0, outputs=outputs)
        ecu.start()
        assert rx.recv(timeout=5.0) is not None  # sending has begun
        t = time.monotonic()
        ecu.stop()
        assert time.monotonic() - t < 0.5
        assert ecu.finished.is_set()
        assert 0 < ecu.frames_sent < total // 10  # stopped within the first seconds of a 60 s drive


def test_ecu_frames_reach_a_python_can_socketcand_client_and_decode(channel: str, db, rolemap) -> None:
    truth = steady_circle(15.0, 100.0, 3.0)
    server = SocketcandServer(virtual_channel_opener({"vsc0": channel}))
    server.start()
    try:
        host, port = server.address
        with (
            can.Bus(interface="virtual", channel=channel) as ecu_bus,
            can.Bus(interface="socketcand", host=host, port=port, channel="vsc0") as client,
        ):
            assert server.wait_for_clients(1, 3.0)
            clock = ScaledClock(0, speed=3.0)
            ecu = VscEcu(truth, ecu_bus, clock, 200_000_000)  # starts after the client's raw mode settled
            with ecu:
                decoder = RoleDecoder(db, rolemap)
                yaw = []
                while not (ecu.finished.is_set() and len(yaw) > 0):
                    msg = client.recv(0.5)
                    if msg is None:
                        continue
                    decoded = decoder.decode(msg.arbitration_id, bytes(msg.data), 0)
                    assert decoded.flags == FrameFlag.OK
                    yaw += [s.value for s in decoded.samples if s.role == "yaw_rate" and s.flags == FrameFlag.OK]
                assert ecu.finished.wait(5.0)
    finally:
        server.stop()
    assert len(yaw) > 100
    assert np.mean(yaw) == pytest.approx(truth.yaw_rate[0] + VscEcuConfig().yaw_rate.bias, abs=0.03 * DEG)
