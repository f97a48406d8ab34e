"""DAQ backends by name: the registry, a third-party entry point, and the NI-DAQmx backend (fake and real package)."""

from __future__ import annotations

import importlib.util
import queue
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest

from drivers.daq import (
    DaqBlock,
    DaqChannelConfig,
    DaqEvent,
    DaqEventKind,
    DaqLink,
    ReconnectPolicy,
    TerminalConfig,
    create_backend,
    known_backends,
    resolve_backend,
)
from drivers.daq.nidaqmx_backend import NidaqmxBackend
from drivers.daq.registry import ENTRY_POINT_GROUP
from sim_devices.daq import ConstantInput, SimDaqBackend
from tests.daq import fake_nidaqmx
from tests.daq.helpers import T0_NS, ManualClock
from vsccore.errors import ConfigError, DeviceError, DeviceTimeoutError

CHANS = [
    DaqChannelConfig("vx", "Dev1/ai0", -10.0, 10.0, TerminalConfig.DIFF),
    DaqChannelConfig("sync", "Dev1/ai7", 0.0, 10.0, TerminalConfig.RSE),
]


# --- registry -----------------------------------------------------------------------------------


def test_sim_backend_by_name_runs_an_acquisition() -> None:
    assert resolve_backend("sim") is SimDaqBackend
    clock = ManualClock()
    b = create_backend("sim", clock=clock, sources={"sim/ai0": ConstantInput(2.5)}, truth_start_ns=T0_NS)
    with b:
        b.configure([DaqChannelConfig("c", "sim/ai0")])
        b.start(1000.0)
        blk = b.read(50, timeout_s=1.0)
    assert blk.first_sample_index == 0 and blk.n_samples == 50
    np.testing.assert_allclose(blk.channel("c"), 2.5, atol=0.002)
    assert not b.running


def test_unknown_backend_lists_the_known_ones() -> None:
    with pytest.raises(ConfigError, match=r"unknown DAQ backend 'labjack'; known backends: .*nidaqmx.*sim"):
        resolve_backend("labjack")


def _install_plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, target: str, code: str) -> None:
    """A real installed distribution (dist-info with entry_points.txt) on sys.path, as pip would leave it."""
    (tmp_path / "acme_daq.py").write_text(textwrap.dedent(code))
    dist = tmp_path / "acme_daq-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-daq\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\n{name} = {target}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "acme_daq", raising=False)


PLUGIN = """
    import numpy as np
    from drivers.daq.base import DaqBackend

    class AcmeBackend(DaqBackend):
        name = "acme"

        def _configure(self, channels):
            pass

        def _start(self, rate_hz, buffer_size):
            self._k = 0

        def _read(self, n, timeout_s):
            first = self._k
            self._k += n
            return first, np.tile(np.arange(first, first + n, dtype=float), (len(self.channels), 1)), None

        def _stop(self):
            pass

    NotABackend = object
"""


def test_third_party_backend_through_the_entry_point(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install_plugin(tmp_path, monkeypatch, "acme", "acme_daq:AcmeBackend", PLUGIN)
    assert known_backends()["acme"] == "acme_daq:AcmeBackend"
    with create_backend("acme", clock=ManualClock()) as b:
        assert type(b).__name__ == "AcmeBackend"
        b.configure([DaqChannelConfig("a", "acme/0")])
        b.start(100.0)
        b.read(3)
        blk = b.read(4)
    assert blk.first_sample_index == 3
    np.testing.assert_array_equal(blk.channel("a"), [3.0, 4.0, 5.0, 6.0])


def test_bad_entry_points_are_reported_by_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install_plugin(tmp_path, monkeypatch, "acme", "acme_daq:NotABackend", PLUGIN)
    with pytest.raises(ConfigError, match=r"DAQ backend 'acme': acme_daq:NotABackend is not a DaqBackend subclass"):
        resolve_backend("acme")


def test_entry_point_cannot_replace_a_builtin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _install_plugin(tmp_path, monkeypatch, "nidaqmx", "acme_daq:AcmeBackend", PLUGIN)
    assert known_backends()["nidaqmx"] == "drivers.daq.nidaqmx_backend:NidaqmxBackend"


# --- NI-DAQmx -----------------------------------------------------------------------------------


def test_nidaqmx_missing_package_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "nidaqmx", None)  # import fails as if not installed
    with pytest.raises(DeviceError, match=r"needs the Python package 'nidaqmx'.*vsc-rig\[nidaqmx\].*NI-DAQmx driver"):
        create_backend("nidaqmx")


