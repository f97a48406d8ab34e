"""`rig demo --fast` end to end: simulate, record with simulated devices, calibrate, validate, rollover."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rig.cli.main import main
from rig.core.config import load_session
from rig.workflows.demo import demo_config_path

# The module's fixture runs the whole `rig demo --fast` (about 2 min on an idle 2-core machine). On a
# busy one the governed simulated clock slows down instead of degrading the figures (issue 15), so the
# demo takes longer by design: 264-300+ s were measured at load 15-25. The suite's 300 s hang guard
# is widened for this module only.
pytestmark = pytest.mark.timeout(1200)


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo")
    main(["demo", "--fast", "--out", str(out)])  # raises SystemExit on any failure
    return out


def test_truth_file_is_a_plausible_drive(demo_out: Path) -> None:
    data = np.genfromtxt(demo_out / "truth.csv", delimiter=",", names=True)
    t = data["t_s"]
    assert np.all(np.diff(t) > 0)
    # the programme starts with a 40 km/h straight run: speed held within 1 %, no sideslip
    first = t < 5.0
    assert np.allclose(data["speed_mps"][first] * 3.6, 40.0, rtol=0.01)
    assert np.max(np.abs(data["beta_cg_deg"][first])) < 0.01
    # and it contains a manoeuvre with real sideslip and load transfer
    assert np.max(np.abs(data["beta_cg_deg"])) > 1.0
    assert np.max(np.abs(data["ltr"])) > 0.3
    assert (demo_out / "truth.png").stat().st_size > 10_000


def test_recorded_session_is_complete(demo_out: Path) -> None:
    from rig.data.info import info_to_json, read_session_info

    info = info_to_json(read_session_info(demo_out / "session" / "demo"))
    text = json.dumps(info)
    for topic in ("/gnss/rover_a/bestpos", "/gnss/rover_b/bestvel", "/can/vsc/frames", "/daq/SimDAQ/samples",
                  "/optical/body", "/relay/raw", "/sim/truth", "/rig/timebase"):
        assert topic in text, topic


def test_calibration_recovers_the_injected_offsets_within_the_stated_uncertainty(demo_out: Path) -> None:
    sim = load_session(demo_config_path()).simulation
    assert sim is not None
    cal = json.loads((demo_out / "session" / "demo.calibration.json").read_text())["results"]
    mount = cal["mount_offset"]
    # The demo's configuration has a fixed seed, so its error is one draw of the GNSS noise. Recorded with
    # seeds 1-5 (4x, one process) the errors were -0.043, +0.061, -0.018, +0.032, -0.052° (mean -0.004°),
    # each inside its own u95 (0.049, 0.084, 0.063, 0.047, 0.079°): no bias, the interval covers. The
    # estimator's coverage over many draws is proven in tests/calibration (Monte-Carlo, 96-99 %).
    # The seed is fixed but the draw is not: which samples the governed clock lets through, and when, moves
    # with the host's scheduling. So one run is one draw, and a 95 % interval alone would fail one run in
    # twenty by design: each error is held inside the 99.9 % interval (u95 x 3.29/1.96). Demo runs (idle
    # and under 6 busy processes) gave optical-zero errors of 0.02-1.08 x u95 (7 runs) and mounting-offset
    # errors of 0.26-1.09 x u95 (6 runs).
    k999 = 3.29 / 1.96
    assert abs(mount["offset_deg"] - sim.true_mount_offset_deg) <= k999 * mount["u95_deg"]
    assert mount["u95_deg"] < 0.1
    zero = cal["optical_zero"]["body"]
    assert abs(zero["zero_deg"] - sim.true_optical_zero_deg["body"]) <= k999 * zero["u95_deg"]
    assert zero["u95_deg"] < 0.05


def test_validation_report_and_rollover_are_written(demo_out: Path) -> None:
    html = (demo_out / "report" / "report.html").read_text()
    assert "<img" in html
    metrics = json.loads((demo_out / "report" / "metrics.json").read_text())
    assert metrics["manoeuvres"]
    assert (demo_out / "rollover.png").stat().st_size > 10_000


def test_steering_ratio_from_the_demo_circles_matches_the_simulated_gear(demo_out: Path) -> None:
    rows = json.loads((demo_out / "session" / "demo.calibration.json").read_text())["results"]["steering_ratio"]["rows"]
    assert {r["direction"] for r in rows} == {"forward", "reverse"}
    assert len(rows) >= 4
    for r in rows:
        # short demo holds (≈ 100° of arc) with RTK noise: within 2 % (the long-hold acceptance test asks 1 %)
        assert abs(r["ratio"] / r["simulation_true_ratio"] - 1.0) < 0.02, r
    assert (demo_out / "steering-ratio.png").stat().st_size > 10_000


# The demo's topics, schemas and message counts as recorded before the layout of rig/ changed (issue 30,
# recorded on the old code at d8d4d8d). Two idle runs of the same code differed by at most 1 message on the
# decoded topics and 0.3 % on the raw ones (reads and blocks are cut as the host schedules them), 5 events
# and 5 time-base records (both written on the host's housekeeping ticks). A run on a loaded host began
# logging 1.45 s of simulated time later (the receivers' configuration took longer: 29 of 3255 BESTPOS,
# 0.9 %), so the decoded counts are held to 3 %. The raw topics (port reads, CAN and DAQ blocks) and the
# events are held to their schemas only: the twins that behave like OEM7 receivers (issue 29) pace their
# ports differently, which changes how many reads carry the same bytes (rover_a: 10257 -> 7054). One topic
# joined since: /gnss/base/time (every receiver logs TIMEB ONCE at connect, the base too).
_GOLDEN = Path(__file__).with_name("golden") / "demo_topics.json"
_LOOSE = ("/raw", "/samples", "/frames", "/rig/events", "/rig/timebase", "/relay/stats")


def _recorded_topics(base: Path) -> dict[str, dict[str, object]]:
    import hashlib

    from mcap.reader import make_reader

    out: dict[str, dict[str, object]] = {}
    for part in sorted(base.parent.glob(base.name + ".*.mcap")):
        with part.open("rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None and summary.statistics is not None
        for cid, ch in summary.channels.items():
            sc = summary.schemas.get(ch.schema_id)
            d = out.setdefault(ch.topic, {"count": 0})
            d.update(schema=sc.name if sc else None, schema_encoding=sc.encoding if sc else None,
                     message_encoding=ch.message_encoding,
                     schema_sha=hashlib.sha256(sc.data).hexdigest()[:16] if sc else None)
            d["count"] = int(d["count"]) + summary.statistics.channel_message_counts.get(cid, 0)  # type: ignore[call-overload]
    return out


def test_topics_schemas_and_counts_are_those_of_the_golden_recording(demo_out: Path) -> None:
    want = json.loads(_GOLDEN.read_text())
    got = _recorded_topics(demo_out / "session" / "demo")
    assert sorted(got) == sorted(want)
    for topic, w in want.items():
        g = got[topic]
        assert {k: v for k, v in g.items() if k != "count"} == {k: v for k, v in w.items() if k != "count"}, topic
        if any(topic.endswith(s) or topic == s for s in _LOOSE):
            assert int(g["count"]) > 0, topic  # type: ignore[call-overload]
            continue  # how many reads and blocks carry the same bytes is the host's scheduling and the twins' pacing
        assert abs(int(g["count"]) - w["count"]) <= max(3, 0.03 * w["count"]), (topic, g["count"], w["count"])  # type: ignore[call-overload]
