"""Channel health: saturated, stuck and floating (disconnected) channels become events; good ones do not."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.analog import LinearScaling
from drivers.daq import ChannelHealth, DaqBlock, DaqChannelConfig, DaqEventKind, HealthLimits
from sim_devices.daq import ConstantInput, FunctionOutput, SimDaqBackend, SimOpticalSensor, SyncPulseOutput
from tests.daq.helpers import T0_NS, ManualClock, optical_channels, optical_wiring, slalom
from vsccore.errors import ConfigError

RATE = 1000.0


def _run(backend: SimDaqBackend, health: ChannelHealth, seconds: float, block: int = 100) -> list:
    backend.start(RATE)
    events = []
    next_index = 0
    for _ in range(int(seconds * RATE) // block):
        blk = backend.read(block, timeout_s=1.0)
        assert blk.first_sample_index == next_index  # the checker never costs a sample
        next_index = blk.next_sample_index
        events += health.check(blk)
    backend.close()
    return events


def test_good_channels_raise_no_events_and_bad_ones_do() -> None:
    from drivers.optical import OpticalSensorSpec, SensorKind, correvit_channels

    truth = slalom(duration=8.0)
    spec = OpticalSensorSpec("body", SensorKind.BODY, (1.6, 0.5, 0.4), correvit_channels("body"))
    sensor = SimOpticalSensor(spec, velocity_noise_mps=0.02)
    chans = optical_channels("body", 0, ("vx", "vy", "slip_angle", "speed")) + [
        DaqChannelConfig("sync", "sim/ai8"),  # 0–5 V TTL on a ±10 V input: 0 V is not at a range end
        DaqChannelConfig("railed", "sim/ai9"),
        DaqChannelConfig("frozen", "sim/ai10"),
        DaqChannelConfig("open", "sim/ai11"),  # not wired: floats
    ]
    sources = optical_wiring(sensor, chans[:4]) | {
        "sim/ai8": SyncPulseOutput((1.0, 3.0, 5.0)),
        "sim/ai9": ConstantInput(11.0),
        "sim/ai10": ConstantInput(2.0),
    }
    b = SimDaqBackend(clock=ManualClock(), truth=truth, sources=sources, truth_start_ns=T0_NS)
    b.configure(chans)
    health = ChannelHealth(chans, limits={"sync": HealthLimits(check_stuck=False)}, clock=ManualClock())
    events = _run(b, health, 6.0)
    by = {(e.kind, e.channel) for e in events}
    assert by == {
        (DaqEventKind.SATURATION, "railed"),
        (DaqEventKind.STUCK, "railed"),
        (DaqEventKind.STUCK, "frozen"),
        (DaqEventKind.FLOATING, "open"),
    }
    assert len(events) == 4  # one event per episode, not one per block
    sat = next(e for e in events if e.kind is DaqEventKind.SATURATION)
    assert sat.sample_index == 0 and "railed" in sat.message and "sim/ai9" in sat.message
    stuck = next(e for e in events if e.channel == "frozen")
    assert stuck.sample_index == 0  # the first window is the constant one
    assert health.stats["railed"].saturated_samples == 6000
    assert health.stats["body_vx"].saturated_samples == 0


def test_saturation_episode_begins_and_clears_with_its_count() -> None:
    # 12 V between t = 1.0 s and t = 1.5 s (beyond the ±10 V range), 1 V otherwise
    chans = [DaqChannelConfig("p", "sim/ai0")]
    fn = FunctionOutput(lambda tr, t: np.where((t >= 1.0) & (t < 1.5), 12.0, 1.0), LinearScaling(1.0))
    b = SimDaqBackend(clock=ManualClock(), truth=slalom(duration=3.0), sources={"sim/ai0": fn}, truth_start_ns=T0_NS)
    b.configure(chans)
    health = ChannelHealth(chans, default=HealthLimits(check_stuck=False, check_floating=False))
    events = _run(b, health, 2.5)
    assert [e.kind for e in events] == [DaqEventKind.SATURATION, DaqEventKind.SATURATION_CLEARED]
    assert events[0].sample_index == 1000
    assert events[1].count == 500
    assert health.stats["p"].saturated_samples == 500


def test_non_finite_samples_count_as_out_of_range_and_windows_do_not_bridge_gaps() -> None:
    chans = [DaqChannelConfig("a", "x/ai0")]
    health = ChannelHealth(chans, default=HealthLimits(window_s=0.1))
    data = np.full((1, 100), 1.0)
    data[0, 10] = np.nan
    ev = health.check(DaqBlock(0, RATE, data, 0, ("a",)))
    # a window holding a NaN is not "stuck" (it is not known to be constant)
    assert [e.kind for e in ev] == [DaqEventKind.SATURATION]
    assert ev[0].sample_index == 10
    # after a gap (lost samples), the 100-sample window starts again
    noisy = 1.0 + np.random.default_rng(0).normal(0, 0.01, (1, 50))
    ev2 = health.check(DaqBlock(500, RATE, noisy, 0, ("a",)))
    assert [e.kind for e in ev2] == [DaqEventKind.SATURATION_CLEARED]
    assert ev2[0].count == 1
    assert health.stats["a"].window.size == 50


def test_limits_for_unknown_channels_are_rejected() -> None:
    with pytest.raises(ConfigError, match=r"unknown DAQ channels \['nope'\]"):
        ChannelHealth([DaqChannelConfig("a", "x/ai0")], limits={"nope": HealthLimits()})
    with pytest.raises(ConfigError, match="window_s"):
        HealthLimits(window_s=0.0)
