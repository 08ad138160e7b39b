#!/usr/bin/env bash
# Regenerates the operation part of docs/gallery/ (docs/gallery/operations.md): the seed's Figure 1
# on every real heart. Each case of ../shared/data/real (skipped with a message where absent) is
# built whole by heartprep's defaults with a 10 mm ventricular septal defect (MM-WHS hearts with
# their label convention, heartprep placing the defect; the HVSMR hearts --at a point of their
# septum: scripts/real-cases.sh); `heartsim plan-operation --approach all` plans both approaches;
# each planned approach is played headless on the cpu backend and drawn from the surgeon's eye the
# plan records in its CSV (# view: --view surgeon --eye … --look-at the defect's face; 640x480),
# where heartsim run opens without view options: at the moment the plan
# says the defect is exposed, and at the operation's end, the patch sewn. The operation's run holds
# the patch to --leak-test MMHG (default 75, the run's: the systolic difference) and its summary (defect closed, the
# stitches in the conduction zone, the real-time factor) goes in the table, beside the same heart
# run as long with no instrument (its real-time factor).
# Usage: scripts/make-operation-gallery.sh [--leak-test MMHG] [BUILD_DIR]   (default build/release, built first)
set -euo pipefail
cd "$(dirname "$0")/.."
real=../shared/data/real
leak=75
if [ "${1:-}" = --leak-test ]; then leak=$2; shift 2; fi
if [ ! -d "$real" ]; then echo "make-operation-gallery: $real is absent: no gallery regenerated" >&2; exit 0; fi
bin=${1:-build/release}
if [ "$bin" = build/release ]; then cmake --build --preset release --target heartprep heartsim >/dev/null; fi
work=build/operation-gallery
mkdir -p "$work" docs/gallery
. scripts/real-cases.sh
field() { sed -n "s/$1/\\1/p" <<<"$2" | head -1; }
pictures=() table=()
for dir in "$real"/*/; do
  name=$(basename "$dir")
  input=$(ls "$dir"*label.nii.gz 2>/dev/null | head -1 || true)
  [ -n "$input" ] || continue
  options=$(vsd_options "$name") || { echo "make-operation-gallery: $name: no place known for a VSD: skipped" >&2; continue; }
  read -ra options <<<"$options"
  case=${name#hvsmr16_}; case=${case#mmwhs_}
  echo "make-operation-gallery: $name" >&2
  [ -f "$work/$case.h5" ] || "$bin/tools/heartprep" build "$input" "${options[@]}" -o "$work/$case.h5" -q 2>/dev/null
  # Exit 1 where neither approach has an incision: each approach's line then says why.
  plans=$("$bin/runtime/heartsim" plan-operation "$work/$case.h5" -o "$work/$case.csv" --approach all 2>&1) || true
  echo "$plans" > "$work/$case.plan.txt"
  without=""
  for approach in right-atrial right-ventricular; do
    plan=$(awk -v a="(--approach $approach)" 'index($0, "plan-operation:") == 1 { on = index($0, a) > 0 } on' <<<"$plans")
    if grep -q "^plan-operation: no " <<<"$plan"; then
      why=$(sed 's/^plan-operation: no [^:]*: //' <<<"$plan" | head -1)
      table+=("| $case | $approach | no incision: $why | | | | | | | |")
      pictures+=("| $case | $approach | no incision | | $why |")
      rm -f "docs/gallery/$case-$approach-exposed.png" "docs/gallery/$case-$approach-sewn.png"
      continue
    fi
    csv="$work/$case.$approach.csv"
    exposed=$(field '.*defect exposed at: \([0-9.]*\) s.*' "$plan")
    seconds=$(field '.*run it .*--seconds \([0-9.]*\).*' "$plan")
    seen=$(field '.*rim seen *\([0-9]* of [0-9]*\) stitch sites.*' "$plan")
    incision=$(field '.*incision *\([0-9]* mm\) along.*' "$plan")
    wall=$(field '.*then through the \([0-9.]*\) mm wall.*' "$plan")
    blood=$(field '.*goes \([0-9.]*\) mm through blood.*' "$plan")
    coronary=$(field '.*coronaries  the nearest course, .*, is \([0-9.]*\) mm from.*' "$plan")
    [ -n "$coronary" ] || coronary="not known"
    spread=$(field '.*pull them \([0-9.]*\) mm apart.*' "$plan")
    view=(--size 640x480)  # the run opens from the surgeon's eye the CSV records
    "$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --trajectory "$csv" --seconds "$exposed" "${view[@]}" \
      --screenshot "docs/gallery/$case-$approach-exposed.png" > "$work/$case.$approach.exposed.log"
    "$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --trajectory "$csv" --seconds "$seconds" "${view[@]}" \
      --leak-test "$leak" --screenshot "docs/gallery/$case-$approach-sewn.png" > "$work/$case.$approach.log"
    log=$(cat "$work/$case.$approach.log")
    closed=$(field '.*defect closed: \(yes\|no\).*' "$log")
    gap=$(field '.*largest rim gap \([0-9.]*\) mm.*' "$log")
    zone=$(field '.*stitches in the conduction zone: \([0-9]* of [0-9]*\).*' "$log")
    [ -n "$zone" ] || zone="no zone"
    rtf=$(field '.*real-time factor \([0-9.e+-]*\).*' "$log")
    if [ -z "$without" ]; then
      without=$("$bin/runtime/heartsim" run "$work/$case.h5" --headless --backend cpu --seconds "$seconds" | sed -n 's/.*real-time factor \([0-9.e+-]*\).*/\1/p')
    fi
    table+=("| $case | $approach | $incision, $spread mm open | $wall | $coronary | $blood | $seen | $closed, $gap mm | $zone | $rtf / $without |")
    pictures+=("| $case | $approach | ![$case, $approach, the defect exposed]($case-$approach-exposed.png) | ![$case, $approach, the patch sewn]($case-$approach-sewn.png) | defect exposed at $exposed s; closed at $leak mmHg: $closed, largest rim gap $gap mm |")
  done
