"""The one error tree of vsc-rig.

Every error the project raises on purpose derives from :class:`RigError`. Leaves also inherit
the matching built-in (``ValueError``, ``TimeoutError``, ``OSError``) so that generic callers can
catch them the usual way. Messages always name the device, port, file or configuration key
concerned.
"""

from __future__ import annotations


class RigError(Exception):
    """Base of every error vsc-rig raises on purpose."""


class ConfigError(RigError, ValueError):
    """A configuration file or value is invalid (the message names the key path)."""


class DecodeError(RigError, ValueError):
    """Bytes or a record could not be decoded (the message says where)."""


class ChecksumError(DecodeError):
    """A frame's CRC or checksum does not verify."""


class DeviceError(RigError, OSError):
    """A device (receiver, CAN interface, DAQ) failed or is unreachable."""


class DeviceTimeoutError(RigError, TimeoutError):
    """A device did not answer in time."""


class CommandError(DeviceError):
    """A device rejected a command (e.g. a NovAtel ``<ERROR`` reply)."""


class SessionFileError(RigError, OSError):
    """A session file is missing, unreadable or could not be written."""


class DiskFullError(SessionFileError):
    """The disk holding the session ran out of space."""


class CalibrationError(RigError, ValueError):
    """A calibration could not be computed from the data given (the message says what is missing)."""


class SimulationError(RigError, ValueError):
    """A simulation scenario or parameter is invalid."""


class AnalysisError(RigError, ValueError):
    """An analysis could not run on the data given."""
