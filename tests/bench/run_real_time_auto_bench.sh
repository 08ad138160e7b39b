#!/usr/bin/env bash
# --real-time auto on the real hearts (docs/benchmarks.md "Real time with --real-time auto"): for
# every case that tests/bench/run_mass_scale_bench.sh built (OUT holds CASE.h5, CASE.rest.txt,
# CASE.csv and mass_scale.csv), at heartprep's defaults on the cpu backend:
#   * a haptic session: a simulated device pressing the most anterior particle (a hand of 100 g
#     pushing 0.05 N posterior from 100 ms, ramped over 400 ms) and a scripted grabber closing on
#     the most inferior particle at 100 ms and pulling it 10 mm inferior by 1100 ms, for SECONDS of
#     wall clock (--real-time auto is the default of a haptic session);
#   * a scripted headless run of the mass-scale benchmark's gesture with --real-time auto for
#     SECONDS simulated.
# Prints one Markdown row per case: the S each run took; for the session (which steps when due and
# never runs ahead) how far behind real time it was at its last step, for the headless run its
# real-time factor over the whole run (the first half second at S = 1 included); and the force
# deviation the mass-scale benchmark measured at that S (during the gesture, after settling).
# Usage: tests/bench/run_real_time_auto_bench.sh [--seconds S] [--out DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=6 out=build/mass-scale-bench
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) sed -n 2,15p "$0"; exit 0 ;;
    *) echo "run_real_time_auto_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -f "$out/mass_scale.csv" ]; then echo "run_real_time_auto_bench: run tests/bench/run_mass_scale_bench.sh --out $out first" >&2; exit 2; fi
cmake --build --preset release --target heartsim >/dev/null
heartsim=build/release/runtime/heartsim
echo "| case | haptic session: S | behind real time at the end | headless --real-time auto: S | real-time factor | force deviation at that S: during the gesture | after settling |"
echo "|---|---|---|---|---|---|---|"
for scenario in "$out"/*.h5; do
  case=$(basename "$scenario" .h5)
  [ -f "$out/$case.rest.txt" ] || continue
  python3 - "$out/$case.rest.txt" "$out/$case.press.csv" "$out/$case.grab.csv" <<'PY'
import re, sys
values = [float(v) for v in re.findall(r"-?\d+\.?\d*(?:[eE][-+]?\d+)?", open(sys.argv[1]).read())]
points = [values[i:i + 3] for i in range(0, len(values) - 2, 3)]
front = min(points, key=lambda p: p[1])
low = min(points, key=lambda p: p[2])
with open(sys.argv[2], "w") as f:
    f.write("# simulated hand pressing a 3 mm probe on the most anterior particle (run_real_time_auto_bench.sh)\n")
    f.write(f"start_mm, {front[0]}, {front[1] - 5}, {front[2]}\nmass_g, 100\ndamping_n_ms_per_mm, 2\nmax_force_n, 3.3\n")
    f.write("time_ms, fx, fy, fz\n0, 0, 0, 0\n100, 0, 0, 0\n500, 0, 0.05, 0\n")
with open(sys.argv[3], "w") as f:
    f.write("# scripted grabber on the most inferior particle, pulling 10 mm inferior (run_real_time_auto_bench.sh)\n")
    f.write(f"0, {low[0]}, {low[1]}, {low[2]}, 1, 0, 0, 0, 0\n100, {low[0]}, {low[1]}, {low[2]}, 1, 0, 0, 0, 1\n")
    f.write(f"1100, {low[0]}, {low[1]}, {low[2] - 10}, 1, 0, 0, 0, 1\n")
PY
  $heartsim run "$scenario" --headless --backend cpu --device "simulated:$out/$case.press.csv" --instrument probe:3,3,3 \
    --device "scripted:$out/$case.grab.csv" --instrument grabber:3,3,3 --seconds "$seconds" >"$out/$case.haptic.log" 2>&1
  $heartsim run "$scenario" --headless --backend cpu --real-time auto --seconds "$seconds" --trajectory "$out/$case.csv" \
    >"$out/$case.auto.log" 2>&1
  python3 - "$case" "$out/$case.haptic.log" "$out/$case.auto.log" "$out/mass_scale.csv" <<'PY'
import csv, re, sys
case, haptic, auto, table = sys.argv[1], open(sys.argv[2]).read(), open(sys.argv[3]).read(), sys.argv[4]
def scale(log):
    chosen = re.findall(r": mass scale ([0-9.]+),", log)
    return float(chosen[-1]) if chosen else 1.0
hs, as_ = scale(haptic), scale(auto)
hf = re.search(r"simulation: ([0-9.e+-]+) ms behind real time", haptic)
af = re.search(r"real-time factor ([0-9.e+-]+)", auto)
rows = {(r["case"], float(r["mass_scale"])): r for r in csv.DictReader(open(table))}
def deviation(s):
    r = rows.get((case, s))
    return ("%.1f %%" % (100 * float(r["ramp_error"])), "%.2f %%" % (100 * float(r["settled_error"]))) if r else ("-", "-")
d = deviation(max(hs, as_))
print(f"| {case} | {hs:g} | {hf.group(1) + ' ms' if hf else '?'} | {as_:g} | {af.group(1) if af else '?'} | {d[0]} (S = {max(hs, as_):g}) | {d[1]} |")
PY
done
