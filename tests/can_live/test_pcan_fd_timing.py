"""PCAN FD timing derived from bitrate, data_bitrate and sample points (drivers.can.timing, open_bus)."""

from __future__ import annotations

from typing import Any

import can
import pytest

from drivers.can.bus import CanBusConfig, open_bus
from drivers.can.timing import PCAN_FD_CLOCKS_HZ, PCAN_FD_TIMING_KEYS, pcan_fd_timing
from vsccore.errors import ConfigError

COMBINATIONS = [
    (500_000, 2_000_000),  # the usual car FD bus (SAE J2284-4's rates)
    (500_000, 5_000_000),  # SAE J2284-5
    (500_000, 4_000_000),
    (1_000_000, 8_000_000),
    (250_000, 1_000_000),
    (125_000, 1_000_000),
    (500_000, 500_000),  # FD frames without bit-rate switch
]


@pytest.mark.parametrize(("bitrate", "data_bitrate"), COMBINATIONS)
def test_derived_timing_gives_exactly_the_bitrates(bitrate: int, data_bitrate: int) -> None:
    t = pcan_fd_timing(bitrate, data_bitrate)
    assert t.nom_bitrate == bitrate  # exact: Fractions
    assert t.data_bitrate == data_bitrate
    assert t.f_clock in PCAN_FD_CLOCKS_HZ
    # within PCAN-Basic's register ranges
    assert 1 <= t.nom_brp <= 1024 and 1 <= t.nom_tseg1 <= 256 and 1 <= t.nom_tseg2 <= 128 and 1 <= t.nom_sjw <= 128
    assert 1 <= t.data_brp <= 1024 and 1 <= t.data_tseg1 <= 32 and 1 <= t.data_tseg2 <= 16 and 1 <= t.data_sjw <= 16
    assert t.nom_sjw <= t.nom_tseg2 and t.data_sjw <= t.data_tseg2
    # independent: python-can's own bit-timing class computes the same bitrates from the registers
    bt = can.BitTimingFd(**t.as_options())
    assert (bt.nom_bitrate, bt.data_bitrate) == (bitrate, data_bitrate)


def test_default_sample_points_are_met_on_the_usual_buses() -> None:
    t = pcan_fd_timing(500_000, 2_000_000)
    assert (t.f_clock, t.nom_brp, t.data_brp) == (80_000_000, 1, 1)  # one time quantum for both phases
    assert float(t.nom_sample_point) == pytest.approx(0.80)
    assert float(t.data_sample_point) == pytest.approx(0.75)
    assert t.as_options() == {"f_clock": 80_000_000, "nom_brp": 1, "nom_tseg1": 127, "nom_tseg2": 32,
                              "nom_sjw": 32, "data_brp": 1, "data_tseg1": 29, "data_tseg2": 10, "data_sjw": 10}
    t5 = pcan_fd_timing(500_000, 5_000_000)
    assert float(t5.data_sample_point) == pytest.approx(0.75)


def test_other_sample_points_are_honoured() -> None:
    t = pcan_fd_timing(500_000, 2_000_000, sample_point=0.875, data_sample_point=0.70)
    assert float(t.nom_sample_point) == pytest.approx(0.875)
    assert float(t.data_sample_point) == pytest.approx(0.70)


def test_an_impossible_rate_is_refused_naming_the_keys_to_give() -> None:
    with pytest.raises(ConfigError, match=r"data_bitrate 3333333 exactly.*f_clock \(or f_clock_mhz\), nom_brp"):
        pcan_fd_timing(500_000, 3_333_333)
    with pytest.raises(ConfigError, match=r"can 'pt'\.data_bitrate: a PCAN FD bus needs bitrate and data_bitrate"):
        CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", fd=True, name="pt")
    with pytest.raises(ConfigError, match=r"options: a PCAN FD timing needs all of its keys; missing data_brp"):
        CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", fd=True, name="pt",
                     options={"f_clock_mhz": 80, **{k: 1 for k in PCAN_FD_TIMING_KEYS if k != "data_brp"}})


def _kwargs(config: CanBusConfig, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    seen: dict[str, Any] = {}

    class Done(Exception):  # noqa: N818 - a control-flow marker of this test
        pass

    def fake_bus(**kwargs: Any) -> can.BusABC:
        seen.update(kwargs)
        raise Done

    monkeypatch.setattr(can, "Bus", fake_bus)
    with pytest.raises(Done):
        open_bus(config)
    return seen


def test_open_bus_passes_the_derived_timing_to_python_can(monkeypatch: pytest.MonkeyPatch) -> None:
    config = CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", fd=True, bitrate=500_000,
                          data_bitrate=2_000_000, listen_only=True)
    kwargs = _kwargs(config, monkeypatch)
    assert {k: kwargs[k] for k in ("f_clock", *PCAN_FD_TIMING_KEYS)} == pcan_fd_timing(500_000, 2_000_000).as_options()
    assert kwargs["fd"] is True and kwargs["state"] == "PASSIVE"
    # and python-can's configuration step turns them into the BitTimingFd PcanBus initialises from
    from can.util import load_config

    loaded = load_config(config=dict(kwargs))
    assert isinstance(loaded["timing"], can.BitTimingFd)
    assert (loaded["timing"].nom_bitrate, loaded["timing"].data_bitrate) == (500_000, 2_000_000)


def test_a_full_timing_in_options_is_used_as_given(monkeypatch: pytest.MonkeyPatch) -> None:
    given = {"f_clock_mhz": 40, "nom_brp": 1, "nom_tseg1": 63, "nom_tseg2": 16, "nom_sjw": 16,
             "data_brp": 1, "data_tseg1": 14, "data_tseg2": 5, "data_sjw": 5}
    config = CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", fd=True, data_bitrate=2_000_000, options=given)
    kwargs = _kwargs(config, monkeypatch)
    assert {k: kwargs[k] for k in given} == given
    assert "f_clock" not in kwargs


def test_session_configuration_derives_or_refuses_at_load() -> None:
    from pathlib import Path

    from rig.core.config import CanConfig

    dbc = Path("x.dbc")
    CanConfig(name="pt", interface="pcan", channel="PCAN_USBBUS1", fd=True, data_bitrate=2_000_000, dbc=dbc,
              data_sample_point=0.7)
    with pytest.raises(ValueError, match=r"no PCAN FD timing gives bitrate 500000 and data_bitrate 3333333"):
        CanConfig(name="pt", interface="pcan", channel="PCAN_USBBUS1", fd=True, data_bitrate=3_333_333, dbc=dbc)
