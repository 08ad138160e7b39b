#!/usr/bin/env bash
# The incision on every real heart (docs/benchmarks.md "Cutting"): each case in ../shared/data/real
# built with heartprep's defaults (30k particles; the MM-WHS cases with their label conventions,
# --labels mmwhs and --labels mmwhs-ordinal), the scripted incision of tests/incision_gesture.h (a scalpel drawn 30 mm
# inferior to superior through the most anterior wall at 0.1 mm/ms, blade 8 mm from 2 mm in front
# of the surface; then two retractors pull the edges 6 mm apart over 500 ms and hold 250 ms) run
# by tests/bench/cut_bench.cpp on the cpu backend with the blade lowered and lifted. Then, per
# case, the same gesture through `heartsim run --headless --trajectory … --save-state`, as a user
# runs it. Writes OUT/cut.csv and prints a Markdown table. "Incision open": over the springs the
# cut run cut within 5 mm of the incision's centre, how much longer their two ends stand apart
# than at rest at the end of each run (the lifted run: the same springs, uncut). "Mesh": the
# detailed mesh opened where the blade lifts (ms, inside that step), the caps' largest and mean
# distance from the blade's plane then, closed 2-manifold at the end, and how far apart the two
# sides' caps stand at the end near the centre.
# Usage: tests/bench/run_cut_bench.sh [--out DIR] [--data DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
out=build/cut-bench data=../shared/data/real
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    -h|--help) sed -n 2,10p "$0"; exit 0 ;;
    *) echo "run_cut_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -d "$data" ]; then echo "run_cut_bench: $data is absent: nothing to measure" >&2; exit 0; fi
cmake --build --preset release --target heartprep heartsim cut_bench >/dev/null
mkdir -p "$out"
rm -f "$out/cut.csv"
heartprep=build/release/tools/heartprep heartsim=build/release/runtime/heartsim bench=build/release/tests/bench/cut_bench
for label in "$data"/*/*label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  tissue=""
  [ "$case" = mmwhs_ct1002 ] && tissue="--labels mmwhs"
  [ "$case" = mmwhs_wh ] && tissue="--labels mmwhs-ordinal"
  [ -f "$out/$case.h5" ] || $heartprep build "$label" -o "$out/$case.h5" -q $tissue
  echo "$case" >&2
  $bench "$out/$case.h5" "$case" "$out/cut.csv" "$out/$case.incision.csv" >&2
  $heartsim run "$out/$case.h5" --headless --backend cpu --trajectory "$out/$case.incision.csv" --seconds 1.125 \
    --save-state "$out/$case.cut-state.h5" > "$out/$case.run.log" 2>&1 || { cat "$out/$case.run.log" >&2; exit 1; }
  echo "  heartsim run: $(grep -E 'ran [0-9]+ steps' "$out/$case.run.log" | head -1)" >&2
done
python3 - "$out/cut.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print("| case | particles | run | springs cut | step while cutting p50 / p99 / max, ms | real-time factor cutting / after | watchdog | finite | incision open, mean / max, mm | mesh opened in, ms | caps from the blade's plane, max / mean, mm | mesh closed | caps apart, mm |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['case']} | {r['particles']} | {r['run']} | {r['springs_cut']} | {float(r['cut_step_p50_ms']):.2f} / {float(r['cut_step_p99_ms']):.2f} / "
          f"{float(r['cut_step_max_ms']):.2f} | {float(r['real_time_factor_cutting']):.2f} / {float(r['real_time_factor_after']):.2f} | "
          f"{r['watchdog_events']} | {'yes' if r['finite'] == '1' else 'NO'} | {float(r['opening_mean_mm']):.2f} / {float(r['opening_max_mm']):.2f} | "
          + (f"{float(r['mesh_open_ms']):.0f} | {float(r['cap_distance_max_mm']):.2f} / {float(r['cap_distance_mean_mm']):.2f} | "
             f"{'yes' if r['mesh_closed'] == '1' else 'NO'} | {float(r['caps_apart_mm']):.2f} |" if r['run'] == 'cut' else "– | – | – | – |"))
PY
