#!/usr/bin/env bash
# Sets up a fresh Debian 12 machine (as root), builds heartsim with its tests, and runs them.
# Usage: scripts/run-tests.sh [all|release|debug|sanitize]
#   all (default, what CI runs): the release build and its whole suite, then the sanitizer job
#       (scripts/run-sanitizers.sh: clang AddressSanitizer + UBSan build, a subset of the tests,
#       every fuzz target for a bounded time)
#   release | debug: that preset's build and whole suite (debug = GCC AddressSanitizer + UBSan)
#   sanitize: the sanitizer job alone
set -euo pipefail
cd "$(dirname "$0")/.."
what="${1:-all}"

bash scripts/install-deps.sh
case "$what" in
  all | release | debug)
    preset="$what"
    [ "$what" = all ] && preset=release
    cmake --preset "$preset" >/dev/null
    cmake --build --preset "$preset" -j "$(nproc)"
    ctest --preset "$preset" -j "$(nproc)"
    ;;
  sanitize) ;;
  *) echo "usage: scripts/run-tests.sh [all|release|debug|sanitize]" >&2; exit 2 ;;
esac
if [ "$what" = all ] || [ "$what" = sanitize ]; then
  bash scripts/run-sanitizers.sh
fi
