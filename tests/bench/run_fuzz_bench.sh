#!/usr/bin/env bash
# Longer fuzzing than CI's 30 s per target (docs/benchmarks.md "Fuzzing"): builds the sanitize
# preset's fuzz targets and runs each one, one after another, for SECONDS from its seed corpus
# alone (a fresh working corpus, so runs compare), printing per target the executions, executions
# per second, the corpus it ended with, coverage (cov: edges, ft: features) and findings.
# Exits 1 if any target found something (inputs kept in OUT/findings/).
# Usage: tests/bench/run_fuzz_bench.sh [--seconds N] [--jobs J] [--out DIR] [TARGET...]
#        (default 600 s per target, one target at a time, build/fuzz-bench; every target)
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=600 jobs=1 out=build/fuzz-bench targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) targets+=("$1"); shift ;;
  esac
done
cmake --preset sanitize >/dev/null
cmake --build --preset sanitize --target fuzzers
echo "run_fuzz_bench: $(nproc) cores, $seconds s per target, $jobs at a time, load $(cut -d' ' -f1-3 /proc/loadavg) ($(date -u +%FT%TZ))"
bash tests/fuzz/run_fuzzers.sh --build build/sanitize --out "$out" --seconds "$seconds" --jobs "$jobs" --fresh "${targets[@]}"
