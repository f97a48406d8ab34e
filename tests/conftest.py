"""Shared test fixtures: leak checks for threads and the paths of shared test material."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import settings

# CI runs the same examples every time (a failure is reproducible from the log); set
# HYPOTHESIS_PROFILE=explore to search with fresh random examples on a workstation.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False, max_examples=500)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture
def shared_dir() -> Path:
    """The ../shared folder beside the checkout (public test vectors, the VW MQB DBC)."""
    if not SHARED.is_dir():
        pytest.skip(f"shared test material not found at {SHARED}")
    return SHARED


def _sdk_runtime_worker(t: threading.Thread) -> bool:
    """A worker of foxglove-sdk's tokio runtime: one runtime per process, started with the first server and
    never stopped (its workers, OS name ``tokio-rt-worker``, outlive every server). When a worker logs through
    Python's ``logging`` (the SDK's "Started server", "Shutdown complete", "Dropping client" lines, maybe
    after its server's test has ended), Python registers it as a ``_DummyThread``, alive for good and not
    joinable. Those and only those are not a test's leak."""
    if not isinstance(t, threading._DummyThread) or t.native_id is None:
        return False
    try:
        return Path(f"/proc/self/task/{t.native_id}/comm").read_text().strip() == "tokio-rt-worker"
    except OSError:
        return False


@pytest.fixture(autouse=True)
def _no_thread_leaks() -> Iterator[None]:
    """Fail any test that leaves a thread running (threads must be stopped and joined)."""
    before = set(threading.enumerate())
    yield
    leaked = [t for t in threading.enumerate() if t not in before and t.is_alive() and not _sdk_runtime_worker(t)]
    for t in leaked:
        t.join(timeout=2.0)
    still = [t.name for t in leaked if t.is_alive()]
    assert not still, f"test leaked running threads: {still}"
