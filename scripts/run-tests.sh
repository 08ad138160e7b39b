#!/usr/bin/env bash
# Sets up a fresh Debian 12 machine (as root), builds heartsim with its tests, and runs them.
# Usage: scripts/run-tests.sh [release|debug]   (debug = AddressSanitizer + UBSan build)
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${1:-release}"

bash scripts/install-deps.sh
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset" -j "$(nproc)"
ctest --preset "$preset" -j "$(nproc)"
