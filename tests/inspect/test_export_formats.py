"""``rig export --format mdf4|parquet|mat``: read back with asammdf, pyarrow (+ DuckDB), h5py, mat73 and hdf5storage
(MAT v7.3) and scipy.io (MAT v5), values equal to what the session holds (rig.data), units present, CAN raw
frames decodable with the session's DBC (MDF4) or byte-equal to the recorded ones (MAT)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.cli.main import app
from rig.data import load_session
from rig.data.stream import iter_groups, open_stream, unit_suffix
from rig.export.mat import export_mat
from rig.export.mdf4 import export_mdf4
from rig.export.parquet import export_parquet
from tests.dataset.synth import DBC, Synth, utc
from tests.dataset.synth import write_session as write_dataset_session
from tests.inspect.recorded import record_validating_drive
from vsccore.errors import ConfigError, SessionFileError

runner = CliRunner()


@pytest.fixture(scope="module")
def ds(tmp_path_factory: pytest.TempPathFactory) -> Synth:
    return write_dataset_session(tmp_path_factory.mktemp("ds"), duration_s=6.0)


def test_unit_suffixes() -> None:
    assert [unit_suffix(u) for u in ("rad/s", "m/s²", "m/s", "rad", "", "Pa", "km/h")] == [
        "radps", "mps2", "mps", "rad", "", "pa", "kmh"]


def test_parquet_hive_dataset_reads_back_with_pyarrow_and_duckdb(ds: Synth, tmp_path: Path) -> None:
    import pyarrow.dataset as pads

    report = export_parquet(ds.base, tmp_path / "pq")
    groups = {f.source for f in report.files}
    assert {"gnss_rover_a_bestpos", "can_can0_frames", "can_can0_roles", "daq_daq1", "truth", "events"} <= groups
    session = load_session(ds.base)
    # GNSS: values and the recorded (common) time base
    d = pads.dataset(tmp_path / "pq" / "gnss_rover_a_bestpos", format="parquet", partitioning="hive")
    tbl = d.to_table().sort_by("time_ns")
    ref = session._table("/gnss/rover_a/bestpos")
    assert tbl.column("lat_deg").to_numpy().tolist() == ref["lat_deg"].tolist()
    assert tbl.column("time_ns").to_numpy().tolist() == ref.time_ns.tolist()
    assert set(tbl.column("session").to_pylist()) == {ds.base.name}  # hive partition column
    assert tbl.schema.field("lat_deg").metadata[b"unit"] == b"deg"
    assert tbl.schema.field("time_ns").type.bit_width == 64 and str(tbl.schema.field("time_s").type) == "double"
    t_s = tbl.column("time_s").to_numpy()
    assert np.allclose(np.diff(t_s), np.diff(tbl.column("time_ns").to_numpy()) / 1e9)
    # CAN roles: wide, unit-suffixed, equal to the dataset's decode and to the truth within DBC resolution
    roles = pads.dataset(tmp_path / "pq" / "can_can0_roles", partitioning="hive").to_table().sort_by("time_ns")
    assert roles.schema.field("yaw_rate_radps").metadata[b"unit"] == b"rad/s"
    yaw = roles.column("yaw_rate_radps").to_numpy()
    ok = roles.column("yaw_rate_ok").to_numpy() & np.isfinite(yaw)
    ref_yaw = session.can_roles("can0")["yaw_rate"]
    assert np.sort(yaw[ok]).tolist() == pytest.approx(np.sort(ref_yaw.values[ref_yaw.ok]).tolist())
    assert np.max(np.abs(yaw[ok] - ds.yaw_rate[: ok.sum()])) < 1e-3
    t = roles.column("time_ns").to_numpy()[ok]
    assert np.max(np.abs(t - utc(ds.can_t_gps))) < 1_000_000  # block time + interface clock vs GPS: within 1 ms
    # raw frames: payload bytes as recorded
    frames = pads.dataset(tmp_path / "pq" / "can_can0_frames", partitioning="hive").to_table()
    rec = session.can_frames("can0").records
    assert frames.num_rows == rec.shape[0]
    assert frames.column("data").to_pylist()[0] == bytes(rec["data"][0][: rec["len"][0]])
    # DAQ channels in volts, equal to the dataset's
    daq = pads.dataset(tmp_path / "pq" / "daq_daq1", partitioning="hive").to_table().sort_by("sample_index")
    d1 = session.daq("daq1")
    name = d1.channel_names[0]
    assert daq.schema.field(f"{name}_V").metadata[b"unit"] == b"V"
    assert np.allclose(daq.column(f"{name}_V").to_numpy(), d1.channel(name), atol=1e-6)
    duckdb = pytest.importorskip("duckdb")
    con = duckdb.connect()
    n, sessions = con.execute(
        "select count(*), count(distinct session) from read_parquet(?, hive_partitioning=true)",
        [str(tmp_path / "pq" / "gnss_rover_a_bestpos" / "*" / "*.parquet")]).fetchone()
    assert (n, sessions) == (len(ref), 1)


def test_parquet_campaign_appends_sessions_and_refuses_overwrite(ds: Synth, tmp_path: Path) -> None:
    import pyarrow.dataset as pads

    (tmp_path / "b").mkdir()
    other = write_dataset_session(tmp_path / "b", name="second", duration_s=3.0)
    export_parquet(ds.base, tmp_path / "campaign", topics=["gnss_*"])
    export_parquet(other.base, tmp_path / "campaign", topics=["gnss_*"])
    assert not (tmp_path / "campaign" / "truth").exists()  # --topics kept only the GNSS groups
    tbl = pads.dataset(tmp_path / "campaign" / "gnss_rover_b_bestpos", partitioning="hive").to_table()
    assert sorted(set(tbl.column("session").to_pylist())) == sorted({ds.base.name, "second"})
    with pytest.raises(SessionFileError, match="already exists"):
        export_parquet(other.base, tmp_path / "campaign", topics=["gnss_*"])
    assert not list((tmp_path / "campaign").rglob(".*partial*"))


def test_mdf4_reads_back_with_asammdf_and_decodes_the_bus_log(ds: Synth, tmp_path: Path) -> None:
    asammdf = pytest.importorskip("asammdf")
    report = export_mdf4(ds.base, tmp_path)
    (f,) = report.files
    session = load_session(ds.base)
    with asammdf.MDF(f.path) as mdf:
        lat = mdf.get("gnss_rover_b_bestpos.lat_deg")
        ref = session._table("/gnss/rover_b/bestpos")
        assert lat.unit == "deg" and lat.samples.tolist() == ref["lat_deg"].tolist()
        start_ns = int(mdf.header.start_time.timestamp() * 1e9)
        assert np.max(np.abs(lat.timestamps * 1e9 + start_ns - ref.time_ns)) < 2_000  # float s from the file start
        yaw = mdf.get("can_can0_roles.yaw_rate_radps")
        assert yaw.unit == "rad/s" and np.nanmax(np.abs(yaw.samples[: ds.yaw_rate.size] - ds.yaw_rate)) < 1e-3
        assert mdf.get("truth.vy_mps").unit == "m/s"
        df = mdf.to_dataframe()
        assert "gnss_rover_b_bestpos.lat_deg" in df.columns and len(df) > 0
        # ASAM bus logging: asammdf decodes the raw frames with the session's DBC
        decoded = mdf.extract_bus_logging({"CAN": [(str(DBC), 0)]})
        names = {ch.name for g in decoded.groups for ch in g.channels}
        assert "ESC_YawRate" in names or any(n.endswith("ESC_YawRate") for n in names)
        yaw_sig = decoded.get(next(n for n in names if n.endswith("ESC_YawRate")))
        assert yaw_sig.samples.size == ds.can_t_gps.size
        assert np.max(np.abs(np.radians(yaw_sig.samples.astype(float)) - ds.yaw_rate)) < 2e-3


def _mat_char(d: Any) -> str:
    """A MAT v7.3 1×L char (or MATLAB's empty char) as text."""
    assert d.attrs["MATLAB_class"] == b"char" and d.attrs["MATLAB_int_decode"] == 2
    if d.attrs.get("MATLAB_empty"):
        assert d[()].tolist() == [0, 0]
        return ""
    assert d.shape[1] == 1  # 1×L in MATLAB is (L, 1) in HDF5
    return str(d[()].astype("<u2").tobytes().decode("utf-16-le"))


def _mat_field(d: Any) -> Any:
    """A MAT v7.3 struct field as rows: a column (HDF5 (1, N)) as 1-D, an N×W matrix (HDF5 (W, N)) as 2-D, an
    N×W char matrix as its space-padded rows stripped."""
    cls = d.attrs["MATLAB_class"]
    v = d[()]
    if cls == b"char":
        return [bytes(r.astype("<u2").tobytes()).decode("utf-16-le").rstrip(" ") for r in v.T]
    if cls == b"logical":
        assert d.attrs["MATLAB_int_decode"] == 1 and v.dtype == np.uint8
        v = v.astype(bool)
    return v[0] if v.shape[0] == 1 else v.T


def _fields(g: Any) -> list[str]:
    return [bytes(a).decode() for a in g.attrs["MATLAB_fields"]]


@pytest.mark.parametrize("chunk_bytes", [4096, None])
def test_mat73_reads_back_with_h5py_equal_to_the_dataset(ds: Synth, tmp_path: Path, chunk_bytes: int | None
                                                         ) -> None:
    """MAT v7.3 (HDF5 behind MATLAB's userblock): every field of a struct equals the session's arrays, with
    units, transposed as MATLAB stores it; the CAN frames byte-equal to the recorded frames. Small chunks make
    every field stream through many chunk writes."""
    import h5py
    import scipy.io

    from rig.export.mat import export_mat as export_mat_file

    report = export_mat_file(ds.base, tmp_path, **({} if chunk_bytes is None else {"chunk_bytes": chunk_bytes}))
    (f,) = report.files
    assert f.path == tmp_path / f"{ds.base.name}.mat" and f.source.startswith("MAT v7.3")
    head = f.path.read_bytes()[:512]
    text = head[:116].decode("ascii")
    assert re.fullmatch(r"MATLAB 7\.3 MAT-file, Platform: [^,]+, Created on: "
                        r"(Mon|Tue|Wed|Thu|Fri|Sat|Sun) [A-Z][a-z]{2} \d\d \d\d:\d\d:\d\d \d{4} "
                        r"HDF5 schema 1\.00 \. *", text), text
    assert head[116:124] == bytes(8) and head[124:128] == b"\x00\x02IM" and head[128:] == bytes(384)
    with pytest.raises(NotImplementedError):  # scipy.io reads v5 only: it names the HDF5 reader
        scipy.io.loadmat(f.path)
    session = load_session(ds.base)
    with h5py.File(f.path, "r") as h:
        assert h.userblock_size == 512
        g = h["gnss_rover_a_bestpos"]
        assert g.attrs["MATLAB_class"] == b"struct"
        ref = session._table("/gnss/rover_a/bestpos")
        assert _fields(g)[:3] == ["time_ns", "time_s", "host_ns"] and _fields(g)[-1] == "units"
        assert set(_fields(g)) == set(g)
        assert g["lat_deg"].shape == (1, len(ref)) and g["lat_deg"].attrs["MATLAB_class"] == b"double"
        assert _mat_field(g["time_ns"]).tolist() == ref.time_ns.tolist()
        t_s = _mat_field(g["time_s"])
        assert np.allclose(np.diff(t_s), np.diff(ref.time_ns) / 1e9) and 0 <= t_s[0] < 10
        for name in ref.columns:
            got = _mat_field(g[name])
            want = ref[name]
            if want.dtype.kind == "U":
                assert got == want.tolist(), name
            else:
                assert np.array_equal(got, want, equal_nan=True), name
        assert g["gps_time_ns"].attrs["MATLAB_class"] == b"int64"  # ns exact, not rounded through double
        assert _mat_char(g["units"]["lat_deg"]) == "deg" and _mat_char(g["units"]["time_ns"]) == "ns"
        assert _mat_char(g["units"]["sol_status"]) == "" and g["units"].attrs["MATLAB_class"] == b"struct"
        assert g["lat_deg"].attrs["units"] == b"deg"
        # events: text columns as char matrices
        ev = h["events"]
        evt = session._table("/rig/events")
        order = np.argsort(_mat_field(ev["time_ns"]), kind="stable")  # the dataset sorts by time, the export
        assert [_mat_field(ev["text"])[i] for i in order] == evt["text"].tolist()  # keeps the recorded order
        # CAN roles and DAQ volts equal the dataset's decode
        roles = h["can_can0_roles"]
        assert _mat_char(roles["units"]["yaw_rate_radps"]) == "rad/s"
        yaw, ok = _mat_field(roles["yaw_rate_radps"]), _mat_field(roles["yaw_rate_ok"])
        assert roles["yaw_rate_ok"].attrs["MATLAB_class"] == b"logical"
        ref_yaw = session.can_roles("can0")["yaw_rate"]
        assert np.sort(yaw[ok]).tolist() == pytest.approx(np.sort(ref_yaw.values[ref_yaw.ok]).tolist())
        d1 = session.daq("daq1")
        name = d1.channel_names[0]
        daq = h["daq_daq1"]
        assert daq[f"{name}_V"].attrs["MATLAB_class"] == b"single"
        assert np.allclose(_mat_field(daq[f"{name}_V"]), d1.channel(name), atol=1e-6)
        # raw CAN frames, byte-equal to the recorded ones
        fr = h["can_can0_frames"]
        rec = session.can_frames("can0").records
        assert _mat_char(fr["channel"]) == "can0"
        data = _mat_field(fr["data"])
        assert fr["data"].shape == (8, rec.shape[0]) and fr["data"].attrs["MATLAB_class"] == b"uint8"
        assert np.array_equal(data, rec["data"])
        assert _mat_field(fr["can_id"]).tolist() == (rec["can_id"] & 0x1FFFFFFF).tolist()
        assert _mat_field(fr["dlc"]).tolist() == rec["dlc"].tolist()
        assert _mat_field(fr["len"]).tolist() == rec["len"].tolist()
        assert _mat_field(fr["host_ns"]).tolist() == rec["host_ts_ns"].tolist()
        assert _mat_field(fr["device_ns"]).tolist() == rec["device_ts_ns"].tolist()
        # the recorded block time (live time base) vs the dataset's after-the-fact mapping: within 1 ms
        assert np.max(np.abs(_mat_field(fr["time_ns"]) - session.can_frames("can0").time_ns)) < 1_000_000
        s = h["session"]
        assert _mat_char(s["name"]) == ds.base.name and s["start_ns"].shape == (1, 1)
        if chunk_bytes == 4096:  # streamed: many chunks per field, each (1, rows) along MATLAB's rows
            ds_t = daq["time_ns"]
            assert ds_t.chunks[0] == 1 and ds_t.id.get_num_chunks() == -(-ds_t.shape[1] // ds_t.chunks[1]) > 5
    # this short synthetic session has no valid RTK baseline: the sideslip struct is skipped, said in a warning
    assert any(w.startswith("sideslip: reference and estimate not exported") for w in report.warnings)


def test_mat73_loads_with_mat73_and_hdf5storage(ds: Synth, tmp_path: Path) -> None:
    """Two independent MAT v7.3 readers load the file: mat73 (MATLAB's struct/char/logical/numeric classes) and
    hdf5storage (which also follows MATLAB_fields and reads the char matrices row by row)."""
    mat73 = pytest.importorskip("mat73")
    hdf5storage = pytest.importorskip("hdf5storage")
    report = export_mat(ds.base, tmp_path)
    path = report.files[0].path
    session = load_session(ds.base)
    ref = session._table("/gnss/rover_a/bestpos")
    m = mat73.loadmat(str(path))
    b = m["gnss_rover_a_bestpos"]
    assert np.asarray(b["lat_deg"]).tolist() == ref["lat_deg"].tolist()
    assert b["units"]["lat_deg"] == "deg" and b["units"]["sol_status"] == ""
    w = len(ref["sol_status"][0].rstrip())
    # mat73 joins a char matrix's characters in MATLAB's column-major order: N rows, W columns
    sol = np.asarray(list(b["sol_status"])).reshape(-1, len(ref)).T
    assert ["".join(r).rstrip() for r in sol] == ref["sol_status"].tolist() and w > 0
    rec = session.can_frames("can0").records
    assert np.array_equal(np.asarray(m["can_can0_frames"]["data"]), rec["data"])
    assert m["session"]["name"] == ds.base.name
    h = hdf5storage.loadmat(str(path))
    hb = h["gnss_rover_a_bestpos"]
    assert list(hb.dtype.names[:3]) == ["time_ns", "time_s", "host_ns"]
    assert [str(x).rstrip() for x in np.ravel(hb["sol_status"][0])] == ref["sol_status"].tolist()
    assert np.ravel(hb["lat_deg"][0]).tolist() == ref["lat_deg"].tolist()


def test_mat73_fields_stream_in_whole_chunks_and_widen(tmp_path: Path) -> None:
    """A field never buffers a whole chunk (bounded memory, whatever the rows); longer text and CAN FD payloads
    arriving later widen the matrix, the earlier rows padded with spaces / zeros."""
    import h5py

    from rig.export.mat import _Struct

    rng = np.random.default_rng(1)
    path = tmp_path / "w.h5"
    words = np.asarray(["a", "bb", "", "ccc", "a much longer text", "β°"], dtype=object)
    with h5py.File(path, "w", rdcc_nbytes=0) as f:
        st = _Struct(f, "s", chunk_bytes=1024)
        sent_t, sent_txt, sent_data = [], [], []
        for k in range(40):
            n = int(rng.integers(1, 300))
            t = np.arange(n, dtype=np.int64) + 10_000 * k
            txt = words[rng.integers(0, 2 if k < 10 else len(words), n)]
            width = 8 if k < 20 else 64
            data = rng.integers(0, 256, (n, width), dtype=np.uint8)
            st.append({"time_ns": t, "text": txt, "data": data}, {"time_ns": "ns"})
            sent_t.append(t)
            sent_txt.extend(txt.tolist())
            sent_data.append(np.pad(data, ((0, 0), (0, 64 - width))))
            for fld in st.fields.values():
                assert fld.n_pending < fld.chunk_rows  # whole chunks went out as soon as there were any
        st.close()
    with h5py.File(path, "r") as f:
        g = f["s"]
        assert _mat_field(g["time_ns"]).tolist() == np.concatenate(sent_t).tolist()
        assert _mat_field(g["text"]) == sent_txt
        assert g["text"].shape[0] == len("a much longer text")
        assert np.array_equal(_mat_field(g["data"]), np.concatenate(sent_data))
        assert _fields(g) == ["time_ns", "text", "data", "units"]
        assert _mat_char(g["units"]["time_ns"]) == "ns" and _mat_char(g["units"]["text"]) == ""


def test_mat_v5_through_scipy(ds: Synth, tmp_path: Path) -> None:
    """--mat-version 5: scipy.io reads the same structs back (text as cell arrays), raw CAN frames included."""
    from scipy.io import loadmat

    report = export_mat(ds.base, tmp_path, version="5")
    assert report.files[0].source.startswith("MAT v5")
    m = loadmat(report.files[0].path, simplify_cells=True)
    bestpos = m["gnss_rover_a_bestpos"]
    session = load_session(ds.base)
    ref = session._table("/gnss/rover_a/bestpos")
    assert np.asarray(bestpos["lat_deg"]).tolist() == ref["lat_deg"].tolist()
    assert np.asarray(bestpos["gps_time_ns"]).tolist() == ref["gps_time_ns"].tolist()
    assert list(bestpos["sol_status"]) == ref["sol_status"].tolist()
    assert bestpos["units"]["lat_deg"] == "deg" and bestpos["units"]["time_ns"] == "ns"
    assert m["can_can0_roles"]["units"]["yaw_rate_radps"] == "rad/s"
    frames = m["can_can0_frames"]
    assert frames["channel"] == "can0"
    assert np.array_equal(frames["data"], session.can_frames("can0").records["data"])
    assert m["session"]["name"] == ds.base.name
    with pytest.raises(ConfigError, match="--mat-version"):
        export_mat(ds.base, tmp_path / "x", version="7")


def test_mat_sideslip_on_one_time_vector(tmp_path: Path) -> None:
    """A simulated drive validates: reference, estimate and error share one time vector in the MAT file (v7.3,
    read with h5py and mat73; and v5, read with scipy.io)."""
    import h5py
    from scipy.io import loadmat

    run = record_validating_drive(tmp_path)
    report = export_mat(run, tmp_path / "mat", topics=["gnss_*"])
    assert "sideslip" in report.files[0].source
    with h5py.File(report.files[0].path, "r") as h:
        s = h["sideslip"]
        t, ref, est, err = (_mat_field(s[k]) for k in ("time_s", "reference_rad", "estimate_rad", "error_rad"))
        assert _mat_char(s["units"]["error_rad"]) == "rad"
        assert _mat_field(s["time_ns"]).shape == t.shape
    assert t.size == ref.size == est.size == err.size > 100
    ok = np.isfinite(err)
    assert ok.sum() > 100 and np.allclose(err[ok], est[ok] - ref[ok])
    mat73 = pytest.importorskip("mat73")
    m = mat73.loadmat(str(report.files[0].path))["sideslip"]
    assert np.array_equal(np.asarray(m["error_rad"]), err, equal_nan=True)
    v5 = export_mat(tmp_path / "run", tmp_path / "mat5", topics=["gnss_*"], version="5")
    s5 = loadmat(v5.files[0].path, simplify_cells=True)["sideslip"]
    assert np.array_equal(np.asarray(s5["error_rad"]), err, equal_nan=True)
    assert s5["units"]["error_rad"] == "rad"


def test_groups_stream_in_bounded_batches(ds: Synth) -> None:
    """Batches never exceed the chunk size (plus one message's rows), whatever the session length."""
    sizes: dict[str, list[int]] = {}
    for chunk in iter_groups(open_stream(ds.base), chunk_rows=40):
        sizes.setdefault(chunk.group, []).append(len(chunk))
    assert len(sizes["gnss_rover_a_bestpos"]) > 1 and max(sizes["gnss_rover_a_bestpos"]) <= 40
    assert max(sizes["daq_daq1"]) <= 100 * 1 + 100  # one DAQ block counts as 100 rows


def test_cli_export_formats(ds: Synth, tmp_path: Path) -> None:
    res = runner.invoke(app, ["export", str(ds.base), "--format", "parquet", "--out", str(tmp_path / "pq"),
                              "--topics", "truth"])
    assert res.exit_code == 0, res.output
    assert "truth/session=" in res.output and (tmp_path / "pq" / "truth").is_dir()
    res = runner.invoke(app, ["export", str(ds.base), "--topics", "truth"])
    assert res.exit_code != 0
    res = runner.invoke(app, ["export", str(ds.base), "--format", "csv", "--out", str(tmp_path / "csv")])
    assert res.exit_code == 0 and (tmp_path / "csv" / "can_can0_roles.csv").is_file()
    for version in ("7.3", "5"):
        res = runner.invoke(app, ["export", str(ds.base), "--format", "mat", "--mat-version", version, "--topics",
                                  "truth", "--out", str(tmp_path / f"mat{version}")])
        assert res.exit_code == 0, res.output
        assert f"(MAT v{version}, " in res.output and (tmp_path / f"mat{version}" / f"{ds.base.name}.mat").is_file()
    res = runner.invoke(app, ["export", str(ds.base), "--format", "mat", "--mat-version", "7", "--out",
                              str(tmp_path / "mat7")])
    assert res.exit_code != 0 and isinstance(res.exception, ConfigError) and "--mat-version" in str(res.exception)
    assert not (tmp_path / "mat7").exists()  # refused before anything is read or written


def test_mdf4_without_asammdf_names_the_extra(ds: Synth, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    from vsccore.errors import ConfigError

    monkeypatch.setitem(sys.modules, "asammdf", None)
    with pytest.raises(ConfigError, match=r"vsc-rig\[mf4\]"):
        export_mdf4(ds.base, tmp_path)


def _damaged_copy(ds: Synth, out: Path, where: str) -> tuple[Path, int, int, set[str], int]:
    """The session's parts copied into ``out`` with one bit flipped in part 0: in the compressed data of a
    chunk after the first that holds rover A's BESTPOS (``chunk``) or in the summary (``summary``); (base,
    that chunk's number, its offset, the topics it holds, the number of parts)."""
    import shutil

    from mcap.reader import make_reader

    from rig.store import find_parts, scan_part

    parts = find_parts(ds.base)
    for p in parts:
        shutil.copy(p, out / p.name)
    scan = scan_part(parts[0])
    with open(parts[0], "rb") as f:
        summary = make_reader(f).get_summary()
    assert scan.problem is None and summary is not None and len(scan.chunks) > 6
    k = next(i for i, ci in enumerate(summary.chunk_indexes) if i > 0 and any(
        summary.channels[cid].topic == "/gnss/rover_a/bestpos" for cid in ci.message_index_offsets))
    assert k < len(scan.chunks) - 1
    c = scan.chunks[k]
    in_chunk = {summary.channels[cid].topic for cid in summary.chunk_indexes[k].message_index_offsets}
    raw = bytearray((out / parts[0].name).read_bytes())
    if where == "chunk":
        at = c.offset + c.length - 30
    else:
        footer = len(raw) - 8 - 29
        at = int.from_bytes(raw[footer + 9 : footer + 17], "little") + 40  # inside the summary section
    raw[at] ^= 0x10
    (out / parts[0].name).write_bytes(bytes(raw))
    return out / ds.base.name, k, c.offset, in_chunk, len(parts)


@pytest.mark.parametrize("where", ["chunk", "summary"])
def test_damaged_part_exports_every_intact_chunk_and_names_the_damage(ds: Synth, tmp_path: Path, where: str
                                                                       ) -> None:
    """A bit flip in a recorded part: the export reads every intact chunk, before and after the damage, and
    warns with the session reader's description of it (was: refused, or stopped at the damage)."""
    import pyarrow.dataset as pads

    import rig.core.topics as T  # noqa: N812 - short alias

    (tmp_path / "s").mkdir()
    base, k, chunk_offset, in_chunk, n_parts = _damaged_copy(ds, tmp_path / "s", where)
    damaged = load_session(base)  # the dataset reader: every intact chunk, with the damage in its warnings
    full = load_session(ds.base)
    report = export_parquet(base, tmp_path / "pq")
    if where == "chunk":
        (note,) = [w for w in report.warnings if f"damaged chunk {k} " in w]
        assert f"offset {chunk_offset}" in note and f"synth.000.mcap (part 1 of {n_parts})" in note
        assert "/gnss/rover_a/bestpos" in note
        assert any(f"damaged chunk {k} " in w for w in damaged.warnings)
    else:
        (note,) = [w for w in report.warnings if "damaged summary" in w]
        assert "no data lost" in note
    groups = {f.source: f.records for f in report.files}
    lost = 0
    for topic, n_full in full.topic_counts.items():
        if not topic.startswith("/gnss/") or topic.endswith(("/raw", "/fix")):
            continue
        group = "gnss_" + topic.removeprefix("/gnss/").replace("/", "_")
        tbl = pads.dataset(tmp_path / "pq" / group, partitioning="hive").to_table()
        ref = damaged._table(topic)
        assert tbl.column("time_ns").to_numpy().tolist() == ref.time_ns.tolist(), topic
        assert groups[group] == len(ref) and damaged.topic_counts.get(topic, 0) == len(ref)
        lost += n_full - len(ref)
        if topic not in in_chunk:  # in other chunks only, before or after the damaged one: all there
            assert len(ref) == n_full, topic
    assert (lost > 0) == (where == "chunk")
    frames = pads.dataset(tmp_path / "pq" / "can_can0_frames", partitioning="hive").to_table()
    assert frames.num_rows == damaged.can_frames("can0").records.shape[0]
    if T.can_frames("can0") not in in_chunk:
        assert frames.num_rows == full.can_frames("can0").records.shape[0]
    res = runner.invoke(app, ["export", str(base), "--format", "mat", "--out", str(tmp_path / "mat")])
    assert res.exit_code == 0, res.output
    assert (f"damaged chunk {k} " if where == "chunk" else "damaged summary") in res.output


def test_can_counter_checks_run_on_across_batches(ds: Synth) -> None:
    """A counter jump on the first frame of a batch is flagged, as when the whole bus is decoded at once (was:
    each batch decoded alone, so its first frame was never checked)."""
    import rig.core.topics as T  # noqa: N812 - short alias
    from drivers.can.dbc import parse_dbc_text
    from drivers.can.roles import encode_role_frame
    from rig.data.stream import can_chunk, role_decoding, roles_chunk

    db = parse_dbc_text(DBC.read_text())
    stream = open_stream(ds.base)
    rd_one = role_decoding(ds.base, stream.attachments, "can0")  # the session's attached DBC and role map
    rm = rd_one.decoder.rolemap
    n = 100
    counters = [k if k < 50 else k + 3 for k in range(n)]  # frames lost just before frame 50
    payloads = np.stack([np.frombuffer(encode_role_frame(db, rm, "ESC_SensorCluster",
                                                         {"yaw_rate": 0.01 * k, "lat_accel": 0.0}, counter=c),
                                       dtype=np.uint8) for k, c in enumerate(counters)])
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 10_000_000

    def block(sl: slice) -> bytes:
        m = t[sl].size
        return T.pack_can_columns(t[sl], t[sl], np.full(m, 257), np.full(m, int(T.CanFlag.RX)), np.full(m, 8),
                                  np.full(m, 8), payloads[sl])

    whole = roles_chunk(rd_one, can_chunk("can_can0_frames", [int(t[0])], [block(slice(0, n))]))
    rd = role_decoding(ds.base, stream.attachments, "can0")
    first = roles_chunk(rd, can_chunk("can_can0_frames", [int(t[0])], [block(slice(0, 50))]))
    second = roles_chunk(rd, can_chunk("can_can0_frames", [int(t[50])], [block(slice(50, n))]))
    assert whole is not None and first is not None and second is not None
    ok = whole.columns["yaw_rate_ok"]
    assert not ok[50] and ok[:50].all() and ok[51:].all()  # the decoder flags the jump over the whole bus
    assert np.concatenate([first.columns["yaw_rate_ok"], second.columns["yaw_rate_ok"]]).tolist() == ok.tolist()
    assert np.concatenate([first.time_ns, second.time_ns]).tolist() == whole.time_ns.tolist()
    assert len(second) == 50  # the frame carried from the first batch is not exported twice


def test_unchunked_mcap_file_exports(tmp_path: Path) -> None:
    """Messages outside chunks (an MCAP file written unchunked by another tool) are exported too (the chunk
    reader has nothing to index there)."""
    import json

    from mcap.writer import Writer

    import rig.core.topics as T  # noqa: N812 - short alias

    spec = T.spec_for_topic(T.gnss_bestvel("rx"))[0].schema
    with open(tmp_path / "hand.mcap", "wb") as f:
        w = Writer(f, use_chunking=False)
        w.start()
        cid = w.register_channel(T.gnss_bestvel("rx"), spec.message_encoding,
                                 w.register_schema(spec.name, spec.schema_encoding, spec.data))
        for k in range(5):
            w.add_message(cid, 10**18 + k, json.dumps({"gps_time_ns": k, "hor_speed_mps": 1.5 * k}).encode(),
                          10**18 + k, sequence=k)
        w.finish()
    report = export_parquet(tmp_path / "hand.mcap", tmp_path / "pq")
    import pyarrow.dataset as pads

    tbl = pads.dataset(tmp_path / "pq" / "gnss_rx_bestvel", partitioning="hive").to_table()
    assert [(f.source, f.records) for f in report.files] == [("gnss_rx_bestvel", 5)]
    assert tbl.column("hor_speed_mps").to_pylist() == [1.5 * k for k in range(5)]
    assert tbl.column("gps_time_ns").to_pylist() == list(range(5))
