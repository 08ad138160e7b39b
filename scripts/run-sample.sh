#!/usr/bin/env bash
# Sets up a fresh Debian 12 machine (as root), builds heartsim, and runs the main job on the
# bundled sample: heartprep build samples/phantom.nii.gz -> out/phantom.h5, inspects it, then
# simulates a scripted two-handed gesture headless and writes a screenshot and the final state.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build --preset release -j "$(nproc)" --target heartprep heartsim

mkdir -p out
build/release/tools/heartprep build samples/phantom.nii.gz -o out/phantom.h5 --cavity 2 --anchor-border
build/release/tools/heartprep inspect out/phantom.h5
build/release/runtime/heartsim run out/phantom.h5 --headless --backend cpu --steps 500 \
  --trajectory samples/probe_and_grab_phantom.csv --screenshot out/phantom.png --save-state out/phantom-state.h5 --stats