done
{
  echo "# Operations"
  echo
  echo "The seed's Figure 1 on every real heart: each case built whole with a 10 mm ventricular septal defect"
  echo "(\`heartprep build CASE --defect vsd\`, heartprep's defaults: walls grown, 30,000 particles; on the HVSMR hearts"
  echo "\`--at\` a point of the septum), \`heartsim plan-operation CASE.h5 -o op.csv --approach all\` (docs/runtime.md"
  echo "\"Planning an operation\"), each approach run headless on the cpu backend and drawn from the surgeon's eye"
  echo "the plan records (\`# view: --view surgeon --eye X,Y,Z --look-at X,Y,Z\`): the defect exposed through the retracted"
  echo "incision, then the patch sewn through it. Made by \`scripts/make-operation-gallery.sh --leak-test $leak\`."
  echo
  echo "## The two approaches compared"
  echo
  echo "Incision: its length and how far the retractors open it. Wall: its thickness along the line of sight."
  echo "Nearest coronary: the nearest coronary course (the landmarks; not known where the label map does not tell"
  echo "the chambers apart). Blood: the line of sight's way from the defect to the wall. Rim seen: the stitch sites"
  echo "seen from the eye through the opening (the plan's estimate on the rest geometry). Closed: the run's closure"
  echo "check at $leak mmHg and its largest rim gap. Zone: the stitches in the conduction zone (a perimembranous"
  echo "defect where the landmarks give the tricuspid and aortic rings). Real-time factor: the operation's run"
  echo "against the same heart run as long with no instrument (cpu backend, this 2-core machine)."
  echo
  echo "| case | approach | incision | wall, mm | nearest coronary, mm | blood, mm | rim seen | closed, largest rim gap | zone | real-time factor, operation / uncut |"
  echo "|---|---|---|---|---|---|---|---|---|---|"
  printf '%s\n' "${table[@]}"
  echo
  echo "## From the surgeon's eye"
  echo
  echo "| case | approach | the defect exposed | the patch sewn | |"
  echo "|---|---|---|---|---|"
  printf '%s\n' "${pictures[@]}"
} > docs/gallery/operations.md
echo "make-operation-gallery: wrote docs/gallery/operations.md" >&2
