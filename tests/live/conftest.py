"""A simulated recording with the live view attached, running on a thread while a test looks at it."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from rig.live import LiveOptions, LiveView
from rig.record.recording import Recording
from rig.sim.record import SimRecording, record_simulated
from tests.session.recording import FAST_RTK, config


@dataclass
class LiveRun:
    view: LiveView
    session: Recording | None = None
    started: threading.Event = field(default_factory=threading.Event)
    stop: threading.Event = field(default_factory=threading.Event)
    finished: threading.Event = field(default_factory=threading.Event)
    """Set when the recording ended (the drive completed, or stop) and the file is finalized."""
    result: list[SimRecording] = field(default_factory=list)
    error: list[BaseException] = field(default_factory=list)


def run_live(tmp: Path, options: LiveOptions, drive: str = "step_steer:lead_s=1,hold_s=300",
             speed: float = 2.0) -> Iterator[LiveRun]:
    """Record ``drive`` with the live view attached on a thread; yields once the view serves.

    The default drive outlasts any test: the recording ends when the test does (``stop``), so a client
    that connects late on a loaded host still finds the car driving.
    """
    cfg = config(drive, speed)
    run = LiveRun(LiveView(options))

    def on_started(s: Recording) -> None:
        run.view.attach(s)
        run.session = s
        run.started.set()

    def body() -> None:
        try:
            run.result.append(record_simulated(cfg, tmp, name="live", rtk=FAST_RTK, lead_s=3.0, stop=run.stop,
                                               on_started=on_started))
        except BaseException as exc:
            run.error.append(exc)
        finally:
            run.started.set()
            run.finished.set()

    th = threading.Thread(target=body, name="test-live-recording")
    th.start()
    try:
        assert run.started.wait(60.0), "the simulated recording did not start"
        assert not run.error, f"recording failed: {run.error}"
        yield run
    finally:
        run.stop.set()
        th.join(120.0)
        run.view.detach()
        assert not th.is_alive()
    assert not run.error, f"recording failed: {run.error}"


@pytest.fixture
def live_run(tmp_path: Path) -> Iterator[LiveRun]:
    yield from run_live(tmp_path, LiveOptions(port=0))
