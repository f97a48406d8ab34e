"""`rig` starts fast: the command modules import their heavy libraries only when a command runs.

``rig --help`` and ``rig config check`` must not pay for scipy, matplotlib, statsmodels, mcap,
cantools, the drivers or the simulator. Checked in fresh interpreters (this test process has most
of them loaded already), plus the few constants the command modules keep in step with the library
modules they no longer import at start-up.
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
            "validate", "rollover", "layout")
"""Every command and command group of ``rig`` (README "Command tour")."""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=120, env=env, check=False)


def test_importing_the_cli_loads_no_heavy_library() -> None:
    code = ("import json, sys, rig.cli.main; "
            "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    r = _run("-c", code)
    assert r.returncode == 0, r.stderr
    loaded = set(json.loads(r.stdout))
    assert "typer" in loaded  # the check sees what was imported
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))


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
    from rig.simworld import FAST_SPEED
    from sim_devices.vehicle import TRUTH_FILE_SUFFIXES

    assert [m.value for m in analysis_cmd.ReferenceChoice] == [m.value for m in ReferenceMethod]
    assert record_cmd.FAST_SPEED == FAST_SPEED
    assert set(sim_cmd.TRUTH_FILE_SUFFIXES) == set(TRUTH_FILE_SUFFIXES)
    assert relay_cmd.DEFAULT_NTRIP_USER_ENV == DEFAULT_NTRIP_USER_ENV
    assert relay_cmd.DEFAULT_NTRIP_PASSWORD_ENV == DEFAULT_NTRIP_PASSWORD_ENV
