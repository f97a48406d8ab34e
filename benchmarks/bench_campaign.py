"""``rig campaign`` throughput: sessions per minute, serial (in-process) against a two-worker LocalCluster.

The sessions are the campaign tests' synthetic ones (:func:`tests.campaign.synth.make_session`: the real Recorder,
20 Hz GNSS on both rovers, 50 Hz CAN with the VSC estimate, simulator truth; ≈ 20 s drives), built once into
``--cache`` (default ``$TMPDIR/vsc_rig_bench_campaign``). Each mode runs into a fresh output directory, so nothing
comes from the campaign cache; the LocalCluster's start-up (worker processes importing the analysis) is timed
separately and also included in its overall figure. Also printed: a re-run with everything cached.

Run: ``.venv/bin/python benchmarks/bench_campaign.py [--sessions 20] [--workers 2] [--estimators 1]``
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.campaign.synth and its estimators

from rig.workflows.campaign import CampaignOptions, find_sessions, run_campaign
from tests.campaign.synth import make_session


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--estimators", type=int, choices=(1, 2), default=1,
                    help="1: the recorded estimate; 2: plus tests.campaign.estimators:linear_ay")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vsc_rig_bench_campaign")
    args = ap.parse_args()
    src = args.cache / f"sessions{args.sessions}"
    if len(list(src.glob("*.000.mcap"))) != args.sessions:
        shutil.rmtree(src, ignore_errors=True)
        t0 = time.perf_counter()
        for i in range(args.sessions):
            make_session(src, i)
        print(f"built {args.sessions} sessions in {time.perf_counter() - t0:.1f} s ({src})")
    sessions = find_sessions([src])
    ests: tuple[str | None, ...] = (None,) if args.estimators == 1 else (None, "tests.campaign.estimators:linear_ay")
    opts = CampaignOptions(estimators=ests)
    out = args.cache / "out"
    print(f"{len(sessions)} sessions, {len(ests)} estimator(s), load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} CPUs")

    shutil.rmtree(out, ignore_errors=True)
    r = run_campaign(sessions, out / "serial", opts, scheduler="serial", report=False)
    print(f"serial:          {r.elapsed_s:6.1f} s  {60 * len(sessions) / r.elapsed_s:6.1f} sessions/min")

    from distributed import Client, LocalCluster

    t0 = time.perf_counter()
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster:
        with Client(cluster) as client:
            client.run(lambda: __import__("rig.evaluate.validate"))  # what every worker pays once
        startup = time.perf_counter() - t0
        r = run_campaign(sessions, out / "dist", opts, scheduler=cluster.scheduler_address, report=False)
        total = startup + r.elapsed_s
        rate = 60 * len(sessions) / r.elapsed_s
        print(f"{args.workers} workers:       {r.elapsed_s:6.1f} s  {rate:6.1f} sessions/min "
              f"(warm cluster); start-up {startup:.1f} s, with it {60 * len(sessions) / total:.1f} sessions/min")
        r = run_campaign(sessions, out / "dist", opts, scheduler=cluster.scheduler_address, report=False)
        print(f"re-run (cached): {r.elapsed_s:6.1f} s  {60 * len(sessions) / r.elapsed_s:6.1f} sessions/min "
              f"({r.cached} cached, {r.computed} computed)")


if __name__ == "__main__":
    main()
