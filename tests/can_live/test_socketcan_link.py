"""SocketCAN bring-up checks (drivers.can.socketcan_link) on fake sysfs trees and ``ip -details`` outputs."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.can.bus import CanBusConfig, bus_notes, open_bus
from drivers.can.socketcan_link import SocketcanLink, check_link, parse_ip_details, read_link
from vsccore.errors import DeviceError

# iproute2's text form (as in the kernel's Documentation/networking/can.rst)
UP_LISTEN_ONLY = """\
4: can0: <NOARP,UP,LOWER_UP,ECHO> mtu 16 qdisc pfifo_fast state UP mode DEFAULT group default qlen 10
    link/can  promiscuity 0 minmtu 0 maxmtu 0
    can <LISTEN-ONLY> state ERROR-ACTIVE (berr-counter tx 0 rx 0) restart-ms 100
\t  bitrate 500000 sample-point 0.875
\t  tq 125 prop-seg 6 phase-seg1 7 phase-seg2 2 sjw 1 brp 1
\t  gs_usb: tseg1 1..16 tseg2 1..8 sjw 1..4 brp 1..1024 brp_inc 1
\t  clock 48000000 numtxqueues 1 numrxqueues 1 gso_max_size 65536 gso_max_segs 65535
"""
DOWN_NO_BITRATE = """\
4: can0: <NOARP,ECHO> mtu 16 qdisc noop state DOWN mode DEFAULT group default qlen 10
    link/can  promiscuity 0 minmtu 0 maxmtu 0
    can state STOPPED restart-ms 0
\t  gs_usb: tseg1 1..16 tseg2 1..8 sjw 1..4 brp 1..1024 brp_inc 1
\t  clock 48000000 numtxqueues 1 numrxqueues 1 gso_max_size 65536 gso_max_segs 65535
"""
UP_ACTIVE_NO_RESTART = """\
4: can0: <NOARP,UP,LOWER_UP,ECHO> mtu 16 qdisc pfifo_fast state UP mode DEFAULT group default qlen 10
    link/can  promiscuity 0 minmtu 0 maxmtu 0
    can state ERROR-ACTIVE (berr-counter tx 0 rx 0) restart-ms 0
\t  bitrate 250000 sample-point 0.875
"""
VCAN = """\
7: vcan0: <NOARP,UP,LOWER_UP> mtu 72 qdisc noqueue state UNKNOWN mode DEFAULT group default qlen 1000
    link/can  promiscuity 0 minmtu 0 maxmtu 0
    vcan numtxqueues 1 numrxqueues 1 gso_max_size 65536 gso_max_segs 65535
"""


def _sysfs(tmp_path: Path, name: str, *, up: bool, operstate: str) -> Path:
    node = tmp_path / name
    node.mkdir()
    (node / "flags").write_text("0x%x\n" % (0xC1 if up else 0xC0), encoding="ascii")  # IFF_UP = 0x1
    (node / "operstate").write_text(operstate + "\n", encoding="ascii")
    return tmp_path


def test_ip_details_are_parsed() -> None:
    link = parse_ip_details("can0", UP_LISTEN_ONLY)
    assert link.up and link.is_controller
    assert link.ctrlmode == {"LISTEN-ONLY"}
    assert (link.state, link.bitrate, link.restart_ms) == ("ERROR-ACTIVE", 500_000, 100)
    down = parse_ip_details("can0", DOWN_NO_BITRATE)
    assert down.up is False and down.bitrate is None and down.state == "STOPPED" and down.restart_ms == 0
    assert parse_ip_details("vcan0", VCAN).kind == "vcan"


def test_an_interface_that_is_down_without_bitrate_names_the_fix(tmp_path: Path) -> None:
    root = _sysfs(tmp_path, "can0", up=False, operstate="down")
    link = read_link("can0", sys_root=root, run_ip=lambda name: DOWN_NO_BITRATE)
    assert link.operstate == "down" and link.up is False
    with pytest.raises(DeviceError) as err:
        check_link(link, bitrate=500_000, listen_only=True, where="can 'pt'")
    text = str(err.value)
    assert "can0 has no bitrate set" in text
    assert "sudo ip link set can0 type can bitrate 500000 restart-ms 100 listen-only on" in text
    assert "sudo ip link set can0 up" in text


def test_an_interface_that_is_down_names_the_fix_without_ip(tmp_path: Path) -> None:
    root = _sysfs(tmp_path, "can0", up=False, operstate="down")
    link = read_link("can0", sys_root=root, run_ip=lambda name: None)  # no iproute2
    with pytest.raises(DeviceError, match=r"can0 is down \(operstate down\).*sudo ip link set can0 up"):
        check_link(link, bitrate=500_000, listen_only=True)


def test_a_missing_interface_is_named(tmp_path: Path) -> None:
    with pytest.raises(DeviceError, match=r"no network interface 'can3'"):
        check_link(read_link("can3", sys_root=tmp_path), bitrate=500_000)


def test_bitrate_and_listen_only_are_checked_and_restart_ms_is_noted(tmp_path: Path) -> None:
    root = _sysfs(tmp_path, "can0", up=True, operstate="up")
    active = read_link("can0", sys_root=root, run_ip=lambda name: UP_ACTIVE_NO_RESTART)
    with pytest.raises(DeviceError, match=r"bitrate: can0 runs at 250000 bit/s, the configuration says 500000"):
        check_link(active, bitrate=500_000, listen_only=True)
    with pytest.raises(DeviceError, match=r"listen_only: can0 is not listen-only.*listen-only on.*listen_only = false"):
        check_link(active, bitrate=250_000, listen_only=True)
    notes = check_link(active, bitrate=250_000, listen_only=False)  # told: an acknowledging interface
    assert any("restart-ms is 0" in n and "sudo ip link set can0 type can restart" in n for n in notes)
    good = read_link("can0", sys_root=root, run_ip=lambda name: UP_LISTEN_ONLY)
    assert check_link(good, bitrate=500_000, listen_only=True) == ()


def test_a_virtual_can_interface_needs_only_to_be_up(tmp_path: Path) -> None:
    root = _sysfs(tmp_path, "vcan0", up=True, operstate="unknown")  # vcan reports UNKNOWN when up
    assert check_link(read_link("vcan0", sys_root=root, run_ip=lambda name: VCAN), bitrate=500_000,
                      listen_only=True) == ()


def test_open_bus_refuses_a_socketcan_interface_that_is_not_set_up() -> None:
    """Before, python-can bound its socket to an interface that was down and the rig recorded nothing."""
    config = CanBusConfig("socketcan", "can0", name="pt", listen_only=True)
    down = parse_ip_details("can0", DOWN_NO_BITRATE)
    with pytest.raises(DeviceError, match=r"CAN bus 'pt' \(socketcan can0\): can0 has no bitrate set.*restart-ms 100"):
        open_bus(config, read_socketcan=lambda name: down)
    missing = SocketcanLink("can0", exists=False)
    with pytest.raises(DeviceError, match=r"no network interface 'can0'"):
        open_bus(config, read_socketcan=lambda name: missing)


def test_restart_ms_zero_is_a_note_when_the_bus_opens() -> None:
    link = parse_ip_details("can0", UP_ACTIVE_NO_RESTART)
    notes = bus_notes(CanBusConfig("socketcan", "can0", bitrate=250_000, listen_only=False),
                      read_socketcan=lambda name: link)
    assert any("restart-ms is 0" in n for n in notes)
