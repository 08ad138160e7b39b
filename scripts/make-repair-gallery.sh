#!/usr/bin/env bash
# Regenerates the septal-defect repair part of docs/gallery/: every real case (../shared/data/real;
# skipped with a message where absent) built by heartprep with a ventricular septal defect (MM-WHS
# hearts with their label convention, heartprep placing the defect; the HVSMR hearts --at a point
# of their septum, as scripts/make-defect-gallery.sh), the repair `heartsim plan-repair` plans on
# it (a patch laid over the opening on the right ventricle's side, or the left where the right's
# rim is too rough to seal, stitches round its rim)
# played headless on the cpu backend for the --seconds the plan suggests, and drawn in the section
# view across the defect (--clip defect --view section, 640x480): the whole section, and a close-up
# 60 mm from the defect's centre (--look-at). Each run's closure check ("defect closed: …") goes
# under its pictures. Writes docs/gallery/repairs.md.
# Usage: scripts/make-repair-gallery.sh [BUILD_DIR]   (default build/release, built first)
set -euo pipefail
cd "$(dirname "$0")/.."
real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-repair-gallery: $real is absent: no gallery regenerated" >&2; exit 0; fi
bin=${1:-build/release}
if [ "$bin" = build/release ]; then cmake --build --preset release --target heartprep heartsim >/dev/null; fi
work=build/repair-gallery
mkdir -p "$work" docs/gallery
. scripts/real-cases.sh
# What each picture shows (looked at when the gallery was made; say again when the data or the rule changes).
declare -A shows=(
  [pat0]="closed from the left (plan-repair's --side auto: the right side's rim lies among trabeculations): the patch lies flat across the opening's left-ventricular mouth, right of the septum here, knots along its edge; the cleft that joins the opening to the right ventricle (below it, left) stays on the patch's far side"
  [pat1]="the patch across the opening on the right-ventricular face, bowing a little into it, knots at both ends of the cut"
  [pat5]="the patch across the opening on the right-ventricular face, its lower part lying along the septum's surface, a knot at its lower end"
  [pat6]="a straight patch across the opening on the right-ventricular face, knots along it"
  [ct1002]="MM-WHS labels the left ventricle's wall only, so the septum's right face is the heart's outside: the patch spans the opening's right mouth, curving with the wall, knots at both ends"
  [wh]="the defect sits at the septum's upper rim: the patch drapes over the crest on its right side, seen partly face on, knots at its ends"
)
rows=()
for dir in "$real"/*/; do
  name=$(basename "$dir")
  input=$(ls "$dir"*label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  options=$(vsd_options "$name") || continue
  read -ra options <<<"$options"
  case=${name#hvsmr16_}; case=${case#mmwhs_}
  echo "make-repair-gallery: $name"
  # As labelled (--walls labelled): the repair is planned on the septum alone; on the whole heart
  # heartprep grows by default it is not yet made to close on every heart (below).
  "$bin/tools/heartprep" build "$input" "${options[@]}" --walls labelled -o "$work/$case.h5" -q 2>/dev/null
  plan=$("$bin/runtime/heartsim" plan-repair "$work/$case.h5" -o "$work/$case.csv")
  seconds=$(echo "$plan" | sed -n 's/.*run it .*--seconds \([0-9.]*\).*/\1/p')
  centre=$(echo "$plan" | sed -n 's/^ *defect .* centred at (\([^)]*\)) mm.*/\1/p' | tr -d ' ')
  patch=$(echo "$plan" | sed -n 's/^ *patch *\(a disc [0-9.]* mm across and [0-9.]* mm thick\).*/\1/p')
  stitches=$(echo "$plan" | sed -n 's/.*a patch and \([0-9]*\) stitches.*/\1/p')
  diameter=$(echo "$plan" | sed -n 's/^ *defect *vsd, \([0-9.]*\) mm across.*/\1/p')
  closure=""
  for shot in section closeup; do
    look=(--look-at "$centre")  # the whole section: the fitted distance (--clip defect alone comes close)
    [ "$shot" = closeup ] && look=(--look-at "$centre,60")
    log=$("$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --trajectory "$work/$case.csv" --seconds "$seconds" --leak-test 10 \
      --clip defect --view section "${look[@]}" --size 640x480 --screenshot "docs/gallery/$case-repair-$shot.png")
    if ! echo "$log" | grep -q "^repair: .* patch laid"; then
      echo "make-repair-gallery: $case: no patch was laid:" >&2
      echo "$log" >&2
      exit 1
    fi
    closure=$(echo "$log" | grep "^defect closed:" || true)
  done
  rows+=("| $case | ![$case repaired, the section across the defect]($case-repair-section.png) | ![$case repaired, 60 mm from the defect]($case-repair-closeup.png) | a $diameter mm VSD; $patch, $stitches stitches; $closure | ${shows[$case]:-} |")
done
{
  echo "# Septal defect repairs"
  echo
  echo "Every real case built as labelled with a ventricular septal defect (\`heartprep build CASE --defect vsd --walls labelled\`;"
  echo "on the MM-WHS hearts heartprep places it, perimembranous; on the HVSMR hearts \`--at\` a point of"
  echo "the septum, as in [defects.md](defects.md)), the repair \`heartsim plan-repair\` plans on it"
  echo "(docs/runtime.md \"Closing a defect\"): a pericardium patch laid over the opening on the right"
  echo "ventricle's side of the septum (the left ventricle's where the right's rim is too rough to seal),"
  echo "then a needle tying stitches round its rim (as many as the plan"
  echo "makes by default), 2 mm beyond the opening's edge. Played by \`heartsim run --headless --backend"
  echo "cpu --trajectory\` for the \`--seconds\` the plan suggests and drawn in the section view across"
  echo "the defect (\`--clip defect --view section\`: the plane holds the defect's axis, the camera looks"
  echo "straight at it, the septum a dark band of cut wall with the opening as a gap in it). The patch"
  echo "(ivory) lies across the gap on one side of the band, seen nearly edge on, its cut face where the"
  echo "plane crosses it; the stitches' knots (blue) sit on it at the rim; the needle (gold) is where the"
  echo "gesture left it. Left the whole section, right a close-up 60 mm from the defect's centre"
  echo "(\`--look-at\`). Under them, the patch the plan chose and the closure check the run printed"
  echo "(libmodel/surgery/closure.h, docs/closure.md: the patch held to 10 mmHg across the septum). Regenerate"
  echo "with \`scripts/make-repair-gallery.sh\`."
  echo
  echo "The hearts are built as their label maps are (\`--walls labelled\`), the septum's right face then"
  echo "the heart's outside on the MM-WHS hearts. On the whole heart heartprep builds by default (walls"
  echo "grown round the right ventricle's blood), the same plan closes the defect on the HVSMR hearts and"
  echo "on ct1002 (held to 10 mmHg), but on wh the fill finds a way out between two stitches (8 and 9):"
  echo "the repair through the whole heart is not yet planned for it."
  echo
  echo "| case | the section across the defect | close-up | patch and closure | what it shows |"
  echo "|---|---|---|---|---|"
  printf '%s\n' "${rows[@]}"
} > docs/gallery/repairs.md
echo "make-repair-gallery: wrote docs/gallery/repairs.md"
