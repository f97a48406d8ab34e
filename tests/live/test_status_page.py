"""The status page during a simulated recording, loaded by headless Chromium (Debian ``chromium``):
values that change between two loads, the token, and a screenshot in docs/img/live.png."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from rig.live import LiveOptions
from tests.live.conftest import LiveRun, run_live

REPO = Path(__file__).resolve().parents[2]
SCREENSHOT = REPO / "docs" / "img" / "live.png"
TOKEN = "car-7f3a9c2e51d4"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture
def page_run(tmp_path: Path) -> Iterator[LiveRun]:
    yield from run_live(tmp_path, LiveOptions(port=0, status_port=0, token=TOKEN), speed=1.0,
                        drive="step_steer:lead_s=2,hold_s=8")


def _status(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url, timeout=5.0) as r:
        doc: dict[str, Any] = json.loads(r.read())
        return doc


def _wait_for(what: str, cond: Callable[[dict[str, Any]], bool], url: str, timeout_s: float = 60.0) -> dict[str, Any]:
    """Poll the status JSON (the page's own endpoint) until ``cond`` holds."""
    deadline = time.monotonic() + timeout_s
    while True:
        doc = _status(url)
        if cond(doc):
            return doc
        if time.monotonic() > deadline:
            raise AssertionError(f"status page: {what} not seen within {timeout_s} s; last {doc}")
        time.sleep(0.2)  # a poll interval against the server, not a wait for an event


def _chromium(tmp: Path, *args: str) -> subprocess.CompletedProcess[str]:
    assert CHROMIUM is not None
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-dev-shm-usage", f"--user-data-dir={tmp / 'chromium-profile'}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True)


def _shown(dom: str, ident: str) -> str:
    m = re.search(rf'id="{ident}">([^<]*)<', dom)
    assert m is not None, f"{ident} not on the page"
    return m.group(1)


@pytest.mark.skipif(CHROMIUM is None, reason="Debian package chromium not installed (apt-get install chromium)")
def test_chromium_loads_the_status_page_during_a_recording(page_run: LiveRun, tmp_path: Path) -> None:
    page = page_run.view.page_url
    assert f"token={TOKEN}" in page
    base = page.split("?")[0]
    # without the token: refused, page and JSON alike
    for path in ("", "status.json"):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(base + path, timeout=5.0)
        err.value.close()
        assert err.value.code == 401
    js = base + "status.json?token=" + TOKEN
    first = _wait_for("a β reference, LTR and fixed rovers",
                      lambda d: "beta_ref_deg" in d and "ltr" in d and "beta_vsc_deg" in d
                      and all(r["fix_type"] == "NARROW_INT" for r in d["rovers"]), js)
    dom1 = _chromium(tmp_path, "--dump-dom", page).stdout
    _wait_for("the recording time to move on", lambda d: d["recording_s"] >= first["recording_s"] + 1.5, js)
    dom2 = _chromium(tmp_path, "--dump-dom", page).stdout
    for dom in (dom1, dom2):
        assert _shown(dom, "fix_rover_a") == "NARROW_INT" and _shown(dom, "fix_rover_b") == "NARROW_INT"
        assert re.fullmatch(r"[+-]\d+\.\d\d°", _shown(dom, "beta_ref")), _shown(dom, "beta_ref")
        assert re.fullmatch(r"\d+\.\d\d\d m", _shown(dom, "baseline"))
        assert _shown(dom, "disk").endswith(" GB")
    # values that change while the car drives and the file grows
    assert _shown(dom1, "recording") != _shown(dom2, "recording")
    changed = [k for k in ("beta_ref", "beta_vsc", "ltr", "speed", "baseline") if _shown(dom1, k) != _shown(dom2, k)]
    assert changed, "no vehicle figure changed between two loads"
    SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
    shot = tmp_path / "live.png"
    _chromium(tmp_path, f"--screenshot={shot}", "--window-size=412,915", "--hide-scrollbars", page)
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 5_000
    shutil.copyfile(shot, SCREENSHOT)
