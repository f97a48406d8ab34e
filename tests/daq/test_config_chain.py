"""From the session configuration to SI values: what the recorder does, against the simulator's truth.

``rig/examples/sim.toml`` is loaded with the real configuration model; its ``[[optical]]``,
``[calibration]`` and ``[daq]`` tables build the optical spec, the analog specs and a
:class:`DaqLink` on the ``sim`` backend chosen by name; the blocks are converted and compared
with the ground truth.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.analog import AnalogChannelSpec, AnalogDecoder
from drivers.daq import DaqBlock, DaqChannelConfig, DaqEvent, DaqEventKind, DaqLink, TerminalConfig
from drivers.optical import OpticalRole, OpticalSensorSpec, SensorKind, convert_block, transfer_to_point
from rig.core.config import AnalogChannelConfig, OpticalSensorConfig, load_session
from sim_devices.daq import SimDaqBackend, SimOpticalSensor, SyncPulseOutput, sim_daq_sources
from tests.daq.helpers import T0_NS, ManualClock, truth_from_body_velocity
from vsccore.errors import ConfigError
from vsccore.gpstime import gps_to_ns

SIM_TOML = Path(__file__).resolve().parents[2] / "rig" / "examples" / "sim.toml"
KMH = 1.0 / 3.6


def braking_slalom(duration: float = 12.0, rate: float = 1000.0):
    """Slalom at 25 m/s with a braking phase (4 m/s²) from 6 s to 8 s."""
    t = np.arange(0.0, duration, 1.0 / rate)
    w = 2 * np.pi * 0.4
    dv = np.where(t < 6.0, 0.0, np.where(t < 8.0, -4.0 * (t - 6.0), -8.0))
    vx = 25.0 + dv
    vy = 0.5 * np.sin(w * t - 0.3)
    r = 0.2 * np.sin(w * t)
    return truth_from_body_velocity(t, vx, vy, r, 0.04 * np.sin(w * t))


@pytest.fixture(scope="module")
def recorded() -> dict[str, Any]:
    session_cfg = load_session(SIM_TOML)
    assert session_cfg.daq is not None and session_cfg.simulation is not None and session_cfg.calibration is not None
    opt_cfg = session_cfg.optical[0] if session_cfg.optical else None
    assert opt_cfg is not None
    sim_cfg = session_cfg.simulation
    # the calibration in force equals the simulated head's true misalignment
    true_zero_deg = sim_cfg.true_optical_zero_deg[opt_cfg.name]
    spec = OpticalSensorSpec.from_config(opt_cfg.model_dump(), zero_offset_deg=true_zero_deg)
    daq_cfg = session_cfg.daq.model_dump()
    channels = [DaqChannelConfig.from_config(c) for c in daq_cfg["channels"]]
    analog = [AnalogChannelSpec.from_config(a) for a in daq_cfg["analog"]]
    epoch = gps_to_ns(sim_cfg.start_gps_week, sim_cfg.start_gps_seconds)
    pulses = [epoch + 1_000_000_000 + i * 2_000_000_000 + 137 for i in range(5)]
    truth = braking_slalom()
    sensor = SimOpticalSensor(
        spec, internal_rate_hz=1000.0, velocity_noise_mps=0.0, zero_offset_rad=math.radians(true_zero_deg)
    )
    sources = sim_daq_sources(
        channels,
        optical=[sensor],
        analog=analog,
        sync_channel=daq_cfg["sync_channel"],
        sync=SyncPulseOutput.from_gps(pulses, epoch),
    )
    options = {
        "truth": truth,
        "sources": sources,
        "truth_start_ns": T0_NS,
        "clock_ppm": sim_cfg.daq_clock_ppm,
        "truth_epoch_gps_ns": epoch,
        "adc_noise_v": 0.0,
    }
    blocks: list[DaqBlock] = []
    events: list[DaqEvent] = []
    enough = threading.Event()

    def on_block(b: DaqBlock) -> None:
        blocks.append(b)
        if b.next_sample_index >= 11_000:
            enough.set()

    session = DaqLink.from_config(
        daq_cfg,
        on_block=on_block,
        on_event=events.append,
        clock=ManualClock(),
        backend_options=options,
    )
    with session:
        assert enough.wait(30.0)
    return {
        "spec": spec,
        "analog": analog,
        "blocks": blocks,
        "events": events,
        "truth": truth,
        "ref": SimDaqBackend(**options),
        "pulses": pulses,
        "epoch": epoch,
    }


def test_spec_from_the_example_configuration(recorded) -> None:
    spec: OpticalSensorSpec = recorded["spec"]
    assert spec.name == "body" and spec.kind is SensorKind.BODY and spec.model == "S350"
    assert spec.mount_xyz_m == (-2.10, 0.0, 0.40)
    assert spec.min_speed_mps == pytest.approx(0.5 * KMH)
    assert spec.zero_offset_rad == pytest.approx(math.radians(0.25))
    assert spec.roles == {OpticalRole.VX, OpticalRole.VY, OpticalRole.SLIP_ANGLE, OpticalRole.VALID}
    vx = spec.channel_for(OpticalRole.VX)
    ang = spec.channel_for(OpticalRole.SLIP_ANGLE)
    assert vx is not None and vx.channel == "s350_vx" and vx.scaling is not None
    assert ang is not None and ang.scaling is not None
    assert float(vx.scaling.to_value(4.0)) == pytest.approx(100.0 * KMH)  # 25 km/h per volt
    assert float(ang.scaling.to_value(-2.5)) == pytest.approx(math.radians(-10.0))  # 4 deg per volt
    assert spec.status_threshold_v == 2.5


def test_blocks_are_contiguous_and_events_are_only_start_stop_and_sync(recorded) -> None:
    blocks = recorded["blocks"]
    assert blocks[0].first_sample_index == 0
    assert all(b.first_sample_index == a.next_sample_index for a, b in zip(blocks, blocks[1:], strict=False))
    assert all(b.n_samples == 100 for b in blocks)  # block_size from the configuration
    kinds = [e.kind for e in recorded["events"]]
    assert kinds[0] is DaqEventKind.STARTED and kinds[-1] is DaqEventKind.STOPPED
    assert set(kinds[1:-1]) == {DaqEventKind.SYNC_EDGE}
    edges = [e for e in recorded["events"] if e.kind is DaqEventKind.SYNC_EDGE]
    assert len(edges) == 5
    t_edge = np.asarray(recorded["ref"].sample_time_s(np.array([e.edge_index for e in edges]), 0.0, 1000.0))
    t_true = (np.asarray(recorded["pulses"]) - recorded["epoch"]) / 1e9
    assert np.max(np.abs(t_edge - t_true)) < 10e-6


def test_optical_slip_transferred_to_cg_matches_truth_within_0_05_deg(recorded) -> None:
    spec: OpticalSensorSpec = recorded["spec"]
    truth = recorded["truth"]
    ref: SimDaqBackend = recorded["ref"]
    for blk in recorded["blocks"]:
        s = convert_block(spec, blk)
        assert s.valid.all() and s.zero_offset_applied_rad == pytest.approx(math.radians(0.25))
        t = np.asarray(ref.sample_time_s(blk.sample_indices(), 0.0, 1000.0))
        r = np.interp(t, truth.t, truth.yaw_rate)
        cg = transfer_to_point(s, spec, r)
        err_cg = np.degrees(cg.sideslip - np.interp(t, truth.t, truth.beta_cg))
        err_mount = np.degrees(s.slip_angle - np.interp(t, truth.t, truth.point_sideslip(*spec.mount_xy)))
        assert np.max(np.abs(err_cg)) < 0.05, blk.first_sample_index
        assert np.max(np.abs(err_mount)) < 0.05, blk.first_sample_index


def test_brake_pressure_channel_from_the_configuration(recorded) -> None:
    (spec,) = recorded["analog"]
    assert spec.name == "mc_pressure" and spec.channel == "p_mc" and spec.unit == "Pa"
    dec = AnalogDecoder(recorded["analog"])
    truth = recorded["truth"]
    ref: SimDaqBackend = recorded["ref"]
    p, t = [], []
    for blk in recorded["blocks"]:
        p.append(dec.decode(blk)["mc_pressure"])
        t.append(np.asarray(ref.sample_time_s(blk.sample_indices(), 0.0, 1000.0)))
    pa, ts = np.concatenate(p), np.concatenate(t)
    model = 1.0e6 * np.maximum(0.0, -np.interp(ts, truth.t, truth.ax) - 0.3)
    # 16-bit over 0–10 V at 25 bar/V: one step is 10/65536 V · 25e5 Pa/V = 381 Pa; no noise here
    step_pa = 10.0 / 65536 * 25e5
    assert np.max(np.abs(pa - model)) <= step_pa / 2 + 1e-6
    braking = (ts > 6.2) & (ts < 7.8)
    # 4 m/s² of braking beyond the 0.3 m/s² coasting threshold at 1 MPa per m/s² (the slalom's
    # r·vy adds a little to the longitudinal acceleration)
    assert np.mean(pa[braking]) == pytest.approx(37e5, rel=0.02)


def test_config_models_with_table_scaling_and_bad_units() -> None:
    table = AnalogChannelConfig(
        name="wheel_pressure_fl", daq_channel="p_fl", unit="bar", table_v=(0.5, 1.5, 4.5), table_value=(0, 20, 250)
    )
    spec = AnalogChannelSpec.from_config(table.model_dump())
    np.testing.assert_allclose(spec.decode([0.5, 1.0, 3.0, 4.5]), np.array([0.0, 10.0, 135.0, 250.0]) * 1e5)
    lin = AnalogChannelSpec.from_config(
        AnalogChannelConfig(name="x", daq_channel="ai5", unit="bar", scale_per_v=50.0, offset_v=0.5).model_dump()
    )
    assert float(lin.decode(2.5)) == pytest.approx(100e5)  # (2.5 − 0.5) V · 50 bar/V
    with pytest.raises(ConfigError, match=r"daq\.analog\.x\.unit: unknown unit 'psia'"):
        AnalogChannelSpec.from_config({"name": "x", "daq_channel": "a", "unit": "psia", "scale_per_v": 1.0})
    wheel = OpticalSensorConfig.model_validate(
        {
            "name": "rim_fl",
            "kind": "wheel",
            "wheel": "fl",
            "mount": {"x_m": 1.4, "y_m": 0.8, "z_m": 0.3},
            "channels": {
                "slip_angle": {"daq_channel": "w_angle", "scale_per_v": 4.0, "unit": "deg", "invert": True},
                "vx": {"daq_channel": "w_vx", "scale_per_v": 10.0, "offset_v": 0.1, "unit": "m/s"},
            },
        }
    )
    ws = OpticalSensorSpec.from_config(wheel.model_dump(), zero_offset_deg=-0.5)
    assert ws.kind is SensorKind.WHEEL and ws.wheel == "fl"
    assert ws.zero_offset_rad == pytest.approx(math.radians(-0.5))
    from drivers.optical import convert_volts

    out = convert_volts(ws, {"w_angle": [1.0], "w_vx": [2.1]})
    assert out.vx[0] == pytest.approx(20.0 * math.cos(math.radians(0.5)) + 20.0 * math.tan(math.radians(-4.0))
                                      * math.sin(math.radians(0.5)) * -1.0, rel=1e-9)
    assert out.slip_angle[0] == pytest.approx(math.radians(-4.0 + 0.5))
    with pytest.raises(ConfigError, match=r"optical\.bad\.channels\.vx\.unit: 'deg' is not a unit of m/s"):
        OpticalSensorSpec.from_config(
            {"name": "bad", "mount": {"x_m": 0.0}, "channels": {"vx": {"daq_channel": "a", "unit": "deg"},
                                                                 "vy": {"daq_channel": "b", "unit": "km/h"}}}
        )


def test_daq_channel_from_config_and_errors() -> None:
    c = DaqChannelConfig.from_config(
        {"name": "sync", "physical": "Dev1/ai7", "range_v": (0.0, 10.0), "terminal": "rse"}
    )
    assert (c.min_v, c.max_v, c.terminal) == (0.0, 10.0, TerminalConfig.RSE)
    with pytest.raises(ConfigError, match=r"daq\.channels: missing key 'physical'"):
        DaqChannelConfig.from_config({"name": "x"})
    with pytest.raises(ConfigError, match=r"daq\.channels: .*'single'"):
        DaqChannelConfig.from_config({"name": "x", "physical": "ai0", "terminal": "single"})
    base = {"backend": "labjack", "device": "X", "rate_hz": 1000.0, "channels": [{"name": "a", "physical": "ai0"}]}
    with pytest.raises(ConfigError, match="unknown DAQ backend 'labjack'"):
        DaqLink.from_config(base, on_block=lambda b: None)
