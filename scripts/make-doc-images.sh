#!/usr/bin/env bash
# Regenerates the pictures in docs/images from the real cases (../shared/data/real; skipped with
# a message where absent) with this checkout's heartprep and heartsim (release build).
#   docs/images/holding-pat1.png   docs/user-guide.md "How the heart is held"
set -euo pipefail
cd "$(dirname "$0")/.."
real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-doc-images: $real is absent: no picture regenerated" >&2; exit 0; fi
cmake --build --preset release --target heartprep heartsim >/dev/null
work=build/doc-images
mkdir -p "$work" docs/images
build/release/tools/heartprep build "$real/hvsmr16_pat1/training_axial_crop_pat1-label.nii.gz" -o "$work/pat1.h5" --cavity 2 -q
build/release/runtime/heartsim run "$work/pat1.h5" --headless --backend cpu --seconds 2 \
  --trajectory samples/probe_and_grab_pat1.csv --view left --size 900x700 --screenshot docs/images/holding-pat1.png