def test_nidaqmx_missing_driver_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_nidaqmx.install(monkeypatch)
    fake_nidaqmx.System.driver_missing = True
    with pytest.raises(DeviceError, match=r"'nidaqmx' is installed but the NI-DAQmx driver could not be loaded"):
        create_backend("nidaqmx")


@pytest.mark.skipif(importlib.util.find_spec("nidaqmx") is None, reason="the nidaqmx package is not installed")
def test_real_nidaqmx_package_without_the_driver() -> None:  # pragma: no cover - depends on the machine
    """With the real package: either the driver is there (hardware machine) or the error names it."""
    try:
        b = create_backend("nidaqmx")
    except DeviceError as exc:
        message = str(exc)
    else:
        assert isinstance(b, NidaqmxBackend) and b.driver_version
        b.close()
        return
    assert "NI-DAQmx driver could not be loaded" in message


def _ni_backend(monkeypatch: pytest.MonkeyPatch) -> NidaqmxBackend:
    fake_nidaqmx.install(monkeypatch)
    b = create_backend("nidaqmx", clock=ManualClock(), device="Dev1")
    assert isinstance(b, NidaqmxBackend)
    b.configure(CHANS)
    return b


def test_nidaqmx_task_is_continuous_hardware_timed_with_overwrite(monkeypatch: pytest.MonkeyPatch) -> None:
    b = _ni_backend(monkeypatch)
    assert b.driver_version == "2024.1.0"
    b.start(1000.0, buffer_size=4000)
    task = fake_nidaqmx.Task.instances[-1]
    assert task.started
    assert [c["physical_channel"] for c in task.ai_channels.added] == ["Dev1/ai0", "Dev1/ai7"]
    ch0, ch1 = task.ai_channels.added
    assert ch0["terminal_config"] is fake_nidaqmx.TerminalConfiguration.DIFF
    assert ch1["terminal_config"] is fake_nidaqmx.TerminalConfiguration.RSE
    assert (ch1["min_val"], ch1["max_val"], ch1["name_to_assign_to_channel"]) == (0.0, 10.0, "sync")
    assert task.timing.cfg == {
        "rate": 1000.0,
        "sample_mode": fake_nidaqmx.AcquisitionType.CONTINUOUS,
        "samps_per_chan": 4000,
    }
    assert task.in_stream.input_buf_size == 4000
    assert task.in_stream.overwrite is fake_nidaqmx.OverwriteMode.OVERWRITE_UNREAD_SAMPLES
    b.close()
    assert task.stopped and task.closed


