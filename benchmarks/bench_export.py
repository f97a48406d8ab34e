"""Export a one-hour session to Parquet (issue 17's target: ≤ 30 s, peak RSS ≤ 1 GB), and optionally MDF4/MAT/CSV.

``mat`` is MAT v7.3 (HDF5, streamed), ``mat5`` MAT v5 through scipy.io (each group held in memory), both
without the sideslip struct (``validation=False``); ``mat+sideslip`` is MAT v7.3 as ``rig export --format mat``
runs it by default, with the ``sideslip`` struct (reference, estimate and error on one time vector): read with
``rig.data.inputs.load_inputs(bounded_memory=True)`` (the GNSS logs, and the three CAN roles it needs decoded a
batch of blocks at a time) and computed without the rest of ``rig validate``. Issue 17's ≤ 1 GB applies to it
too. (Before, through ``load_inputs`` + ``validate_session``: 3.3 GB peak on the one-hour session, 1.8 GB of it
reading the whole session, 1.5 GB more in the steering reconstruction.)

The session is the one :mod:`benchmarks.bench_validate` synthesises with the real Recorder (three GNSS
receivers at 20 Hz with raw bytes, a 500 kbit/s CAN bus at 2000 frames/s with the simulated ECU's frames,
eight DAQ channels at 1 kHz, the optical topic at 100 Hz), built once and cached (default
``$TMPDIR/vsc_rig_bench_export/<minutes>min``).

Each export runs in a child process (``python -c``) so that its peak RSS is its own: the child's
``resource.getrusage(RUSAGE_SELF).ru_maxrss`` as it ends (the children's counter would give the largest child
so far), its CPU time (user + system) from ``RUSAGE_CHILDREN`` around it, and wall time around it. The
machine's load average is printed before and after each run: on a shared machine the wall time is the CPU time
stretched by the load.

Run: ``.venv/bin/python benchmarks/bench_export.py [--minutes 60] [--formats parquet,mdf4] [--rebuild]``
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _cpu import children_cpu_s

REPO = Path(__file__).resolve().parents[1]
TARGET_S = 30.0
TARGET_RSS_MB = 1024.0

_CHILD = """
import resource
import sys
from rig.export.csv import export_csv
from rig.export.mat import export_mat
from rig.export.mdf4 import export_mdf4
from rig.export.parquet import export_parquet
fmt = sys.argv[1]
fn = {"parquet": export_parquet, "mdf4": export_mdf4, "mat": export_mat, "mat5": export_mat, "mat+sideslip": export_mat,
      "csv": export_csv}[fmt]
kw = {"validation": fmt == "mat+sideslip"} if fmt.startswith("mat") else {}
if fmt == "mat5":
    kw["version"] = "5"
seen = []
if fmt != "csv":  # the CLI's progress bar is driven by this callback: count its updates and how far they got
    kw["progress"] = lambda done, start, end: seen.append((done - start) / max(end - start, 1))
report = fn(sys.argv[2], sys.argv[3], **kw)
print(sum(f.records for f in report.files), sum(f.bytes for f in report.files), len(report.files), len(seen),
      max(seen, default=-1.0), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vsc_rig_bench_export")
    ap.add_argument("--formats", default="parquet",
                    help="Comma-separated: parquet, mdf4, mat, mat5, mat+sideslip, csv.")
    ap.add_argument("--rebuild", action="store_true")
    args = ap.parse_args()
    cache: Path = args.cache / f"{args.minutes:g}min"
    if args.rebuild and cache.exists():
        shutil.rmtree(cache)
    if not list(cache.glob("hour.*.mcap")):
        sys.path.insert(0, str(REPO))
        from benchmarks.bench_validate import build

        print(f"building the synthetic session in {cache} (once) ...")
        build(cache, args.minutes)
    base = cache / "hour"
    size = sum(p.stat().st_size for p in cache.glob("hour.*.mcap"))
    print(f"session {base} ({size / 1e6:.0f} MB, {args.minutes:g} min)")
    for fmt in args.formats.split(","):
        out = Path(tempfile.mkdtemp(prefix=f"bench_export_{fmt}_"))
        try:
            before = children_cpu_s()
            load0 = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", _CHILD, fmt, str(base), str(out)], cwd=REPO,
                                 capture_output=True, text=True, check=False)
            wall = time.perf_counter() - t0
            if res.returncode != 0:
                raise SystemExit(f"{fmt} export failed:\n{res.stderr}")
            last = res.stdout.splitlines()[-1].split()  # asammdf prints too
            rows, nbytes, nfiles, updates = (int(x) for x in last[:4])
            reached = float(last[4])
            cpu = children_cpu_s() - before
            rss_mb = int(last[5]) / 1024.0  # Linux: kB
            verdict = "OK" if wall <= TARGET_S and rss_mb <= TARGET_RSS_MB else "OVER TARGET"
            print(f"{fmt:<12} {wall:7.1f} s wall  {cpu:7.1f} s CPU  peak RSS {rss_mb:7.0f} MB  {rows} rows  "
                  f"{nbytes / 1e6:.0f} MB in {nfiles} files  (target ≤ {TARGET_S:g} s, ≤ {TARGET_RSS_MB:g} MB: "
                  f"{verdict}; load average {load0:.1f} → {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")
            if updates:
                print(f"{'':<12} progress bar: {updates} updates, reached {reached:.0%}")
        finally:
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
