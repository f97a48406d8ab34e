"""A password in the relay source URL is never written: a simulated session recorded with
``--debug`` through an NTRIP caster that requires it, exported as CSV and raw GNSS, then every byte
of every file and every line of output is searched for the password and its Basic-auth token.
The export's RTKLIB hint names each raw file's own format."""

from __future__ import annotations

import base64
import os
import subprocess
import sys
from pathlib import Path

from sim_devices.ntrip_caster import FileFeeder, NtripCaster
from tests.relay.helpers import base_epoch

REPO = Path(__file__).resolve().parents[2]
USER = "rtkuser"
PASSWORD = "s3cr3t-Pw/x"  # a '/' too: the URL form has to carry it percent-encoded or not
ENV_PASSWORD = "env-only-s3cr3t"


def _rig(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", "--debug", *args], capture_output=True, text=True,
                          env=env, cwd=REPO, timeout=300, check=False)


def test_no_byte_of_a_recorded_session_or_its_exports_holds_the_ntrip_password(tmp_path: Path) -> None:
    capture = tmp_path / "base.rtcm3"
    capture.write_bytes(b"".join(base_epoch()) * 20)
    with NtripCaster(users={USER: PASSWORD}) as caster:
        feeder = FileFeeder(caster.add_mountpoint("SIMBASE"), capture, baud=115200)
        feeder.start()
        try:
            url = f"ntrip://{USER}:{PASSWORD}@127.0.0.1:{caster.port}/SIMBASE"
            text = (REPO / "rig/examples/sim.toml").read_text()
            roles = REPO / "rig/examples/roles/vsc_sim.toml"
            text = text.replace('roles_file = "roles/vsc_sim.toml"', f'roles_file = "{roles}"')
            text = text.replace('source = "receiver:base"', f'source = "{url}"')
            assert url in text
            cfg = tmp_path / "cfg" / "session.toml"
            cfg.parent.mkdir()
            cfg.write_text(text)
            env = {**os.environ, "PYTHONPATH": str(REPO), "VSC_RIG_NTRIP_PASSWORD": ENV_PASSWORD}
            out = tmp_path / "out"
            rec = _rig("sim", "record", str(cfg), "--out", str(out), "--name", "secret", "--drive",
                       "straight:duration_s=4", "--fast", "--no-dashboard", "--one-process", env=env)
            assert rec.returncode == 0, rec.stderr[-3000:]
        finally:
            feeder.stop()
        assert caster.unauthorized == 0  # the password did reach the caster
    parts = sorted(out.glob("*.mcap"))
    assert parts
    exp = _rig("export", str(parts[0]), "--csv", str(tmp_path / "csv"), "--raw-gnss", str(tmp_path / "raw"), env=env)
    assert exp.returncode == 0, exp.stderr[-3000:]
    token = base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode()
    secrets = [PASSWORD, ENV_PASSWORD, token, PASSWORD.replace("/", "%2F")]
    files = [p for d in ("out", "csv", "raw") for p in (tmp_path / d).rglob("*") if p.is_file()]
    assert any(p.name == "events.csv" for p in files) and any(p.suffix == ".gps" for p in files)
    for p in files:
        data = p.read_bytes()
        for s in secrets:
            assert s.encode() not in data, f"{s!r} written into {p}"
    for output in (rec.stdout, rec.stderr, exp.stdout, exp.stderr):
        for line in output.splitlines():
            assert not any(s in line for s in secrets), line
    events = (tmp_path / "csv" / "events.csv").read_text()
    assert f"ntrip://{USER}:***@127.0.0.1" in events  # the source is still named, redacted
    # RTKLIB hint: the base receiver's port carries RTCM3, the rovers' NovAtel logs
    hints = exp.stdout + exp.stderr
    assert f"convbin -r rtcm3 {tmp_path / 'raw' / 'base.gps'}" in hints
    assert f"convbin -r nov {tmp_path / 'raw' / 'rover_a.gps'}" in hints
