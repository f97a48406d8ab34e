"""DAQ backends chosen by name, imported only when used (the python-can ``BACKENDS`` pattern).

Built-in names map to ``"module:Class"`` strings; third-party packages add backends through the
entry-point group ``vsc_rig.daq_backends``. A failed import is wrapped in a
:class:`~vsccore.errors.DeviceError` naming the backend, an unknown name in a
:class:`~vsccore.errors.ConfigError` listing the known ones.
"""

from __future__ import annotations

import importlib
import logging
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from vsccore.errors import ConfigError, DeviceError

from .base import DaqBackend

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "vsc_rig.daq_backends"

BUILTIN_BACKENDS: dict[str, str] = {
    "nidaqmx": "drivers.daq.nidaqmx_backend:NidaqmxBackend",
    # The simulated DAQ lives in sim_devices, which drivers must never import statically (an
    # import-linter contract). It is named here only as a string and imported lazily, exactly as
    # a third-party backend registered through the entry point would be; the package also
    # declares it under the entry-point group, so both routes lead to the same class.
    "sim": "sim_devices.daq:SimDaqBackend",
}


def _entry_points() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known_backends() -> dict[str, str]:
    """Every backend name with its ``"module:Class"`` target (built-ins and entry points)."""
    known = dict(BUILTIN_BACKENDS)
    for name, ep in _entry_points().items():
        if name in known and known[name] != ep.value:
            # A built-in name keeps its built-in class: an installed plug-in must not silently
            # replace the backend a configuration file asked for.
            log.warning(
                "DAQ backend entry point %r -> %s ignored: the built-in %s has that name", name, ep.value, known[name]
            )
            continue
        known[name] = ep.value
    return known


def _import_target(name: str, target: str) -> type[DaqBackend]:
    module_name, sep, attr = target.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigError(f"DAQ backend {name!r}: target {target!r} is not of the form 'module:Class'")
    try:
        # importlib with a string, not an import statement: see the note on BUILTIN_BACKENDS.
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise DeviceError(f"DAQ backend {name!r} ({target}) could not be imported: {exc}") from exc
    try:
        cls = getattr(module, attr)
    except AttributeError:
        raise DeviceError(f"DAQ backend {name!r}: module {module_name!r} has no attribute {attr!r}") from None
    if not (isinstance(cls, type) and issubclass(cls, DaqBackend)):
        raise ConfigError(f"DAQ backend {name!r}: {target} is not a DaqBackend subclass")
    return cls


def resolve_backend(name: str) -> type[DaqBackend]:
    """The backend class registered under ``name``.

    Raises:
        ConfigError: unknown name (the message lists the known names) or a bad registration.
        DeviceError: the backend's module could not be imported (e.g. a missing optional package).
    """
    known = known_backends()
    if name not in known:
        raise ConfigError(f"unknown DAQ backend {name!r}; known backends: {', '.join(sorted(known))}")
    return _import_target(name, known[name])


def create_backend(name: str, **kwargs: Any) -> DaqBackend:
    """Resolve ``name`` and construct the backend with ``kwargs`` (e.g. ``clock=...``)."""
    return resolve_backend(name)(**kwargs)
