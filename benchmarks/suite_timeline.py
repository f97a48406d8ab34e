"""Where the test suite's CPU goes, idle against loaded: a per-test timeline and its comparison (issue 15's §5).

As a pytest plugin it writes one line per test to ``$SUITE_TIMELINE_DIR/tl-<worker>.txt``: node id, start
(``time.perf_counter``), wall s, the worker's own CPU s (``time.process_time``: every thread of it) and the
CPU s of its sub-processes that ended meanwhile (``RUSAGE_CHILDREN``). A thread a test leaves running is
charged to the tests after it; the collection and worker start-up before the first test are not in it.

    SUITE_TIMELINE_DIR=/tmp/tl-idle PYTHONPATH=benchmarks .venv/bin/python -m pytest -q -n 6 \\
        --dist loadscope -p suite_timeline
    SUITE_TIMELINE_DIR=/tmp/tl-load PYTHONPATH=benchmarks benchmarks/stress_suite.sh -p suite_timeline

As a script it compares two such runs: the totals, the tests and folders whose CPU grew most, and each
worker's end (the tail: how long the last worker ran after the others)::

    .venv/bin/python benchmarks/suite_timeline.py /tmp/tl-idle /tmp/tl-load [--top 30]
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import pytest
from _cpu import children_cpu_s

_out: IO[str] | None = None


def _file() -> IO[str]:
    global _out
    if _out is None:
        folder = Path(os.environ.get("SUITE_TIMELINE_DIR", "suite-timeline"))
        folder.mkdir(parents=True, exist_ok=True)
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        _out = open(folder / f"tl-{worker}.txt", "a", buffering=1, encoding="utf-8")  # noqa: SIM115 (the run's)
    return _out


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None, None, None]:
    w0, c0 = time.perf_counter(), time.process_time()
    ch0 = children_cpu_s()
    yield
    children = children_cpu_s() - ch0
    _file().write(f"{item.nodeid}\t{w0:.3f}\t{time.perf_counter() - w0:.4f}\t{time.process_time() - c0:.4f}"
                  f"\t{children:.4f}\n")


def pytest_unconfigure(config: pytest.Config) -> None:
    global _out
    if _out is not None:
        _out.close()
        _out = None


# --- the comparison ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Row:
    start: float
    wall: float
    cpu: float
    children: float
    worker: str

    @property
    def total_cpu(self) -> float:
        return self.cpu + self.children


def load(folder: Path) -> dict[str, Row]:
    rows: dict[str, Row] = {}
    files = sorted(folder.glob("tl-*.txt"))
    if not files:
        raise SystemExit(f"{folder}: no tl-*.txt (run the suite with -p suite_timeline and SUITE_TIMELINE_DIR)")
    for f in files:
        worker = f.stem[3:]
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
            fields = line.split("\t")
            if len(fields) != 5:
                raise SystemExit(f"{f}:{n}: expected 5 tab-separated fields, got {len(fields)}")
            start, wall, cpu, children = (float(x) for x in fields[1:])
            rows[fields[0]] = Row(start, wall, cpu, children, worker)
    return rows


def _workers(rows: dict[str, Row]) -> str:
    t0 = min(r.start for r in rows.values())
    ends: dict[str, float] = defaultdict(float)
    for r in rows.values():
        ends[r.worker] = max(ends[r.worker], r.start + r.wall - t0)
    last = max(ends.values())
    idle = sum(last - e for e in ends.values()) / len(ends)
    return (f"workers end {min(ends.values()):.0f}-{last:.0f} s after the first test "
            f"(mean wait for the last: {idle:.0f} s)")


def compare(idle: dict[str, Row], loaded: dict[str, Row], top: int) -> None:
    common = [k for k in idle if k in loaded]
    if not common:
        raise SystemExit("the two runs have no test in common")

    def total(rows: dict[str, Row], attr: str) -> float:
        return sum(getattr(rows[k], attr) for k in common)

    ci, cl = total(idle, "total_cpu"), total(loaded, "total_cpu")
    print(f"{len(common)} tests in both runs")
    print(f"idle:   test wall {total(idle, 'wall'):7.0f} s  CPU {ci:6.0f} s ({total(idle, 'children'):.0f} s of it in "
          f"sub-processes); {_workers(idle)}")
    print(f"loaded: test wall {total(loaded, 'wall'):7.0f} s  CPU {cl:6.0f} s ({total(loaded, 'children'):.0f} s of "
          f"it in sub-processes); {_workers(loaded)}")
    print(f"CPU loaded/idle: {cl / ci:.3f}")
    grown = sorted(common, key=lambda k: loaded[k].total_cpu - idle[k].total_cpu, reverse=True)
    print(f"\nthe {top} tests whose CPU grew most (s): growth | idle wall, CPU | loaded wall, CPU")
    for k in grown[:top]:
        ri, rl = idle[k], loaded[k]
        print(f"{rl.total_cpu - ri.total_cpu:7.2f} | {ri.wall:7.1f} {ri.total_cpu:6.1f} | {rl.wall:7.1f} "
              f"{rl.total_cpu:6.1f}  {k}")
    folders: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])
    for k in common:
        parts = k.split("::", 1)[0].split("/")
        f = "/".join(parts[:2]) if len(parts) > 2 else parts[-1]
        folders[f][0] += idle[k].total_cpu
        folders[f][1] += loaded[k].total_cpu
    print("\nCPU by folder (s): idle -> loaded (growth)")
    for f, (a, b) in sorted(folders.items(), key=lambda kv: kv[1][0] - kv[1][1]):
        print(f"{a:7.1f} -> {b:7.1f} ({100 * (b / a - 1) if a > 0 else 0:+5.1f} %)  {f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0])
    ap.add_argument("idle", type=Path)
    ap.add_argument("loaded", type=Path)
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args()
    compare(load(args.idle), load(args.loaded), args.top)


if __name__ == "__main__":
    main()
