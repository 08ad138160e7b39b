#!/usr/bin/env bash
# Regenerates the incision part of docs/gallery/: every real case (../shared/data/real; skipped
# with a message where absent) built by heartprep with its defaults (MM-WHS hearts with their
# label convention), both approaches of `heartsim plan-incision` (a right ventriculotomy and a
# right atriotomy, each with two retractors pulling the edges 6 mm apart), played headless on the
# cpu backend for the --seconds the plan suggests, and drawn from outside, looking at the opened
# incision from the --view and --look-at the plan prints (640x480). Writes docs/gallery/incisions.md.
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
  [pat0]="ventriculotomy: the right ventricle's anterior free wall, a clean slit held open, the cut faces inside; atriotomy: the right lateral wall below the open right atrioventricular orifice (the atrial wall is not in the segmentation), a slit held open"
  [pat1]="ventriculotomy: the anterior free wall, held open; atriotomy: the thin right wall beside the atrioventricular orifice, the incision gapes widest at its top"
  [pat5]="ventriculotomy: the anterior free wall near the acute margin, held open with the cavity showing through; atriotomy: the right wall in front of the open atrioventricular orifice, a wide lens of cut faces"
  [pat6]="ventriculotomy: the anterior free wall, a narrow slit; atriotomy: lands on the ragged rim of the open right atrioventricular orifice, the cut is hard to make out among the segmentation's holes"
  [ct1002]="MM-WHS labels the left ventricle's wall only: ventriculotomy on the left ventricle's anterior wall, held open; atriotomy on the septum's right face near the base, a V-shaped notch"
  [wh]="MM-WHS labels the left ventricle's wall only: ventriculotomy on the left ventricle's anterior wall; atriotomy on the septum's right face below its upper rim, a short notch"
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
    view=$(echo "$plan" | sed -n 's/.*see it *add --view \([a-z]*\) --look-at.*/\1/p')
    look=$(echo "$plan" | sed -n 's/.*see it .*--look-at \([-0-9.,]*\).*/\1/p')
    where=$(echo "$plan" | sed -n 's/.*particle [0-9]* at (\([^)]*\)) mm.*/\1/p')
    log=$("$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --trajectory "$work/$case-$approach.csv" \
      --seconds "$seconds" --size 640x480 --view "$view" --look-at "$look" --screenshot "docs/gallery/$case-$approach.png")
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
  echo "Every real case built with \`heartprep build CASE -o CASE.h5\` (the defaults; \`--labels mmwhs\` or"
  echo "\`mmwhs-ordinal\` for the MM-WHS hearts), the two incisions \`heartsim plan-incision\` plans on it"
  echo "(docs/runtime.md \"Planning an incision\"): a 30 mm right ventriculotomy through the most anterior"
  echo "wall of the heart's middle third, the blade pointing posterior, and a 30 mm right atriotomy on the"
  echo "most rightward wall of its upper half that holds the whole cut, the blade pointing medially; each"
  echo "cut from inferior to superior, then two retractors (the gold spheres) grab its edges and pull them"
  echo "6 mm apart. Played by \`heartsim run --headless --backend cpu --trajectory\` for the \`--seconds\`"
  echo "the plan suggests and drawn from the \`--view\` and \`--look-at\` it prints: the camera outside,"
  echo "75 mm from the incision's centre (from the front for the ventriculotomy, from the patient's right"
  echo "for the atriotomy: the patient's front on the picture's right). The cut faces, drawn in a deeper"
  echo "red, line the opened incision. Under each picture, the point the plan chose (LPS mm). Regenerate"
  echo "with \`scripts/make-incision-gallery.sh\`."
  echo
  echo "The segmentations label no atrial wall (HVSMR 2016's myocardium is the ventricles' wall, MM-WHS's"
  echo "the left ventricle's): the atriotomy's rule finds the most rightward wall of the upper half, which"
  echo "on these hearts lies beside the right atrioventricular junction or, on the MM-WHS hearts, on the"
  echo "septum's right face; the ventriculotomy lands on the right ventricle's anterior wall of the HVSMR"
  echo "hearts and on the left ventricle's of the MM-WHS hearts."
  echo
  echo "| case | right ventriculotomy (from the front) | right atriotomy (from the patient's right) | what it shows |"
  echo "|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
} > docs/gallery/incisions.md
echo "make-incision-gallery: wrote docs/gallery/incisions.md"
