"""Fixtures of the replay tests: one short recorded simulated session, leak checks, unique channels."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import can.interfaces.virtual as virtual
import pytest

from rig.core.config import load_session as load_config
from rig.data import Session, load_session
from rig.replay.scheduling import realtime_priority
from rig.sim.record import record_simulated
from rig.workflows.demo import demo_config_path
from sim_devices.vehicle.scenarios import make_scenario
from tests.session.recording import FAST_RTK
from vsccore.errors import ConfigError

_counter = itertools.count()


@pytest.fixture(scope="package")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Session:
    """A 1 s lead plus a step steer (about 3 s of drive) recorded with every simulated device, the VSC ECU on a
    virtual bus: its CAN frames (7 messages, 4 with counters and CRC-8 checksums) are what the tests replay."""
    out = tmp_path_factory.mktemp("replay_src")
    cfg = load_config(demo_config_path(), {"simulation.speed": 1.0})
    drive = make_scenario("step_steer", speed_kmh=60.0, lead_s=0.5, rise_s=0.2, hold_s=1.5)
    rec = record_simulated(cfg, out, name="src", drive=drive, lead_s=1.0, rtk=FAST_RTK)
    assert rec.completed and rec.summary.recording.error is None
    return load_session(out / "src")


@pytest.fixture(autouse=True)
def _no_channel_leaks() -> Iterator[None]:
    """Every virtual bus shut down after each test (the root conftest checks the threads)."""
    with virtual.channels_lock:
        channels_before = set(virtual.channels)
    yield
    with virtual.channels_lock:
        leaked = set(virtual.channels) - channels_before
    assert not leaked, f"virtual CAN channels left open: {leaked}"


@pytest.fixture
def channel(request: pytest.FixtureRequest) -> str:
    """A virtual channel name no other test uses."""
    return f"replay-{request.node.name}-{next(_counter)}"


def session_path(ds: Session) -> Path:
    return Path(ds.path)


def fifo_allowed() -> bool:
    """Whether this process may put a thread on SCHED_FIFO (root, CAP_SYS_NICE or an rtprio limit)."""
    try:
        with realtime_priority(1):
            return True
    except ConfigError:
        return False
