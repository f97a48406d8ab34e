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



def _shares_session_fixtures(folder: Path) -> bool:
    conftest = folder / "conftest.py"
    if not conftest.is_file():
        return False
    text = conftest.read_text(encoding="utf-8")
    return 'scope="session"' in text or 'scope="package"' in text


def _scope_of(nodeid: str) -> str:
    """The unit of work of a test under pytest-xdist: the test itself if it is one of `_OWN_UNITS`, else its
    folder under tests/ if that folder's conftest holds session- or package-scoped fixtures (recorded sessions:
    recorded once, on one worker, as in a serial run), otherwise its file (module-scoped fixtures stay on one
    worker)."""
    if _without_parameters(nodeid) in _OWN_UNITS:
        return nodeid
    path = nodeid.split("::", 1)[0]
    parts = path.split("/")
    if len(parts) > 2 and parts[0] == "tests" and _shares_session_fixtures(_TESTS / parts[1]):
        return f"tests/{parts[1]}"
    return path


def _without_parameters(nodeid: str) -> str:
    """``file::test`` of ``file::test[param]`` (unchanged when it has no parameters)."""
    return nodeid.split("[", 1)[0]


_TESTS = Path(__file__).resolve().parent

_GUIDE = "tests/docs/test_guide_commands.py"
_GUIDE_SESSION = f"{_GUIDE}::test_the_guide_session_block_records"
_GUIDE_PAGE_ALONE = f"{_GUIDE}::test_guide_page_alone"

_OWN_UNITS = (_GUIDE_SESSION, _GUIDE_PAGE_ALONE)
"""Tests each of whose parametrizations is a unit of work of its own: the guide's recorded session (shared by
the workers through a file lock) and the guide pages that run in copies of it, beside the pages run in order."""

_LONG_UNITS = (_GUIDE_SESSION, "tests/test_demo.py", "tests/ppk/test_ppk_dropout.py")
"""Units of work that take minutes though they hold few tests (each records a simulated drive at 8x in a
fixture), longest first. xdist orders the units by their number of tests, which put these last, so the whole
suite waited for them at its end (idle, 4 workers on 2 cores, 2026-12-05: the guide's session 156 s, the
demo's 168 s, the PPK dropout's 130 s). They go first; the rest keeps xdist's order."""

_WAITING_UNITS = (_GUIDE, _GUIDE_PAGE_ALONE)
"""Long units (or tests whose every parametrization is one) that use what a unit of `_LONG_UNITS` records (the
guide's pages: 70-130 s idle): they come right after the units the workers start with, so a worker takes one
when it has finished its first unit (the guide session's worker: as soon as it has recorded it) instead of
waiting for the recording from the start, or taking it last and making the suite wait for it."""


def _work_order(units: dict[str, int], workers: int) -> list[str]:
    """The order of the units of work (``units``: unit → its number of tests) for ``workers`` workers: the long
    units, then as many of xdist's order (most tests first) as fill the other workers, then the waiting units,
    then the rest."""
    front = [u for u in _LONG_UNITS if u in units]
    waiting = [u for u in units if _without_parameters(u) in _WAITING_UNITS]
    rest = [u for u in sorted(units, key=lambda u: -units[u]) if u not in front and u not in waiting]
    fill = max(0, workers - len(front))
    return front + rest[:fill] + waiting + rest[fill:]


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist's: no error under `-p no:xdist`
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object | None:
    """`pytest -n N --dist loadscope` (the README's test command) schedules by `_scope_of`.

    xdist's own `loadgroup` does not work with pytest 9 (its worker writes the group into
    `item._nodeid`, which pytest 9 no longer reads), so the grouping is done here, on the controller.
    """
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class FolderOrFileScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _scope_of(nodeid)

        def schedule(self) -> None:
            if self.collection is None and self.registered_collections:
                # the work queue is an ordered dict: a unit entered now keeps its place when the base class
                # fills it with its tests (and only units this collection has are entered)
                units: dict[str, int] = {}
                for nodeid in next(iter(self.registered_collections.values())):
                    unit = _scope_of(nodeid)
                    units[unit] = units.get(unit, 0) + 1
                for unit in _work_order(units, len(self.nodes)):
                    self.workqueue[unit] = {}
            super().schedule()

    return FolderOrFileScheduling(config, log)
