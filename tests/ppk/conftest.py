"""Fixtures of the PPK tests: the simulated-GNSS fixtures (drive, time base, port reader, fd leak check)."""

from tests.sim_gnss.conftest import _no_fd_leaks, open_port, timebase, truth

__all__ = ["_no_fd_leaks", "open_port", "timebase", "truth"]
