"""Shared kernel of vsc-rig: the error tree, angle conventions and GPS time.

Every other package (``drivers``, ``calibration``, ``sim_devices``, ``rig``) may import this one;
it imports none of them.
"""

__version__ = "0.1.0"
