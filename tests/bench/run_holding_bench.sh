#!/usr/bin/env bash
# How the real hearts are held (docs/benchmarks.md "Holding a real heart"): every case
# in ../shared/data/real built with heartprep's defaults ("after") and with the options that
# reproduce the old defaults ("before": no supports, unstressed rest state, nothing anchored,
# and the same with --anchor-border); then holding_bench on each: drift after 5 s with no
# instrument, a 3 mm probe pressed 5 mm into the anterior wall.
# Usage: tests/bench/run_holding_bench.sh [OUT_DIR]   (default build/holding-bench)
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-build/holding-bench}"
real="../shared/data/real"
if [ ! -d "$real" ]; then echo "run_holding_bench: $real is absent: nothing to measure" >&2; exit 0; fi
cmake --build --preset release --target heartprep holding_bench >/dev/null
mkdir -p "$out"
heartprep=build/release/tools/heartprep
before="--support none --rest-state imaged --allow-free"
for label in "$real"/*/*-label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  $heartprep build "$label" -o "$out/$case.h5" --no-visual -q
  $heartprep build "$label" -o "$out/$case-before.h5" --no-visual -q $before
  $heartprep build "$label" -o "$out/$case-before-border.h5" --no-visual -q $before --anchor-border
done
build/release/tests/bench/holding_bench --csv "$out/holding.csv" "$out"/*.h5
