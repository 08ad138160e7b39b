#!/usr/bin/env bash
# The watchdog soak (docs/benchmarks.md "Soak"): soak_bench on the phantom with an anchored
# border (where a pull beside the anchors used to freeze the simulation for good) and on every
# case in ../shared/data/real built with heartprep's defaults (held by supports), 10^5 steps each.
# Usage: tests/bench/run_soak_bench.sh [--steps N] [OUT_DIR]   (default 100000, build/soak-bench)
set -euo pipefail
cd "$(dirname "$0")/../.."
steps=100000
if [ "${1:-}" = "--steps" ]; then steps="$2"; shift 2; fi
out="${1:-build/soak-bench}"
cmake --build --preset release --target heartprep soak_bench >/dev/null
mkdir -p "$out"
heartprep=build/release/tools/heartprep
$heartprep build samples/phantom.nii.gz -o "$out/phantom-anchored.h5" --cavity 2 --anchor-border --no-visual -q
scenarios=("$out/phantom-anchored.h5")
real="../shared/data/real"
if [ -d "$real" ]; then
  for label in "$real"/*/*-label.nii.gz; do
    case=$(basename "$(dirname "$label")")
    $heartprep build "$label" -o "$out/$case.h5" --no-visual -q
    scenarios+=("$out/$case.h5")
  done
else
  echo "run_soak_bench: $real is absent: the phantom only" >&2
fi
status=0
for scenario in "${scenarios[@]}"; do
  build/release/tests/bench/soak_bench "$scenario" --steps "$steps" || status=1
done
exit $status
