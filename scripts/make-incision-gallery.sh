#!/usr/bin/env bash
# Regenerates the incision part of docs/gallery/: every real case (../shared/data/real; skipped
# with a message where absent) built by heartprep with its defaults (MM-WHS hearts with their
# label convention), both approaches of `heartsim plan-incision` (a right ventriculotomy and a
# right atriotomy, each with two retractors pulling the edges 6 mm apart), played headless on the
# cpu backend for the --seconds the plan suggests, and drawn from outside, looking at the opened
# incision from the --view and --look-at the plan records in its CSV (its "# view:" line, where
# heartsim run opens without view options; 640x480). Writes docs/gallery/incisions.md.
# Usage: scripts/make-incision-gallery.sh [BUILD_DIR]   (default build/release, built first)
set -euo pipefail
cd "$(dirname "$0")/.."
real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-incision-gallery: $real is absent: no gallery regenerated" >&2; exit 0; fi
bin=${1:-build/release}
if [ "$bin" = build/release ]; then cmake --build --preset release --target heartprep heartsim >/dev/null; fi
work=build/incision-gallery
mkdir -p "$work" docs/gallery
rows=()
# What each picture shows (looked at when the gallery was made; say again when the data or the rule changes).
declare -A shows=(
  [pat0]="ventriculotomy: the right ventricle's anterior free wall, a slit held open onto the cavity; atriotomy: the lateral wall of the chamber at the right heart border (the grown blood-pool wall), a slit held open onto its cavity"
  [pat1]="ventriculotomy: the anterior free wall, held open, its cut faces folded at the middle where the blade grazed the surface; atriotomy: the right heart border's chamber wall, the opening's edge ragged under the left retractor"
  [pat5]="ventriculotomy: the anterior free wall near the acute margin, held open with the cavity showing through; atriotomy: the right heart border's chamber wall, a narrow slit, its cut faces showing"
  [pat6]="ventriculotomy: the anterior free wall, a narrow slit; atriotomy: the right heart border's chamber wall, a slit held open"
  [ct1002]="ventriculotomy: the right ventricle's grown free wall, the fibres drawn across it, held open; atriotomy: the right atrium's grown wall, a slit held open"
  [wh]="ventriculotomy: the right ventricle's grown free wall, the right coronary artery's course in yellow at the left; atriotomy: the right atrium's grown lateral wall, a slit held open"
)
for dir in "$real"/*/; do
  name=$(basename "$dir")
  input=$(ls "$dir"*label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  case $name in
    mmwhs_ct1002) case=ct1002; labels=(--labels mmwhs) ;;
    mmwhs_wh) case=wh; labels=(--labels mmwhs-ordinal) ;;
    hvsmr16_*) case=${name#hvsmr16_}; labels=() ;;
    *) continue ;;
  esac
  echo "make-incision-gallery: $name"
  "$bin/tools/heartprep" build "$input" "${labels[@]}" -o "$work/$case.h5" -q 2>/dev/null
  cells=()
  for approach in ventriculotomy atriotomy; do
    plan=$("$bin/runtime/heartsim" plan-incision "$work/$case.h5" -o "$work/$case-$approach.csv" --approach "$approach")
    seconds=$(echo "$plan" | sed -n 's/.*run it .*--seconds \([0-9.]*\).*/\1/p')
    where=$(echo "$plan" | sed -n 's/.*particle [0-9]* at (\([^)]*\)) mm.*/\1/p')
    log=$("$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --trajectory "$work/$case-$approach.csv" \
      --seconds "$seconds" --size 640x480 --screenshot "docs/gallery/$case-$approach.png")
    if ! echo "$log" | grep -q "^incision: the detailed mesh opened along"; then
      echo "make-incision-gallery: $case $approach: the mesh did not open:" >&2
      echo "$log" >&2
      exit 1
    fi
    cells+=("![$case, $approach]($case-$approach.png)<br>at $where")
  done
  rows+=("| $case | ${cells[0]} | ${cells[1]} | ${shows[$case]:-} |")
done
{
  echo "# Incisions"
  echo
  echo "Every real case built with \`heartprep build CASE -o CASE.h5\` (the defaults, walls grown where the"
  echo "labels show only blood; \`--labels mmwhs\` or \`mmwhs-ordinal\` for the MM-WHS hearts), the two incisions"
  echo "\`heartsim plan-incision\` plans on it (docs/runtime.md \"Planning an incision\"): a 30 mm right"
  echo "ventriculotomy, the blade pointing posterior, and a 30 mm right atriotomy, the blade pointing"
  echo "medially; each cut from inferior to superior through the wall, then two retractors (the gold"
  echo "spheres) grab its edges and pull them 6 mm apart. Played by \`heartsim run --headless --backend cpu"
  echo "--trajectory\` for the \`--seconds\` the plan suggests and drawn from the \`--view\` and \`--look-at\`"
  echo "it records in the CSV: the camera outside, 75 mm from the incision's centre (from the front for the"
  echo "ventriculotomy, from the patient's right for the atriotomy: the patient's front on the picture's"
  echo "right). The cut faces, drawn in a deeper red, line the opened incision. Under each picture, the"
  echo "point the plan chose (LPS mm). Regenerate with \`scripts/make-incision-gallery.sh\`."
  echo
  echo "On the MM-WHS hearts each approach keeps to its chamber's grown wall (the right ventricle's, the"
  echo "right atrium's), and tests/test_incision_plan.cpp follows each blade into that chamber's blood in"
  echo "the label map. HVSMR 2016 labels one blood pool: the ventriculotomy takes the most anterior wall"
  echo "of the heart's middle third (the right ventricle's free wall on these hearts), and the atriotomy"
  echo "the chamber at the right heart border beside the ventricles' upper half, which the label map"
  echo "cannot name."
  echo
  echo "| case | right ventriculotomy (from the front) | right atriotomy (from the patient's right) | what it shows |"
  echo "|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
} > docs/gallery/incisions.md
echo "make-incision-gallery: wrote docs/gallery/incisions.md"
