"""Starting a child process that a test will stop with SIGINT, as Ctrl-C in a terminal does."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def ctrl_c_reaches_children() -> Iterator[None]:
    """Children started inside get Python's normal Ctrl-C handling even when the test process
    ignores SIGINT: a shell without job control starts background jobs (``cmd &``) with SIGINT
    ignored, and an ignored signal stays ignored across exec, so the child would never see it.
    A handled signal is reset to its default in the child instead."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
