"""Start-up time of the ``rig`` command, as whole processes (what a user waits for).

Measures, median of ``--runs`` runs each, wall clock of a fresh process:

- ``python -c pass`` and ``python -c "import typer"``: the floors (interpreter, and the CLI library
  with rich, that every ``rig`` command pays before any code of ours runs);
- ``rig --help``: goal ≤ 0.3 s;
- ``rig info SESSION`` on a 30-minute session: goal ≤ 0.5 s.

The 30-minute session is the synthetic one of the ``rig info`` tests (``tests/inspect/synth.py``:
two rovers at 20 Hz through the real recorder), written once into ``--cache`` and reused. The
machine may be shared: the floors say how much of each figure is not ``rig``'s. Run from the
repository root::

    python benchmarks/bench_startup.py [--runs 9] [--cache /tmp/vsc-rig-bench-startup]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HELP_GOAL_S = 0.3
INFO_GOAL_S = 0.5
SESSION_S = 1800.0


def _session(cache: Path) -> Path:
    done = cache / "done"
    if not done.exists():
        cache.mkdir(parents=True, exist_ok=True)
        sys.path.insert(0, str(ROOT))
        from tests.inspect.synth import write_session

        t0 = time.perf_counter()
        write_session(cache, name="run30min", duration_s=SESSION_S, rollover_bytes=None)
        print(f"(wrote the {SESSION_S / 60:.0f}-minute session in {time.perf_counter() - t0:.1f} s)")
        done.write_text("ok\n")
    files = sorted(cache.glob("*.mcap"))
    if not files:
        raise SystemExit(f"no .mcap in {cache}: delete the folder and run again")
    return files[0]


def _time(argv: list[str], runs: int) -> tuple[float, float]:
    env = {**os.environ, "COLUMNS": "120", "NO_COLOR": "1", "TERM": "dumb"}
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        proc = subprocess.run(argv, capture_output=True, env=env, cwd=ROOT, check=False)
        times.append(time.perf_counter() - t0)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.decode()[-500:]}")
    return statistics.median(times), min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=9, help="runs per figure (median shown; default 9)")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/vsc-rig-bench-startup"),
                        help="folder for the generated 30-minute session")
    args = parser.parse_args()
    session = _session(args.cache)
    py = sys.executable
    rows = [
        ("python -c pass", [py, "-c", "pass"], None),
        ("python -c 'import typer'", [py, "-c", "import typer"], None),
        ("rig --help", [py, "-m", "rig", "--help"], HELP_GOAL_S),
        (f"rig info ({session.stat().st_size / 1e6:.0f} MB, {SESSION_S / 60:.0f} min)", [py, "-m", "rig", "info",
                                                                                        str(session)], INFO_GOAL_S),
    ]
    print(f"whole processes, {args.runs} runs each (wall clock)")
    for label, argv, goal in rows:
        median, best = _time(argv, args.runs)
        verdict = "" if goal is None else f"  goal <= {goal:.1f} s: {'met' if median <= goal else 'NOT met'}"
        print(f"  {label:<32} median {median:6.3f} s  best {best:6.3f} s{verdict}")


if __name__ == "__main__":
    main()
