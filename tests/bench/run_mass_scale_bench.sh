#!/usr/bin/env bash
# Run time against error with the mass scale S as the knob (docs/benchmarks.md "Mass scaling: run
# time against error"): every case in ../shared/data/real built with heartprep's defaults (30k
# particles, E = 10 kPa; MM-WHS CT 1002's myocardium is label 205: --tissue=205), the standard press-and-grab
# gesture of tests/bench/press_and_grab_gesture.py (a 3 mm probe pressing the most anterior particle 13 mm
# along +y from 11 mm in front of it, a 3 mm grabber pulling the most inferior particle 10 mm inferior,
# both over the first 100 ms, then held), run on the cpu backend at S = 1, 2, 4, 8, 16 by
# tests/bench/mass_scale_bench.cpp. Writes OUT/mass_scale.csv, prints a Markdown table, and draws
# OUT/mass-scale.png (real-time factor against the force's deviation during the gesture:
# tests/bench/plot_benchmarks.py mass-scale, matplotlib: Debian's python3-matplotlib,
# scripts/install-deps.sh --bench). docs/images/mass-scale.png is that plot of the run
# docs/images/mass-scale.csv holds.
# Usage: tests/bench/run_mass_scale_bench.sh [--seconds S] [--out DIR] [--data DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=3 out=build/mass-scale-bench data=../shared/data/real
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    -h|--help) sed -n 2,13p "$0"; exit 0 ;;
    *) echo "run_mass_scale_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -d "$data" ]; then echo "run_mass_scale_bench: $data is absent: nothing to measure" >&2; exit 0; fi
cmake --build --preset release --target heartprep mass_scale_bench >/dev/null
mkdir -p "$out"
rm -f "$out/mass_scale.csv"
heartprep=build/release/tools/heartprep bench=build/release/tests/bench/mass_scale_bench
for label in "$data"/*/*label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  tissue=""
  [ "$case" = mmwhs_ct1002 ] && tissue="--tissue=205"
  [ -f "$out/$case.h5" ] || $heartprep build "$label" -o "$out/$case.h5" -q $tissue
  h5dump -d /particles/rest_position -y -w 0 -o "$out/$case.rest.txt" "$out/$case.h5" >/dev/null
  python3 tests/bench/press_and_grab_gesture.py "$out/$case.rest.txt" "$out/$case.csv"
  echo "$case" >&2
  $bench "$out/$case.h5" "$out/$case.csv" "$seconds" 300 "$case" "$out/mass_scale.csv" >&2
done
python3 - "$out/mass_scale.csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print("| case | particles | S | step ms × substeps | substeps per simulated ms | real-time factor | watchdog events | force deviation during the gesture | after settling |")
print("|---|---|---|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['case']} | {r['particles']} | {r['mass_scale']} | {float(r['dt_ms']):.4g} × {r['substeps']} | {float(r['substeps_per_simulated_ms']):.3g} | "
          f"{float(r['real_time_factor']):.2f} | {r['watchdog_events']} | {100 * float(r['ramp_error']):.1f} % | {100 * float(r['settled_error']):.2f} % |")
PY
/usr/bin/python3 tests/bench/plot_benchmarks.py mass-scale "$out/mass_scale.csv" "$out/mass-scale.png"
echo "wrote $out/mass_scale.csv and $out/mass-scale.png" >&2
