"""Start-up time of the ``rig`` command, as whole processes (what a user waits for).

Measures, median of ``--runs`` runs each, wall clock of a fresh process:

- ``python -c pass`` and ``python -c "import typer"``: the floors (interpreter, and the CLI library
  with rich, that every ``rig`` command pays before any code of ours runs);
- ``rig --help``: goal ≤ 0.3 s (answered from the command table, without typer);
- ``rig info --help``: the typer path of one command (typer, rich and that command's module);
- ``rig info SESSION`` on a 30-minute session: goal ≤ 0.5 s; once with the synthetic session's 8 KiB
  chunks (4500 chunk indexes, of which the few holding events are decompressed) and once with the
  recorder's default 4 MiB chunks (few chunk indexes, every one decompressed: each holds events);
- ``rig info --verify SESSION``: the thorough path (every chunk's CRC, verdicts computed from the data),
  for reference, ``--verify-runs`` runs.

Bytecode: the processes run with their bytecode cached (``PYTHONPYCACHEPREFIX`` in the cache folder,
one unmeasured warm-up run per row), as an installed ``rig`` runs; a development shell with
``PYTHONDONTWRITEBYTECODE=1`` compiles every module of the project on every start, which costs
more than some of the goals (``--no-bytecode-cache`` measures that). The load average is printed
before and after: on a shared machine the floors say how much of each figure is not ``rig``'s.

The 30-minute session is the synthetic one of the ``rig info`` tests (``tests/inspect/synth.py``:
two rovers at 20 Hz through the real recorder), written once into ``--cache`` and reused. The
machine may be shared: the floors say how much of each figure is not ``rig``'s. Run from the
repository root::

    python benchmarks/bench_startup.py [--runs 9] [--cache /tmp/vsc-rig-bench-startup] [--baseline DIR]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _cpu import children_cpu_s

ROOT = Path(__file__).resolve().parents[1]
HELP_GOAL_S = 0.3
INFO_GOAL_S = 0.5
SESSION_S = 1800.0
SMALL_CHUNK = 8 * 1024
"""The synthetic session's own chunk size: 4500 chunks, the most index work per message."""
DEFAULT_CHUNK = 4 * 1024 * 1024
"""The recorder's default (RecorderOptions.chunk_size): every chunk holds events, so each is decompressed."""


def _session(cache: Path, chunk_size: int) -> Path:
    """The 30-minute session with ``chunk_size`` chunks, written once into ``cache``."""
    name = "run30min" if chunk_size == SMALL_CHUNK else f"run30min-chunk{chunk_size}"
    done = cache / f"{name}.done"
    if not done.exists() and chunk_size == SMALL_CHUNK and (cache / "done").exists():
        done.write_text("ok\n")  # written by an earlier version of this script
    if not done.exists():
        cache.mkdir(parents=True, exist_ok=True)
        sys.path.insert(0, str(ROOT))
        from tests.inspect.synth import write_session

        t0 = time.perf_counter()
        write_session(cache, name=name, duration_s=SESSION_S, rollover_bytes=None, chunk_size=chunk_size)
        print(f"(wrote the {SESSION_S / 60:.0f}-minute session with {chunk_size // 1024} KiB chunks in "
              f"{time.perf_counter() - t0:.1f} s)")
        done.write_text("ok\n")
    files = sorted(cache.glob(f"{name}.*.mcap"))
    if not files:
        raise SystemExit(f"no {name}.*.mcap in {cache}: delete the folder and run again")
    return files[0]


