"""Analog scaling: known volts → known SI values, table scaling, unit conversion, decoding of blocks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.analog import (
    AnalogChannelSpec,
    AnalogDecoder,
    LinearScaling,
    TableScaling,
    brake_pressure_spec,
    scaling_from_dict,
    scaling_to_dict,
    si_factor,
)
from drivers.daq import DaqBlock
from vsccore.errors import ConfigError


def test_unit_factors_are_the_si_definitions() -> None:
    assert si_factor("bar") == (100_000.0, "Pa")
    assert si_factor("km/h")[0] == pytest.approx(1000.0 / 3600.0)
    assert si_factor("deg")[0] == pytest.approx(math.pi / 180.0)
    # 1 psi = 0.45359237 kg * 9.80665 m/s² / (0.0254 m)²  (exact definitions of lb and inch)
    assert si_factor("psi")[0] == pytest.approx(0.45359237 * 9.80665 / 0.0254**2, rel=1e-12)
    with pytest.raises(ConfigError, match=r"daq\.p\.unit: unknown unit 'furlong'.*bar"):
        si_factor("furlong", "daq.p.unit")


def test_ratiometric_pressure_transducer_known_points() -> None:
    # 0.5 V ↔ 0 bar, 4.5 V ↔ 250 bar: 62.5 bar per volt
    spec = brake_pressure_spec("p_master", "p_master")
    volts = np.array([0.5, 2.5, 4.5, 1.3])
    expected_bar = np.array([0.0, 125.0, 250.0, 50.0])
    np.testing.assert_allclose(spec.decode(volts), expected_bar * 1e5, rtol=1e-12, atol=1e-6)
    assert spec.unit == "Pa"


def test_linear_from_unit_and_inverse() -> None:
    s = LinearScaling.from_unit(25.0, offset=-12.5, unit="bar")  # 25 bar/V, −12.5 bar at 0 V
    assert s.to_value(1.0) == pytest.approx(12.5e5)
    assert s.to_volts(12.5e5) == pytest.approx(1.0)
    with pytest.raises(ConfigError, match="zero"):
        LinearScaling(0.0)


def test_angle_scaling_plus_minus_ten_volts_is_plus_minus_forty_degrees() -> None:
    s = LinearScaling.from_points(-10.0, -40.0, 10.0, 40.0, "deg")
    np.testing.assert_allclose(s.to_value([-10.0, 0.0, 2.5, 10.0]), np.radians([-40.0, 0.0, 10.0, 40.0]))


def test_table_scaling_interpolates_and_extrapolates_piecewise_linearly() -> None:
    # a non-linear transducer: 0 V 0 bar, 1 V 10 bar, 3 V 50 bar, 5 V 150 bar
    t = TableScaling.from_unit([0.0, 1.0, 3.0, 5.0], [0.0, 10.0, 50.0, 150.0], "bar")
    v = np.array([0.0, 0.5, 2.0, 4.0, 5.0, 6.0, -1.0])
    bar = np.array([0.0, 5.0, 30.0, 100.0, 150.0, 200.0, -10.0])
    np.testing.assert_allclose(t.to_value(v), bar * 1e5, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(t.to_volts(bar * 1e5), v, rtol=1e-12, atol=1e-12)


def test_table_scaling_decreasing_values_inverse() -> None:
    t = TableScaling((0.0, 2.0, 4.0), (100.0, 60.0, 0.0))
    np.testing.assert_allclose(t.to_value([1.0, 3.0]), [80.0, 30.0])
    np.testing.assert_allclose(t.to_volts([80.0, 30.0]), [1.0, 3.0])


@pytest.mark.parametrize(
    ("volts", "values", "match"),
    [
        ((0.0, 1.0, 1.0), (0.0, 1.0, 2.0), "strictly increasing"),
        ((0.0, 2.0, 1.0), (0.0, 1.0, 2.0), "strictly increasing"),
        ((0.0, 1.0, 2.0), (0.0, 2.0, 1.0), "strictly monotonic"),
        ((0.0,), (0.0,), "at least 2"),
        ((0.0, 1.0), (0.0, 1.0, 2.0), "equally long"),
        ((0.0, float("nan")), (0.0, 1.0), "finite"),
    ],
)
def test_table_scaling_rejects_bad_tables(volts: tuple[float, ...], values: tuple[float, ...], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        TableScaling(volts, values)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.floats(0.01, 5.0), min_size=2, max_size=8),
    st.lists(st.floats(0.01, 100.0), min_size=8, max_size=8),
    st.floats(-2.0, 30.0),
)
def test_table_round_trip(dv: list[float], dx: list[float], v: float) -> None:
    volts = tuple(np.cumsum(dv) - 1.0)
    values = tuple(np.cumsum(dx[: len(dv)]))
    t = TableScaling(volts, values)
    assert float(t.to_volts(t.to_value(v))) == pytest.approx(v, rel=1e-9, abs=1e-9)


def test_scaling_dict_forms_and_round_trip() -> None:
    lin = scaling_from_dict({"kind": "linear", "scale": 62.5, "offset": -31.25, "unit": "bar"}, "daq.p_fl")
    assert lin.to_value(2.5) == pytest.approx(125e5)
    pts = scaling_from_dict({"points": [[-10, -40], [10, 40]], "unit": "deg"})
    assert pts.to_value(10.0) == pytest.approx(math.radians(40.0))
    tab = scaling_from_dict({"kind": "table", "volts": [0, 5], "values": [0, 200], "unit": "bar"})
    for s in (lin, pts, tab):
        again = scaling_from_dict(scaling_to_dict(s))
        np.testing.assert_allclose(again.to_value([-1.0, 0.3, 4.0]), s.to_value([-1.0, 0.3, 4.0]))
    with pytest.raises(ConfigError, match=r"daq\.x: missing key 'scale'"):
        scaling_from_dict({"kind": "linear"}, "daq.x")
    with pytest.raises(ConfigError, match=r"daq\.x\.kind: unknown scaling kind 'cubic'"):
        scaling_from_dict({"kind": "cubic"}, "daq.x")
    with pytest.raises(ConfigError, match=r"daq\.x: .*strictly increasing"):
        scaling_from_dict({"kind": "table", "volts": [1, 0], "values": [0, 1]}, "daq.x")


def test_channel_spec_from_dict_converts_bar_to_pa() -> None:
    spec = AnalogChannelSpec.from_dict(
        {"name": "p_rl", "channel": "ai5", "scaling": {"scale": 50.0, "unit": "bar"}}, "analog"
    )
    assert spec.unit == "Pa"
    assert spec.decode(2.0) == pytest.approx(100e5)
    assert AnalogChannelSpec.from_dict(spec.to_dict()).decode(2.0) == pytest.approx(100e5)


def test_decoder_decodes_block_and_names_missing_channel() -> None:
    data = np.array([[0.5, 2.5, 4.5], [1.0, 2.0, 3.0]])
    block = DaqBlock(0, 1000.0, data, 0, ("p_master", "other"))
    dec = AnalogDecoder([brake_pressure_spec("master", "p_master")])
    np.testing.assert_allclose(dec.decode(block)["master"], [0.0, 125e5, 250e5], atol=1e-6)
    bad = AnalogDecoder([brake_pressure_spec("fl", "p_fl")])
    with pytest.raises(ConfigError, match=r"no channel 'p_fl'.*p_master"):
        bad.decode(block)
    with pytest.raises(ConfigError, match="unique"):
        AnalogDecoder([brake_pressure_spec("fl", "a"), brake_pressure_spec("fl", "b")])
