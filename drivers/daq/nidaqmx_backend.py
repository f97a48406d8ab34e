"""National Instruments DAQ backend through the official ``nidaqmx`` package (optional extra).

Install with ``pip install 'vsc-rig[nidaqmx]'``; the NI-DAQmx driver itself (a system install
from NI) must be present too. Both are checked when the backend is constructed, and their absence
is a :class:`~vsccore.errors.DeviceError` that says which one is missing.

Acquisition: one task, one voltage channel per :class:`DaqChannelConfig`, sample clock
``CONTINUOUS`` at the requested rate with a buffer of ``buffer_size`` samples per channel, read
with :class:`nidaqmx.stream_readers.AnalogMultiChannelReader.read_many_sample` into a
preallocated float64 buffer. The buffer is in overwrite mode, so the hardware sample clock keeps
running when the reader falls behind: DAQmx then fails the read with error −200279 (samples no
longer available), the backend re-reads from half a buffer behind the most recent sample, and
reports the skipped index range. Sample indices therefore stay on the DAQ's own clock across an
overflow.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

import numpy as np

from vsccore.clock import Clock
from vsccore.errors import DeviceError, DeviceTimeoutError

from .base import DaqBackend, DaqChannelConfig, FloatArray, LostSamples, TerminalConfig

# NI-DAQmx error codes this backend treats specially (nidaqmx.error_codes.DAQmxErrors).
ERR_SAMPLES_NO_LONGER_AVAILABLE = -200279
"""The reader fell behind and unread samples were overwritten (overflow)."""
ERR_SAMPLES_NOT_YET_AVAILABLE = -200284
"""A read timed out before the requested samples were acquired."""

INSTALL_HINT = "pip install 'vsc-rig[nidaqmx]'"

# Enum member names changed across nidaqmx versions (DIFFERENTIAL → DIFF, …): try both.
_TERMINAL_NAMES: dict[TerminalConfig, tuple[str, ...]] = {
    TerminalConfig.RSE: ("RSE",),
    TerminalConfig.NRSE: ("NRSE",),
    TerminalConfig.DIFF: ("DIFF", "DIFFERENTIAL"),
    TerminalConfig.PSEUDODIFF: ("PSEUDO_DIFF", "PSEUDODIFFERENTIAL"),
}


class _Nidaqmx:
    """The parts of the nidaqmx package this backend uses, imported lazily."""

    def __init__(self) -> None:
        try:
            self.nidaqmx: ModuleType = importlib.import_module("nidaqmx")
            self.constants: ModuleType = importlib.import_module("nidaqmx.constants")
            self.stream_readers: ModuleType = importlib.import_module("nidaqmx.stream_readers")
            self.errors: ModuleType = importlib.import_module("nidaqmx.errors")
            self.system: ModuleType = importlib.import_module("nidaqmx.system")
        except ImportError as exc:
            raise DeviceError(
                "DAQ backend 'nidaqmx' needs the Python package 'nidaqmx', which is not installed "
                f"({INSTALL_HINT}), and the NI-DAQmx driver from National Instruments: {exc}"
            ) from exc

    def check_driver(self) -> str:
        """Return the NI-DAQmx driver version, or raise a DeviceError saying the driver is missing."""
        try:
            v = self.system.System.local().driver_version
        except (self.errors.Error, OSError) as exc:
            raise DeviceError(
                "DAQ backend 'nidaqmx': the Python package 'nidaqmx' is installed but the NI-DAQmx "
                f"driver could not be loaded (install NI-DAQmx from National Instruments): {exc}"
            ) from exc
        return f"{v.major_version}.{v.minor_version}.{v.update_version}"

    def terminal(self, cfg: TerminalConfig) -> Any:
        enum = self.constants.TerminalConfiguration
        for member in _TERMINAL_NAMES[cfg]:
            if hasattr(enum, member):
                return getattr(enum, member)
        raise DeviceError(f"DAQ backend 'nidaqmx': this nidaqmx version has no terminal configuration {cfg.value!r}")


class NidaqmxBackend(DaqBackend):
    """Continuous hardware-timed analog input on an NI DAQ device.

    Raises (on construction):
        DeviceError: the ``nidaqmx`` package or the NI-DAQmx driver is missing.
    """

    name = "nidaqmx"

    def __init__(
        self, *, clock: Clock | None = None, device: str | None = None, task_name: str = "vsc_rig_daq"
    ) -> None:
        super().__init__(clock=clock, device=device or "nidaqmx")
        self._ni = _Nidaqmx()
        self.driver_version = self._ni.check_driver()
        self._task_name = task_name
        self._task: Any = None
        self._reader: Any = None
        self._next_index = 0

    def _configure(self, channels: tuple[DaqChannelConfig, ...]) -> None:
        for c in channels:
            self._ni.terminal(c.terminal)  # fail at configure time, not at start

    def _daq_error(self, exc: Exception, what: str) -> DeviceError:
        code = getattr(exc, "error_code", None)
        return DeviceError(f"DAQ {self._device} ({self._task_name}): {what} failed (NI-DAQmx error {code}): {exc}")

    def _start(self, rate_hz: float, buffer_size: int) -> None:
        ni = self._ni
        c = ni.constants
        try:
            task = ni.nidaqmx.Task(self._task_name)
        except ni.errors.DaqError as exc:
            raise self._daq_error(exc, "creating the task") from exc
        try:
            for ch in self.channels:
                task.ai_channels.add_ai_voltage_chan(
                    ch.physical_channel,
                    name_to_assign_to_channel=ch.name,
                    terminal_config=ni.terminal(ch.terminal),
                    min_val=ch.min_v,
                    max_val=ch.max_v,
                )
            task.timing.cfg_samp_clk_timing(
                rate_hz, sample_mode=c.AcquisitionType.CONTINUOUS, samps_per_chan=buffer_size
            )
            task.in_stream.input_buf_size = buffer_size
            # Keep the sample clock running through an overflow; see the module docstring.
            # ``overwrite`` since nidaqmx 0.7 (``over_write`` before, now deprecated).
            attr = "overwrite" if hasattr(type(task.in_stream), "overwrite") else "over_write"
            setattr(task.in_stream, attr, c.OverwriteMode.OVERWRITE_UNREAD_SAMPLES)
            task.in_stream.relative_to = c.ReadRelativeTo.CURRENT_READ_POSITION
            task.in_stream.offset = 0
            self._reader = ni.stream_readers.AnalogMultiChannelReader(task.in_stream)
            task.start()
        except ni.errors.DaqError as exc:
            task.close()
            raise self._daq_error(exc, "starting the acquisition") from exc
        self._task = task
        self._next_index = 0

    def _read_into(self, buf: FloatArray, n: int, timeout_s: float) -> None:
        got = self._reader.read_many_sample(buf, number_of_samples_per_channel=n, timeout=timeout_s)
        if got != n:
            raise DeviceError(f"DAQ {self._device}: read returned {got} samples per channel, expected {n}")

    def _read(self, n_samples: int, timeout_s: float) -> tuple[int, FloatArray, LostSamples | None]:
        ni = self._ni
        buf = np.empty((len(self.channels), n_samples), dtype=np.float64)
        first = self._next_index
        lost: LostSamples | None = None
        try:
            self._read_into(buf, n_samples, timeout_s)
        except ni.errors.DaqError as exc:
            if exc.error_code == ERR_SAMPLES_NOT_YET_AVAILABLE:
                raise DeviceTimeoutError(
                    f"DAQ {self._device}: {n_samples} samples not acquired within {timeout_s} s"
                ) from exc
            if exc.error_code != ERR_SAMPLES_NO_LONGER_AVAILABLE:
                raise self._daq_error(exc, "reading samples") from exc
            first = self._recover_overflow(buf, n_samples, timeout_s)
            lost = LostSamples(self._next_index, first)
        self._next_index = first + n_samples
        return first, buf, lost

    def _available(self) -> int:
        if self._task is None:
            return 0
        try:
            return int(self._task.in_stream.avail_samp_per_chan)
        except self._ni.errors.DaqError:
            return 0  # the next read reports what is wrong with the task

    def _recover_overflow(self, buf: FloatArray, n_samples: int, timeout_s: float) -> int:
        """Re-read from half a buffer behind the newest sample; return the first index read."""
        ni = self._ni
        stream = self._task.in_stream
        back = max(n_samples, self.buffer_size // 2)
        try:
            stream.relative_to = ni.constants.ReadRelativeTo.MOST_RECENT_SAMPLE
            stream.offset = -back
            self._read_into(buf, n_samples, timeout_s)
            # After the read the read position is just past our block: index of its first sample.
            first = int(stream.curr_read_pos) - n_samples
        except ni.errors.DaqError as exc:
            raise self._daq_error(exc, "recovering from a buffer overflow") from exc
        finally:
            try:
                stream.relative_to = ni.constants.ReadRelativeTo.CURRENT_READ_POSITION
                stream.offset = 0
            except ni.errors.DaqError:
                pass  # the task is broken: the next read reports it as a DeviceError
        if first <= self._next_index:
            raise DeviceError(
                f"DAQ {self._device}: overflow recovery read from sample {first}, not after {self._next_index}"
            )
        return first

    def _stop(self) -> None:
        task, self._task, self._reader = self._task, None, None
        if task is None:
            return
        try:
            task.stop()
        except self._ni.errors.DaqError as exc:
            raise self._daq_error(exc, "stopping the task") from exc
        finally:
            task.close()
