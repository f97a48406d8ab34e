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


class EncodeError(RigError, ValueError):
    """A record could not be encoded for the wire (a value does not fit its field; the message says which)."""


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


class NtripError(DeviceError):
    """An NTRIP caster refused a request or broke the protocol (the message names caster and mountpoint)."""


class NtripAuthError(NtripError):
    """An NTRIP caster refused the credentials (401); retrying would not help."""


class NtripMountpointError(NtripError):
    """An NTRIP caster does not serve the mountpoint asked for (the message lists the ones it has)."""


class CommandTimeoutError(CommandError, DeviceTimeoutError):
    """A device did not answer a command in time (the message names the device, port and command)."""
