#!/usr/bin/env bash
# Regenerates docs/gallery/: every real case (../shared/data/real; skipped with a message where
# absent) built with heartprep's defaults, at rest, pressed and grabbed, from one fixed camera
# (the patient's left, 800x600), with this checkout's release build. The gestures come from each
# case's own detailed mesh (tests/bench/accuracy_bench gesture): a 3 mm probe pressing the most
# anterior point 6 mm in, and a 3 mm grabber pulling the most inferior point 10 mm down, each
# over 100 ms and held to 0.3 s.
# Usage: scripts/make-gallery.sh
set -euo pipefail
cd "$(dirname "$0")/.."
real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-gallery: $real is absent: no gallery regenerated" >&2; exit 0; fi
cmake --build --preset release --target heartprep heartsim accuracy_bench >/dev/null
bin=build/release
work=build/gallery
mkdir -p "$work" docs/gallery
view=(--view left --size 800x600)
{
  echo "# Gallery"
  echo
  echo "Every real case in \`../shared/data/real\`, built with \`heartprep build CASE -o CASE.h5\` (the"
  echo "defaults), drawn by \`heartsim run --headless --backend cpu\` from the patient's left. Pressed: a"
  echo "3 mm probe 6 mm into the most anterior point; grabbed: the most inferior point pulled 10 mm"
  echo "down; each over 100 ms, shown at 0.3 s. Regenerate with \`scripts/make-gallery.sh\`. The"
  echo "small dark openings at the top of pat1 are holes of its segmentation (there at rest too)."
  echo "Every real heart with a 10 mm septal defect, in the section view: [defects.md](defects.md)."
  echo "Every real heart with a planned ventriculotomy and atriotomy held open: [incisions.md](incisions.md)."
  echo "Every real heart whole, from the surgeon's place, with its coronary arteries, and cut to show its grown walls: [whole-hearts.md](whole-hearts.md)."
  echo
  echo "| case | at rest | pressed | grabbed |"
  echo "|---|---|---|---|"
} > docs/gallery/README.md
for dir in "$real"/*/; do
  name=$(basename "$dir")
  input=$(ls "$dir"*-label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  case=${name#hvsmr16_}
  echo "make-gallery: $name"
  "$bin/tools/heartprep" build "$input" -o "$work/$case.h5" -q
  "$bin/tests/bench/accuracy_bench" gesture "$work/$case.h5" "$work/$case-press.csv" --hands press
  "$bin/tests/bench/accuracy_bench" gesture "$work/$case.h5" "$work/$case-grab.csv" --hands grab
  "$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --steps 0 "${view[@]}" \
    --screenshot "docs/gallery/$case-rest.png" >/dev/null
  for gesture in press grab; do
    "$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --seconds 0.3 --trajectory "$work/$case-$gesture.csv" \
      "${view[@]}" --screenshot "docs/gallery/$case-$gesture.png" >/dev/null
  done
  echo "| $case | ![$case at rest]($case-rest.png) | ![$case pressed]($case-press.png) | ![$case grabbed]($case-grab.png) |" \
    >> docs/gallery/README.md
done
echo "make-gallery: wrote docs/gallery/"
