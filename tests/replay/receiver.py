"""The receiving side of the replay tests: the rig's live CAN reader on a bus, its frames written as a second
recording by the real recorder and read back with the dataset API.

:class:`ReceivingSide` runs that side in a process of its own, as on a bench where the ECU receives: a
socketcand server on 127.0.0.1 (its bus stamps each frame with the kernel's arrival stamp of the player's
``< send >``, see :mod:`sim_devices.socketcand`) and the recorder reading from it, which records that stamp
as the frame's device time (``device_ts_ns``; its own receive time is ``host_ts_ns``). The player's process
then holds no thread of the receiver, so the interpreter lock, the garbage collector and the scheduling of
the receiving side do not delay the player's sends, and the stamps are taken where a bench interface takes
them: on the receiving side, when the frame reaches it.
"""

from __future__ import annotations

import multiprocessing
import sys
import threading
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import rig.core.topics as T  # noqa: N812 - short alias
from drivers.can.bus import BusEvent, BusOpened, CanBusConfig, CanBusLink, CanFrame, CanFrameFlag
from rig.data import Session, load_session
from rig.replay.scheduling import realtime_priority
from rig.store import Attachment, Recorder, RecorderOptions, session_metadata
from sim_devices.socketcand import SocketcandServer, virtual_channel_opener
from vsccore.clock import SystemClock


class ReceivingRecorder:
    """A :class:`CanBusLink` (the recorder's reader) that keeps every frame; :meth:`write` records them."""

    def __init__(self, config: CanBusConfig) -> None:
        self.frames: list[CanFrame] = []
        self.opened = threading.Event()
        self._cond = threading.Condition()
        self.session = CanBusLink(config, self._on_frame, self._on_event, clock=SystemClock(), stats_period_s=None)

    def _on_frame(self, frame: CanFrame) -> None:
        with self._cond:
            self.frames.append(frame)
            self._cond.notify_all()

    def _on_event(self, event: BusEvent) -> None:
        if isinstance(event, BusOpened):
            self.opened.set()

    def __enter__(self) -> ReceivingRecorder:
        self.session.start()
        assert self.opened.wait(5.0), "receiving bus did not open"
        return self

    def __exit__(self, *exc: object) -> None:
        self.session.stop()

    def wait_for(self, count: int, timeout_s: float) -> bool:
        """Wait until ``count`` frames have arrived; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: len(self.frames) >= count, timeout_s)

    def write(self, out: Path, name: str, source: Session, bus: str = "vsc") -> Session:
        """Record the received frames as ``/can/<bus>/frames`` (with the source's DBC and roles); read them back."""
        atts = [Attachment(n, "text/plain", data) for n, data in source.attachments.items()]
        with Recorder(out, name, session_metadata(session={"name": name}), attachments=atts,
                      options=RecorderOptions(min_free_bytes=0, reserve_bytes=0)) as rec:
            src = rec.source(f"can.{bus}", maxsize=len(self.frames) + 1)
            for k in range(0, len(self.frames), 100):
                block = self.frames[k: k + 100]
                records = [T.CanFrameRecord(f.device_ts_ns, f.host_ts_ns, f.arbitration_id, _flags(f), f.dlc, f.data)
                           for f in block]
                assert src.put(T.can_frames(bus), block[0].host_ts_ns, block[0].host_ts_ns, T.pack_can_block(records))
        return load_session(out / name)


def _flags(f: CanFrame) -> T.CanFlag:
    flags = T.CanFlag(0) if f.flags & CanFrameFlag.TX_ECHO else T.CanFlag.RX
    if f.is_extended:
        flags |= T.CanFlag.EXTENDED
    if f.is_fd:
        flags |= T.CanFlag.FD
    if f.flags & CanFrameFlag.REMOTE:
        flags |= T.CanFlag.REMOTE
    return flags


def _receiving_side(channel: str, source: str, out: str, count: int, timeout_s: float, conn: Connection,
                    rt_priority: int | None = None) -> None:
    """The child process of :class:`ReceivingSide`: serve ``vsc0`` over socketcand, record ``count`` frames.

    ``rt_priority``: every thread of the process on SCHED_FIFO at that priority (threads inherit it) and a
    0.2 ms interpreter switch interval, so that the server reads each ``< send >`` as it arrives and stamps it
    alone, as a bench's interface stamps in hardware: a descheduled server reads several sends in one go,
    and TCP gives them all the latest segment's stamp (``benchmarks/bench_replay.py --rx-rt-priority``)."""
    try:
        if rt_priority is not None:
            sys.setswitchinterval(0.0002)
        opener = virtual_channel_opener({"vsc0": channel})
        with realtime_priority(rt_priority), SocketcandServer(opener, rawmode_settle_s=0.0) as server:
            host, port = server.address
            rx = CanBusConfig(interface="socketcand", channel="vsc0", options={"host": host, "port": port}, name="rx")
            with ReceivingRecorder(rx) as receiver:
                conn.send(("ready", host, port))
                complete = receiver.wait_for(count, timeout_s)
        if not complete:
            conn.send(("error", f"received {len(receiver.frames)} of {count} frames in {timeout_s} s"))
            return
        receiver.write(Path(out), "again", load_session(source))
        conn.send(("done", len(receiver.frames)))
    except Exception as exc:  # reported to the test, which fails with it
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


class ReceivingSide:
    """A socketcand server with the rig's recorder reading from it, in another process (module docstring).

    ``bus_spec`` is the player's ``--bus`` once it is ready; :meth:`result` waits for ``count`` frames and
    returns them as a recording (``out/again``) written with ``source``'s DBC and role map.
    """

    def __init__(self, channel: str, source: Session, out: Path, count: int, timeout_s: float = 60.0,
                 rt_priority: int | None = None) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._conn, self._child = ctx.Pipe(duplex=False)
        self._out = out
        self._proc = ctx.Process(target=_receiving_side, name="replay-receiving-side",
                                 args=(channel, str(source.path), str(out), count, timeout_s, self._child,
                                       rt_priority))
        self.bus_spec = ""

    def _recv(self, timeout_s: float) -> tuple[Any, ...]:
        if not self._conn.poll(timeout_s):
            raise AssertionError(f"receiving side: no answer in {timeout_s} s")
        msg: tuple[Any, ...] = self._conn.recv()
        if msg[0] == "error":
            raise AssertionError(f"receiving side: {msg[1]}")
        return msg

    def __enter__(self) -> ReceivingSide:
        self._proc.start()
        self._child.close()
        try:
            _ready, host, port = self._recv(60.0)
        except BaseException:
            self.__exit__()
            raise
        self.bus_spec = f"socketcand:vsc0,host={host},port={port}"
        return self

    def result(self, timeout_s: float) -> Session:
        """The received frames as a recording, once all have arrived (AssertionError otherwise)."""
        self._recv(timeout_s)
        return load_session(self._out / "again")

    def __exit__(self, *exc: object) -> None:
        self._proc.join(10.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        self._conn.close()
