"""Interface options, listen-only and the frame-time choice of a [[can]] bus (drivers.can.interfaces, open_bus)."""

from __future__ import annotations

import inspect
import queue
import re
import threading
from typing import Any

import can
import pytest

from drivers.can.bus import CanBusConfig, CanBusLink, FrameTime, TimestampSource, open_bus
from drivers.can.interfaces import PROFILES, ListenOnly, check_options, default_frame_time, listen_only_options
from vsccore.clock import ScaledClock
from vsccore.errors import ConfigError

T0_NS = 1_700_000_000_000_000_000


class _CapturedError(Exception):
    """Raised by the fake ``can.Bus`` once it has the keyword arguments."""


@pytest.fixture
def bus_kwargs(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """``can.Bus`` replaced: the keyword arguments open_bus would pass to python-can."""
    seen: dict[str, Any] = {}

    def fake_bus(**kwargs: Any) -> can.BusABC:
        seen.update(kwargs)
        raise _CapturedError

    monkeypatch.setattr(can, "Bus", fake_bus)
    return seen


def _open(config: CanBusConfig) -> None:
    with pytest.raises(_CapturedError):
        open_bus(config)


# --- the profiles against the installed python-can ------------------------------------------------------


def _accepted(interface: str) -> set[str]:
    """Keyword names python-can's backend takes: its constructor's parameters and the kwargs keys it reads."""
    module_name, class_name = can.interfaces.BACKENDS[interface]
    module = __import__(module_name, fromlist=[class_name])
    cls = getattr(module, class_name)
    names = {p.name for p in inspect.signature(cls.__init__).parameters.values()
             if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)} - {"self"}
    source = inspect.getsource(inspect.getmodule(cls))
    names |= set(re.findall(r"kwargs\.get\(\s*\"(\w+)\"", source))
    names |= set(re.findall(r"\"(\w+)\" in kwargs", source))
    if interface == "pcan":  # the FD timing keys, read through PCAN_FD_PARAMETER_LIST
        from can.interfaces.pcan.basic import PCAN_FD_PARAMETER_LIST

        names |= set(PCAN_FD_PARAMETER_LIST) | {"f_clock", "f_clock_mhz"}
    return names | {"can_filters"}


@pytest.mark.parametrize("interface", sorted(PROFILES))
def test_every_profile_option_is_one_python_can_takes(interface: str) -> None:
    accepted = _accepted(interface)
    profile = PROFILES[interface]
    assert profile.options <= accepted, profile.options - accepted
    if profile.listen_only_key is not None:
        assert profile.listen_only_key in accepted


# --- options ----------------------------------------------------------------------------------------------


def test_a_misspelt_option_is_refused_naming_key_interface_and_the_right_one() -> None:
    # python-can's Vector backend takes **kwargs: it would have dropped "appname" without a word
    with pytest.raises(ConfigError, match=r"can 'car'\.options\.appname: python-can's 'vector' interface takes "
                                          r"no option 'appname'; did you mean 'app_name'"):
        CanBusConfig(interface="vector", channel="0", name="car", options={"appname": "CANalyzer"})
    with pytest.raises(ConfigError, match=r"options\.bitrate: not an option .*'bitrate'"):
        CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", options={"bitrate": 250_000})
    with pytest.raises(ConfigError, match=r"options\.driver_mode: .*'kvaser'.*listen_only"):
        CanBusConfig(interface="kvaser", channel="0", options={"driver_mode": True})
    # options each interface does take pass, and an interface the rig does not know is not checked
    check_options("pcan", {"f_clock_mhz": 80, "auto_reset": True, "device_id": 3}, where="x")
    check_options("vector", {"app_name": "vsc-rig", "rx_queue_size": 4096}, where="x")
    check_options("kvaser", {"exclusive": True, "accept_virtual": False}, where="x")
    check_options("socketcan", {"receive_own_messages": False, "local_loopback": True}, where="x")
    check_options("slcan", {"tty_baudrate": 115200, "anything": 1}, where="x")


def test_options_reach_python_can_as_they_are(bus_kwargs: dict[str, Any]) -> None:
    _open(CanBusConfig(interface="vector", channel="0", options={"app_name": "vsc-rig", "rx_queue_size": 4096}))
    assert bus_kwargs["app_name"] == "vsc-rig" and bus_kwargs["rx_queue_size"] == 4096
    assert bus_kwargs["interface"] == "vector" and bus_kwargs["bitrate"] == 500_000


def test_an_option_python_can_rejects_is_a_config_error_naming_key_and_interface(
        monkeypatch: pytest.MonkeyPatch) -> None:
    def strict_bus(**kwargs: Any) -> can.BusABC:
        raise TypeError("__init__() got an unexpected keyword argument 'tty_baud'")

    monkeypatch.setattr(can, "Bus", strict_bus)
    with pytest.raises(ConfigError, match=r"can 'car'\.options\.tty_baud: python-can's 'slcan' interface"):
        open_bus(CanBusConfig(interface="slcan", channel="/dev/ttyACM0", name="car", options={"tty_baud": 1}))


