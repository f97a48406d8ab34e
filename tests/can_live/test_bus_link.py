"""CanBusLink against python-can virtual buses and a fault-injecting bus."""

from __future__ import annotations

import time
from typing import Any

import can
import pytest

from drivers.can.bus import (
    BusGap,
    BusLoadMeter,
    BusLost,
    BusOpened,
    BusState,
    BusStateChanged,
    CanBusConfig,
    CanBusLink,
    CanFrame,
    CanFrameFlag,
    TimestampSource,
    _stuff_bits,
    crc15_can,
    frame_bit_times,
    open_bus,
    timestamp_source_for,
)
from tests.can_live.collect import Collector
from tests.can_live.faulty_bus import Plug, faulty_factory
from vsccore.clock import ScaledClock
from vsccore.errors import ConfigError, DeviceError

T0_NS = 1_700_000_000_000_000_000


def _session(channel: str, col: Collector, **kw: Any) -> CanBusLink:
    cfg_kw = {k: kw.pop(k) for k in ("bitrate", "fd", "data_bitrate") if k in kw}
    config = CanBusConfig(interface="virtual", channel=channel, name="test", **cfg_kw)
    return CanBusLink(config, col.frame, col.event, clock=ScaledClock(T0_NS), **kw)


# --- frames --------------------------------------------------------------------------------------


def test_every_frame_kind_is_delivered_with_device_and_host_time(channel: str) -> None:
    col = Collector()
    sent = [
        can.Message(timestamp=1000.25, arbitration_id=0x123, data=b"\x01\x02\x03", is_extended_id=False),
        can.Message(timestamp=1000.5, arbitration_id=0x1ABCDEF0, data=b"", is_extended_id=True),
        can.Message(timestamp=1000.75, arbitration_id=0x7FF, is_remote_frame=True, dlc=4, is_extended_id=False),
        can.Message(
            timestamp=1001.0,
            arbitration_id=0x42,
            data=bytes(range(20)),
            is_fd=True,
            bitrate_switch=True,
            is_extended_id=False,
        ),
        can.Message(
            timestamp=1001.25, arbitration_id=0x004, data=bytes([0, 0x04, 0, 0, 0, 0, 0, 0]), is_error_frame=True
        ),
    ]
    with (
        _session(channel, col) as session,
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
    ):
        for m in sent:
            tx.send(m)
        got = col.wait_frames(len(sent))
        warning = col.wait_event(BusStateChanged, where=lambda e: e.state is not BusState.UNKNOWN)
        assert session.stats().frames_total == len(sent)
    assert got[0].arbitration_id == 0x123
    assert got[0].data == b"\x01\x02\x03"
    assert got[0].dlc == 3
    assert got[0].device_ts_ns == 1_000_250_000_000
    assert all(f.host_ts_ns >= T0_NS for f in got)
    assert all(f.timestamp_source is TimestampSource.HOST for f in got)
    assert got[1].is_extended
    assert got[1].arbitration_id == 0x1ABCDEF0
    assert got[1].data == b""
    assert got[2].flags == CanFrameFlag.REMOTE
    assert got[2].dlc == 4
    # a 20-byte FD payload travels with DLC code 11 (24 bytes) on the wire; python-can keeps 20 here
    assert got[3].is_fd
    assert CanFrameFlag.BITRATE_SWITCH in got[3].flags
    assert got[3].dlc == 11
    assert CanFrameFlag.ERROR_FRAME in got[4].flags
    # controller-problem error frame with RX/TX warning status: error warning, still active
    assert warning.state is BusState.WARNING
    assert session.stopped.is_set()


