"""`rig can monitor` with interface options and its listen-only default (typer's CliRunner, in-process)."""

from __future__ import annotations

from typer.testing import CliRunner

from rig.cli.main import app

runner = CliRunner()


def _monitor(channel: str, *extra: str) -> tuple[int, str]:
    result = runner.invoke(app, ["can", "monitor", "--interface", "virtual", "--channel", channel,
                                 "--duration", "0.2", "--interval", "0.1", *extra])
    # a RigError leaves the command (rig's entry point prints it as one line): keep its text
    return result.exit_code, result.output + (str(result.exception) if result.exception else "")


def test_monitor_opens_listen_only_and_passes_options(channel: str) -> None:
    code, out = _monitor(channel, "--option", "rx_queue_size=1000")
    assert code == 0, out
    assert f"opened virtual {channel} (host timestamps, listen-only)" in out
    code, out = _monitor(channel, "--active")
    assert code == 0, out
    assert "active)" in out


def test_monitor_refuses_an_option_the_interface_does_not_take(channel: str) -> None:
    code, out = _monitor(channel, "--option", "app_name=vsc-rig")
    assert code != 0
    assert "options.app_name: python-can's 'virtual' interface takes no option 'app_name'" in out
