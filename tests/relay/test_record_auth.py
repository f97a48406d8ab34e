"""``rig record`` with a correction source that refuses the credentials (RTKLIB str2str's bare
``HTTP/1.0 401 Unauthorized`` line): the recording goes on without RTK, the refusal is an error event
in the file naming the reason, the dashboard shows the relay FAILED with it, and the caster is asked
once (no retry on bad credentials)."""

from __future__ import annotations

import threading
from pathlib import Path

from rig.core import topics as T  # noqa: N812 - topics used as a namespace
from rig.data import load_session
from rig.record.recording import Recording
from rig.record.status import DeviceState, RecordingStatus
from rig.sim.record import record_simulated
from tests.relay.test_integrity import BareStatusCaster
from tests.session.recording import FAST_RTK, config

PASSWORD = "wr0ng-pass"


def test_a_refused_correction_login_in_rig_record_is_an_event_and_a_dashboard_alarm(tmp_path: Path) -> None:
    caster = BareStatusCaster(b"HTTP/1.0 401 Unauthorized\r\n")
    snapshots: list[RecordingStatus] = []
    lock = threading.Lock()

    def tick(s: Recording) -> None:
        snap = s.board.snapshot(s.clock.now_ns())
        with lock:
            snapshots.append(snap)

    try:
        url = f"ntrip://alice:{PASSWORD}@127.0.0.1:{caster.port}/MOUNT"
        cfg = config("straight:duration_s=4,speed_kmh=40", 2.0, **{"relay.source": url})
        rec = record_simulated(cfg, tmp_path, name="auth", rtk=FAST_RTK, tick=tick)
    finally:
        caster.close()
    assert rec.completed  # the recording went on without corrections
    assert len(caster.requests) == 1  # bad credentials are never retried
    ds = load_session(tmp_path / "auth")
    relay_errors = [e for _t, e in ds.events if e.kind is T.EventKind.ERROR and "relay" in e.text]
    assert relay_errors, [e.text for _t, e in ds.events]
    text = relay_errors[0].text
    assert "credentials refused" in text and "401" in text, text
    assert PASSWORD not in text
    alarms = [d for snap in snapshots for d in snap.devices
              if d.kind == "relay" and d.state is DeviceState.LOST and d.detail.startswith("FAILED:")]
    assert alarms, [(d.name, d.state, d.detail) for snap in snapshots[-1:] for d in snap.devices]
    assert "401" in alarms[-1].detail and PASSWORD not in alarms[-1].detail
