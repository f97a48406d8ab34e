"""The README's test command schedules the suite's units of work (tests/conftest.py): a folder with shared
recorded sessions is one unit, every other file its own, and the long units go first."""

from __future__ import annotations

import re
from pathlib import Path

from tests.conftest import _LONG_UNITS, _OWN_UNITS, _WAITING_UNITS, _scope_of, _work_order

ROOT = Path(__file__).resolve().parent.parent


def _unit_exists(unit: str) -> bool:
    """A file or folder of tests, or a test (``file::name``) defined in its file."""
    path, _, test = unit.partition("::")
    if not test:
        return (ROOT / path).exists()
    text = (ROOT / path).read_text(encoding="utf-8") if (ROOT / path).is_file() else ""
    return re.search(rf"^def {re.escape(test)}\(", text, re.MULTILINE) is not None


def test_the_long_units_exist_and_are_units() -> None:
    """A renamed folder, file or test would silently drop out of the order: each entry is a unit of work of a
    test it holds."""
    for unit in _LONG_UNITS + _WAITING_UNITS:
        assert _unit_exists(unit), unit
        if "::" in unit:
            assert unit in _OWN_UNITS and _scope_of(f"{unit}[x]") == f"{unit}[x]", unit
            continue
        path = ROOT / unit
        tests = sorted(path.rglob("test_*.py")) if path.is_dir() else [path]
        assert tests and all(t.is_file() for t in tests), unit
        for t in tests:
            assert _scope_of(f"{t.relative_to(ROOT).as_posix()}::test_x") == unit, t
    for unit in _OWN_UNITS:
        assert _unit_exists(unit), unit


def test_long_units_first_then_one_per_free_worker_then_the_units_waiting_for_them() -> None:
    units = {"tests/test_demo.py": 5, "tests/docs/test_guide_commands.py": 9, "tests/a.py": 40, "tests/b.py": 30,
             "tests/c.py": 20, "tests/d.py": 1,
             "tests/docs/test_guide_commands.py::test_the_guide_session_block_records": 1,
             "tests/docs/test_guide_commands.py::test_guide_page_alone[guide/live-and-exports.md]": 1}
    order = _work_order(units, workers=4)
    assert order == ["tests/docs/test_guide_commands.py::test_the_guide_session_block_records", "tests/test_demo.py",
                     "tests/a.py", "tests/b.py", "tests/docs/test_guide_commands.py",
                     "tests/docs/test_guide_commands.py::test_guide_page_alone[guide/live-and-exports.md]",
                     "tests/c.py", "tests/d.py"]
    assert sorted(_work_order(units, workers=1)) == sorted(units)  # every unit, once
    assert _work_order(units, workers=1)[2:4] == order[4:6]  # the waiting units right after the long ones


def test_each_guide_page_run_alone_is_a_unit_of_its_own() -> None:
    a = _scope_of("tests/docs/test_guide_commands.py::test_guide_page_alone[guide/live-and-exports.md]")
    b = _scope_of("tests/docs/test_guide_commands.py::test_guide_page_alone[guide/other.md]")
    assert a != b and a.endswith("[guide/live-and-exports.md]")
    assert _scope_of("tests/docs/test_guide_commands.py::test_guide_commands_run[guide/report.md]") == (
        "tests/docs/test_guide_commands.py")


def test_folders_with_shared_sessions_are_one_unit_other_files_their_own() -> None:
    assert _scope_of("tests/docs/test_guide_commands.py::test_guide_commands_run[guide/hardware.md]") == (
        "tests/docs/test_guide_commands.py")
    assert _scope_of("tests/replay/test_schedule.py::test_stop_ends_a_spin") == "tests/replay"
    assert _scope_of("tests/novatel/test_framer.py::test_x") == "tests/novatel/test_framer.py"
    assert _scope_of("tests/test_demo.py::test_truth_file_is_a_plausible_drive") == "tests/test_demo.py"
