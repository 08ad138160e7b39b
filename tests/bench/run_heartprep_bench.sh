#!/usr/bin/env bash
# heartprep speed and accuracy benchmark (issues 2 and 3): prints Markdown tables, writes CSV files.
# Not a test: nothing here fails on a time. Usage:
#   tests/bench/run_heartprep_bench.sh [--out DIR] [--reps N] [--parts build,critical,surface,real,part2]
# Needs a release heartprep (HEARTPREP=path, else build/release, else build-bench) and the packages
# of scripts/install-deps.sh --bench.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"

if [ -z "${HEARTPREP:-}" ]; then
  for candidate in "$repo/build/release/tools/heartprep" "$repo/build-bench/tools/heartprep"; do
    if [ -x "$candidate" ]; then HEARTPREP="$candidate"; break; fi
  done
fi
if [ -z "${HEARTPREP:-}" ] || [ ! -x "$HEARTPREP" ]; then
  echo "run_heartprep_bench: no heartprep binary; build one first, e.g." >&2
  echo "  cmake --preset release && cmake --build build/release --target heartprep -j2" >&2
  exit 1
fi

# Debian's interpreter on purpose: VTK (python3-paraview) and python3-numpy are installed for it, and a
# pyenv or venv python3 earlier in PATH would not see them.
PY=/usr/bin/python3
if ! "$PY" -c "import vtk, numpy" 2>/dev/null || [ ! -x /usr/bin/time ]; then
  echo "run_heartprep_bench: VTK (python3-paraview), python3-numpy or GNU time missing; run scripts/install-deps.sh --bench" >&2
  exit 1
fi

exec "$PY" "$repo/tests/bench/heartprep_bench.py" --heartprep "$HEARTPREP" "$@"
