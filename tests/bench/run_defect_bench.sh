#!/usr/bin/env bash
# Septal defects on every real heart (docs/benchmarks.md "Septal defects"): `heartprep defect` with
# a 10 mm opening on each case in ../shared/data/real, timed as a user runs it: on the MM-WHS
# hearts (chambers labelled: --labels mmwhs / mmwhs-ordinal) every automatic site, vsd and asd; on
# the HVSMR hearts (one blood pool) a VSD at the septum point the tests use
# (tests/test_defect.cpp). Prints a Markdown table: the site, the diameter asked and measured (the
# clear passage), the wall's thickness there, the voxels carved, the places tried, and the wall
# time of the whole command (reading and writing the label map included) and of the defect alone.
# Usage: tests/bench/run_defect_bench.sh [--out DIR] [--data DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
out=build/defect-bench data=../shared/data/real
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    -h|--help) sed -n 2,8p "$0"; exit 0 ;;
    *) echo "run_defect_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -d "$data" ]; then echo "run_defect_bench: $data is absent: nothing to measure" >&2; exit 0; fi
cmake --build --preset release --target heartprep >/dev/null
mkdir -p "$out"
heartprep=build/release/tools/heartprep
echo "| case | defect | site | asked mm | passage mm | wall mm | voxels carved | places tried | command s | defect s |"
echo "|---|---|---|---|---|---|---|---|---|---|"
row() {  # case, type, site label, heartprep arguments...
  local case=$1 type=$2 site=$3; shift 3
  local start end log
  log="$out/$case-$type-$site.log"
  start=$(date +%s.%N)
  "$heartprep" defect "$@" --type "$type" --diameter 10 -o "$out/$case-$type-$site.nii.gz" > "$log" 2>&1 || { cat "$log" >&2; exit 1; }
  end=$(date +%s.%N)
  python3 - "$log" "$case" "$type" "$site" "$start" "$end" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
case, kind, site, start, end = sys.argv[2:7]
passage = re.search(r"a clear passage ([0-9.]+) mm", text).group(1)
voxels = re.search(r"(\d+) voxels carved", text).group(1)
wall = re.search(r"wall ([0-9.]+) mm thick", text).group(1)
tried = re.search(r"(\d+) place\(s\) tried", text)
seconds = re.search(r"; ([0-9.]+) s\n", text).group(1)
print(f"| {case} | {kind} | {site} | 10 | {passage} | {wall} | {voxels} | {tried.group(1) if tried else '(--at)'} | "
      f"{float(end) - float(start):.2f} | {seconds} |")
PY
}
. scripts/real-cases.sh
for label in "$data"/*/*label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  case "$case" in
    mmwhs_ct1002|mmwhs_wh)
      read -ra labels <<<"$(label_options "$case")"
      for site in perimembranous muscular apical; do row "$case" vsd "$site" "$label" "${labels[@]}" --site "$site"; done
      row "$case" asd secundum "$label" "${labels[@]}" --site secundum ;;
    *)
      [ -n "${septum_point[$case]:-}" ] && row "$case" vsd at "$label" --at "${septum_point[$case]}" ;;
  esac
done