# --- listen-only --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("interface", "key", "silent", "active"), [
    ("pcan", "state", "PASSIVE", "ACTIVE"),
    ("vector", "listen_only", True, False),
    ("kvaser", "driver_mode", False, True),
])
def test_listen_only_becomes_the_interfaces_own_option(bus_kwargs: dict[str, Any], interface: str, key: str,
                                                       silent: object, active: object) -> None:
    _open(CanBusConfig(interface=interface, channel="1", listen_only=True))
    assert bus_kwargs[key] == silent
    bus_kwargs.clear()
    _open(CanBusConfig(interface=interface, channel="1", listen_only=False))
    assert bus_kwargs[key] == active
    bus_kwargs.clear()
    _open(CanBusConfig(interface=interface, channel="1"))  # not asked: python-can's default (rig replay)
    assert key not in bus_kwargs


def test_pcan_listen_only_state_is_one_python_can_understands() -> None:
    from can.util import load_config

    cfg = load_config(config={"interface": "pcan", "channel": "PCAN_USBBUS1", **listen_only_options("pcan", True)})
    assert cfg["state"] is can.BusState.PASSIVE


def test_the_reading_link_opens_listen_only_unless_told(channel: str) -> None:
    opened: list[CanBusConfig] = []

    def factory(config: CanBusConfig) -> can.BusABC:
        opened.append(config)
        return can.Bus(interface="virtual", channel=channel)

    link = CanBusLink(CanBusConfig(interface="virtual", channel=channel), lambda f: None, clock=ScaledClock(T0_NS),
                      bus_factory=factory)
    with link:
        pass
    assert opened[0].listen_only is True
    told = CanBusLink(CanBusConfig(interface="virtual", channel=channel, listen_only=False), lambda f: None,
                      clock=ScaledClock(T0_NS))
    assert told.config.listen_only is False


def test_listen_only_support_is_stated_per_interface() -> None:
    assert PROFILES["socketcan"].listen_only is ListenOnly.IP_LINK
    assert PROFILES["socketcand"].listen_only is ListenOnly.SERVER
    assert PROFILES["virtual"].listen_only is ListenOnly.NONE
    assert {PROFILES[i].listen_only for i in ("pcan", "vector", "kvaser")} == {ListenOnly.OPTION}


# --- which time places a frame ---------------------------------------------------------------------------


def test_frame_time_defaults_to_what_each_interface_provides() -> None:
    assert default_frame_time("socketcan") is FrameTime.INTERFACE  # kernel receive stamps
    assert default_frame_time("socketcand") is FrameTime.INTERFACE  # the server's kernel stamps
    assert default_frame_time("virtual") is FrameTime.INTERFACE  # the sender's send time
    assert default_frame_time("pcan") is FrameTime.INTERFACE
    assert default_frame_time("slcan") is FrameTime.HOST  # python-can's time.time() after the read
    assert default_frame_time("no_such_interface") is FrameTime.HOST


def test_timestamp_source_key_chooses_interface_or_host_stamps() -> None:
    table = {"name": "car", "interface": "socketcan", "channel": "can0"}
    assert CanBusConfig.from_mapping(table).uses_interface_stamps
    host = CanBusConfig.from_mapping({**table, "timestamp_source": "host"})
    assert host.frame_time is FrameTime.HOST and not host.uses_interface_stamps
    assert host.clock is TimestampSource.KERNEL  # the stamps' clock is still said (kept as device time)
    hw = CanBusConfig.from_mapping({"interface": "slcan", "channel": "x", "timestamp_source": "hardware"})
    assert hw.clock is TimestampSource.HARDWARE and hw.uses_interface_stamps
    with pytest.raises(ConfigError, match=r"can 'car'\.timestamp_source: 'gps' is not one of interface, host"):
        CanBusConfig.from_mapping({**table, "timestamp_source": "gps"})


def test_host_frame_time_meters_the_bus_on_host_receive_times(channel: str) -> None:
    """With host times, the load meter ignores the interface stamps too (here: all one stamp, which as
    interface times would make the rate unmeasurable)."""
    frames: queue.Queue[Any] = queue.Queue()
    config = CanBusConfig(interface="virtual", channel=channel, frame_time=FrameTime.HOST)
    clock = ScaledClock(T0_NS, speed=1.0)
    with CanBusLink(config, frames.put, clock=clock, stats_window_s=5.0) as link, \
            can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx:
        for k in range(5):
            tx.send(can.Message(timestamp=1000.0, arbitration_id=0x100 + k, data=b"\x00", is_extended_id=False))
            frames.get(timeout=3.0)
            clock.sleep_until_ns(clock.now_ns() + 10_000_000, threading.Event())  # host times 10 ms apart
        stats = link.stats()
    assert stats.frames_per_s > 0
