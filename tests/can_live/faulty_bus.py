"""A python-can bus that can be unplugged, made to hang, and plugged back in (fault injection)."""

from __future__ import annotations

import threading
from typing import Any

import can

from drivers.can.bus import CanBusConfig


class Plug:
    """Shared state of the simulated adapter: present or pulled, silent or talking."""

    def __init__(self) -> None:
        self.present = True
        self.silent = False
        self.opens = 0
        self.lock = threading.Lock()

    def unplug(self) -> None:
        self.present = False

    def replug(self) -> None:
        self.present = True


class FaultyBus(can.BusABC):
    """Wraps a virtual bus. While unplugged ``recv``/``send`` raise ``CanOperationError`` as a
    vanished USB adapter does; while silent ``recv`` returns nothing (a hung adapter)."""

    def __init__(self, channel: str, plug: Plug, **kwargs: Any) -> None:
        if not plug.present:
            raise can.CanInitializationError(f"adapter for {channel} not found")
        self._inner = can.Bus(interface="virtual", channel=channel)
        self._plug = plug
        with plug.lock:
            plug.opens += 1
        super().__init__(channel=channel, **kwargs)
        self.channel_info = f"faulty virtual {channel}"

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._plug.present:
            raise can.CanOperationError("device disconnected")
        if self._plug.silent:
            return None, False
        return self._inner.recv(timeout), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._plug.present:
            raise can.CanOperationError("device disconnected")
        self._inner.send(msg, timeout)

    def shutdown(self) -> None:
        super().shutdown()
        self._inner.shutdown()


def faulty_factory(plug: Plug):
    def open_faulty(config: CanBusConfig) -> can.BusABC:
        return FaultyBus(str(config.channel), plug)

    return open_faulty
