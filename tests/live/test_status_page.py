"""The status page during a simulated recording, loaded by headless Chromium (Debian ``chromium``):
values that change between two loads, the token, and a screenshot.

The screenshot goes under the test's ``tmp_path`` (a test run leaves the checkout unchanged). To
regenerate the guide's image ``docs/img/live.png`` from it, run the test with ``RIG_UPDATE_DOCS_IMG=1``::

    RIG_UPDATE_DOCS_IMG=1 .venv/bin/python -m pytest -q tests/live/test_status_page.py
"""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from drivers.relay.endpoints import Secret
from rig.live import LiveOptions
from tests.live.conftest import LiveRun, run_live

REPO = Path(__file__).resolve().parents[2]
DOCS_IMG = REPO / "docs" / "img" / "live.png"
UPDATE_DOCS_IMG = os.environ.get("RIG_UPDATE_DOCS_IMG") == "1"
WINDOW = (412, 915)  # a phone's viewport in CSS pixels (Chromium's headless device scale factor is 1)
TOKEN = "car-7f3a9c2e51d4"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture
def page_run(tmp_path: Path) -> Iterator[LiveRun]:
    # a drive longer than the test: the fixture's stop event ends the recording, so two Chromium
    # start-ups on a loaded host never outlast the drive (a finished recording's figures stand still)
    yield from run_live(tmp_path, LiveOptions(port=0, status_port=0, token=Secret(TOKEN)), speed=1.0,
                        drive="step_steer:lead_s=2,hold_s=300")


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


def _shown_s(dom: str) -> int:
    """The recording time the page shows (m:ss), in whole seconds."""
    m = re.fullmatch(r"(\d+):(\d\d)", _shown(dom, "recording"))
    assert m is not None, _shown(dom, "recording")
    return int(m.group(1)) * 60 + int(m.group(2))


def png_size(data: bytes) -> tuple[int, int]:
    """Width and height of a PNG from its IHDR chunk (the first chunk after the 8-byte signature)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    assert data[12:16] == b"IHDR", "PNG without IHDR first"
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


@pytest.mark.skipif(CHROMIUM is None, reason="Debian package chromium not installed (apt-get install chromium)")
def test_chromium_loads_the_status_page_during_a_recording(page_run: LiveRun, tmp_path: Path) -> None:
    shown = page_run.view.page_url
    assert TOKEN not in shown and shown.endswith("?token=***")  # what the terminal shows
    base = shown.split("?")[0]
    page = base + "?token=" + TOKEN
    # without the token: refused, page and JSON alike
    for path in ("", "status.json"):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(base + path, timeout=5.0)
        err.value.close()
        assert err.value.code == 401
    js = base + "status.json?token=" + TOKEN
    _wait_for("a β reference, LTR and fixed rovers",
                      lambda d: "beta_ref_deg" in d and "ltr" in d and "beta_vsc_deg" in d
                      and all(r["fix_type"] == "NARROW_INT" for r in d["rovers"]), js)
    dom1 = _chromium(tmp_path, "--dump-dom", page).stdout
    # the second load once the recording time has passed a whole second beyond what the first load showed
    # (Chromium's start-up can take seconds under load: wait on the shown time, not on the JSON's first read)
    shown1 = _shown_s(dom1)
    _wait_for("the recording time to move on", lambda d: d["recording_s"] >= shown1 + 1.2, js)
    dom2 = _chromium(tmp_path, "--dump-dom", page).stdout
    for dom in (dom1, dom2):
        assert _shown(dom, "fix_rover_a") == "NARROW_INT" and _shown(dom, "fix_rover_b") == "NARROW_INT"
        assert re.fullmatch(r"[+-]\d+\.\d\d°", _shown(dom, "beta_ref")), _shown(dom, "beta_ref")
        assert re.fullmatch(r"\d+\.\d\d\d m", _shown(dom, "baseline"))
        assert _shown(dom, "disk").endswith(" GB")
    # values that change while the car drives and the file grows
    assert _shown_s(dom2) > shown1, (_shown(dom1, "recording"), _shown(dom2, "recording"))
    changed = [k for k in ("beta_ref", "beta_vsc", "ltr", "speed", "baseline") if _shown(dom1, k) != _shown(dom2, k)]
    assert changed, "no vehicle figure changed between two loads"
    shot = tmp_path / "live.png"
    _chromium(tmp_path, f"--screenshot={shot}", f"--window-size={WINDOW[0]},{WINDOW[1]}", "--hide-scrollbars", page)
    data = shot.read_bytes()
    assert png_size(data) == WINDOW and len(data) > 5_000
    if UPDATE_DOCS_IMG:  # only on request: a test run leaves the checkout as it was
        DOCS_IMG.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(shot, DOCS_IMG)


def test_png_size_reads_the_ihdr_chunk() -> None:
    ihdr = struct.pack(">II", 412, 915) + bytes([8, 6, 0, 0, 0])
    png = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + b"\0\0\0\0"
    assert png_size(png) == (412, 915)
    with pytest.raises(AssertionError, match="not a PNG"):
        png_size(b"GIF89a" + bytes(30))
