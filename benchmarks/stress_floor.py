"""The host's own ratio for issue 15's §5: a purely CPU-bound dummy suite, idle and under 6 busy processes.

The README's test command (6 pytest-xdist workers on 2 cores) must finish under 6 CPU-bound background
processes within 2× its idle time. The kernel shares a busy machine per thread, so 6 busy workers get
about half of it; what the ratio is beyond that depends on the host (cache, scheduler slices) and on the
suite (work that grows with wall time). This script measures the first part alone: 60 modules of 20
tests, each a fixed amount of Python and numpy work — tight loops and matrix products, and object work
(dicts, strings, JSON, small arrays) whose working set the time slices of a busy machine keep evicting —
with no threads, no waiting and no simulated devices, run
with the README's pytest options idle and under the same stress load as ``stress_suite.sh``, and prints
wall time, CPU time and the loaded/idle ratio. The suite's own ratio (``stress_suite.sh``) beyond this
one is CPU the suite spends more under load.

Usage: .venv/bin/python benchmarks/stress_floor.py [--modules 60] [--loops 1000000]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _cpu import children_cpu_s

_TEST = '''import json

import numpy as np
import pytest


@pytest.mark.parametrize("k", range(10))
def test_burn(k):
    s = 0
    for j in range({loops}):
        s += j * k
    a = np.random.default_rng(k).random((300, 300))
    for _ in range(3):
        a = a @ a.T
        a /= np.abs(a).max()
    assert s >= 0 and a.shape == (300, 300)


@pytest.mark.parametrize("k", range(10))
def test_objects(k):
    # what most of the suite does: objects, dicts, strings, small arrays (a working set beyond the L1/L2)
    rows = [{{"t": i * 1e-3, "name": f"sig{{i % 97}}", "v": [i, k, i * k]}} for i in range({loops} // 20)]
    text = json.dumps(rows)
    back = json.loads(text)
    x = np.asarray([r["v"][0] for r in back], dtype=np.float64)
    assert len(back) == len(rows) and float(np.sum(np.diff(np.sort(x)))) >= 0
'''


def _run(folder: Path) -> tuple[float, float]:
    """Wall and CPU seconds (children: pytest and its workers) of one run of the dummy suite."""
    before = children_cpu_s()
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "6", "--dist", "loadscope",
                           "-p", "no:cacheprovider"], cwd=folder, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"dummy suite failed:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    return wall, children_cpu_s() - before


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modules", type=int, default=60)
    ap.add_argument("--loops", type=int, default=1_000_000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="stress-floor-") as tmp:
        folder = Path(tmp)
        (folder / "pytest.ini").write_text("[pytest]\n")
        for i in range(args.modules):
            (folder / f"test_m{i:03d}.py").write_text(_TEST.format(loops=args.loops))
        idle = _run(folder)
        print(f"idle:   wall {idle[0]:6.1f} s, CPU {idle[1]:6.1f} s", flush=True)
        stress = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(6)]
        try:
            loaded = _run(folder)
        finally:
            for p in stress:
                p.kill()
            for p in stress:
                p.wait()
        print(f"loaded: wall {loaded[0]:6.1f} s, CPU {loaded[1]:6.1f} s (6 busy processes, {os.cpu_count()} cores)")
        print(f"ratio loaded/idle {loaded[0] / idle[0]:.2f}×, CPU {loaded[1] / idle[1] - 1:+.1%} under load")
    return 0


if __name__ == "__main__":
    sys.exit(main())
