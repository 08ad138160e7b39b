#!/usr/bin/env bash
# heartsim runtime benchmark (docs/benchmarks.md "heartsim runtime"): Sørensen & Mosegaard's Table 1 per backend, steps/s of the
# gl and cpu backends, picking buffer against direct and search contacts for K = 1, 2, 4, 8.
# Prints Markdown tables, writes CSV files. Not a test: nothing here fails on a time. Usage:
#   tests/bench/run_runtime_bench.sh [--out DIR] [--steps N] [--cases phantom,pat1,...]
#       [--parts table1,speed,contact] [--backends gl,cpu] [--size WxH] [--frames N]
#       [--slide-mm MM] [--refresh 1,2,4,8] [--data DIR]
# Needs release heartsim and heartprep (HEARTSIM=path, HEARTPREP=path, else build/release, else
# build-rbench), h5dump (hdf5-tools) and python3-numpy for /usr/bin/python3. The same script runs
# on a machine with a GPU: it prints the GL renderer (heartsim info) so the tables say which device
# ran them. heartsim takes the default EGL device; under libglvnd, e.g.
#   __EGL_VENDOR_LIBRARY_FILENAMES=/usr/share/glvnd/egl_vendor.d/10_nvidia.json
# picks NVIDIA's EGL (the environment is passed through unchanged).
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"

find_tool() {  # $1 = target, $2 = folder inside the build tree
  local candidate
  for candidate in "$repo/build/release/$2/$1" "$repo/build-rbench/$2/$1"; do
    if [ -x "$candidate" ]; then echo "$candidate"; return; fi
  done
}
HEARTSIM="${HEARTSIM:-$(find_tool heartsim runtime)}"
HEARTPREP="${HEARTPREP:-$(find_tool heartprep tools)}"
if [ -z "$HEARTSIM" ] || [ ! -x "$HEARTSIM" ] || [ -z "$HEARTPREP" ] || [ ! -x "$HEARTPREP" ]; then
  echo "run_runtime_bench: no heartsim/heartprep binaries; build them first, e.g." >&2
  echo "  cmake --preset release && cmake --build build/release --target heartsim heartprep -j2" >&2
  exit 1
fi
if ! "$HEARTSIM" run --help 2>/dev/null | grep -q -- --stats-csv; then
  echo "run_runtime_bench: $HEARTSIM has no --stats-csv; rebuild it" >&2
  exit 1
fi

# Debian's interpreter on purpose: python3-numpy is installed for it.
PY=/usr/bin/python3
if ! "$PY" -c "import numpy" 2>/dev/null || ! command -v h5dump >/dev/null; then
  echo "run_runtime_bench: python3-numpy or h5dump (hdf5-tools) missing; run scripts/install-deps.sh --bench" >&2
  exit 1
fi

exec "$PY" "$repo/tests/bench/runtime_bench.py" --heartsim "$HEARTSIM" --heartprep "$HEARTPREP" "$@"
