"""RTKLIB's convbin turns a simulated rover's NovAtel stream (RANGECMPB + GPSEPHEMB) into RINEX obs."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from drivers.novatel import Frame
from drivers.novatel.rawobs import GLONASS_PRN_OFFSET, SatSystem, decode_rangecmp
from sim_devices.gnss import SimTimeBase
from sim_devices.gnss.rover import SimRover
from sim_devices.vehicle import GroundTruth
from tests.sim_gnss.conftest import SPEED, PortReader

pytestmark = pytest.mark.skipif(shutil.which("convbin") is None, reason="RTKLIB convbin not installed (apt rtklib)")

EPOCHS = 6


def _rinex_obs(path: Path) -> dict[str, set[str]]:
    """Satellites per epoch line (``> yyyy mm dd hh mm ss``) of a RINEX 3 observation file."""
    epochs: dict[str, set[str]] = {}
    current: set[str] | None = None
    in_header = True
    for line in path.read_text().splitlines():
        if in_header:
            in_header = "END OF HEADER" not in line
            continue
        if line.startswith(">"):
            current = set()
            epochs[line[2:29].strip()] = current
        elif current is not None and line[:1] in "GR" and line[1:3].strip().isdigit():
            current.add(line[:3].replace(" ", "0"))
    return epochs


def test_convbin_finds_every_simulated_observation(truth: GroundTruth, timebase: SimTimeBase,
                                                     open_port: Callable[..., PortReader], tmp_path: Path) -> None:
    clock = timebase.make_clock(speed=SPEED, lead_s=0.0)
    rover = SimRover("rover_a", truth=truth, lever_arm=(0.0, 0.0, 1.5), timebase=timebase, clock=clock)
    rover.start()
    try:
        port = open_port(rover.port_path)
        assert port.command("LOG RANGECMPB ONTIME 1").message.ok  # type: ignore[union-attr]
        assert port.command("LOG GPSEPHEMB ONCHANGED").message.ok  # type: ignore[union-attr]

        def cmp(fs: list[Frame]) -> list[Frame]:
            return [f for f in fs if f.log is not None and f.log.header.message_name == "RANGECMP"]

        port.until(lambda fs: len(cmp(fs)) >= EPOCHS, timeout_s=30.0)
    finally:
        rover.stop()
    stream = tmp_path / "rover_a.gps"
    stream.write_bytes(b"".join(f.raw for f in port.frames))
    obs_path = tmp_path / "rover_a.obs"
    run = subprocess.run(["convbin", "-r", "nov", "-v", "3.04", "-o", str(obs_path), str(stream)],
                         capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    epochs = _rinex_obs(obs_path)
    frames = cmp(port.frames)
    assert len(epochs) == len(frames) >= EPOCHS
    for (stamp, sats), frame in zip(sorted(epochs.items()), frames, strict=True):
        records = decode_rangecmp(frame.log.body).records  # type: ignore[union-attr, arg-type]
        expected = {f"G{r.prn:02d}" if r.system is SatSystem.GPS else f"R{r.prn - GLONASS_PRN_OFFSET:02d}"
                    for r in records}
        assert sats == expected, stamp
        assert any(s.startswith("G") for s in sats) and any(s.startswith("R") for s in sats)


ROVER_LOGS = [{"name": "BESTPOSB", "period_s": 0.05}, {"name": "BESTVELB", "period_s": 0.05},
              {"name": "TIMEB", "period_s": 1.0}, {"name": "RANGECMPB", "period_s": 1.0},
              {"name": "GPSEPHEMB", "trigger": "onchanged"}]


def test_convbin_on_rig_export_of_a_recorded_session(tmp_path: Path) -> None:
    """`rig export --raw-gnss` of a simulated session whose rover logs RANGECMPB: convbin finds every epoch."""
    from drivers.novatel import FrameReader
    from rig.core.config import load_session as load_config
    from rig.export.raw_gnss import export_raw_gnss
    from rig.sim.record import record_simulated
    from rig.workflows.demo import demo_config_path
    from sim_devices.vehicle.scenarios import make_scenario

    cfg = load_config(demo_config_path(), {"simulation.speed": 2.0, "receivers.1.logs": ROVER_LOGS})
    rec = record_simulated(cfg, tmp_path, name="rec", drive=make_scenario("straight", speed_kmh=40.0, duration_s=4.0),
                           lead_s=2.0)
    assert rec.completed and rec.summary.recording.error is None
    export_raw_gnss(tmp_path / "rec", tmp_path / "raw")
    stream = tmp_path / "raw" / "rover_a.gps"
    with open(stream, "rb") as f:
        frames = [fr for fr in FrameReader(f) if fr.log is not None and fr.log.header.message_name == "RANGECMP"]
    assert len(frames) >= 3
    obs_path = tmp_path / "rover_a.obs"
    run = subprocess.run(["convbin", "-r", "nov", "-v", "3.04", "-o", str(obs_path), str(stream)],
                         capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    epochs = _rinex_obs(obs_path)
    assert len(epochs) == len(frames)
    for sats, frame in zip((epochs[k] for k in sorted(epochs)), frames, strict=True):
        n_sats = len({(r.system, r.prn) for r in decode_rangecmp(frame.log.body).records})  # type: ignore[union-attr, arg-type]
        assert len(sats) == n_sats >= 8
