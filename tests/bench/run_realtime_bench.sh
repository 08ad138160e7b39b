#!/usr/bin/env bash
# Real time on the real hearts (docs/benchmarks-solver.md "Real time on the real hearts"): every
# case in ../shared/data/real built with heartprep's defaults (30k particles, E = 10 kPa,
# ζ = 0.1), then `heartsim run --headless --backend cpu --seconds S --trajectory T --stats` with
# a two-handed gesture written here for that heart: a 3 mm probe pressing the most anterior
# particle 5 mm deep from the front, and a 3 mm grabber pulling the most inferior particle 10 mm
# inferior, both over the first 100 ms and then held (the gesture of samples/probe_and_grab_pat1.csv).
# Prints one Markdown row per case: step, substeps, real-time factor, watchdog events, forces.
# Usage: tests/bench/run_realtime_bench.sh [--seconds S] [--out DIR] [--data DIR] [--particles N]
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=5 out=build/realtime-bench data=../shared/data/real particles=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    --particles) particles="--particles $2"; shift 2 ;;
    -h|--help) sed -n 2,10p "$0"; exit 0 ;;
    *) echo "run_realtime_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -d "$data" ]; then echo "run_realtime_bench: $data is absent: nothing to measure" >&2; exit 0; fi
cmake --build --preset release --target heartprep heartsim >/dev/null
mkdir -p "$out"
heartprep=build/release/tools/heartprep heartsim=build/release/runtime/heartsim
echo "| case | particles | step ms (critical) | substeps | substeps/s | real-time factor | watchdog events | probe N | grabber N |"
echo "|---|---|---|---|---|---|---|---|---|"
for label in "$data"/*/*-label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  $heartprep build "$label" -o "$out/$case.h5" -q $particles
  # The gesture from the rest positions: the most anterior (least y, LPS) and most inferior
  # (least z) particles.
  h5dump -d /particles/rest_position -y -w 0 -o "$out/$case.rest.txt" "$out/$case.h5" >/dev/null
  python3 tests/bench/press_and_grab_gesture.py "$out/$case.rest.txt" "$out/$case.csv"
  log="$out/$case.log"
  $heartsim run "$out/$case.h5" --headless --backend cpu --seconds "$seconds" --trajectory "$out/$case.csv" --stats >"$log" 2>&1
  step=$(grep -oE "step [0-9.e-]+ ms = [0-9]+ substeps of [0-9.e-]+ ms \(critical [0-9.e-]+ ms\)" "$log")
  dt=$(echo "$step" | awk '{print $2}'); subs=$(echo "$step" | awk '{print $5}'); crit=$(echo "$step" | grep -oE "critical [0-9.e-]+" | awk '{print $2}')
  rate=$(grep -oE "[0-9]+ substeps/s" "$log" | head -1 | awk '{print $1}')
  rtf=$(grep -oE "real-time factor [0-9.e-]+" "$log" | awk '{print $3}')
  events=$(grep -c "watchdog" "$log" || true)
  n=$(grep -oE "backend: [0-9]+ particles" "$log" | awk '{print $2}')
  f0=$(grep -E "^hand 0 force" "$log" | sed 's/hand 0 force //'); f1=$(grep -E "^hand 1 force" "$log" | sed 's/hand 1 force //')
  echo "| $case | $n | $dt ($crit) | $subs | $rate | $rtf | $events | $f0 | $f1 |"
done
