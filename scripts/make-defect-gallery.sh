#!/usr/bin/env bash
# Regenerates the septal-defect part of docs/gallery/: every real case (../shared/data/real;
# skipped with a message where absent) built by heartprep with a 10 mm VSD and its defaults
# otherwise, and drawn in the section view across the defect (`heartsim run --clip defect`: the
# plane holding the defect's axis, the camera looking at it) and, beside it, the same case built
# without the defect under the same plane and camera. MM-WHS hearts label their chambers
# (--labels mmwhs, mmwhs-ordinal): heartprep places the defect itself (perimembranous); the HVSMR
# hearts have one blood pool: the VSD goes --at a point of their septum (tests/test_defect.cpp).
# Usage: scripts/make-defect-gallery.sh
set -euo pipefail
cd "$(dirname "$0")/.."
real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-defect-gallery: $real is absent: no gallery regenerated" >&2; exit 0; fi
cmake --build --preset release --target heartprep heartsim >/dev/null
bin=build/release
work=build/defect-gallery
mkdir -p "$work" docs/gallery
. scripts/real-cases.sh
rows=()
for dir in "$real"/*/; do
  name=$(basename "$dir")
  input=$(ls "$dir"*label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  options=$(vsd_options "$name") || continue
  read -ra options <<<"$options"
  read -ra labels <<<"$(label_options "$name")"
  case=${name#hvsmr16_}; case=${case#mmwhs_}
  echo "make-defect-gallery: $name"
  "$bin/tools/heartprep" build "$input" "${options[@]}" --diameter 10 -o "$work/$case-vsd.h5" -q 2>/dev/null
  "$bin/tools/heartprep" build "$input" "${labels[@]}" -o "$work/$case.h5" -q 2>/dev/null
  # The whole section: --look-at on the defect's centre keeps the fitted distance (--clip defect alone comes close).
  centre=$("$bin/tools/heartprep" inspect "$work/$case-vsd.h5" | sed -n 's/^defect .* centre \([^(]*\) (LPS mm).*/\1/p' | tr -d ' ')
  log=$("$bin/runtime/heartsim" run "$work/$case-vsd.h5" --headless --backend cpu --steps 0 --size 800x600 --clip defect \
    --look-at "$centre" --screenshot "docs/gallery/$case-vsd-section.png")
  # The same plane and camera on the intact heart: the plane the run printed, the camera aimed by it.
  plane=$(echo "$log" | sed -n 's/.*through (\([^)]*\)) mm, normal (\([^)]*\)).*/\1,\2/p' | tr -d ' ')
  "$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --steps 0 --size 800x600 --clip "$plane" --view section \
    --screenshot "docs/gallery/$case-intact-section.png" >/dev/null
  measured=$("$bin/tools/heartprep" inspect "$work/$case-vsd.h5" | sed -n 's/^defect *//p')
  rows+=("| $case | ![$case with a 10 mm VSD, section across it]($case-vsd-section.png) | ![$case intact, the same section]($case-intact-section.png) | $measured |")
done
{
  echo "# Septal defects in the section view"
  echo
  echo "Every real case built with a 10 mm ventricular septal defect (\`heartprep build CASE --defect vsd"
  echo "--diameter 10\`; on the MM-WHS hearts heartprep places it, perimembranous; on the HVSMR hearts at"
  echo "a point of the septum) and drawn by \`heartsim run --headless --clip defect --look-at\` on its centre (the whole section): the plane holds"
  echo "the defect's axis and the camera looks straight at it, so the septum shows as a dark band of cut"
  echo "wall with the opening as a gap in it. Beside it, the same case built without the defect, under"
  echo "the same plane and camera. Regenerate with \`scripts/make-defect-gallery.sh\`."
  echo
  echo "| case | 10 mm VSD | intact | the defect (heartprep inspect) |"
  echo "|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
} > docs/gallery/defects.md
echo "make-defect-gallery: wrote docs/gallery/defects.md"
