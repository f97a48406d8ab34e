"""``rig sim record --fault``: the faults a road test meets, rehearsed on the simulated car and recorded as the
rig sees them (a correction cable pulled, a receiver reset, an open DAQ input), and bad fault specs refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.cli.main import app
from rig.core.config import load_session as load_config
from rig.data import load_session
from rig.sim.faults import parse_fault
from rig.workflows.demo import demo_config_path
from vsccore.errors import ConfigError

runner = CliRunner()
NS = 1_000_000_000


@pytest.fixture(scope="module")
def faulty(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("faults")
    res = runner.invoke(app, [
        "sim", "record", str(demo_config_path()), "--out", str(out), "--name", "f",
        "--drive", "straight:duration_s=40,speed_kmh=50", "--speed", "8", "--no-dashboard",
        "--fault", "corrections:rover_a@6..14", "--fault", "reset:rover_b@8", "--fault", "daq-float:p_mc",
        "--fault", "can-bus-off@20..22",
    ])
    assert res.exit_code == 0, res.output
    return out / "f"


def _pos_types(ds: object, receiver: str, t0_ns: int) -> tuple[np.ndarray, np.ndarray]:
    pos = ds.gnss(receiver).bestpos  # type: ignore[attr-defined]
    return (pos.time_ns - t0_ns) / NS, np.asarray(pos["pos_type"])


def test_a_pulled_correction_cable_loses_rtk_for_the_span_and_it_comes_back(faulty: Path) -> None:
    ds = load_session(faulty)
    t0 = ds.truth().time_ns[0]
    t, kind = _pos_types(ds, "rover_a", t0)
    fixed = kind == "NARROW_INT"
    assert fixed[(t > 2) & (t < 6)].all()  # fixed before the cable is pulled
    assert not fixed[(t > 12) & (t < 14)].any()  # corrections older than the rover's limit: no RTK
    # the cable back at 14 s: the relay's sink opens the port again (its back-off), the rover floats, then fixes
    # (the simulated engine: 2 s to float, 10 s to fix)
    refix = t[(t > 14) & fixed]
    assert refix.size and refix[0] < 14 + 20, refix[:1]
    assert fixed[t > refix[0]].all() and fixed[t > 38].all()


def test_a_receiver_reset_is_seen_and_it_is_configured_again(faulty: Path) -> None:
    ds = load_session(faulty)
    resets = [e for _t, e in ds.events if e.source == "rover_b" and "receiver reset?" in e.text]
    assert resets, [e.text for _t, e in ds.events if e.source == "rover_b"]
    t0 = ds.truth().time_ns[0]
    t, kind = _pos_types(ds, "rover_b", t0)
    assert not (kind[(t > 8.5) & (t < 12)] == "NARROW_INT").any()  # no RTK before fine time again
    assert (kind[t > 38] == "NARROW_INT").all()  # logging and fixed again after the reset
    configured = [e for _t, e in ds.events if e.source == "rover_b" and e.text.startswith("configured")]
    assert len(configured) >= 2


def test_an_open_daq_input_reads_noise_and_hum(faulty: Path) -> None:
    ds = load_session(faulty)
    d = ds.daq("SimDAQ")
    v = d.volts[d.channel_names.index("p_mc")]
    assert v.std() > 0.2  # an open input: wide-band noise and mains hum, no pressure signal


def test_a_bus_off_is_recorded_with_its_recovery(faulty: Path) -> None:
    ds = load_session(faulty)
    texts = [e.text for _t, e in ds.events if e.source.startswith("can")]
    assert any("bus-off" in t.lower() or "bus_off" in t.lower() for t in texts), texts
    t0 = ds.truth().time_ns[0]
    frames = ds.can_frames("vsc")
    t = (frames.time_ns - t0) / NS
    assert not ((t > 20.2) & (t < 21.8)).any()  # silent while off the bus
    assert ((t > 23) & (t < 24)).any()  # back after the restart


@pytest.mark.parametrize(("spec", "match"), [
    ("corrections:rover_z@1..2", "no receiver 'rover_z'"),
    ("corrections:rover_a@5..2", "T1 > T0"),
    ("reset:rover_a", "say when"),
    ("smoke@3", "unknown fault 'smoke'"),
    ("daq-float:nope", "no DAQ channel 'nope'"),
])
def test_a_bad_fault_spec_is_refused_with_what_is_wrong(spec: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_fault(spec, load_config(demo_config_path()))