def test_bus_off_error_frame_reopens_the_interface_and_reports_the_gap(channel: str) -> None:
    col = Collector()
    with _session(channel, col, backoff_initial_s=0.05) as session, can.Bus(interface="virtual", channel=channel) as tx:
        assert isinstance(col.wait_event(BusOpened), BusOpened)
        tx.send(can.Message(arbitration_id=0x040, is_error_frame=True, data=bytes(8)))  # CAN_ERR_BUSOFF
        changed = col.wait_event(BusStateChanged, where=lambda e: e.state is not BusState.UNKNOWN)
        assert changed.state is BusState.BUS_OFF
        lost = col.wait_event(BusLost)
        assert "bus-off" in lost.reason
        gap = col.wait_event(BusGap)
        assert gap.recovered
        assert gap.reopen_attempts >= 1
        assert gap.end_ns > gap.start_ns
        tx.send(can.Message(arbitration_id=0x100, data=b"\xaa"))
        frames = col.wait_frames(2)
        assert frames[-1].arbitration_id == 0x100
        assert session.stats().gaps_total == 1
        assert session.stats().error_frames_total == 1


# --- bit times and bus load -----------------------------------------------------------------------


def test_crc15_matches_the_catalogue_check_value() -> None:
    # CRC-15/CAN of the ASCII string "123456789" is 0x059E (Greg Cook's CRC catalogue)
    bits = [(byte >> i) & 1 for byte in b"123456789" for i in range(7, -1, -1)]
    assert crc15_can(bits) == 0x059E


@pytest.mark.parametrize(
    ("bits", "stuffed"),
    [
        ([0] * 4, 0),
        ([0] * 5, 1),
        ([0] * 10, 2),  # the stuff bit after five 0s starts no 0-run: five more 0s need another
        ([0] * 5 + [1] * 4, 2),  # the stuff bit (1) counts into the following run of 1s
        ([1, 0] * 20, 0),
        ([1] * 9, 1),  # five 1s, a stuffed 0, then only four 1s
        ([1] * 10, 2),
    ],
)
def test_stuff_bits_follow_the_iso_11898_rule(bits: list[int], stuffed: int) -> None:
    assert _stuff_bits(bits) == stuffed


@pytest.mark.parametrize("ident", [0x000, 0x123, 0x555, 0x7FF])
@pytest.mark.parametrize("data", [b"", b"\x00" * 8, b"\xff" * 8, bytes(range(8)), b"\x55\xaa" * 4])
def test_classic_frame_lengths_lie_within_the_textbook_bounds(ident: int, data: bytes) -> None:
    n = len(data)
    total, fast = frame_bit_times(ident, False, data)
    # base frame: 47 fixed bits + 8n data bits, plus at most floor((34 + 8n - 1) / 4) stuff bits
    assert fast == 0
    assert 47 + 8 * n <= total <= 47 + 8 * n + (34 + 8 * n - 1) // 4
    ext, _ = frame_bit_times(ident << 18 | 0x2AAAA, True, data)
    assert 67 + 8 * n <= ext <= 67 + 8 * n + (54 + 8 * n - 1) // 4


def test_fd_bit_rate_switch_moves_the_payload_to_the_data_phase() -> None:
    slow, zero = frame_bit_times(0x100, False, bytes(64), is_fd=True, bitrate_switch=False)
    arb, data = frame_bit_times(0x100, False, bytes(64), is_fd=True, bitrate_switch=True)
    assert zero == 0
    assert arb + data == slow
    assert data > 8 * 64
    assert arb < 40
    # at 500 kbit/s nominal and 2 Mbit/s data the frame takes much less time with BRS
    assert arb / 500e3 + data / 2e6 < 0.4 * slow / 500e3


def test_meter_gives_exact_rates_for_a_known_frame_rate() -> None:
    meter = BusLoadMeter(window_s=1.0)
    for i in range(3000):
        meter.add(i * 1_000_000, 100e-6, is_error=(i % 10 == 0))  # 1 kHz, 100 µs each, every 10th an error
    rate, error_rate, busy = meter.rates()
    assert rate == pytest.approx(1000.0, rel=1e-9)
    assert error_rate == pytest.approx(100.0, rel=0.01)
    assert busy == pytest.approx(0.1, rel=1e-9)


