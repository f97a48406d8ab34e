"""``rig ppk`` on a short recorded session: per-rover runs, the side file, the systems each rover is solved with,
and its errors."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from drivers.novatel.rawobs import GloEphemeris
from rig.cli.main import app, main
from rig.data.sidefiles import PPK_COLUMNS, PPK_METADATA_KEY, PpkQuality, ppk_file_path, ppk_metadata, read_ppk_file
from rig.ppk.rtklib import run_ppk, usable_systems, write_rinex_nav
from tests.ppk.filtered import copy_without_logs
from vsccore.errors import AnalysisError

pytestmark = pytest.mark.skipif(shutil.which("rnx2rtkp") is None or shutil.which("convbin") is None,
                                reason="RTKLIB not installed (apt-get install rtklib)")

A_LOGS = [{"name": "BESTPOSB", "period_s": 0.05}, {"name": "BESTVELB", "period_s": 0.05},
          {"name": "TIMEB", "period_s": 1.0}, {"name": "RANGECMPB", "period_s": 0.2},
          {"name": "GPSEPHEMB", "trigger": "onchanged"}, {"name": "GLOEPHEMERISB", "trigger": "onchanged"}]
B_LOGS = [{"name": "BESTPOSB", "period_s": 0.05}, {"name": "BESTVELB", "period_s": 0.05},
          {"name": "TIMEB", "period_s": 1.0}, {"name": "RANGECMPB", "period_s": 0.2},
          {"name": "GPSEPHEMB", "trigger": "onchanged"}]
"""Rover B logs raw observations and GPS ephemerides, no GLOEPHEMERISB (a configuration from before GLONASS)."""
NO_GLO_B = ("rover_b: no GLOEPHEMERISB in the session; GLONASS not used for rover_b — log GLOEPHEMERISB ONCHANGED on "
            "rover_b (see examples/car-template.toml)")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from rig.core.config import load_session as load_config
    from rig.sim.record import record_simulated
    from rig.workflows.demo import demo_config_path
    from sim_devices.vehicle.scenarios import make_scenario

    out = tmp_path_factory.mktemp("ppk_cli")
    cfg = load_config(demo_config_path(), {"simulation.speed": 2.0, "receivers.1.logs": A_LOGS,
                                           "receivers.2.logs": B_LOGS})
    rec = record_simulated(cfg, out, name="rec", drive=make_scenario("straight", speed_kmh=40.0, duration_s=6.0),
                           lead_s=2.0)
    assert rec.completed and rec.summary.recording.error is None
    return Path(out) / "rec"


def test_ppk_one_rover_writes_the_side_file(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "a.ppk.parquet"
    res = CliRunner().invoke(app, ["ppk", str(session), "--rover", "rover_a", "--out", str(out),
                                   "--keep", str(tmp_path / "work")])
    assert res.exit_code == 0, res.output
    assert "rover_a: fix ratio " in res.output and "rover_b" not in res.output
    assert tuple(pq.read_schema(out).names) == PPK_COLUMNS
    sols = read_ppk_file(out)
    assert set(sols) == {"rover_a"}
    s = sols["rover_a"]
    # 5 Hz RANGECMPB over the recording, GPS times on the 200 ms grid, mostly fixed, near the start point
    assert s.gps_time_ns.size >= 25
    assert np.all(s.gps_time_ns % 200_000_000 == 0)
    assert np.mean(s.q == PpkQuality.FIX) >= 0.9
    assert np.all(np.abs(s.lat_deg - 48.7758) < 0.01) and np.all(np.abs(s.lon_deg - 9.1829) < 0.01)
    # RTKLIB's inputs are kept for a user to open: RINEX obs/nav of the rover and the base, the .pos
    assert {"rover_a.obs", "rover_a.nav", "base.obs", "rover_a.pos"} <= {p.name for p in (tmp_path / "work").iterdir()}
    assert not ppk_file_path(session).exists()  # --out went elsewhere


def _rig(*args: str, path: str | None = None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
    if path is not None:
        env["PATH"] = path
    return subprocess.run([sys.executable, "-m", "rig", *args], capture_output=True, text=True, timeout=300,
                          env=env, check=False)


def _main(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """``rig ARGS`` in this process (exit status, stdout, stderr): the CLI's error handling without a new Python."""
    capsys.readouterr()
    try:
        main([*args])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_ppk_names_the_logs_a_rover_lacks(session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    copy, removed = copy_without_logs(session, tmp_path / "nob", {"rover_b": {"RANGECMP", "GPSEPHEM"}})
    assert removed["rover_b"] > 0
    code, _out, err = _main(capsys, "ppk", str(copy))
    assert code == 2, err
    assert "rig: error: " in err
    assert "rover rover_b has no RANGECMPB and no GPSEPHEMB in the recording" in err
    assert "log RANGECMPB ONTIME 0.05 and GPSEPHEMB ONCHANGED on rover_b" in err and "rover_a" not in err
    assert not ppk_file_path(copy).exists()


def test_ppk_on_a_session_without_any_rangecmp(session: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """No rover logged raw observations: a clear error (exit 2) naming every rover and the log, no side file."""
    copy, removed = copy_without_logs(session, tmp_path / "norange", {"rover_a": {"RANGECMP"},
                                                                      "rover_b": {"RANGECMP"}})
    assert min(removed.values()) > 0
    code, out, err = _main(capsys, "ppk", str(copy))
    assert code == 2, err
    assert out == ""
    assert err.startswith(f"rig: error: {copy}: no raw observations (RANGECMPB) from any rover, nothing to "
                          "post-process: rover rover_a has no RANGECMPB; rover rover_b has no RANGECMPB"), err
    assert "log RANGECMPB ONTIME 0.05 on rover_a; log RANGECMPB ONTIME 0.05 on rover_b" in err
    assert len(err.strip().splitlines()) == 1
    assert not ppk_file_path(copy).exists()


def _nav_satellites(path: Path) -> set[str]:
    return {ln[:3] for ln in path.read_text().splitlines() if ln[:1] in "GR" and ln[1:3].isdigit()}


def test_ppk_default_solves_a_rover_without_gloephemeris_with_gps_and_says_so(
        session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Default systems: rover_a (GLOEPHEMERISB logged) with GPS + GLONASS, rover_b (GPSEPHEMB only) with GPS alone,
    a warning naming rover_b, GLONASS and the log, and the systems of each rover in the output and the side file."""
    out = tmp_path / "both.parquet"
    code, stdout, err = _main(capsys, "ppk", str(session), "--out", str(out), "--keep", str(tmp_path / "w"))
    assert code == 0, err
    assert err.splitlines() == [f"warning: {NO_GLO_B}"]
    assert "rover_a: fix ratio " in stdout and "GPS + GLONASS, " in stdout.split("rover_a:")[1].splitlines()[0]
    line_b = stdout.split("rover_b:")[1].splitlines()[0]
    assert "GPS only, 0 GLONASS ephemerides)" in line_b, stdout
    sols = read_ppk_file(out)
    assert sols["rover_a"].systems == ("G", "R") and sols["rover_b"].systems == ("G",)
    assert sols["rover_b"].fixed.mean() >= 0.9
    meta = ppk_metadata(pq.read_schema(out).metadata)
    assert meta["systems_asked"] == ["G", "R"] and meta["systems_explicit"] is False
    assert meta["rovers"]["rover_b"] == {"systems": ["G"], "glonass_ephemerides": 0}
    assert meta["rovers"]["rover_a"]["glonass_ephemerides"] >= 5
    assert meta["warnings"] == [NO_GLO_B]
    # RTKLIB got for rover_b what it was told: GPS only in the navigation file and the options
    w = tmp_path / "w"
    assert {s[0] for s in _nav_satellites(w / "rover_b.nav")} == {"G"}
    assert {s[0] for s in _nav_satellites(w / "rover_a.nav")} == {"G", "R"}
    assert "pos1-navsys       =1\n" in (w / "rover_b.conf").read_text()
    assert "pos1-navsys       =5\n" in (w / "rover_a.conf").read_text()
    assert PPK_METADATA_KEY in (pq.read_schema(out).metadata or {})


def test_ppk_of_a_copy_without_gloephemeris(session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A copy of the session with every GLOEPHEMERIS log removed (an older recording): by default a warning per rover
    and the GPS-only solution (the same as --systems G on the original); --systems G,R asked explicitly cannot be
    met by any rover: exit 2, naming why and what to run instead, and no side file."""
    copy, removed = copy_without_logs(session, tmp_path / "noglo", {"rover_a": {"GLOEPHEMERIS"}})
    assert removed["rover_a"] > 0
    res = run_ppk(copy, rovers=["rover_a"], out=tmp_path / "copy.parquet")
    assert res.warnings == (NO_GLO_B.replace("rover_b", "rover_a"),)
    (r,) = res.rovers
    assert r.systems == ("G",) and r.glonass_ephemerides == 0 and r.systems_text == "GPS only"
    gps = run_ppk(session, rovers=["rover_a"], out=tmp_path / "gps.parquet", systems=("G",))
    assert gps.warnings == ()
    got, expect = read_ppk_file(res.out)["rover_a"], read_ppk_file(gps.out)["rover_a"]
    np.testing.assert_array_equal(got.gps_time_ns, expect.gps_time_ns)
    np.testing.assert_array_equal(got.q, expect.q)
    np.testing.assert_allclose(got.lat_deg, expect.lat_deg, rtol=0, atol=1e-9)
    assert got.fixed.mean() >= 0.9

    target = tmp_path / "explicit.parquet"
    code, out, err = _main(capsys, "ppk", str(copy), "--systems", "G,R", "--out", str(target))
    assert code == 2, err
    assert out == "" and len(err.strip().splitlines()) == 1
    assert err.startswith(f"rig: error: {copy}: GLONASS asked for (--systems G,R) but usable for no rover: "), err
    assert NO_GLO_B in err and NO_GLO_B.replace("rover_b", "rover_a") in err
    assert err.rstrip().endswith("solve without it: --systems G")
    assert not target.exists()


def test_ppk_explicit_glonass_on_a_session_where_one_rover_has_it(session: Path, tmp_path: Path) -> None:
    """--systems G,R where rover_a can use GLONASS and rover_b cannot: solved, rover_b with GPS and a warning; only
    rover_b asked for explicitly with G,R: an error (GLONASS usable for no rover asked for)."""
    res = run_ppk(session, out=tmp_path / "x.parquet", systems=("G", "R"))
    assert res.warnings == (NO_GLO_B,)
    assert {r.rover: r.systems for r in res.rovers} == {"rover_a": ("G", "R"), "rover_b": ("G",)}
    assert ppk_metadata(pq.read_schema(res.out).metadata)["systems_explicit"] is True
    with pytest.raises(AnalysisError, match=r"GLONASS asked for \(--systems G,R\) but usable for no rover: rover_b: "
                                            r"no GLOEPHEMERISB"):
        run_ppk(session, rovers=["rover_b"], out=tmp_path / "y.parquet", systems=("G", "R"))
    assert not (tmp_path / "y.parquet").exists()


def test_usable_systems_names_each_missing_input() -> None:
    """A system is used only with the rover's observations, its ephemerides and the base's observations."""
    assert usable_systems("rover_a", ("G", "R"), rover_obs="GR", ephemerides="GR", base_obs="GR") == (("G", "R"), ())
    used, notes = usable_systems("rover_a", ("G", "R"), rover_obs="G", ephemerides="GR", base_obs="G")
    assert used == ("G",)
    assert notes == (("rover_a: no GLONASS observations in its RANGECMPB and no GLONASS observations in the base "
                      "corrections; GLONASS not used for rover_a — let rover_a track GLONASS and log RTCM1087 on the "
                      "base (see examples/car-template.toml)"),)
    used, notes = usable_systems("rover_b", ("R",), rover_obs="GR", ephemerides="G", base_obs="GR")
    assert used == () and notes == (NO_GLO_B,)


def test_ppk_side_file_without_systems_metadata(tmp_path: Path) -> None:
    """A side file written before the systems were recorded still reads (systems unknown: ())."""
    import pyarrow as pa

    cols: dict[str, object] = {c: [0.0] for c in PPK_COLUMNS}
    cols.update(rover=["rover_a"], gps_time_ns=[1], time_ns=[1], q=[1], ns=[9])
    pq.write_table(pa.table(cols), tmp_path / "old.parquet")
    assert read_ppk_file(tmp_path / "old.parquet")["rover_a"].systems == ()
    assert ppk_metadata(None) == {}


def test_ppk_unknown_rover(session: Path) -> None:
    with pytest.raises(AnalysisError, match=r"no rover named base \(rovers: rover_a, rover_b\)"):
        run_ppk(session, rovers=["base"])


def test_ppk_without_rtklib_names_the_debian_package(session: Path, tmp_path: Path) -> None:
    res = _rig("ppk", str(session), "--rover", "rover_a", path=str(tmp_path))  # nothing on PATH
    assert res.returncode == 2, res.stderr
    assert "RTKLIB's convbin and rnx2rtkp not found on PATH" in res.stderr
    assert "apt-get install rtklib" in res.stderr


def test_base_position_is_the_reference_point_raised_by_the_antenna_height(tmp_path: Path) -> None:
    """RTCM 1006's antenna height (RINEX ANTENNA: DELTA H/E/N) goes up along the ellipsoid normal, as RTKLIB does."""
    import pymap3d

    from rig.ppk.rtklib import _approx_position

    x, y, z = pymap3d.geodetic2ecef(48.7758, 9.1829, 347.9)
    header = (f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'M: Mixed':<20}RINEX VERSION / TYPE\n"
              f"{x:14.4f}{y:14.4f}{z:14.4f}{'':18}APPROX POSITION XYZ\n"
              f"{1.5:14.4f}{0.0:14.4f}{0.0:14.4f}{'':18}ANTENNA: DELTA H/E/N\n"
              f"{'':60}END OF HEADER\n")
    obs = tmp_path / "base.obs"
    obs.write_text(header)
    pos = _approx_position(obs)
    assert pos is not None
    lat, lon, h = pymap3d.ecef2geodetic(*pos)
    assert abs(lat - 48.7758) < 1e-9 and abs(lon - 9.1829) < 1e-9
    assert abs(h - (347.9 + 1.5)) < 1e-3
    obs.write_text(header.replace(f"{x:14.4f}{y:14.4f}{z:14.4f}", f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}"))
    assert _approx_position(obs) is None  # no position in the corrections


def test_ppk_with_the_bases_own_observations(session: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """--base: RINEX obs or RTCM3 of the base (its own log, a reference station) instead of the relayed stream."""
    from vsccore.errors import SessionFileError

    ref = run_ppk(session, rovers=["rover_a"], out=tmp_path / "relay.parquet", work_dir=tmp_path / "w")
    shutil.copy(tmp_path / "w" / "base.obs", tmp_path / "site.obs")
    shutil.copy(tmp_path / "w" / "raw" / "corrections.rtcm3", tmp_path / "site.rtcm3")
    expect = read_ppk_file(ref.out)["rover_a"]
    for name in ("site.obs", "site.rtcm3"):
        code, _out, err = _main(capsys, "ppk", str(session), "--rover", "rover_a", "--base", str(tmp_path / name),
                                "--out", str(tmp_path / f"{name}.parquet"))
        assert code == 0, err
        got = read_ppk_file(tmp_path / f"{name}.parquet")["rover_a"]
        np.testing.assert_array_equal(got.gps_time_ns, expect.gps_time_ns)
        np.testing.assert_array_equal(got.q, expect.q)
        np.testing.assert_allclose(got.lat_deg, expect.lat_deg, rtol=0, atol=1e-9)
    with pytest.raises(SessionFileError, match=r"nowhere.obs: no such base observation file \(--base\)"):
        run_ppk(session, rovers=["rover_a"], base=tmp_path / "nowhere.obs")
    text = (tmp_path / "site.obs").read_text()
    (tmp_path / "nopos.obs").write_text("\n".join(ln for ln in text.splitlines() if "APPROX POSITION" not in ln))
    with pytest.raises(AnalysisError, match=r"nopos.obs: no base position"):
        run_ppk(session, rovers=["rover_a"], base=tmp_path / "nopos.obs", out=tmp_path / "x.parquet")


def _rinex_obs_satellites(path: Path) -> set[str]:
    """Satellites of a RINEX 3 observation file (the first field of each observation line)."""
    sats: set[str] = set()
    body = False
    with open(path) as f:
        for line in f:
            if body and line[:1] in "GRECJS" and line[1:3].strip().isdigit():
                sats.add(line[:3])
            body = body or "END OF HEADER" in line
    return sats


def test_ppk_solves_with_glonass_as_well(session: Path, tmp_path: Path) -> None:
    """GLOEPHEMERISB logged: the RINEX obs of rover and base carry GLONASS, the navigation file its ephemerides,
    and RTKLIB solves with more satellites than GPS alone, fixing at least as many epochs."""
    both = run_ppk(session, rovers=["rover_a"], out=tmp_path / "gr.parquet", work_dir=tmp_path / "gr")
    gps = run_ppk(session, rovers=["rover_a"], out=tmp_path / "g.parquet", work_dir=tmp_path / "g", systems=("G",))
    wd = tmp_path / "gr"
    rover_r = {s for s in _rinex_obs_satellites(wd / "rover_a.obs") if s.startswith("R")}
    base_r = {s for s in _rinex_obs_satellites(wd / "base.obs") if s.startswith("R")}
    nav_r = {ln[:3] for ln in (wd / "rover_a.nav").read_text().splitlines() if ln.startswith("R")}
    assert len(rover_r) >= 5 and rover_r == base_r and nav_r == rover_r, (rover_r, base_r, nav_r)
    assert "M: MIXED" in (wd / "rover_a.nav").read_text().splitlines()[0]
    (rb,), (rg,) = both.rovers, gps.rovers
    print(f"\n  GPS+GLONASS: median {rb.satellites_median:g} satellites, {rb.fixed}/{rb.observation_epochs} fixed; "
          f"GPS only: median {rg.satellites_median:g}, {rg.fixed}/{rg.observation_epochs} fixed")
    assert rb.glonass_ephemerides == len(nav_r) and rg.glonass_ephemerides == 0
    assert rb.satellites_median >= rg.satellites_median + len(rover_r) - 1
    assert rb.fixed >= rg.fixed and rb.epochs == rg.epochs
    sb, sg = read_ppk_file(both.out)["rover_a"], read_ppk_file(gps.out)["rover_a"]
    fixed = sb.fixed & sg.fixed
    assert fixed.sum() >= 0.9 * len(fixed)
    # both fixed solutions agree within the centimetres of their uncertainties (same ambiguities, more geometry)
    assert np.max(np.abs(sb.height_m[fixed] - sg.height_m[fixed])) < 0.05
    assert np.median(sb.sdu_m[fixed]) < np.median(sg.sdu_m[fixed])


def _glo(**kw: float) -> GloEphemeris:
    eph = GloEphemeris(
        sloto=14 + 37, freqo=0, sat_type=1, false_iod=0, ephem_week=2400, ephem_time_ms=(345600 - 882) * 1000,
        time_offset_s=10782, nt_day=1, reserved1=0, reserved2=0, issue=11, health=0, pos_x_m=-23_114_356.25,
        pos_y_m=3_366_334.5, pos_z_m=3_757_992.75, vel_x_mps=-101.5, vel_y_mps=1686.25, vel_z_mps=-3402.75,
        ls_acc_x_mps2=1.862645149230957e-06, ls_acc_y_mps2=-9.313225746154785e-07, ls_acc_z_mps2=0.0,
        tau_n_s=-6.5e-05, delta_tau_n_s=0.0, gamma_n=9.0e-13, tk_s=9000, p=0, ft=0, age_days=2, flags=5)
    return replace(eph, **kw)


def test_rinex_nav_glonass_record(tmp_path: Path) -> None:
    """RINEX 3.04 GLONASS record: UTC epoch (tb − 18 s), −τn, +γn, frame time in s of the UTC week, km, FCN."""
    nav = tmp_path / "m.nav"
    assert write_rinex_nav([], nav, [_glo()]) == 1
    lines = nav.read_text().splitlines()
    assert lines[0][40:60].strip() == "M: MIXED"
    rec = lines[lines.index(f"{'':60}END OF HEADER") + 1:]
    assert len(rec) == 4
    # tb = GPS week 2400, 345600 − 882 s → 2026-01-07 23:45:18 GPS = 23:45:00 UTC
    assert rec[0].startswith("R14 2026 01 07 23 45 00")

    def values(line: str, first: int) -> list[float]:
        n = 3 if first > 4 else 4
        return [float(line[first + 19 * i: first + 19 * (i + 1)].replace("D", "E")) for i in range(n)]

    assert values(rec[0], 23) == pytest.approx([6.5e-05, 9.0e-13, (345600 - 882 - 18 - 900) % 604800])
    assert values(rec[1], 4) == pytest.approx([-23_114.35625, -0.1015, 1.862645149230957e-09, 0.0], rel=1e-11)
    assert values(rec[2], 4) == pytest.approx([3_366.3345, 1.68625, -9.313225746154785e-10, -7.0], rel=1e-11)
    assert values(rec[3], 4) == pytest.approx([3_757.99275, -3.40275, 0.0, 2.0], rel=1e-11)
    with pytest.raises(AnalysisError, match="GLOEPHEMERIS slot 14 tb 344718 s: non-finite"):
        write_rinex_nav([], nav, [_glo(tau_n_s=float("nan"))])


def test_ppk_unknown_system_is_refused(session: Path) -> None:
    with pytest.raises(AnalysisError, match="unknown satellite system X"):
        run_ppk(session, rovers=["rover_a"], systems=("G", "X"))
    with pytest.raises(AnalysisError, match=r"satellite system E \(Galileo\) is not supported by rig ppk"):
        run_ppk(session, rovers=["rover_a"], systems=("G", "E"))


def _nav_records(path: Path, system: str) -> dict[tuple[str, str], list[float]]:
    """RINEX 3 navigation records of one system: (satellite, epoch) -> the numbers of the record, in order."""
    lines = path.read_text().splitlines()
    body = lines[next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1:]
    out: dict[tuple[str, str], list[float]] = {}
    key: tuple[str, str] | None = None
    for ln in body:
        if ln[:1].strip():
            key = (ln[:3], ln[4:23]) if ln.startswith(system) else None
            if key is not None:
                out[key] = []
            text = ln[23:]
        else:
            text = ln[4:]
        if key is not None:
            out[key] += [float(text[i:i + 19].replace("D", "E")) for i in range(0, len(text.rstrip()), 19)]
    return out


def test_rtklib_decodes_our_gloephemerisb_like_we_do(session: Path, tmp_path: Path) -> None:
    """RTKLIB's own NovAtel decoder (convbin, decode_gloephemerisb) reads the simulated GLOEPHEMERISB frames into the
    same GLONASS navigation records as our decoder and RINEX writer: an outside check of the encoding."""
    run_ppk(session, rovers=["rover_a"], out=tmp_path / "x.parquet", work_dir=tmp_path / "w")
    ours = _nav_records(tmp_path / "w" / "rover_a.nav", "R")
    res = subprocess.run(["convbin", "-r", "nov", "-v", "3.04", "-o", str(tmp_path / "c.obs"), "-n",
                          str(tmp_path / "c.nav"), str(tmp_path / "w" / "raw" / "rover_a.gps")],
                         capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    theirs = _nav_records(tmp_path / "c.nav", "R")
    assert len(ours) >= 5 and set(theirs) == set(ours)
    for key, values in ours.items():
        assert len(theirs[key]) == len(values) == 15, key
        np.testing.assert_allclose(theirs[key], values, rtol=1e-11, atol=1e-20, err_msg=str(key))
