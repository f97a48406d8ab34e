"""The receiving side of the replay tests: the rig's live CAN reader on a bus, its frames written as a second
recording by the real recorder and read back with the dataset API."""

from __future__ import annotations

import threading
from pathlib import Path

import rig.topics as T  # noqa: N812 - short alias
from drivers.can.bus import BusEvent, BusOpened, CanBusConfig, CanBusSession, CanFrame, CanFrameFlag
from rig.dataset import Session, load_session
from rig.recorder import Attachment, Recorder, RecorderOptions, session_metadata
from vsccore.clock import SystemClock


class ReceivingRecorder:
    """A :class:`CanBusSession` (the recorder's reader) that keeps every frame; :meth:`write` records them."""

    def __init__(self, config: CanBusConfig) -> None:
        self.frames: list[CanFrame] = []
        self.opened = threading.Event()
        self._cond = threading.Condition()
        self.session = CanBusSession(config, self._on_frame, self._on_event, clock=SystemClock(), stats_period_s=None)

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