def test_session_bus_load_from_a_known_frame_rate(channel: str) -> None:
    col = Collector()
    payload = bytes(range(8))
    bits, _ = frame_bit_times(0x123, False, payload)
    with (
        _session(channel, col, bitrate=500_000, stats_window_s=1.0) as session,
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
    ):
        for i in range(1500):  # 1 kHz on the device clock, sent as fast as the virtual bus takes it
            tx.send(can.Message(timestamp=50.0 + i * 1e-3, arbitration_id=0x123, data=payload, is_extended_id=False))
        col.wait_frames(1500)
        stats = session.stats()
    assert stats.frames_per_s == pytest.approx(1000.0, rel=1e-6)
    # 1000 frames/s of `bits` bits each on 500 kbit/s; a base frame with 8 bytes is 111..135 bits
    assert stats.bus_load_pct == pytest.approx(100.0 * bits * 1000 / 500_000, rel=1e-6)
    assert 100.0 * 111 * 1000 / 500_000 <= stats.bus_load_pct <= 100.0 * 135 * 1000 / 500_000
    assert stats.frames_total == 1500
    assert stats.error_frames_total == 0


# --- recovery -------------------------------------------------------------------------------------


def _faulty_session(channel: str, col: Collector, plug: Plug, **kw: Any) -> CanBusLink:
    config = CanBusConfig(interface="faulty", channel=channel, name="faulty")
    return CanBusLink(config, col.frame, col.event, clock=ScaledClock(T0_NS), bus_factory=faulty_factory(plug), **kw)


def test_interface_that_disappears_and_comes_back_is_reopened(channel: str) -> None:
    col = Collector()
    plug = Plug()
    with (
        _faulty_session(channel, col, plug, backoff_initial_s=0.02, backoff_max_s=0.1) as session,
        can.Bus(interface="virtual", channel=channel) as tx,
    ):
        tx.send(can.Message(arbitration_id=0x10, data=b"\x01"))
        first = col.wait_frames(1)[0]
        plug.unplug()
        lost = col.wait_event(BusLost)
        assert "device disconnected" in lost.reason
        assert session.state is BusState.DISCONNECTED
        plug.replug()
        gap = col.wait_event(BusGap)
        assert gap.recovered
        assert gap.start_ns == lost.host_ts_ns
        assert gap.end_ns > gap.start_ns
        assert gap.last_frame_ns == first.host_ts_ns
        assert gap.reopen_attempts >= 1
        tx.send(can.Message(arbitration_id=0x11, data=b"\x02"))
        assert col.wait_frames(1)[0].arbitration_id == 0x11
    assert plug.opens >= 2


def test_stop_returns_promptly_during_back_off(channel: str) -> None:
    col = Collector()
    plug = Plug()
    session = _faulty_session(channel, col, plug, backoff_initial_s=30.0, backoff_max_s=30.0)
    session.start()
    plug.unplug()
    col.wait_event(BusLost)
    t = time.monotonic()
    session.stop()
    elapsed = time.monotonic() - t
    assert elapsed < 0.5
    gap = col.wait_event(BusGap)
    assert not gap.recovered
    assert gap.reopen_attempts == 0
    assert session.stopped.is_set()


def test_a_silent_interface_is_reopened_after_the_silence_timeout(channel: str) -> None:
    col = Collector()
    plug = Plug()
    with _faulty_session(channel, col, plug, silence_timeout_s=0.2, backoff_initial_s=0.02):
        col.wait_event(BusOpened)
        plug.silent = True
        lost = col.wait_event(BusLost)
        assert "no frame" in lost.reason
        plug.silent = False
        assert col.wait_event(BusGap).recovered


def test_a_failing_consumer_stops_the_session_and_is_kept(channel: str) -> None:
    def bad_consumer(frame: CanFrame) -> None:
        raise ValueError(f"consumer cannot take 0x{frame.arbitration_id:X}")

    config = CanBusConfig(interface="virtual", channel=channel)
    session = CanBusLink(config, bad_consumer, clock=ScaledClock(T0_NS))
    session.start()
    with can.Bus(interface="virtual", channel=channel) as tx:
        tx.send(can.Message(arbitration_id=0x7, data=b""))
        assert session.stopped.wait(3.0)
    session.stop()
    assert isinstance(session.failure, ValueError)
    assert "0x7" in str(session.failure)
    assert session.bus is None


