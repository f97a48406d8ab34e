"""`rig` starts fast: the command modules import their heavy libraries only when a command runs.

``rig --help`` answers from the command table of :mod:`rig.cli.main` without importing typer or a
command module; a command imports only its own module; ``rig config check`` and ``rig info`` must
not pay for scipy, matplotlib, statsmodels, cantools, python-can, pandas, the drivers or the
simulator. Checked in fresh interpreters (this test process has most of them loaded already), plus
the few constants the command modules keep in step with the library modules they no longer import
at start-up, and the table's help lines against the commands' own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

HEAVY = ("scipy", "matplotlib", "statsmodels", "mcap", "cantools", "can", "numpy", "pydantic", "rich",
         "drivers", "calibration", "sim_devices")
"""Top-level packages that importing ``rig.cli.main`` must not load."""

COMMANDS = ("sim", "gnss", "config", "can", "demo", "relay", "recover", "record", "info", "export",
            "calibrate-baseline", "calibrate-steering-ratio", "calibrate-imu", "steering-ratio", "steering",
            "validate", "rollover", "layout", "replay", "campaign", "ppk", "preflight")
"""Every command and command group of ``rig`` (README "Command tour")."""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=120, env=env, check=False)


def _loaded_after(statement: str) -> tuple[set[str], set[str]]:
    """(top-level packages, rig.cli modules) loaded in a fresh interpreter after ``statement``."""
    code = ("import json, sys\n"
            f"{statement}\n"
            "print(json.dumps(sorted(sys.modules)))")
    r = _run("-c", code)
    assert r.returncode == 0, r.stderr
    modules = set(json.loads(r.stdout.splitlines()[-1]))
    return {m.split(".")[0] for m in modules}, {m for m in modules if m.startswith("rig.cli.")}


def test_importing_the_cli_loads_no_heavy_library() -> None:
    loaded, cli = _loaded_after("import rig.cli.main")
    assert "typer" not in loaded and cli == {"rig.cli.main"}  # the command tree is built on demand
    loaded, cli = _loaded_after("from rig.cli.main import app")  # the whole tree
    assert "typer" in loaded and "rig.cli.info_cmd" in cli  # the check sees what was imported
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))


def test_help_and_version_import_no_typer_and_no_command_module() -> None:
    for flag, needle in (("--help", "Usage: rig [OPTIONS] COMMAND [ARGS]..."), ("--version", "vsc-rig ")):
        loaded, cli = _loaded_after("from rig.cli.main import main\n"
                                    "try:\n"
                                    f"    main([{flag!r}])\n"
                                    "except SystemExit as e:\n"
                                    "    assert not e.code, e.code\n"
                                    f"print({needle!r})")
        assert "typer" not in loaded and "numpy" not in loaded, flag
        assert cli == {"rig.cli.main"}, flag


def test_a_command_imports_only_its_own_module() -> None:
    _loaded, cli = _loaded_after("from rig.cli.main import main\n"
                                 "try:\n"
                                 "    main(['info', '--help'])\n"
                                 "except SystemExit as e:\n"
                                 "    assert not e.code, e.code")
    assert cli == {"rig.cli.main", "rig.cli.info_cmd"}, sorted(cli)


def test_the_help_table_matches_the_commands_own_help() -> None:
    """rig --help lists COMMANDS; each entry's help is the command's own (a new command goes in the table)."""
    from typer.main import get_command

    from rig.cli.main import COMMANDS as TABLE
    from rig.cli.main import DEBUG_HELP, TRACE_FRAMES_HELP, VERSION_HELP, app

    group = get_command(app)
    assert sorted(c.name for c in TABLE) == sorted(group.commands), (  # type: ignore[attr-defined]
        "add the command to rig.cli.main.COMMANDS (rig --help lists it from there)")
    for entry in TABLE:
        cmd = group.commands[entry.name]  # type: ignore[attr-defined]
        own = (cmd.short_help or cmd.help or "").split("\n\n")[0]
        assert " ".join(own.split()) == " ".join(entry.help.split()), entry.name
    helps = {p.opts[0]: getattr(p, "help", None) for p in group.params}
    assert (helps["--version"], helps["--debug"], helps["--trace-frames"]) == (VERSION_HELP, DEBUG_HELP,
                                                                                TRACE_FRAMES_HELP)


def test_help_on_a_terminal_that_cannot_show_unicode() -> None:
    env = {**os.environ, "COLUMNS": "100", "PYTHONIOENCODING": "ascii"}
    r = subprocess.run([sys.executable, "-m", "rig", "--help"], capture_output=True, text=True, timeout=120, env=env,
                       check=False, encoding="ascii")
    assert r.returncode == 0, r.stderr
    listed = {line.strip("| ").split(" ")[0] for line in r.stdout.splitlines() if line.startswith("| ")}
    assert set(COMMANDS) <= listed, sorted(set(COMMANDS) - listed)
    assert "(measured = M?true + b)" in " ".join(r.stdout.split())  # what ascii cannot show is replaced


def test_help_lists_every_command_group_and_each_group_has_help() -> None:
    r = _run("-m", "rig", "--help")
    assert r.returncode == 0, r.stderr
    listed = {line.strip("│ ").split(" ")[0] for line in r.stdout.splitlines() if line.startswith("│ ")}
    assert set(COMMANDS) <= listed, sorted(set(COMMANDS) - listed)
    # every command's own help resolves its option types without the heavy modules loaded up front
    from typer.main import get_command

    from rig.cli.main import app

    group = get_command(app)
    names = set(group.commands)  # type: ignore[attr-defined]
    assert names == set(COMMANDS), sorted(names ^ set(COMMANDS))


@pytest.mark.parametrize("command", [c for c in COMMANDS if c not in ("config",)])
def test_each_command_help_renders(command: str) -> None:
    from typer.testing import CliRunner

    from rig.cli.main import app

    result = CliRunner().invoke(app, [*command.split(), "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage" in result.output


def test_config_check_loads_no_analysis_library() -> None:
    code = ("import json, sys\n"
            "from rig.cli.main import main\n"
            "try:\n"
            "    main(['config', 'check', 'rig/examples/sim.toml'])\n"
            "except SystemExit as e:\n"
            "    assert not e.code, e.code\n"
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    r = _run("-c", code)
    assert r.returncode == 0, r.stderr
    assert "OK" in r.stdout
    loaded = set(json.loads(r.stdout.splitlines()[-1]))
    assert "pydantic" in loaded  # the configuration was validated
    assert not loaded & {"scipy", "matplotlib", "statsmodels", "mcap", "cantools", "can"}


def test_constants_mirrored_in_the_command_modules_match_their_sources() -> None:
    from drivers.relay.endpoints import DEFAULT_NTRIP_PASSWORD_ENV, DEFAULT_NTRIP_USER_ENV
    from rig.analysis.reference import ReferenceMethod
    from rig.cli import analysis_cmd, record_cmd, relay_cmd, sim_cmd
    from rig.sim.record import FAST_SPEED
    from sim_devices.vehicle import TRUTH_FILE_SUFFIXES

    assert [m.value for m in analysis_cmd.ReferenceChoice] == [m.value for m in ReferenceMethod]
    assert record_cmd.FAST_SPEED == FAST_SPEED
    assert set(sim_cmd.TRUTH_FILE_SUFFIXES) == set(TRUTH_FILE_SUFFIXES)
    assert relay_cmd.DEFAULT_NTRIP_USER_ENV == DEFAULT_NTRIP_USER_ENV
    assert relay_cmd.DEFAULT_NTRIP_PASSWORD_ENV == DEFAULT_NTRIP_PASSWORD_ENV
