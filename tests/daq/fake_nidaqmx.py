"""A stand-in for the ``nidaqmx`` package, modelling a continuous acquisition with an overwrite buffer.

It follows the documented behaviour the backend relies on: a read from the current read position
fails with −200279 once those samples have been overwritten, with −200284 when they are not yet
acquired; ``ReadRelativeTo.MOST_RECENT_SAMPLE`` with a negative offset reads the newest samples;
``curr_read_pos`` is the index after the last sample read. The test sets ``acquired`` by hand.
Channel i of sample k reads ``i + k / 1000`` volts so a test can check the sample index of data.
"""

from __future__ import annotations

import sys
import types
from enum import Enum
from typing import ClassVar

import numpy as np


class Error(Exception):
    pass


class DaqNotFoundError(Error):
    pass


class DaqError(Error):
    def __init__(self, message: str, error_code: int) -> None:
        super().__init__(message)
        self.error_code = error_code


class AcquisitionType(Enum):
    FINITE = 10178
    CONTINUOUS = 10123


class TerminalConfiguration(Enum):  # the names of nidaqmx >= 0.7
    DEFAULT = -1
    RSE = 10083
    NRSE = 10078
    DIFF = 10106
    PSEUDO_DIFF = 12529


class OverwriteMode(Enum):
    OVERWRITE_UNREAD_SAMPLES = 10252
    DO_NOT_OVERWRITE_UNREAD_SAMPLES = 10159


class ReadRelativeTo(Enum):
    FIRST_SAMPLE = 10424
    CURRENT_READ_POSITION = 10425
    REFERENCE_TRIGGER = 10426
    FIRST_PRETRIGGER_SAMPLE = 10427
    MOST_RECENT_SAMPLE = 10428


class InStream:
    # Slots like the real class: setting a property the real package does not have fails here too.
    __slots__ = ("_task", "curr_read_pos", "input_buf_size", "offset", "overwrite", "relative_to")

    def __init__(self, task: Task) -> None:
        self._task = task
        self.input_buf_size = 0
        self.overwrite = OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES
        self.relative_to = ReadRelativeTo.CURRENT_READ_POSITION
        self.offset = 0
        self.curr_read_pos = 0

    @property
    def total_samp_per_chan_acquired(self) -> int:
        return self._task.acquired

    @property
    def avail_samp_per_chan(self) -> int:
        return max(0, self._task.acquired - self.curr_read_pos)


class AIChannels:
    def __init__(self) -> None:
        self.added: list[dict] = []

    def add_ai_voltage_chan(self, physical_channel: str, **kw: object) -> None:
        self.added.append({"physical_channel": physical_channel, **kw})


class Timing:
    def __init__(self) -> None:
        self.cfg: dict = {}

    def cfg_samp_clk_timing(self, rate: float, **kw: object) -> None:
        self.cfg = {"rate": rate, **kw}


class Task:
    instances: ClassVar[list[Task]] = []
    fail_read_code: ClassVar[int | None] = None
    """Every read, start and stop fails with this DAQmx error (a device that was unplugged)."""
    auto_acquire: ClassVar[bool] = False
    """Reads that want samples not yet acquired get them, as if the wait had passed."""

    def __init__(self, name: str = "") -> None:
        self.name = name
        self.ai_channels = AIChannels()
        self.timing = Timing()
        self.in_stream = InStream(self)
        self.acquired = 0
        self.started = self.stopped = self.closed = False
        Task.instances.append(self)

    def start(self) -> None:
        if Task.fail_read_code is not None:
            raise DaqError("Device cannot be accessed.", Task.fail_read_code)
        self.started = True

    def stop(self) -> None:
        if Task.fail_read_code is not None:
            raise DaqError("Device cannot be accessed.", Task.fail_read_code)
        self.stopped = True

    def close(self) -> None:
        self.closed = True


class AnalogMultiChannelReader:
    def __init__(self, in_stream: InStream) -> None:
        self._s = in_stream

    def read_many_sample(self, data: np.ndarray, number_of_samples_per_channel: int, timeout: float = 10.0) -> int:
        s, task, n = self._s, self._s._task, number_of_samples_per_channel
        if Task.fail_read_code is not None:
            raise DaqError("Device cannot be accessed.", Task.fail_read_code)
        if s.relative_to is ReadRelativeTo.CURRENT_READ_POSITION:
            start = s.curr_read_pos + s.offset
        elif s.relative_to is ReadRelativeTo.MOST_RECENT_SAMPLE:
            start = task.acquired + s.offset
        else:
            raise AssertionError(f"fake does not model {s.relative_to}")
        oldest = task.acquired - s.input_buf_size
        if start < oldest:
            if s.overwrite is not OverwriteMode.OVERWRITE_UNREAD_SAMPLES:
                raise AssertionError("without overwrite mode the acquisition would have stopped")
            raise DaqError("Attempted to read samples that are no longer available.", -200279)
        if start + n > task.acquired and Task.auto_acquire:
            task.acquired = start + n
        if start + n > task.acquired:
            raise DaqError("Some or all of the samples requested have not yet been acquired.", -200284)
        k = np.arange(start, start + n)
        data[:] = np.arange(data.shape[0])[:, None] + k[None, :] / 1000.0
        s.curr_read_pos = start + n
        return n


class _Version:
    major_version, minor_version, update_version = 2024, 1, 0


class System:
    driver_missing: ClassVar[bool] = False

    @classmethod
    def local(cls) -> System:
        return cls()

    @property
    def driver_version(self) -> _Version:
        if System.driver_missing:
            raise DaqNotFoundError("Could not find an installation of NI-DAQmx.")
        return _Version()


def install(monkeypatch) -> types.ModuleType:
    """Put the fake package into sys.modules for one test."""
    Task.instances.clear()
    Task.fail_read_code = None
    Task.auto_acquire = False
    System.driver_missing = False
    pkg = types.ModuleType("nidaqmx")
    pkg.Task = Task  # type: ignore[attr-defined]
    mods = {
        "nidaqmx": pkg,
        "nidaqmx.constants": types.ModuleType("nidaqmx.constants"),
        "nidaqmx.stream_readers": types.ModuleType("nidaqmx.stream_readers"),
        "nidaqmx.errors": types.ModuleType("nidaqmx.errors"),
        "nidaqmx.system": types.ModuleType("nidaqmx.system"),
    }
    c = mods["nidaqmx.constants"]
    for e in (AcquisitionType, TerminalConfiguration, OverwriteMode, ReadRelativeTo):
        setattr(c, e.__name__, e)
    mods["nidaqmx.stream_readers"].AnalogMultiChannelReader = AnalogMultiChannelReader  # type: ignore[attr-defined]
    err = mods["nidaqmx.errors"]
    err.Error, err.DaqError, err.DaqNotFoundError = Error, DaqError, DaqNotFoundError  # type: ignore[attr-defined]
    mods["nidaqmx.system"].System = System  # type: ignore[attr-defined]
    for name, mod in mods.items():
        monkeypatch.setitem(sys.modules, name, mod)
    return pkg
