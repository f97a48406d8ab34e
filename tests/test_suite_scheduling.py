"""The README's test command schedules the suite's units of work (tests/conftest.py): a folder with shared
recorded sessions is one unit, every other file its own, and the long units go first."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import _LONG_UNITS, _scope_of

ROOT = Path(__file__).resolve().parent.parent


def test_the_long_units_exist_and_are_units() -> None:
    """A renamed folder or file would silently drop out of the long-first order: each entry is a unit of work
    of a test it holds."""
    for unit in _LONG_UNITS:
        path = ROOT / unit
        tests = sorted(path.rglob("test_*.py")) if path.is_dir() else [path]
        assert tests and all(t.is_file() for t in tests), unit
        for t in tests:
            assert _scope_of(f"{t.relative_to(ROOT).as_posix()}::test_x") == unit, t


def test_folders_with_shared_sessions_are_one_unit_other_files_their_own() -> None:
    assert _scope_of("tests/docs/test_guide_commands.py::test_guide_commands_run[guide/hardware.md]") == (
        "tests/docs/test_guide_commands.py")
    assert _scope_of("tests/replay/test_schedule.py::test_stop_ends_a_spin") == "tests/replay"
    assert _scope_of("tests/novatel/test_framer.py::test_x") == "tests/novatel/test_framer.py"
    assert _scope_of("tests/test_demo.py::test_truth_file_is_a_plausible_drive") == "tests/test_demo.py"
