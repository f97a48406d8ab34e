"""CPU seconds (user + system) of the processes a benchmark started and waited for (``RUSAGE_CHILDREN``):
take it before and after, the difference is theirs. Imported by the scripts beside it (run as
``python benchmarks/NAME.py``, or with ``PYTHONPATH=benchmarks`` as a pytest plugin)."""

from __future__ import annotations

import resource


def children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime
