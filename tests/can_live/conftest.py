"""Fixtures of the live-CAN tests: leak checks for threads and virtual channels, unique channels."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Iterator

import can.interfaces.virtual as virtual
import pytest

_counter = itertools.count()


@pytest.fixture(autouse=True)
def _no_leaks() -> Iterator[None]:
    """Every bus shut down, every thread joined: counts return to their baseline after each test."""
    threads_before = set(threading.enumerate())
    count_before = threading.active_count()
    with virtual.channels_lock:
        channels_before = set(virtual.channels)
    yield
    for t in threading.enumerate():
        if t not in threads_before:
            t.join(timeout=2.0)
    assert threading.active_count() == count_before, (
        f"threads not back to baseline: {[t.name for t in threading.enumerate() if t not in threads_before]}"
    )
    with virtual.channels_lock:
        leaked = set(virtual.channels) - channels_before
    assert not leaked, f"virtual CAN channels left open: {leaked}"


@pytest.fixture
def channel(request: pytest.FixtureRequest) -> str:
    """A virtual channel name no other test uses."""
    return f"{request.node.name}-{next(_counter)}"
