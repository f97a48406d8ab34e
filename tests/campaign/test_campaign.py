"""``rig campaign``: 20 simulated sessions on a two-worker ``distributed.LocalCluster`` against a serial run,
a corrupted session reported and not fatal, the cache on a re-run, side-by-side estimators."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from rig.workflows.campaign import (
    CampaignOptions,
    KeyMode,
    SessionTask,
    analyse_session,
    find_sessions,
    run_campaign,
    session_content_key,
)
from tests.calib_cli.synth import run_cli
from tests.campaign.synth import corrupt, make_session
from vsccore.errors import ConfigError, SessionFileError

N_SESSIONS = 20
CORRUPTED = 7
LINEAR = "tests.campaign.estimators:linear_ay"


@pytest.fixture(scope="module")
def campaign_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("campaign") / "sessions"
    for i in range(N_SESSIONS):
        make_session(out / ("week1" if i < 10 else "week2"), i)
    corrupt(out / "week1" / f"run{CORRUPTED:02d}")
    return out


@pytest.fixture(scope="module")
def cluster() -> Iterator[str]:
    """A LocalCluster of two worker processes (its workers import the analysis once for every test)."""

    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as c:
        # distributed's process-wide offload thread ("Dask-Offload", a ThreadPoolExecutor the library never shuts
        # down) starts with a client's first large message: started here, it is not counted as a thread the tests leak
        from distributed.utils import _offload_executor

        _offload_executor.submit(lambda: None).result(timeout=30)
        yield c.scheduler_address


def _manifest(out: Path) -> dict[str, object]:
    doc = json.loads((out / "campaign.json").read_text(encoding="utf-8"))
    assert isinstance(doc, dict)
    return doc


def test_distributed_equals_serial_corrupted_reported_rerun_cached(campaign_dir: Path, cluster: str,
                                                                   tmp_path: Path) -> None:
    serial, dist = tmp_path / "serial", tmp_path / "dist"
    # serial through the CLI, the recorded estimate and an offline estimator side by side
    code = run_cli(["campaign", str(campaign_dir), "--out", str(serial), "--scheduler", "serial",
                    "--estimator", "vsc_beta_estimate", "--estimator", LINEAR])
    assert code == 0
    sessions = find_sessions([campaign_dir])
    assert len(sessions) == N_SESSIONS
    opts = CampaignOptions(estimators=(None, LINEAR))
    res = run_campaign(sessions, dist, opts, scheduler=cluster)
    assert res.scheduler == cluster and res.computed == 2 * N_SESSIONS and res.cached == 0

    a, b = pq.read_table(serial / "metrics.parquet"), pq.read_table(dist / "metrics.parquet")
    assert a.num_rows > 10 * N_SESSIONS
    assert a.equals(b)
    assert pq.read_table(serial / "compare.parquet").equals(pq.read_table(dist / "compare.parquet"))

    rows = a.to_pylist()
    bad = [r for r in rows if r["session"] == f"run{CORRUPTED:02d}"]
    assert [r["verdict"] for r in bad] == ["ERROR", "ERROR"]
    assert {r["estimator"] for r in bad} == {"vsc_beta_estimate", LINEAR}
    assert all(r["error"] and "run07" in r["error"] for r in bad)
    assert res.failed == 2 and {e[0] for e in res.errors} == {str(campaign_dir / "week1" / "run07")}
    good = {r["session"] for r in rows if r["verdict"] in ("PASS", "FAIL")}
    assert len(good) == N_SESSIONS - 1  # every other session scored
    overall = [r for r in rows if r["kind"] == "overall" and r["ay_bin"] == "all"]
    assert len(overall) == 2 * (N_SESSIONS - 1)
    for r in overall:
        assert r["n"] > 100 and r["rmse_deg"] > 0.0 and r["time_base_verdict"] == "good"
        assert r["speed_kmh"] == pytest.approx(50.0, abs=15.0) and r["start_utc"] is not None
    # a_y bins: per manoeuvre and overall, |a_y| bins partition the "all" row's samples
    for r in overall:
        bins = [x for x in rows if x["path"] == r["path"] and x["estimator"] == r["estimator"]
                and x["kind"] == "overall" and x["ay_bin"] != "all"]
        assert sum(x["n"] for x in bins) == r["n"]
        rms = math.sqrt(sum(x["n"] * x["rmse_deg"] ** 2 for x in bins) / r["n"])
        assert rms == pytest.approx(r["rmse_deg"], rel=1e-9)

    # side by side: the comparison's columns are the long table's values for each estimator
    cmp = pq.read_table(dist / "compare.parquet").to_pylist()
    for c in cmp:
        if c["kind"] != "overall" or c["ay_bin"] != "all":
            continue
        for est in ("vsc_beta_estimate", LINEAR):
            long = next(r for r in overall if r["path"] == c["path"] and r["estimator"] == est)
            assert c[f"rmse_deg[{est}]"] == long["rmse_deg"]
        # the recorded estimate is the true β with a small gain error; β = −k·a_y misses the transients
        assert c[f"rmse_deg[{LINEAR}]"] > c["rmse_deg[vsc_beta_estimate]"]

    html = (dist / "report.html").read_text(encoding="utf-8")
    assert html.count("data:image/png;base64,") == 2 and "run07" in html

    # a second run: every validation from the cache, the cluster gets no task, the cache entries untouched
    entries = sorted((dist / "cache").rglob("*.json"))
    assert len(entries) == 2 * N_SESSIONS  # the corrupted session's error follows from its bytes: cached too
    stamps = [p.stat().st_mtime_ns for p in entries]
    again = run_campaign(sessions, dist, opts, scheduler=cluster)
    assert (again.computed, again.cached, again.failed) == (0, 2 * N_SESSIONS, 2)
    assert _manifest(dist)["computed"] == 0
    assert [p.stat().st_mtime_ns for p in entries] == stamps
    assert pq.read_table(dist / "metrics.parquet").equals(b)

    # a changed session (re-recorded) and a new one: only those two are computed
    for p in (campaign_dir / "week1").glob("run03.*"):
        p.unlink()
    make_session(campaign_dir / "week1", 3)
    make_session(campaign_dir / "week2", N_SESSIONS)
    third = run_campaign(find_sessions([campaign_dir]), dist, opts, scheduler=cluster)
    assert third.sessions == N_SESSIONS + 1
    assert (third.computed, third.cached, third.failed) == (4, 2 * (N_SESSIONS - 1), 2)
    status = _manifest(dist)["status"]
    assert isinstance(status, dict)
    assert {p for p, s in status.items() if "computed" in s.values()} == {
        str(campaign_dir / "week1" / "run03"), str(campaign_dir / "week2" / f"run{N_SESSIONS:02d}")}


def test_failing_estimator_is_a_row_and_the_campaign_goes_on(campaign_dir: Path, tmp_path: Path) -> None:
    sessions = find_sessions([str(campaign_dir / "week2" / "run1[01].*.mcap")])
    assert [s.name for s in sessions] == ["run10", "run11"]
    res = run_campaign(sessions, tmp_path, CampaignOptions(estimators=("tests.campaign.estimators:broken", None)),
                       scheduler="serial", report=False)
    rows = pq.read_table(res.table).to_pylist()
    broken = [r for r in rows if r["estimator"] == "tests.campaign.estimators:broken"]
    assert len(broken) == 2 and all(r["verdict"] == "ERROR" and "crashed on purpose" in r["error"] for r in broken)
    assert {r["verdict"] for r in rows if r["estimator"] == "vsc_beta_estimate" and r["ay_bin"] == "all"} <= {
        "PASS", "FAIL"}
    assert res.report is None and not (tmp_path / "report.html").exists()


def test_session_task_never_raises_for_a_missing_session(tmp_path: Path) -> None:
    out = analyse_session(SessionTask(str(tmp_path / "nothing"), (None,), "rts", False, False))
    (row,) = out["results"]["vsc_beta_estimate"]["rows"]
    assert row["verdict"] == "ERROR" and "nothing" in row["error"] and out["results"]["vsc_beta_estimate"]["cacheable"]


def test_calibrate_and_rollover_columns(campaign_dir: Path, tmp_path: Path) -> None:
    (s,) = find_sessions([campaign_dir / "week2" / "run13"])
    res = run_campaign([s], tmp_path, CampaignOptions(calibrate=True, rollover=True), scheduler="serial",
                       report=False)
    rows = pq.read_table(res.table).to_pylist()
    assert rows and all(r["verdict"] != "ERROR" for r in rows)
    r = rows[0]
    # the antennas are mounted true (offset 0) in the synthetic sessions: calibrate-baseline finds that, and it is used
    assert r["mount_offset_deg"] == pytest.approx(0.0, abs=0.1) and r["mount_offset_u95_deg"] > 0.0
    assert r["calibration_note"].startswith("mounting offset") and "used" in r["calibration_note"]
    assert r["rollover_peak_ltr"] is not None and 0.0 < r["rollover_peak_ltr"] < 1.5
    assert r["rollover_ltr_error_rms"] is not None and r["rollover_ltr_error_rms"] < 0.1


def test_content_key_follows_the_bytes_and_the_calibration_file(tmp_path: Path) -> None:
    base = make_session(tmp_path, 1)
    quick = session_content_key(base)
    full = session_content_key(base, KeyMode.FULL)
    assert quick != full and session_content_key(base) == quick
    (tmp_path / "run01.calibration.json").write_text("{}", encoding="utf-8")
    assert session_content_key(base) != quick
    (tmp_path / "run01.calibration.json").unlink()
    part = tmp_path / "run01.000.mcap"
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0xFF  # a flipped bit in the data section: the full key sees it
    part.write_bytes(bytes(data))
    assert session_content_key(base, KeyMode.FULL) != full
    assert session_content_key(base) != quick  # (the mtime changed)


def test_bad_arguments_are_named(tmp_path: Path) -> None:
    with pytest.raises(SessionFileError, match="nowhere"):
        find_sessions([tmp_path / "nowhere"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(SessionFileError, match="holds no session"):
        find_sessions([tmp_path / "empty"])
    with pytest.raises(ConfigError, match=r"package\.module:function"):
        CampaignOptions(estimators=("nocolon",)).check()
    with pytest.raises(ConfigError, match="--workers"):
        run_campaign([], tmp_path / "o", workers=-1)
    assert run_cli(["campaign", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2
