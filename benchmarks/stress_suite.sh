#!/usr/bin/env bash
# Run the README's test command under a CPU stress load: 6 CPU-bound background processes (on a
# 2-core machine, as issue 15 measured), then print the suite's wall time. The stressors are ended
# by their process ids when the script ends, however it ends.
# Usage: benchmarks/stress_suite.sh [extra pytest args]
#        benchmarks/stress_suite.sh --demo OUT_DIR   (instead: benchmarks/bench_demo_figures.py 3 times)
set -uo pipefail
cd "$(dirname "$0")/.."
pids=()
for _ in 1 2 3 4 5 6; do python3 -c 'while True: pass' & pids+=($!); done
trap 'kill "${pids[@]}" 2>/dev/null' EXIT
start=$(date +%s)
if [ "${1:-}" = "--demo" ]; then
  out=${2:?usage: stress_suite.sh --demo OUT_DIR}
  rc=0
  for run in 1 2 3; do
    t0=$(date +%s)
    .venv/bin/python benchmarks/bench_demo_figures.py "$out/run$run" || rc=$?
    echo "stress_suite: demo run $run under 6 busy processes: wall $(( $(date +%s) - t0 )) s"
  done
  exit $rc
fi
# the README's test command, as the README writes it (its first `.venv/bin/python -m pytest …`)
cmd=$(grep -m1 -o '\.venv/bin/python -m pytest [^`]*' README.md)
[ -n "$cmd" ] || { echo "stress_suite: no '.venv/bin/python -m pytest' command in README.md" >&2; exit 2; }
echo "stress_suite: $cmd $*"
$cmd "$@"
rc=$?
echo "stress_suite: README test command under 6 busy processes: exit $rc, wall $(( $(date +%s) - start )) s"
exit $rc
