#!/usr/bin/env bash
# Run time against error on real hearts (docs/benchmarks.md "The detailed mesh on real hearts").
# For every real case (../shared/data/real; skipped with a message where absent): heartprep
# build at 10k, 30k, 100k and 300k particles (defaults otherwise), and the 30k build without the
# thin-wall layout and the embedding (--thin-walls keep --mapping tangent, "keep + tangent"); one scripted gesture per case, placed
# from the detailed mesh (the same at every particle count: accuracy_bench gesture, press and
# grab together); heartsim run --backend cpu --seconds 0.3 on each, writing the deformed detailed
# mesh (/visual/positions); then accuracy_bench table: each run's mesh against the 300k run's,
# vertex by vertex, and the cpu wall time per simulated second heartsim reports; then
# tests/bench/plot_benchmarks.py accuracy draws the table (matplotlib: Debian's python3-matplotlib,
# scripts/install-deps.sh --bench).
# Usage: tests/bench/run_accuracy_bench.sh [OUT_DIR]   (default build/accuracy-bench)
# Writes OUT_DIR/accuracy.csv, OUT_DIR/accuracy.md, and docs/images/run-time-vs-error.png with its
# data beside it, docs/images/run-time-vs-error.csv (a copy of accuracy.csv).
set -euo pipefail
cd "$(dirname "$0")/../.."
real=../shared/data/real
if [ ! -d "$real" ]; then echo "run_accuracy_bench: $real is absent: nothing to measure" >&2; exit 0; fi
out=${1:-build/accuracy-bench}
mkdir -p "$out" docs/images
cmake --build --preset release --target heartprep heartsim accuracy_bench >/dev/null
bin=build/release
runs="$out/runs.csv"
echo "case,label,particles,state,wall_s,simulated_s" > "$runs"
seconds=0.3
for dir in "$real"/*/; do
  input=$(ls "$dir"*-label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  case=$(basename "$dir"); case=${case#hvsmr16_}
  builds=("10000:--particles 10000" "30000:--particles 30000" "100000:--particles 100000" "300000:--particles 300000"
          "30000-before:--particles 30000 --thin-walls keep --mapping tangent")
  for b in "${builds[@]}"; do
    label=${b%%:*}; options=${b#*:}
    echo "run_accuracy_bench: $case $label: build" >&2
    # shellcheck disable=SC2086
    "$bin/tools/heartprep" build "$input" -o "$out/$case-$label.h5" $options -q
  done
  "$bin/tests/bench/accuracy_bench" gesture "$out/$case-10000.h5" "$out/$case-gesture.csv" --hands both
  for b in "${builds[@]}"; do
    label=${b%%:*}
    echo "run_accuracy_bench: $case $label: run" >&2
    log=$("$bin/runtime/heartsim" run "$out/$case-$label.h5" --headless --backend cpu --seconds "$seconds" \
          --trajectory "$out/$case-gesture.csv" --save-state "$out/$case-$label-state.h5")
    wall_ms=$(sed -n 's/.* simulated in \([0-9.e+]*\) ms wall.*/\1/p' <<<"$log")
    particles=$(sed -n 's/^cpu backend: \([0-9]*\) particles.*/\1/p' <<<"$log")
    label_text=defaults; [ "$label" = 30000-before ] && label_text="keep + tangent"
    echo "$case,$label_text,$particles,$out/$case-$label-state.h5,$(awk "BEGIN{print $wall_ms/1000}"),$seconds" >> "$runs"
  done
done
"$bin/tests/bench/accuracy_bench" table "$runs" "$out/accuracy.csv" "$out/accuracy.md"
/usr/bin/python3 tests/bench/plot_benchmarks.py accuracy "$out/accuracy.csv" docs/images/run-time-vs-error.png
cp "$out/accuracy.csv" docs/images/run-time-vs-error.csv
echo "run_accuracy_bench: wrote $out/accuracy.csv, $out/accuracy.md and docs/images/run-time-vs-error.png (.csv)" >&2
