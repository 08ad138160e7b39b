#!/usr/bin/env bash
# Many scalpel strokes (docs/benchmarks.md "Many strokes"): the shipped phantom built with
# heartprep's defaults, then tests/bench/stroke_bench.cpp opens its detailed mesh along random
# strokes (a fixed seed), one lift at a time, and prints the wall time of all the lifts after 1,
# 25, 50, 100 and 200 strokes, the mesh's size, the triangles re-meshed and whether it is closed.
# Usage: tests/bench/run_stroke_bench.sh [--out DIR] [--seed N] [--counts 1,25,50,100,200] [--blade MM]
#   --blade: the blade's length (default 8 mm, as the scripted incisions; 20 mm: the window's K scalpel)
set -euo pipefail
cd "$(dirname "$0")/../.."
out=build/stroke-bench seed=1 counts=1,25,50,100,200 blade=8
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --counts) counts="$2"; shift 2 ;;
    --blade) blade="$2"; shift 2 ;;
    -h|--help) sed -n 2,7p "$0"; exit 0 ;;
    *) echo "run_stroke_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
cmake --build --preset release --target heartprep stroke_bench >/dev/null
mkdir -p "$out"
[ -f "$out/phantom.h5" ] || build/release/tools/heartprep build samples/phantom.nii.gz -o "$out/phantom.h5" -q
build/release/tests/bench/stroke_bench "$out/phantom.h5" --seed "$seed" --counts "$counts" --blade "$blade"