def test_nidaqmx_blocks_follow_the_sample_clock_and_overflow_names_the_lost_range(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    b = _ni_backend(monkeypatch)
    b.start(1000.0, buffer_size=1000)
    task = fake_nidaqmx.Task.instances[-1]
    with pytest.raises(DeviceTimeoutError, match=r"Dev1: 100 samples not acquired within 0\.5 s"):
        b.read(100, timeout_s=0.5)
    task.acquired = 250
    blocks = [b.read(100), b.read(100)]
    assert [blk.first_sample_index for blk in blocks] == [0, 100]
    # the fake puts channel i of sample k at i + k/1000 V: the data are those of the reported indices
    for blk in blocks:
        np.testing.assert_allclose(blk.channel("sync"), 1.0 + blk.sample_indices() / 1000.0)
        assert blk.lost_before is None
    # the reader falls behind: samples 200 … 3499 acquired, only the last 1000 still in the buffer
    task.acquired = 3500
    after = b.read(100)
    assert after.lost_before is not None
    # re-read from half a buffer behind the newest sample: 3500 − 500
    assert after.first_sample_index == 3000
    assert (after.lost_before.start_index, after.lost_before.stop_index) == (200, 3000)
    np.testing.assert_allclose(after.channel("vx"), after.sample_indices() / 1000.0)
    assert task.in_stream.relative_to is fake_nidaqmx.ReadRelativeTo.CURRENT_READ_POSITION  # restored
    nxt = b.read(100)
    assert nxt.first_sample_index == 3100 and nxt.lost_before is None
    np.testing.assert_allclose(nxt.channel("vx"), nxt.sample_indices() / 1000.0)
    b.close()


def test_nidaqmx_device_error_becomes_a_device_error(monkeypatch: pytest.MonkeyPatch) -> None:
    b = _ni_backend(monkeypatch)
    b.start(1000.0)
    fake_nidaqmx.Task.fail_read_code = -201003  # device cannot be accessed (unplugged USB DAQ)
    msg = r"DAQ Dev1 \(vsc_rig_daq\): reading samples failed \(NI-DAQmx error -201003\)"
    with pytest.raises(DeviceError, match=msg):
        b.read(10)
    with pytest.raises(DeviceError, match=r"stopping the task failed"):
        b.close()
    assert fake_nidaqmx.Task.instances[-1].closed  # the task is released all the same
    b.close()  # idempotent


def test_session_on_nidaqmx_reconnects_after_the_device_was_unplugged(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_nidaqmx.install(monkeypatch)
    fake_nidaqmx.Task.auto_acquire = True
    events: queue.Queue[DaqEvent] = queue.Queue()
    blocks: list[DaqBlock] = []
    enough = threading.Event()

    def on_block(block: DaqBlock) -> None:
        blocks.append(block)
        if len(blocks) == 5:
            fake_nidaqmx.Task.fail_read_code = -201003  # USB DAQ pulled: reads, stop and start fail
        if block.segment == 2 and block.first_sample_index >= 300:
            enough.set()

    def wait_for(kind: DaqEventKind) -> DaqEvent:
        while True:
            ev = events.get(timeout=10.0)
            if ev.kind is kind:
                return ev

    cfg = {
        "backend": "nidaqmx",
        "device": "Dev1",
        "rate_hz": 1000.0,
        "block_size": 100,
        "buffer_samples": 2000,
        "channels": [{"name": "vx", "physical": "Dev1/ai0"}, {"name": "sync", "physical": "Dev1/ai7"}],
    }
    session = DaqLink.from_config(
        cfg, on_block=on_block, on_event=events.put, clock=ManualClock(),
        reconnect=ReconnectPolicy(initial_s=0.01, max_s=0.05),
    )
    with session:
        disc = wait_for(DaqEventKind.DISCONNECTED)
        failed = wait_for(DaqEventKind.CONNECT_FAILED)
        fake_nidaqmx.Task.fail_read_code = None  # plugged back in
        rec = wait_for(DaqEventKind.RECONNECTED)
        assert enough.wait(10.0)
    assert session.error is None
    assert "-201003" in disc.message and "-201003" in failed.message
    assert rec.segment == 2
    assert [b.first_sample_index for b in blocks[:5]] == [0, 100, 200, 300, 400]
    seg2 = [b for b in blocks if b.segment == 2]
    assert seg2[0].first_sample_index == 0
    np.testing.assert_allclose(seg2[3].channel("sync"), 1.0 + seg2[3].sample_indices() / 1000.0)
    assert all(t.closed for t in fake_nidaqmx.Task.instances)  # no task left open, even the failed ones
