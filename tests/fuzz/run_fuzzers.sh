#!/usr/bin/env bash
# Runs the libFuzzer targets of a sanitize build, each for a bounded time over its seed corpus
# (tests/fuzz/corpus/<target>/), and prints per target: executions, executions per second, the
# corpus it ended with, coverage (cov: edges, ft: features) and findings. Exits 1 if any target
# found something (a crash, a sanitizer report, an escaped exception, a leak, a timeout, an
# allocation over the limit); the input that did it is kept in OUT/findings/.
# Used by scripts/run-sanitizers.sh (CI) and tests/bench/run_fuzz_bench.sh.
#
#   tests/fuzz/run_fuzzers.sh [--seconds N] [--jobs J] [--out DIR] [--fresh] [--build DIR] [TARGET...]
#     --seconds N   per target (default 30)
#     --jobs J      targets run at the same time (default 1)
#     --out DIR     logs, working corpora and findings (default BUILD/fuzz)
#     --fresh       start each working corpus empty (only the seeds), for comparable figures
#     --build DIR   the sanitize build (default build/sanitize)
#     TARGET...     some targets only (default: every fuzz_* in BUILD/tests/fuzz)
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=30 jobs=1 out="" fresh=0 build=build/sanitize targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --fresh) fresh=1; shift ;;
    --build) build="$2"; shift 2 ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    -*) echo "run_fuzzers: unknown option $1" >&2; exit 2 ;;
    *) targets+=("$1"); shift ;;
  esac
done
out="${out:-$build/fuzz}"
if [ ${#targets[@]} -eq 0 ]; then
  for f in "$build"/tests/fuzz/fuzz_*; do [ -x "$f" ] && targets+=("$(basename "$f")"); done
fi
if [ ${#targets[@]} -eq 0 ]; then
  echo "run_fuzzers: no fuzz targets in $build/tests/fuzz (build the sanitize preset first)" >&2
  exit 2
fi
mkdir -p "$out/logs" "$out/findings" "$out/corpus"
symbolizer=$(command -v llvm-symbolizer || command -v llvm-symbolizer-14 || true)
[ -n "$symbolizer" ] && export ASAN_SYMBOLIZER_PATH="$symbolizer"
export UBSAN_OPTIONS="print_stacktrace=1"
# Leaks inside HDF5 and ITK's NrrdIO on their own error paths (tests/fuzz/lsan.supp).
export LSAN_OPTIONS="suppressions=$PWD/tests/fuzz/lsan.supp:print_suppressions=0"

run_one() {
  local target="$1" seeds="tests/fuzz/corpus/$1" corpus="$out/corpus/$1"
  [ "$fresh" = 1 ] && rm -rf "$corpus"
  mkdir -p "$corpus"
  rm -f "$out/findings/$target"-*
  # -rss_limit_mb / -malloc_limit_mb: a reader that asks for more than 2 GiB in all or 1 GiB at
  # once for inputs of a few kilobytes is a finding; -timeout: 10 s for one input (our seeds read
  # in milliseconds); -close_fd_mask=1: the readers print nothing worth keeping on stdout.
  local status=0
  "$build/tests/fuzz/$target" -max_total_time="$seconds" -rss_limit_mb=2048 -malloc_limit_mb=1024 -timeout=10 \
    -print_final_stats=1 -close_fd_mask=1 -artifact_prefix="$out/findings/$target-" "$corpus" "$seeds" \
    > "$out/logs/$target.log" 2>&1 || status=$?
  echo "$status" > "$out/logs/$target.status"
}

running=0
for target in "${targets[@]}"; do
  if [ ! -d "tests/fuzz/corpus/$target" ]; then
    echo "run_fuzzers: $target has no seed corpus tests/fuzz/corpus/$target" >&2
    exit 2
  fi
  echo "run_fuzzers: $target for ${seconds} s" >&2
  run_one "$target" &
  running=$((running + 1))
  if [ "$running" -ge "$jobs" ]; then wait -n; running=$((running - 1)); fi
done
wait

failed=0
printf '%-24s %12s %9s %14s %8s %8s  %s\n' target execs exec/s corpus cov ft findings
for target in "${targets[@]}"; do
  log="$out/logs/$target.log"
  status=$(cat "$out/logs/$target.status")
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  last=$(grep -E '^#[0-9]+.*cov: ' "$log" | tail -1 || true)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
  corp=$(sed -n 's/.* corp: \([^ ]*\).*/\1/p' <<<"$last")
  findings=$(find "$out/findings" -name "$target-*" -type f | sort | tr '\n' ' ')
  if [ "$status" != 0 ] || [ -n "$findings" ]; then
    failed=1
    summary="exit $status ${findings:-(no input saved)}"
  else
    summary="none"
  fi
  printf '%-24s %12s %9s %14s %8s %8s  %s\n' "$target" "${execs:-?}" "${rate:-?}" "${corp:-?}" "${cov:-?}" "${ft:-?}" "$summary"
done
if [ "$failed" = 1 ]; then
  for target in "${targets[@]}"; do
    if [ "$(cat "$out/logs/$target.status")" != 0 ]; then
      echo "---- $target: the end of $out/logs/$target.log" >&2
      tail -60 "$out/logs/$target.log" >&2
    fi
  done
  echo "run_fuzzers: findings (inputs in $out/findings/; reproduce with $build/tests/fuzz/TARGET FILE)" >&2
  exit 1
fi
