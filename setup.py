"""Build the optional C part of vsc-rig: the NovAtel framer's per-chunk entry (drivers/novatel/_feed.c).

Everything else is in pyproject.toml. The extension is optional: where no C compiler or Python headers
are found, the install goes on and ``drivers.novatel.Framer`` uses its pure-Python twin (the same frames
and counts; a 1-byte-at-a-time feed costs more, see benchmarks/bench_framer_chunking.py).
"""

from setuptools import Extension, setup

setup(ext_modules=[Extension("drivers.novatel._feed", ["drivers/novatel/_feed.c"], optional=True)])
