"""Faults a road test meets, rehearsed on the simulated car (``rig sim record --fault``): a correction cable
pulled for a span, a receiver reset, a receiver's port unplugged, the CAN adapter or the DAQ unplugged, a DAQ
input left open, the CAN bus driven bus-off. Each acts on the simulated devices exactly as the real fault does;
the recording is told nothing and records what it sees."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from rig.core.config import SessionConfig
from rig.record.recording import Recording
from rig.sim.record import Action
from rig.sim.world import SIM_PREFIX, SimWorld
from vsccore.errors import ConfigError

DeviceAction = Callable[[SimWorld, Recording], None]

__all__ = ["FaultKind", "SimFault", "fault_actions", "floating_channels", "parse_fault"]


class FaultKind(StrEnum):
    """What goes wrong."""

    CORRECTIONS = "corrections"  # the correction cable to a rover pulled (RECEIVER, a span)
    RESET = "reset"  # a receiver resets behind its open port (RECEIVER, an instant)
    UNPLUG = "unplug"  # a receiver's command port unplugged (RECEIVER, a span)
    CAN_UNPLUG = "can-unplug"  # the CAN adapter unplugged (a span)
    CAN_BUS_OFF = "can-bus-off"  # the VSC bus driven bus-off (error warning, passive, bus-off, restart; a span)
    DAQ_UNPLUG = "daq-unplug"  # the DAQ unplugged (a span)
    DAQ_FLOAT = "daq-float"  # a DAQ input left open: noise and mains hum (CHANNEL, the whole session)


_SPAN = frozenset({FaultKind.CORRECTIONS, FaultKind.UNPLUG, FaultKind.CAN_UNPLUG, FaultKind.CAN_BUS_OFF,
                   FaultKind.DAQ_UNPLUG})
_TARGETED = frozenset({FaultKind.CORRECTIONS, FaultKind.RESET, FaultKind.UNPLUG, FaultKind.DAQ_FLOAT})
_TIME = r"[0-9]+(?:\.[0-9]+)?"
_SPEC = re.compile(
    rf"^(?P<kind>[a-z-]+)(?::(?P<target>[A-Za-z0-9_.-]+))?(?:@(?P<t0>{_TIME})(?:\.\.(?P<t1>{_TIME}))?)?$")


@dataclass(frozen=True, slots=True)
class SimFault:
    """One fault: its kind, the receiver or DAQ channel it hits, and when (s of drive time; None: always)."""

    kind: FaultKind
    target: str | None
    t0_s: float | None
    t1_s: float | None


def parse_fault(text: str, cfg: SessionConfig) -> SimFault:
    """``KIND[:TARGET][@T0[..T1]]``, e.g. ``corrections:rover_a@30..60``, ``reset:rover_b@45``, ``can-unplug@10..12``,
    ``daq-float:slip_angle`` (times in s of drive time).

    Raises:
        ConfigError: an unknown kind, a target the configuration does not have, a missing or reversed span.
    """
    where = f"--fault {text!r}"
    m = _SPEC.match(text.strip())
    if m is None:
        raise ConfigError(f"{where}: expected KIND[:TARGET][@T0[..T1]], e.g. corrections:rover_a@30..60")
    try:
        kind = FaultKind(m["kind"])
    except ValueError:
        raise ConfigError(f"{where}: unknown fault {m['kind']!r} ({', '.join(k.value for k in FaultKind)})") from None
    target = m["target"]
    t0 = float(m["t0"]) if m["t0"] else None
    t1 = float(m["t1"]) if m["t1"] else None
    if kind in _TARGETED and target is None:
        raise ConfigError(f"{where}: {kind.value} needs a target ({kind.value}:NAME)")
    if kind not in _TARGETED and target is not None:
        raise ConfigError(f"{where}: {kind.value} takes no target")
    receivers = {r.name: r for r in cfg.receivers}
    if kind in (FaultKind.CORRECTIONS, FaultKind.RESET, FaultKind.UNPLUG) and target not in receivers:
        raise ConfigError(f"{where}: no receiver {target!r} (receivers: {sorted(receivers)})")
    if kind is FaultKind.CORRECTIONS:
        rc = receivers[str(target)]
        if rc.correction_device is None or not rc.correction_device.startswith(SIM_PREFIX):
            raise ConfigError(f"{where}: receiver {target!r} has no simulated correction cable (correction_device)")
    if kind is FaultKind.DAQ_FLOAT:
        names = [c.name for c in cfg.daq.channels] if cfg.daq is not None else []
        if target not in names:
            raise ConfigError(f"{where}: no DAQ channel {target!r} (channels: {names})")
        if t0 is not None:
            raise ConfigError(f"{where}: an open input is open for the whole session (no @time)")
        return SimFault(kind, target, None, None)
    if t0 is None:
        raise ConfigError(f"{where}: say when (@T0{'..T1' if kind in _SPAN else ''}, s of drive time)")
    if kind in _SPAN and (t1 is None or t1 <= t0):
        raise ConfigError(f"{where}: {kind.value} needs a span @T0..T1 with T1 > T0")
    if kind not in _SPAN and t1 is not None:
        raise ConfigError(f"{where}: {kind.value} happens at an instant (@T0)")
    return SimFault(kind, target, t0, t1)


def floating_channels(faults: list[SimFault]) -> set[str]:
    """The DAQ channels left open."""
    return {str(f.target) for f in faults if f.kind is FaultKind.DAQ_FLOAT}


def fault_actions(faults: list[SimFault], cfg: SessionConfig) -> list[Action]:
    """The faults as actions at their drive times (the devices in the recorder's process)."""
    receivers = {r.name: r for r in cfg.receivers}
    out: list[Action] = []
    for f in faults:
        if f.t0_s is None:
            continue
        name = str(f.target)
        if f.kind is FaultKind.CORRECTIONS:
            cable = str(receivers[name].correction_device).removeprefix(SIM_PREFIX).partition("/")[2] or None
            out += [(f.t0_s, _unplug(name, cable)), (_t1(f), _replug(name, cable))]
        elif f.kind is FaultKind.UNPLUG:
            out += [(f.t0_s, _unplug(name, None)), (_t1(f), _replug(name, None))]
        elif f.kind is FaultKind.RESET:
            out.append((f.t0_s, _reset(name)))
        elif f.kind is FaultKind.CAN_BUS_OFF:
            out.append((f.t0_s, _bus_off(_t1(f) - f.t0_s)))
        elif f.kind is FaultKind.CAN_UNPLUG:
            out += [(f.t0_s, lambda w, _s: w.can_link.unplug()), (_t1(f), lambda w, _s: w.can_link.replug())]
        elif f.kind is FaultKind.DAQ_UNPLUG:
            out += [(f.t0_s, lambda w, _s: w.daq_link.unplug()), (_t1(f), lambda w, _s: w.daq_link.replug())]
    return out


def _t1(f: SimFault) -> float:
    assert f.t1_s is not None
    return f.t1_s


def _unplug(receiver: str, port: str | None) -> DeviceAction:
    def act(world: SimWorld, _s: Recording) -> None:
        world.receivers[receiver].unplug(port)
    return act


def _replug(receiver: str, port: str | None) -> DeviceAction:
    def act(world: SimWorld, _s: Recording) -> None:
        world.receivers[receiver].replug(port)
    return act


def _reset(receiver: str) -> DeviceAction:
    def act(world: SimWorld, _s: Recording) -> None:
        world.receivers[receiver].reset()
    return act


def _bus_off(duration_s: float) -> DeviceAction:
    def act(world: SimWorld, _s: Recording) -> None:
        for ecu in world.ecus.values():
            ecu.bus_off(duration_s)
    return act
