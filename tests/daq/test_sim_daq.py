"""Simulated DAQ: quantisation, saturation, noise, hold and lag, sample-clock error, overflow, timing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.analog import AnalogDecoder, LinearScaling, brake_pressure_spec
from drivers.daq import DaqChannelConfig, find_edges
from drivers.optical import OpticalSensorSpec, SensorKind, convert_block, correvit_channels
from sim_devices.daq import (
    BrakePressureOutput,
    ConstantInput,
    FunctionOutput,
    SimDaqBackend,
    SimDaqLink,
    SimOpticalSensor,
    SyncPulseOutput,
)
from tests.daq.helpers import T0_NS, ManualClock, optical_channels, optical_wiring, ramp, steady_circle
from vsccore.errors import ConfigError, DeviceError, DeviceTimeoutError

RATE = 1000.0
STEP_PM10 = 20.0 / 65536


def body_spec() -> OpticalSensorSpec:
    return OpticalSensorSpec("body", SensorKind.BODY, (1.6, 0.5, 0.4), correvit_channels("body"))


def make(truth, sources, channels, clock=None, **kw):
    b = SimDaqBackend(clock=clock or ManualClock(), truth=truth, sources=sources, truth_start_ns=T0_NS, **kw)
    b.configure(channels)
    return b


def test_quantisation_step_is_range_over_65536() -> None:
    chans = [DaqChannelConfig("pm10", "sim/ai0", -10.0, 10.0), DaqChannelConfig("u5", "sim/ai1", 0.0, 5.0)]
    slow = LinearScaling(1.0)  # volts = truth time · 0.01 V/s → far finer than one step per sample
    sources = {
        "sim/ai0": FunctionOutput(lambda tr, t: 0.3 + 0.01 * t, slow),
        "sim/ai1": FunctionOutput(lambda tr, t: 1.7 + 0.01 * t, slow),
    }
    b = make(steady_circle(duration=3.0), sources, chans, adc_noise_v=0.0)
    v = b.generate(t1_s=2.0)
    for row, lo, step in ((v[0], -10.0, STEP_PM10), (v[1], 0.0, 5.0 / 65536)):
        levels = np.unique(row)
        assert np.min(np.diff(levels)) == pytest.approx(step, rel=1e-9)
        codes = (levels - lo) / step
        np.testing.assert_allclose(codes, np.round(codes), atol=1e-6)
    # and the quantised value never differs from the input by more than half a step
    t = b.sample_time_s(np.arange(v.shape[1]), 0.0, RATE)
    assert np.max(np.abs(v[0] - (0.3 + 0.01 * t))) <= STEP_PM10 / 2 + 1e-12


def test_saturation_at_the_input_range() -> None:
    chans = [
        DaqChannelConfig("hi", "sim/ai0"),
        DaqChannelConfig("lo", "sim/ai1"),
        DaqChannelConfig("u", "sim/ai2", 0, 5),
    ]
    sources = {"sim/ai0": ConstantInput(12.5), "sim/ai1": ConstantInput(-11.0), "sim/ai2": ConstantInput(7.0)}
    b = make(None, sources, chans)
    v = b.generate(t1_s=0.5)
    assert np.all(v[0] == 10.0 - STEP_PM10)  # the top code of a ±10 V 16-bit converter
    assert np.all(v[1] == -10.0)
    assert np.all(v[2] == 5.0 - 5.0 / 65536)


def test_adc_noise_std() -> None:
    chans = [DaqChannelConfig("c", "sim/ai0")]
    b = make(None, {"sim/ai0": ConstantInput(1.0)}, chans, adc_noise_v=0.004)
    v = b.generate(t1_s=20.0)[0]
    # quantisation adds step²/12, negligible here
    assert np.std(v) == pytest.approx(math.sqrt(0.004**2 + STEP_PM10**2 / 12), rel=0.03)
    assert np.mean(v) == pytest.approx(1.0, abs=1e-4)


def test_velocity_noise_std_and_internal_update_hold() -> None:
    truth = steady_circle(duration=12.0)
    spec = body_spec()
    sensor = SimOpticalSensor(spec, internal_rate_hz=250.0, velocity_noise_mps=0.05)
    chans = optical_channels("body", 0)
    b = make(truth, optical_wiring(sensor, chans), chans, adc_noise_v=0.0)
    v = b.generate(t1_s=10.0)
    k = np.arange(v.shape[1])
    # held at 250 Hz: with a 1 kHz DAQ the output changes at most once every 4 samples
    vx_volts = v[0]
    assert np.all(vx_volts[4 * (k[:-4] // 4) + 1] == vx_volts[4 * (k[:-4] // 4)])
    changes = np.count_nonzero(np.diff(vx_volts))
    assert 0.9 * v.shape[1] / 4 < changes <= v.shape[1] / 4
    # one value per internal update: its std is the configured noise (quantisation ~2 mm/s is small)
    from drivers.daq import DaqBlock

    s = convert_block(spec, DaqBlock(0, RATE, v, 0, tuple(c.name for c in chans)))
    vx_updates = s.vx[::4]
    vx_true = truth.point_velocity(1.6, 0.5)[0][0]
    lsb_mps = STEP_PM10 / 0.04 / 3.6
    assert np.std(vx_updates) == pytest.approx(math.sqrt(0.05**2 + lsb_mps**2 / 12), rel=0.05)
    assert np.mean(vx_updates) == pytest.approx(vx_true, abs=4 * 0.05 / math.sqrt(vx_updates.size))


@pytest.mark.parametrize(("lag_s", "delay_s"), [(0.0, 0.0), (0.05, 0.0), (0.02, 0.01)])
def test_lag_of_a_ramp(lag_s: float, delay_s: float) -> None:
    accel = 2.0
    truth = ramp(v0=5.0, accel=accel, duration=10.0)
    spec = OpticalSensorSpec("body", SensorKind.BODY, (0.0, 0.0, 0.0), correvit_channels("body"))
    f_int = 250.0
    sensor = SimOpticalSensor(spec, internal_rate_hz=f_int, lag_s=lag_s, delay_s=delay_s, velocity_noise_mps=0.0)
    chans = optical_channels("body", 0)
    b = make(truth, optical_wiring(sensor, chans), chans, adc_noise_v=0.0)
    v = b.generate(t1_s=9.0)
    from drivers.daq import DaqBlock

    s = convert_block(spec, DaqBlock(0, RATE, v, 0, tuple(c.name for c in chans)))
    t = np.asarray(b.sample_time_s(np.arange(v.shape[1]), 0.0, RATE))
    settled = t > 1.0 + 10 * lag_s
    measured_lag = np.mean((5.0 + accel * t - s.vx)[settled]) / accel
    # Expected: a first-order lag updated every h lags a ramp by h / (e^{h/τ} − 1) (→ τ − h/2 for
    # h ≪ τ); the zero-order hold adds the mean age of the held value at the sample instants; plus
    # the pure delay.
    h = 1.0 / f_int
    filt = 0.0 if lag_s == 0 else h / math.expm1(h / lag_s)
    hold = np.mean((t - np.floor(t * f_int + 1e-6) / f_int)[settled])
    expected = filt + hold + delay_s
    assert measured_lag == pytest.approx(expected, abs=2e-5)
    # to first order in h/τ: τ − h/2 + hold + delay (hold 1.5 ms: samples 0…3 ms into each update)
    assert hold == pytest.approx(1.5e-3, abs=1e-6)
    approx = (lag_s - h / 2 if lag_s else 0.0) + hold + delay_s
    assert measured_lag == pytest.approx(approx, abs=1e-4)


def test_below_min_speed_status_is_invalid_and_angle_zero() -> None:
    truth = ramp(v0=0.0, accel=1.0, duration=3.0)  # below 0.5 km/h for the first 0.139 s
    spec = body_spec()
    sensor = SimOpticalSensor(spec, internal_rate_hz=1000.0, velocity_noise_mps=0.0)
    chans = optical_channels("body", 0)
    b = make(truth, optical_wiring(sensor, chans), chans)
    v = b.generate(t1_s=1.0)
    t = np.asarray(b.sample_time_s(np.arange(v.shape[1]), 0.0, RATE))
    from drivers.daq import DaqBlock

    s = convert_block(spec, DaqBlock(0, RATE, v, 0, tuple(c.name for c in chans)))
    slow = t < 0.5 / 3.6 - 0.002
    fast = t > 0.5 / 3.6 + 0.002
    assert np.all(v[4][slow] < 1.0) and np.all(v[4][fast] > 4.0)
    assert not s.valid[slow].any() and s.valid[fast].all()
    assert np.all(np.isnan(s.slip_angle[slow]))


def test_sample_clock_error_moves_sync_edges_as_predicted() -> None:
    truth = steady_circle(duration=10.0)
    edges_s = (1.0, 3.5004, 8.25)
    chans = [DaqChannelConfig("sync", "sim/ai0", 0.0, 10.0)]
    src = {"sim/ai0": SyncPulseOutput(edges_s, width_s=0.2, rise_time_s=0.004)}
    ppm, offset = 80.0, 0.0021
    b = make(truth, src, chans, clock_ppm=ppm, clock_offset_s=offset, adc_noise_v=0.002)
    v = b.generate(t1_s=9.0)[0]
    found = find_edges(v, low=1.0, high=4.0)
    expected = (np.asarray(edges_s) - offset) * RATE * (1 + ppm * 1e-6)
    np.testing.assert_allclose(found, expected, atol=0.01)  # 10 µs at 1 kHz
    nominal = np.asarray(edges_s) * RATE
    assert np.all(np.abs(found - nominal) > 1.0)  # the error is visible, and large enough to matter


def test_live_blocks_equal_offline_generation() -> None:
    truth = steady_circle(duration=6.0)
    spec = body_spec()
    sensor = SimOpticalSensor(spec, lag_s=0.01, velocity_noise_mps=0.03, seed=7)
    chans = optical_channels("body", 0) + [DaqChannelConfig("sync", "sim/ai9", 0, 10)]
    sources = optical_wiring(sensor, chans[:5]) | {"sim/ai9": SyncPulseOutput((1.2345,))}
    clock = ManualClock()
    b = make(truth, sources, chans, clock=clock, adc_noise_v=0.001, seed=3)
    b.start(RATE)
    blocks = [b.read(n, timeout_s=5.0) for n in (1, 37, 250, 1000, 3, 1709)]
    b.stop()
    data = np.concatenate([blk.data for blk in blocks], axis=1)
    idx = np.concatenate([blk.sample_indices() for blk in blocks])
    np.testing.assert_array_equal(idx, np.arange(data.shape[1]))
    offline = b.generate(t1_s=4.0)
    np.testing.assert_array_equal(data, offline[:, : data.shape[1]])
    assert all(blk.lost_before is None for blk in blocks)
    # the clock only reached the last sample's instant: samples were never delivered early
    assert clock.now_ns() == T0_NS + round(b.sample_time_s(data.shape[1] - 1) * 1e9)


def test_overflow_reports_lost_range_and_loses_no_earlier_sample() -> None:
    truth = steady_circle(duration=30.0)
    sensor = SimOpticalSensor(body_spec(), velocity_noise_mps=0.03)
    chans = optical_channels("body", 0)
    clock = ManualClock()
    b = make(truth, optical_wiring(sensor, chans), chans, clock=clock)
    b.start(RATE, buffer_size=1000)
    first = b.read(200, timeout_s=1.0)
    clock.advance(5.0)  # the reader stalls for 5 s with a 1 s buffer
    now_s = (clock.now_ns() - T0_NS) / 1e9
    acquired = math.floor(now_s * RATE) + 1  # samples 0 … acquired−1 exist by now
    after = b.read(100, timeout_s=1.0)
    assert after.lost_before is not None
    assert after.lost_before.start_index == 200
    assert after.lost_before.stop_index == acquired - 1000
    assert after.first_sample_index == after.lost_before.stop_index
    assert after.lost_before.count == acquired - 1000 - 200
    nxt = b.read(100, timeout_s=1.0)
    assert nxt.lost_before is None and nxt.first_sample_index == after.next_sample_index
    offline = b.generate(t1_s=10.0)
    np.testing.assert_array_equal(first.data, offline[:, :200])
    np.testing.assert_array_equal(after.data, offline[:, after.first_sample_index : after.next_sample_index])
    np.testing.assert_array_equal(nxt.data, offline[:, nxt.first_sample_index : nxt.next_sample_index])


def test_timeout_consumes_nothing() -> None:
    chans = [DaqChannelConfig("c", "sim/ai0")]
    clock = ManualClock()
    b = make(None, {"sim/ai0": ConstantInput(1.0)}, chans, clock=clock)
    b.start(RATE, buffer_size=5000)
    with pytest.raises(DeviceTimeoutError, match=r"sim: 3000 samples not acquired within 1\.0 s"):
        b.read(3000, timeout_s=1.0)
    blk = b.read(3000, timeout_s=5.0)
    assert blk.first_sample_index == 0
    with pytest.raises(ConfigError, match="5000-sample buffer"):
        b.read(6000, timeout_s=10.0)


def test_brake_pressure_channels_decode_to_the_model_pressure() -> None:
    truth = ramp(v0=30.0, accel=-4.0, duration=5.0)
    specs = [brake_pressure_spec("p_master", "p_master"), brake_pressure_spec("p_rl", "p_rl")]
    chans = [DaqChannelConfig("p_master", "sim/ai0", 0, 5), DaqChannelConfig("p_rl", "sim/ai1", 0, 5)]
    sources = {
        "sim/ai0": BrakePressureOutput("master", specs[0].scaling),
        "sim/ai1": BrakePressureOutput("rl", specs[1].scaling),
    }
    b = make(truth, sources, chans)
    from drivers.daq import DaqBlock

    v = b.generate(t1_s=4.0)
    p = AnalogDecoder(specs).decode(DaqBlock(0, RATE, v, 0, ("p_master", "p_rl")))
    master_expected = 1.0e6 * (4.0 - 0.3)  # 37 bar for 4 m/s² of braking
    assert np.mean(p["p_master"][100:-100]) == pytest.approx(master_expected, abs=500.0)
    assert np.mean(p["p_rl"][100:-100]) == pytest.approx(0.7 * master_expected, abs=500.0)


def test_unplugged_device_fails_start_and_read() -> None:
    link = SimDaqLink()
    chans = [DaqChannelConfig("c", "sim/ai0")]
    b = make(None, {"sim/ai0": ConstantInput(0.0)}, chans, link=link)
    b.start(RATE)
    b.read(10, 1.0)
    link.unplug()
    with pytest.raises(DeviceError, match="disappeared"):
        b.read(10, 1.0)
    b.stop()
    with pytest.raises(DeviceError, match="not found"):
        b.start(RATE)
    link.replug()
    b.start(RATE)
    assert b.read(10, 1.0).first_sample_index == 0
    b.close()


def test_configuration_errors() -> None:
    spec = body_spec()
    sensor = SimOpticalSensor(spec)
    chans = optical_channels("body", 0)
    b = SimDaqBackend(clock=ManualClock(), sources=optical_wiring(sensor, chans))
    with pytest.raises(ConfigError, match="needs ground truth"):
        b.configure(chans)
    with pytest.raises(ConfigError, match="unique"):
        b.configure([DaqChannelConfig("a", "sim/ai0"), DaqChannelConfig("a", "sim/ai1")])
    with pytest.raises(ConfigError, match="configure channels before start"):
        b.start(RATE)
    with pytest.raises(ConfigError, match="min_v < max_v"):
        DaqChannelConfig("x", "sim/ai0", 5.0, -5.0)