def _time(argv: list[str], runs: int, env: dict[str, str], cwd: Path = ROOT) -> tuple[float, float, float]:
    """(median wall, best wall, median CPU time user+sys) of ``runs`` fresh processes.

    The CPU time is what the process itself needed: on a loaded machine it stays close to the wall
    time of a quiet one, which waiting for a core does not add to.
    """
    subprocess.run(argv, capture_output=True, env=env, cwd=cwd, check=False)  # warm-up: bytecode, page cache
    times = []
    cpu = []
    for _ in range(runs):
        c0 = children_cpu_s()
        t0 = time.perf_counter()
        proc = subprocess.run(argv, capture_output=True, env=env, cwd=cwd, check=False)
        times.append(time.perf_counter() - t0)
        cpu.append(children_cpu_s() - c0)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.decode()[-500:]}")
    return statistics.median(times), min(times), statistics.median(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=9, help="runs per figure (median shown; default 9)")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/vsc-rig-bench-startup"),
                        help="folder for the generated 30-minute session")
    parser.add_argument("--verify-runs", type=int, default=3, help="runs of rig info --verify (default 3)")
    parser.add_argument("--baseline", type=Path, default=None,
                        help="a checkout of an earlier version (git archive REV | tar -x -C DIR): its rig --help "
                             "and rig info are timed too, under the same load (--baseline-runs runs)")
    parser.add_argument("--baseline-runs", type=int, default=3, help="runs of each baseline row (default 3)")
    parser.add_argument("--no-bytecode-cache", action="store_true",
                        help="keep the environment's bytecode setting (PYTHONDONTWRITEBYTECODE) instead of caching")
    args = parser.parse_args()
    session = _session(args.cache, SMALL_CHUNK)
    big = _session(args.cache, DEFAULT_CHUNK)
    env = {**os.environ, "COLUMNS": "120", "NO_COLOR": "1", "TERM": "dumb"}
    if not args.no_bytecode_cache:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(args.cache / "pycache")
    py = sys.executable
    size = f"{session.stat().st_size / 1e6:.0f} MB, {SESSION_S / 60:.0f} min, 8 KiB chunks"
    rows: list[tuple[str, list[str], float | None, int]] = [
        ("python -c pass", [py, "-c", "pass"], None, args.runs),
        ("python -c 'import typer'", [py, "-c", "import typer"], None, args.runs),
        ("rig --help", [py, "-m", "rig", "--help"], HELP_GOAL_S, args.runs),
        ("rig info --help", [py, "-m", "rig", "info", "--help"], None, args.runs),
        (f"rig info ({size})", [py, "-m", "rig", "info", str(session)], INFO_GOAL_S, args.runs),
        ("rig info (the same, 4 MiB chunks)", [py, "-m", "rig", "info", str(big)], INFO_GOAL_S, args.runs),
        ("rig info --verify", [py, "-m", "rig", "info", "--verify", str(session)], None, args.verify_runs),
    ]
    cached = "off (environment's setting)" if args.no_bytecode_cache else "cached"
    print(f"whole processes, median of N runs (wall clock); bytecode {cached}; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    for label, argv, goal, runs in rows:
        median, best, cpu = _time(argv, runs, env)
        verdict = "" if goal is None else f"  goal <= {goal:.1f} s: {'met' if median <= goal else 'NOT met'}"
        print(f"  {label:<40} N={runs:<3} median {median:6.3f} s  best {best:6.3f} s  CPU {cpu:6.3f} s{verdict}")
    if args.baseline is not None:
        old = args.baseline.resolve()
        old_env = {**env, "PYTHONPATH": str(old)}  # and run from there: `python -m` puts the cwd first
        if not args.no_bytecode_cache:
            old_env["PYTHONPYCACHEPREFIX"] = str(args.cache / "pycache-baseline")
        for label, argv in (("baseline: rig --help", [py, "-m", "rig", "--help"]),
                            (f"baseline: rig info ({size})", [py, "-m", "rig", "info", str(session)])):
            median, best, cpu = _time(argv, args.baseline_runs, old_env, cwd=old)
            print(f"  {label:<40} N={args.baseline_runs:<3} median {median:6.3f} s  best {best:6.3f} s  "
                  f"CPU {cpu:6.3f} s")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