# --- opening and configuration --------------------------------------------------------------------


def test_first_open_failure_is_a_device_error_naming_the_bus() -> None:
    plug = Plug()
    plug.unplug()
    config = CanBusConfig(interface="faulty", channel="gone", name="chassis")
    session = CanBusLink(config, lambda f: None, clock=ScaledClock(T0_NS), bus_factory=faulty_factory(plug))
    with pytest.raises(can.CanInitializationError):
        session.start()
    with pytest.raises(DeviceError, match="chassis"):
        open_bus(CanBusConfig(interface="no_such_interface", channel="x", name="chassis"))


def test_socketcand_without_server_fails_fast() -> None:
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t = time.monotonic()
    with pytest.raises(DeviceError, match="no socketcand server"):
        open_bus(CanBusConfig(interface="socketcand", channel="can0", options={"host": "127.0.0.1", "port": port}))
    assert time.monotonic() - t < 2.0  # python-can's own client would retry for 10 s


def test_config_is_validated_with_the_key_named() -> None:
    with pytest.raises(ConfigError, match=r"can 'v'\.data_bitrate"):
        CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", data_bitrate=2_000_000, name="v")
    with pytest.raises(ConfigError, match="bitrate"):
        CanBusConfig(interface="pcan", channel="PCAN_USBBUS1", bitrate=0)


def test_timestamp_sources_per_interface() -> None:
    assert timestamp_source_for("socketcan") is TimestampSource.KERNEL
    assert timestamp_source_for("PCAN") is TimestampSource.HARDWARE
    assert timestamp_source_for("virtual") is TimestampSource.HOST
    assert timestamp_source_for("something_new") is TimestampSource.HOST
    cfg = CanBusConfig(interface="slcan", channel="/dev/ttyACM0", timestamp_source=TimestampSource.HARDWARE)
    assert cfg.clock is TimestampSource.HARDWARE


def test_bus_config_from_a_session_configuration_table() -> None:
    from pathlib import Path

    from rig.core.config import load_session

    cfg = load_session(Path(__file__).resolve().parents[2] / "examples" / "sim.toml")
    bus = CanBusConfig.from_mapping(cfg.can[0].model_dump())
    assert (bus.name, bus.interface, bus.channel, bus.bitrate, bus.fd) == ("vsc", "virtual", "vsc-sim", 500_000, False)
    assert bus.clock is TimestampSource.HOST
    remote = CanBusConfig.from_mapping(
        {"name": "car", "interface": "socketcand", "channel": "vsc0", "host": "10.0.0.2", "port": 29536},
        channel="can1",
    )
    assert remote.options == {"host": "10.0.0.2", "port": 29536}
    assert (remote.channel, remote.clock) == ("can1", TimestampSource.KERNEL)
    with pytest.raises(ConfigError, match=r"can 'car'\.channel: missing"):
        CanBusConfig.from_mapping({"name": "car", "interface": "pcan"})
    with pytest.raises(ConfigError, match=r"timestamp_source: 'gps'"):
        CanBusConfig.from_mapping({"interface": "pcan", "channel": "x", "timestamp_source": "gps"})


def test_error_counters_and_passive_state_from_a_controller_error_frame(channel: str) -> None:
    col = Collector()
    # SocketCAN error class CRTL | CNT: data[1] = RX error passive, data[6] = TEC, data[7] = REC
    report = can.Message(arbitration_id=0x004 | 0x200, is_error_frame=True, data=bytes([0, 0x10, 0, 0, 0, 0, 96, 131]))
    with _session(channel, col) as session, can.Bus(interface="virtual", channel=channel) as tx:
        assert session.stats().tx_error_counter is None
        tx.send(report)
        changed = col.wait_event(BusStateChanged, where=lambda e: e.state is not BusState.UNKNOWN)
        assert changed.state is BusState.PASSIVE
        stats = session.stats()
    assert (stats.tx_error_counter, stats.rx_error_counter) == (96, 131)
    assert stats.error_frames_total == 1
