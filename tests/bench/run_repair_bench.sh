#!/usr/bin/env bash
# The repair of a 10 mm ventricular septal defect on every real heart (docs/benchmarks.md "Closing a
# defect"): each case in ../shared/data/real built with heartprep's defaults (30k particles) and
# `--defect vsd` (the HVSMR cases, one blood pool, at a point on their septum; the MM-WHS cases find
# it by their chamber labels, --labels mmwhs and --labels mmwhs-ordinal), `heartsim plan-repair`'s
# repair played by `heartsim run --headless --backend B --trajectory … --save-state`, then the same
# heart for as long without a patch (no instruments), and scripts/check-closure.py's independent
# flood fill of the saved state. Writes OUT/repair.csv and prints a Markdown table: heartsim's
# verdict and rim gap, the independent verdict, watchdog events, the real-time factors with and
# without the patch, and what the patch's steps cost.
# With --repeat N the two runs alternate N times and each factor is the best of its N (a shared
# machine's other work only ever slows a run).
# The hearts are built as labelled (--walls labelled), as the table in docs/benchmarks.md; --whole
# builds them whole (heartprep's default, walls grown); --leak-test MMHG: heartsim run's (default here 10, as the table
# in docs/benchmarks.md; the run's own default is 75).
# Usage: tests/bench/run_repair_bench.sh [--out DIR] [--data DIR] [--backend cpu|gl] [--stitches N (default: plan-repair's)] [--repeat N] [--whole] [--leak-test MMHG]
set -euo pipefail
cd "$(dirname "$0")/../.."
out=build/repair-bench data=../shared/data/real backend=cpu stitches= repeat=1 walls="--walls labelled" leak="--leak-test 10"
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    --backend) backend="$2"; shift 2 ;;
    --stitches) stitches="$2"; shift 2 ;;
    --repeat) repeat="$2"; shift 2 ;;
    --whole) walls=; shift ;;
    --leak-test) leak="--leak-test $2"; shift 2 ;;
    -h|--help) sed -n 2,15p "$0"; exit 0 ;;
    *) echo "run_repair_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -d "$data" ]; then echo "run_repair_bench: $data is absent: nothing to measure" >&2; exit 0; fi
heartprep=${HEARTPREP:-build/release/tools/heartprep} heartsim=${HEARTSIM:-build/release/runtime/heartsim}
if [ -z "${HEARTSIM:-}" ]; then cmake --build --preset release --target heartprep heartsim >/dev/null; fi
. scripts/real-cases.sh
mkdir -p "$out"
csv="$out/repair.csv"
echo "case,particles,stitches,closed,rim_gap_mm,independent,watchdog,rtf_patch,rtf_without,patch_ms_per_step,patch_share_pct,seconds" > "$csv"
for label in "$data"/*/*label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  options=$(vsd_options "$case") || { echo "$case: no place known for a VSD: skipped" >&2; continue; }
  h5="$out/$case.vsd.h5"
  [ -f "$h5" ] || $heartprep build "$label" -o "$h5" -q $options $walls
  plan=$($heartsim plan-repair "$h5" -o "$out/$case.repair.csv" ${stitches:+--stitches="$stitches"})
  seconds=$(grep -o -- '--seconds [0-9.]*' <<<"$plan" | head -1 | cut -d' ' -f2)
  echo "$case: $seconds s" >&2
  for ((r = 1; r <= repeat; r++)); do
    $heartsim run "$h5" --headless --backend "$backend" --trajectory "$out/$case.repair.csv" --seconds "$seconds" \
      --save-state "$out/$case.repaired.h5" $leak > "$out/$case.run.$r.log" 2>&1 || { cat "$out/$case.run.$r.log" >&2; exit 1; }
    $heartsim run "$h5" --headless --backend "$backend" --seconds "$seconds" > "$out/$case.without.$r.log" 2>&1 ||
      { cat "$out/$case.without.$r.log" >&2; exit 1; }
  done
  # The fastest of each (the repair's runs are the same run: the same verdict every time).
  best() { grep -H -o 'real-time factor [0-9.e+-]*' "$@" | sort -t' ' -k3 -g | tail -1 | cut -d: -f1; }
  cp "$(best "$out/$case".run.*.log)" "$out/$case.run.log"
  cp "$(best "$out/$case".without.*.log)" "$out/$case.without.log"
  independent=$(python3 scripts/check-closure.py "$out/$case.repaired.h5" --scenario "$h5" | grep -o 'defect closed: [a-z]*' | cut -d' ' -f3 || true)
  python3 - "$case" "$stitches" "$seconds" "$independent" "$out/$case.run.log" "$out/$case.without.log" >> "$csv" <<'PY'
import re, sys
case, stitches, seconds, independent, run, without = sys.argv[1:]
r, w = open(run).read(), open(without).read()
stitches = re.search(r"a patch, (\d+) stitches", r).group(1)
rtf = lambda text: float(re.search(r"real-time factor ([0-9.e+-]+)", text).group(1))
closed = re.search(r"defect closed: (yes|no), largest rim gap ([0-9.]+) mm", r)
patch = re.search(r"took ([0-9.e+-]+) ms each .*: ([0-9.]+) % of the wall", r)
particles = re.search(r"backend: (\d+) particles", r).group(1)
watchdog = re.search(r"watchdog: (\d+) events", r)
print(f"{case},{particles},{stitches},{closed.group(1)},{closed.group(2)},{independent or '?'},{watchdog.group(1) if watchdog else 0},"
      f"{rtf(r)},{rtf(w)},{patch.group(1) if patch else ''},{patch.group(2) if patch else ''},{seconds}")
PY
done
python3 - "$csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print("| case | particles | stitches | defect closed (heartsim) | largest rim gap, mm | independent flood fill | watchdog | real-time factor with / without the patch | patch step, ms (share of wall) |")
print("|---|---|---|---|---|---|---|---|---|")
for r in rows:
    ratio = float(r["rtf_patch"]) / float(r["rtf_without"])
    print(f"| {r['case']} | {r['particles']} | {r['stitches']} | {r['closed']} | {float(r['rim_gap_mm']):.2f} | {r['independent']} | {r['watchdog']} | "
          f"{float(r['rtf_patch']):.3f} / {float(r['rtf_without']):.3f} ({100 * (ratio - 1):+.1f} %) | {float(r['patch_ms_per_step'] or 0):.3f} ({r['patch_share_pct']} %) |")
PY
