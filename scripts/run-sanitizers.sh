#!/usr/bin/env bash
# The sanitizer job (CI runs it after the release suite, through scripts/run-tests.sh): builds the
# sanitize preset (clang, AddressSanitizer + UndefinedBehaviorSanitizer, libFuzzer; build/sanitize),
# runs its subset of the tests under the sanitizers, then every fuzz target for a bounded time
# over its seed corpus (tests/fuzz/README.md). Fails on a failing test, a sanitizer report or any
# fuzzer finding. Packages: scripts/install-deps.sh (clang, libclang-rt-14-dev, llvm).
# Usage: scripts/run-sanitizers.sh [--fuzz-seconds N]   (default 30 per target, two at a time)
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=30
if [ "${1:-}" = "--fuzz-seconds" ]; then seconds="$2"; fi

jobs=$(nproc)
cmake --preset sanitize >/dev/null
cmake --build --preset sanitize -j "$jobs"
ctest --preset sanitize -j "$jobs"
bash tests/fuzz/run_fuzzers.sh --build build/sanitize --seconds "$seconds" --jobs "$jobs"
