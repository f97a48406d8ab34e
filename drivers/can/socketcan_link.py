"""SocketCAN bring-up: is the interface up, at the right bitrate, listen-only, restarting after bus-off?

Bitrate, listen-only and ``restart-ms`` of a SocketCAN interface are ``ip link`` settings that
python-can cannot make: binding a socket to an interface that is down or has no bitrate succeeds,
and the rig would then record nothing without a word. :func:`read_link` reads
``/sys/class/net/<if>/`` and ``ip -details link show <if>``; :func:`check_link` turns what is found
into an error that names the commands to run::

    sudo ip link set can0 type can bitrate 500000 restart-ms 100 listen-only on
    sudo ip link set can0 up

``restart-ms`` makes the kernel restart the controller that long after a bus-off; without it a
bus-off lasts until ``sudo ip link set can0 type can restart``.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vsccore.errors import DeviceError

__all__ = ["IpRunner", "SocketcanLink", "check_link", "fix_commands", "parse_ip_details", "read_link"]

IpRunner = Callable[[str], str | None]
"""``ifname → output of ip -details link show ifname`` (None when ``ip`` is not available)."""

SYS_CLASS_NET = Path("/sys/class/net")
_IFF_UP = 0x1


@dataclass(frozen=True, slots=True)
class SocketcanLink:
    """What is known of one SocketCAN network interface (None: could not be read)."""

    name: str
    exists: bool
    up: bool | None = None
    operstate: str | None = None
    kind: str | None = None
    """``can`` for a CAN controller, ``vcan``/``vxcan`` for virtual ones (from ``ip -details``)."""
    ctrlmode: frozenset[str] = frozenset()
    """Control-mode flags, e.g. ``LISTEN-ONLY``, ``FD``."""
    state: str | None = None
    """Controller state as ``ip`` prints it: ``ERROR-ACTIVE``, ``ERROR-WARNING``, ``ERROR-PASSIVE``,
    ``BUS-OFF``, ``STOPPED``."""
    bitrate: int | None = None
    dbitrate: int | None = None
    restart_ms: int | None = None
    details_read: bool = False
    """Whether ``ip -details`` output was available."""

    @property
    def is_controller(self) -> bool:
        """A real CAN controller (bitrate, listen-only and restart-ms apply)."""
        return self.kind == "can"


_FLAGS = re.compile(r"^\d+:\s+\S+?:\s+<([^>]*)>", re.MULTILINE)
_CAN_LINE = re.compile(r"^\s*can\s+(?:<([^>]*)>\s+)?state\s+(\S+)", re.MULTILINE)
_VIRTUAL = re.compile(r"^\s*(vcan|vxcan)\b", re.MULTILINE)
_RESTART = re.compile(r"\brestart-ms\s+(\d+)")
_BITRATE = re.compile(r"^\s*bitrate\s+(\d+)", re.MULTILINE)
_DBITRATE = re.compile(r"^\s*dbitrate\s+(\d+)", re.MULTILINE)


def parse_ip_details(name: str, text: str) -> SocketcanLink:
    """Parse ``ip -details link show NAME`` (iproute2's text form, as in the kernel's can.rst)."""
    flags = _FLAGS.search(text)
    up = None if flags is None else "UP" in flags.group(1).split(",")
    can_line = _CAN_LINE.search(text)
    kind: str | None = None
    ctrlmode: frozenset[str] = frozenset()
    state = None
    if can_line is not None:
        kind = "can"
        ctrlmode = frozenset(m for m in (can_line.group(1) or "").split(",") if m)
        state = can_line.group(2)
    elif (virtual := _VIRTUAL.search(text)) is not None:
        kind = virtual.group(1)
    restart = _RESTART.search(text)
    bitrate = _BITRATE.search(text)
    dbitrate = _DBITRATE.search(text)
    return SocketcanLink(
        name=name,
        exists=True,
        up=up,
        kind=kind,
        ctrlmode=ctrlmode,
        state=state,
        bitrate=None if bitrate is None else int(bitrate.group(1)),
        dbitrate=None if dbitrate is None else int(dbitrate.group(1)),
        restart_ms=None if restart is None else int(restart.group(1)),
        details_read=True,
    )


def _run_ip(name: str) -> str | None:
    ip = shutil.which("ip")
    if ip is None:
        return None
    try:
        done = subprocess.run([ip, "-details", "link", "show", name], capture_output=True, text=True, timeout=2.0,
                              check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def read_link(name: str, *, sys_root: Path = SYS_CLASS_NET, run_ip: IpRunner = _run_ip) -> SocketcanLink:
    """What ``/sys/class/net/NAME`` and ``ip -details link show NAME`` say of a SocketCAN interface."""
    node = sys_root / name
    if not node.exists():
        return SocketcanLink(name, exists=False)
    operstate = _read(node / "operstate")
    up: bool | None = None
    flags = _read(node / "flags")
    if flags is not None:
        try:
            up = bool(int(flags, 16) & _IFF_UP)
        except ValueError:
            up = None
    text = run_ip(name)
    if text is None:
        return SocketcanLink(name, exists=True, up=up, operstate=operstate)
    link = parse_ip_details(name, text)
    return SocketcanLink(
        name, exists=True, up=up if up is not None else link.up, operstate=operstate, kind=link.kind,
        ctrlmode=link.ctrlmode, state=link.state, bitrate=link.bitrate, dbitrate=link.dbitrate,
        restart_ms=link.restart_ms, details_read=True,
    )


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="ascii").strip()
    except OSError:
        return None


def fix_commands(name: str, bitrate: int | None, *, data_bitrate: int | None = None, listen_only: bool = True,
                 restart_ms: int = 100) -> str:
    """The ``ip link`` commands that bring ``name`` up as the configuration wants it."""
    settings = f"bitrate {bitrate or 500_000}"
    if data_bitrate is not None:
        settings += f" dbitrate {data_bitrate} fd on"
    settings += f" restart-ms {restart_ms}"
    if listen_only:
        settings += " listen-only on"
    return (f"sudo ip link set {name} down; sudo ip link set {name} type can {settings}; "
            f"sudo ip link set {name} up")


def check_link(link: SocketcanLink, *, bitrate: int | None, data_bitrate: int | None = None,
               listen_only: bool | None = None, where: str = "can") -> tuple[str, ...]:
    """Refuse an interface the rig cannot record from as configured; return what is worth a warning.

    Raises:
        DeviceError: the interface does not exist, is down, has no bitrate or another bitrate than
            configured, or acknowledges frames (not listen-only) while ``listen_only`` is asked; the
            message names the ``ip link`` commands (or the ``[[can]]`` key) that fix it.
    """
    name = link.name
    fix = fix_commands(name, bitrate, data_bitrate=data_bitrate, listen_only=listen_only is not False)
    if not link.exists:
        raise DeviceError(f"{where}: no network interface {name!r} (is the adapter plugged in and its driver "
                          f"loaded? `ip link show` lists them)")
    if link.kind in ("vcan", "vxcan"):
        if link.up is False:
            raise DeviceError(f"{where}: {name} is down: sudo ip link set {name} up")
        return ()
    if link.is_controller and link.bitrate is None:
        raise DeviceError(f"{where}: {name} has no bitrate set (state {link.state or '?'}): {fix}")
    if link.up is False:
        raise DeviceError(f"{where}: {name} is down (operstate {link.operstate or '?'}): {fix}")
    if not link.is_controller:
        if link.details_read:
            return ()
        return (f"{name}: `ip -details link show` not available: bitrate, listen-only and restart-ms not checked",)
    if bitrate is not None and link.bitrate != bitrate:
        raise DeviceError(f"{where}.bitrate: {name} runs at {link.bitrate} bit/s, the configuration says {bitrate}: "
                          f"{fix} (or set bitrate = {link.bitrate})")
    if data_bitrate is not None and link.dbitrate != data_bitrate:
        raise DeviceError(f"{where}.data_bitrate: {name} has data bitrate {link.dbitrate}, the configuration says "
                          f"{data_bitrate}: {fix}")
    if listen_only and "LISTEN-ONLY" not in link.ctrlmode:
        raise DeviceError(f"{where}.listen_only: {name} is not listen-only, so it would acknowledge frames on the "
                          f"car's bus: {fix} (or set listen_only = false to record from an acknowledging interface)")
    notes = []
    if not link.restart_ms:
        notes.append(f"{name}: restart-ms is 0: after a bus-off the controller stays off until "
                     f"`sudo ip link set {name} type can restart` (set restart-ms 100 for automatic recovery)")
    if link.state is not None and link.state not in ("ERROR-ACTIVE",):
        notes.append(f"{name}: controller state {link.state}")
    return tuple(notes)
