"""The `rig` command: help, version, one-line errors and exit codes."""

from __future__ import annotations

import subprocess
import sys

import pytest
from typer.testing import CliRunner

from rig.cli.main import app, main
from vsccore import __version__

runner = CliRunner()


def test_help_lists_every_command_group() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "config" in result.output


def test_version() -> None:
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert __version__ in result.output


def test_project_error_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[vehicle]\nmass_kgg = 3\n")
    with pytest.raises(SystemExit) as excinfo:
        main(["config", "check", str(bad)])
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("rig: error: ")
    assert "mass_kgg" in err
    assert "Traceback" not in err


def test_debug_shows_traceback(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[vehicle]\nmass_kgg = 3\n")
    proc = subprocess.run(
        [sys.executable, "-m", "rig", "--debug", "config", "check", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode != 0
    assert "Traceback" in proc.stderr
    assert "ConfigFileError" in proc.stderr


def test_a_command_exit_code_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    """typer.Exit(1) from a command (e.g. `rig validate` on FAIL) must reach the shell as 1."""
    import typer

    from rig.cli import main as main_module

    probe = typer.Typer()

    @probe.command()
    def fail() -> None:
        raise typer.Exit(1)

    monkeypatch.setattr(main_module, "app", probe)
    with pytest.raises(SystemExit) as excinfo:
        main_module.main([])
    assert excinfo.value.code == 1
