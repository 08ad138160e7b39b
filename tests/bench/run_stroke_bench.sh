#!/usr/bin/env bash
# Many scalpel strokes (docs/benchmarks.md "Many strokes"): the shipped phantom built with
# heartprep's defaults, then tests/bench/stroke_bench.cpp opens its detailed mesh along random
# strokes (a fixed seed), one lift at a time, and prints the wall time of all the lifts after 1,
# 25, 50, 100 and 200 strokes, the mesh's size, the triangles re-meshed and whether it is closed.
# Usage: tests/bench/run_stroke_bench.sh [--out DIR] [--seed N] [--counts 1,25,50,100,200] [--blade MM] [--against TABLE] [--no-build]
#   --blade: the blade's length (default 8 mm, as the scripted incisions; 20 mm: the window's K scalpel)
#   --against: the table an earlier run printed (e.g. its DIR/strokes-8mm-seed1.md, kept from another
#     build): each count both ran must have the same digest (mesh and mapping bit for bit), else exit 1
#   --no-build: run the stroke_bench and heartprep already built in build/release
set -euo pipefail
cd "$(dirname "$0")/../.."
out=build/stroke-bench seed=1 counts=1,25,50,100,200 blade=8 against= build=1
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --counts) counts="$2"; shift 2 ;;
    --blade) blade="$2"; shift 2 ;;
    --against) against="$2"; shift 2 ;;
    --no-build) build=0; shift ;;
    -h|--help) sed -n 2,11p "$0"; exit 0 ;;
    *) echo "run_stroke_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ -n "$against" ] && [ ! -r "$against" ]; then echo "run_stroke_bench: --against $against: no such table" >&2; exit 2; fi
[ "$build" = 1 ] && cmake --build --preset release --target heartprep stroke_bench >/dev/null
mkdir -p "$out"
[ -f "$out/phantom.h5" ] || build/release/tools/heartprep build samples/phantom.nii.gz -o "$out/phantom.h5" -q
table="$out/strokes-${blade}mm-seed${seed}.md"
build/release/tests/bench/stroke_bench "$out/phantom.h5" --seed "$seed" --counts "$counts" --blade "$blade" | tee "$table.new"
mv "$table.new" "$table"
[ -z "$against" ] && exit 0
# The rows "| strokes | ... | digest |" of both tables, by stroke count.
digests() { awk -F'|' '$2 ~ /^ *[0-9]+ *$/ { gsub(/ /, "", $2); gsub(/ /, "", $(NF-1)); print $2, $(NF-1) }' "$1"; }
compared=0 differ=0
while read -r n digest; do
  theirs=$(digests "$against" | awk -v n="$n" '$1 == n { print $2 }')
  [ -z "$theirs" ] && continue
  compared=$((compared + 1))
  if [ "$theirs" != "$digest" ]; then echo "after $n strokes: digest $digest, $against has $theirs" >&2; differ=$((differ + 1)); fi
done < <(digests "$table")
if [ "$compared" = 0 ]; then echo "run_stroke_bench: $against shares no stroke count with this run" >&2; exit 1; fi
if [ "$differ" != 0 ]; then echo "run_stroke_bench: the mesh or mapping differs from $against at $differ of $compared counts" >&2; exit 1; fi
echo "the same mesh and mapping as $against, bit for bit, at all $compared counts both ran"
