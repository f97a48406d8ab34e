"""Acceptance (issue 15): a deliberately starved recording — the CAN reader made slower than the simulated
ECU sends — is refused by ``rig validate`` with exit status 2 naming the CAN stream, and the recording
itself says so: the CAN channels end before the session (gap events, the closing summary's "late")."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can
import pytest

from rig.core.config import load_session as load_config
from rig.core.topics import EventKind
from rig.record.recording import Recording, RecordingSummary, summary_lines
from rig.sim.world import SimWorld
from rig.workflows.demo import demo_config_path
from sim_devices.gnss import RtkParams
from sim_devices.vehicle.scenarios import make_scenario
from tests.calib_cli.synth import run_cli

NS = 1_000_000_000
READ_DELAY_S = 0.004
"""Each frame the CAN reader takes costs this much more wall time: ~250 frames/s, fewer than the ECU sends."""


class StarvedBus(can.BusABC):
    """A python-can bus whose every received frame costs the reader ``delay_s`` (a CPU-starved reader).

    The delay is the fault being injected (it stands for the time a starved thread does not run), not a
    wait in the test."""

    def __init__(self, inner: can.BusABC, delay_s: float) -> None:
        super().__init__(channel=getattr(inner, "channel_info", "starved"))
        self._inner = inner
        self._delay_s = delay_s
        self.channel_info = f"starved {inner.channel_info}"

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg = self._inner.recv(timeout)
        if msg is not None:
            time.sleep(self._delay_s)
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._inner.send(msg, timeout)

    def shutdown(self) -> None:
        super().shutdown()
        self._inner.shutdown()


@pytest.fixture(scope="module")
def starved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RecordingSummary]:
    out = tmp_path_factory.mktemp("starved")
    # the free-running clock: with the governed one the simulated ECU would wait for its reader (no starvation)
    cfg = load_config(demo_config_path(), {"simulation.speed": 1.0, "simulation.governed": False})
    world = SimWorld(cfg, drive=make_scenario("straight", speed_kmh=50.0, duration_s=6.0), lead_s=2.0,
                     rtk=RtkParams(time_to_float_s=0.5, time_to_fix_s=1.0), governed=False)
    world.start()
    try:
        assert world.clock is not None
        session = Recording(
            cfg, out_dir=out, name="starved", clock=world.clock, ports=world, daq_factory=world.daq_session,
            can_factory=lambda c: StarvedBus(world.can_bus(c), READ_DELAY_S), plugins=[world],
        )
        session.start()
        try:
            until = threading.Event()
            while world.clock.now_ns() < world.end_ns and not session.failed.is_set():
                until.wait(0.1)  # the simulated drive runs in real time; poll its clock as record_simulated does
        finally:
            summary = session.stop()
    finally:
        world.stop()
    assert summary.recording.error is None
    return out / "starved", summary


def test_the_recording_reports_the_starved_can_stream_as_late(starved: tuple[Path, RecordingSummary]) -> None:
    _base, summary = starved
    late_can = {t: s for t, s in summary.late.items() if t.startswith("/can/")}
    assert late_can, summary.late  # old code: no such report
    assert max(late_can.values()) > 1.0
    head = summary_lines(summary)
    assert "late" in head[0] and any("ended before the session" in line for line in head), head
    assert summary.verdicts["can:vsc"].verdict.value == "unusable", summary.verdicts["can:vsc"].message()


def test_the_starved_stream_is_refused_on_its_timing_figure_too(starved: tuple[Path, RecordingSummary]) -> None:
    """Not only its early end: the frames' floor rose by seconds above the map, which the map cannot be checked
    against (the reader's backlog and a clock running away look alike), live and offline."""
    from rig.core.quality import Verdict
    from rig.data import load_session
    from rig.data.verdicts import session_verdicts

    path, summary = starved
    for q in (summary.verdicts["can:vsc"], session_verdicts(load_session(path))["can:vsc"]):
        timing = next(f for f in q.figures if f.name == "timing_error_ms")
        assert timing.verdict is Verdict.UNUSABLE, q.message()
        assert timing.value > 100.0 and "can:vsc unusable: timing error" in q.message()


def test_the_file_holds_the_early_end_as_a_gap_event(starved: tuple[Path, RecordingSummary]) -> None:
    from rig.data import load_session

    ds = load_session(starved[0])
    gaps = [e for _t, e in ds.events if e.kind is EventKind.GAP and e.details.get("gap") == "ended_early"]
    can = [e for e in gaps if any(str(t).startswith("/can/vsc/") for t in e.details["topics"])]
    assert len(can) == 1, [e.text for e in gaps]  # one event per device and span, naming its topics
    (ev,) = can
    assert ev.source == "can.vsc" and "/can/vsc/roles" in ev.details["topics"]
    assert ev.start_ns is not None and ev.end_ns is not None and ev.end_ns - ev.start_ns > NS


def test_rig_validate_exits_2_naming_the_can_stream(
    starved: tuple[Path, RecordingSummary], capsys: pytest.CaptureFixture[str],
) -> None:
    assert run_cli(["validate", "--no-progress", str(starved[0])]) == 2
    err = capsys.readouterr().err
    assert "can:vsc unusable" in err and "fix:" in err, err
    print(err)
