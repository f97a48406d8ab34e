"""vsc-rig application: the ``rig`` command, configuration, recorder, time base, dataset and analysis."""

from vsccore import __version__

__all__ = ["__version__"]
