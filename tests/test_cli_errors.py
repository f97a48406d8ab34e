"""Every way `rig` can end on bad input: one line on stderr and a documented exit status, no traceback.

Usage errors run through a real subprocess (the console entry point's code path, with whatever typer
is installed); the dependency audit checks that every third-party package the code imports is
declared in pyproject.toml, so an upgrade of typer that drops click cannot break the CLI again.
"""

from __future__ import annotations

import ast
import importlib.metadata
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import typer

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "drivers", "calibration", "sim_devices", "vsccore")


def _rig(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
    return subprocess.run(
        [sys.executable, "-m", "rig", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=ROOT,
        check=False,
    )


USAGE_ERRORS = [
    (("info", "--bogus"), "rig info", "--bogus"),
    (("relay",), "rig relay", "--from"),
    (("--bogus",), "rig", "--bogus"),
    (("calibrate-baseline",), "rig calibrate-baseline", "session"),
    (("sim", "record", "rig/examples/sim.toml", "--out", "x", "--speed", "fast"), "rig sim record", "--speed"),
    (("can", "monitor", "--bitrate", "many"), "rig can monitor", "--bitrate"),
]


@pytest.mark.parametrize(("args", "command", "names"), USAGE_ERRORS, ids=[" ".join(a) for a, _, _ in USAGE_ERRORS])
def test_usage_error_is_one_line_and_exit_2(args: tuple[str, ...], command: str, names: str) -> None:
    proc = _rig(*args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"{command}: error: "), lines[0]
    assert names in lines[0]
    assert "Traceback" not in proc.stderr
    assert proc.stdout == ""


def test_a_group_without_a_command_shows_its_help_and_no_error() -> None:
    proc = _rig("sim")
    assert proc.returncode == 2
    assert "record" in proc.stdout
    assert proc.stderr.strip() == ""


def _failing_app(exc: BaseException) -> typer.Typer:
    probe = typer.Typer()

    @probe.callback()
    def root(debug: bool = typer.Option(False, "--debug")) -> None:
        pass

    @probe.command()
    def boom() -> None:
        raise exc

    return probe


def test_unexpected_exception_is_one_line_and_nonzero(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    from rig.cli import main as main_module

    monkeypatch.setattr(main_module, "app", _failing_app(ZeroDivisionError("float division\nby zero")))
    with pytest.raises(SystemExit) as excinfo:
        main_module.main(["boom"])
    assert excinfo.value.code == 1
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "rig: internal error: ZeroDivisionError: float division by zero (run with --debug for the traceback)"
    ]


def test_unexpected_exception_with_debug_raises_for_the_traceback(monkeypatch: pytest.MonkeyPatch) -> None:
    from rig.cli import main as main_module

    monkeypatch.setattr(main_module, "app", _failing_app(ZeroDivisionError("x")))
    with pytest.raises(ZeroDivisionError):
        main_module.main(["--debug", "boom"])


def _imported_top_level_modules() -> dict[str, str]:
    """Top-level module name -> first place it is imported, over every package (nested imports too)."""
    found: dict[str, str] = {}
    for package in PACKAGES:
        for file in sorted((ROOT / package).rglob("*.py")):
            tree = ast.parse(file.read_text(encoding="utf-8"), filename=str(file))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    found.setdefault(name.split(".")[0], f"{file.relative_to(ROOT)}:{node.lineno}")
    return found


def _normalize(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_every_imported_third_party_package_is_declared() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = {_normalize(re.split(r"[<>=!~;\[ ]", req, maxsplit=1)[0]) for req in project["dependencies"]}
    optional = {
        _normalize(re.split(r"[<>=!~;\[ ]", req, maxsplit=1)[0])
        for reqs in project["optional-dependencies"].values()
        for req in reqs
    }
    distributions = importlib.metadata.packages_distributions()
    missing = []
    for module, where in sorted(_imported_top_level_modules().items()):
        if module in sys.stdlib_module_names or module in PACKAGES:
            continue
        dists = {_normalize(d) for d in distributions.get(module, [module])}
        if not dists & (declared | optional):
            missing.append(f"{module} ({where}; distribution {sorted(dists)})")
    assert not missing, f"imported but not declared in pyproject.toml: {missing}"


def test_declared_dependencies_have_lower_bounds() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    unbounded = [req for req in project["dependencies"] if ">=" not in req]
    assert not unbounded, unbounded
