#!/usr/bin/env bash
# Sets up a fresh Debian 12 machine (as root), builds heartsim, and runs the main job on the
# bundled sample: heartprep build samples/phantom.nii.gz -> out/phantom.h5, inspects it, then
# simulates a scripted two-handed gesture headless and writes a screenshot and the final state.
# Last, a two-second haptic session (a simulated device pressing, a scripted grabber pulling) on
# a 12,000-particle phantom, recorded, and the recording replayed. heartprep's defaults hold the
# heart (posterior supports, a rest state balanced under gravity): no anchors or gravity needed.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build --preset release -j "$(nproc)" --target heartprep heartsim

mkdir -p out
build/release/tools/heartprep build samples/phantom.nii.gz -o out/phantom.h5 --cavity 2
build/release/tools/heartprep inspect out/phantom.h5
build/release/runtime/heartsim run out/phantom.h5 --headless --backend cpu --steps 500 \
  --trajectory samples/probe_and_grab_phantom.csv --screenshot out/phantom.png --save-state out/phantom-state.h5 --stats

# Haptics (docs/haptics.md): two devices at 1 kHz beside the simulation, recorded, then replayed.
build/release/tools/heartprep build samples/phantom.nii.gz -o out/phantom-haptics.h5 --cavity 2 --particles 12000 -q
build/release/runtime/heartsim run out/phantom-haptics.h5 --headless --backend cpu --seconds 2 \
  --device simulated:samples/haptics/press_phantom.csv --device scripted:samples/haptics/grab_phantom.csv \
  --record out/phantom-session.h5
build/release/runtime/heartsim run out/phantom-haptics.h5 --headless --replay out/phantom-session.h5
