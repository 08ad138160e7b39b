#!/usr/bin/env bash
# Regenerates docs/gallery/whole-hearts.md: every real case (../shared/data/real; skipped with a
# message where absent) built whole with heartprep's defaults (walls grown where its labels show
# only blood), seen from the surgeon's place (--view surgeon: the patient supine, the surgeon on
# the patient's right) with the coronary arteries its landmarks give, and cut through its centre
# (--clip centre, seen from the front) so the grown walls (ochre) show beside the labelled
# myocardium (dark red). With this checkout's release build.
# Usage: scripts/make-whole-heart-gallery.sh
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/real-cases.sh
real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-whole-heart-gallery: $real is absent: no gallery regenerated" >&2; exit 0; fi
cmake --build --preset release --target heartprep heartsim >/dev/null
bin=build/release
work=build/gallery
mkdir -p "$work" docs/gallery
page=docs/gallery/whole-hearts.md
rows=()
for dir in "$real"/*/; do
  name=$(basename "$dir")
  input=$(ls "$dir"*label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  case=${name#hvsmr16_}
  case=${case#mmwhs_}
  echo "make-whole-heart-gallery: $name"
  # shellcheck disable=SC2046
  "$bin/tools/heartprep" build "$input" $(label_options "$name") -o "$work/$case-whole.h5" -q
  courses=$("$bin/tools/heartprep" inspect "$work/$case-whole.h5" | grep -cE '^ *(lad|rca|lcx)_course: [0-9]+ points' || true)
  made_of=$("$bin/tools/heartprep" inspect "$work/$case-whole.h5" | sed -n 's/^heart *//p' | head -1)
  "$bin/runtime/heartsim" run "$work/$case-whole.h5" --headless --backend cpu --steps 0 --view surgeon --size 800x800 \
    --screenshot "docs/gallery/$case-whole-surgeon.png" >/dev/null
  "$bin/runtime/heartsim" run "$work/$case-whole.h5" --headless --backend cpu --steps 0 --clip centre --size 800x800 \
    --screenshot "docs/gallery/$case-whole-section.png" >/dev/null
  rows+=("| $case | ![$case from the surgeon's place]($case-whole-surgeon.png) | ![$case cut through its centre]($case-whole-section.png) | $courses of 3 | ${made_of:-} |")
done
{
  echo "# Whole hearts"
  echo
  echo "Every real case in \`../shared/data/real\` built with \`heartprep build CASE -o CASE.h5\` (the defaults:"
  echo "walls grown where the labels show only blood; \`--labels mmwhs\` or \`mmwhs-ordinal\` for the MM-WHS"
  echo "hearts). Left: from the surgeon's place (\`heartsim run --view surgeon\`: the patient supine, the"
  echo "surgeon on the patient's right looking down on the heart's front, the patient's head on the"
  echo "left), with the coronary arteries along the courses heartprep found (MM-WHS only: HVSMR 2016"
  echo "labels one blood pool for every chamber, so no groove and no course can be found there, and"
  echo "none is drawn). Right: cut through the heart's centre (\`--clip centre\`, from the front): the"
  echo "walls heartprep grew are ochre, the labelled myocardium dark red. Regenerate with"
  echo "\`scripts/make-whole-heart-gallery.sh\`."
  echo
  echo "| case | surgeon's view | section | coronary courses | inspect's summary |"
  echo "|---|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
} > "$page"
echo "make-whole-heart-gallery: wrote $page"
