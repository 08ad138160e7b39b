#!/usr/bin/env bash
# heartsim haptics benchmark: the device thread's period p50/p99/max with the machine
# idle, under simulation load and under simulation + rendering load; pose → force latency; the
# error of the force rendered between simulation updates with hold against extrapolation; and the
# force error of the picking buffer against its refresh interval K. Records haptic sessions with
# `heartsim run … --device … --record`, analyses them with haptics_bench (tests/bench/
# haptics_bench.cpp) and `heartsim run … --replay`. Prints Markdown tables and writes them to
# OUT/haptics_bench.md (CSV beside). Not a test: nothing here fails on a time.
# docs/benchmarks.md, "Haptics".
#
# Run from anywhere (it works in the repository root):
#   tests/bench/run_haptics_bench.sh [--out DIR] [--seconds S] [--quick] [--parts LIST]
#       [--k-steps N] [--refresh 1,2,4,8] [--data DIR] [--no-build]
# Environment: BUILD_DIR (default build/release, the release preset's; relative to the repository),
#   JOBS (build jobs, default: the build tool's), HEARTSIM / HEARTPREP / HAPTICS_BENCH (binaries;
#   when any is given nothing is built). Needs awk, sed, timeout; xvfb-run for the full-load row,
#   h5dump for the tool motion of part picking, an OpenGL 4.3 device for part picking.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$repo"

usage() {
  cat <<EOF
usage: tests/bench/run_haptics_bench.sh [options]

Records haptic sessions with heartsim and prints, as Markdown tables (also into OUT/haptics_bench.md):
  period   haptic period p50/p99/max and pose -> force latency: idle (a scripted device on a
           1000-particle phantom), simulation load (12000-particle phantom, two hands simulated +
           scripted, cpu backend, headless), full load (the same in the window under Xvfb, so
           llvmpipe rendering loads the CPU too), pat1 headless (30000 particles; needs --data)
  interp   force error of the device thread against the published forces: --interpolation hold
           against extrapolate, the same two-hand phantom session
  picking  a probe session recorded with --backend gl --contact search, replayed with --contact
           picking --picking-refresh K and --contact direct; force error against search per K
           (needs OpenGL 4.3: llvmpipe here, so slow and not GPU timings; skipped without gl)

options:
  --out DIR         scenarios, recordings, logs and tables (default /tmp/heartsim-haptics-bench)
  --seconds S       wall seconds per recorded session of parts period and interp (default 5)
  --quick           short sessions: --seconds 2, --k-steps 50
  --parts LIST      comma-separated subset of period,interp,picking (default all)
  --k-steps N       steps of the gl search recording of part picking (default 200, about 2.5 s
                    wall on llvmpipe here); each replay runs as many
  --refresh LIST    picking refresh intervals K (default 1,2,4,8)
  --data DIR        HVSMR cases (default ../shared/data/real); pat1 is skipped if absent
  --no-build        do not build; use the binaries in BUILD_DIR (or HEARTSIM, HEARTPREP, HAPTICS_BENCH)
  -h, --help        this text

environment:
  BUILD_DIR         build tree (default build/release, the release preset's binaryDir); with the
                    default it runs 'cmake --build --preset release --target heartprep heartsim
                    haptics_bench', else 'cmake --build BUILD_DIR --target ...' (configured as
                    Release with Ninja if it has no CMakeCache.txt)
  JOBS              parallel build jobs (e.g. JOBS=1 on a shared machine)
  HEARTSIM, HEARTPREP, HAPTICS_BENCH
                    binaries to use; when any is given nothing is built
EOF
}

out=/tmp/heartsim-haptics-bench
seconds=5
k_steps=200
quick=0
parts=period,interp,picking
refresh=1,2,4,8
data="$repo/../shared/data/real"
build=1
seconds_given=0
k_steps_given=0
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="${2:?--out needs a folder}"; shift 2 ;;
    --seconds) seconds="${2:?--seconds needs a number}"; seconds_given=1; shift 2 ;;
    --k-steps) k_steps="${2:?--k-steps needs a number}"; k_steps_given=1; shift 2 ;;
    --quick) quick=1; shift ;;
    --parts) parts="${2:?--parts needs a list}"; shift 2 ;;
    --refresh) refresh="${2:?--refresh needs a list}"; shift 2 ;;
    --data) data="${2:?--data needs a folder}"; shift 2 ;;
    --no-build) build=0; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "run_haptics_bench: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
if [ "$quick" = 1 ]; then
  [ "$seconds_given" = 1 ] || seconds=2
  [ "$k_steps_given" = 1 ] || k_steps=50
fi
is_number() { [[ "$1" =~ ^[0-9]+([.][0-9]+)?$ ]] && awk -v x="$1" 'BEGIN { exit !(x > 0) }'; }
is_number "$seconds" || { echo "run_haptics_bench: --seconds '$seconds': expected a positive number" >&2; exit 2; }
[[ "$k_steps" =~ ^[1-9][0-9]*$ ]] || { echo "run_haptics_bench: --k-steps '$k_steps': expected a positive integer" >&2; exit 2; }
[[ "$refresh" =~ ^[0-9]+(,[0-9]+)*$ ]] || { echo "run_haptics_bench: --refresh '$refresh': expected e.g. 1,2,4,8" >&2; exit 2; }
want() { [[ ",$parts," == *",$1,"* ]]; }
for p in ${parts//,/ }; do
  case "$p" in period|interp|picking) ;; *) echo "run_haptics_bench: --parts: unknown part '$p' (period, interp, picking)" >&2; exit 2 ;; esac
done

for tool in awk sed grep uptime timeout; do
  command -v "$tool" >/dev/null || { echo "run_haptics_bench: '$tool' not found" >&2; exit 1; }
done

# ---- binaries -------------------------------------------------------------------------------
BUILD_DIR="${BUILD_DIR:-build/release}"
case "$BUILD_DIR" in /*) ;; *) BUILD_DIR="$repo/$BUILD_DIR" ;; esac
if [ "$build" = 1 ] && [ -z "${HEARTSIM:-}${HEARTPREP:-}${HAPTICS_BENCH:-}" ]; then
  command -v cmake >/dev/null || { echo "run_haptics_bench: cmake not found (or pass --no-build)" >&2; exit 1; }
  jobs=()
  [ -n "${JOBS:-}" ] && jobs=(-j "$JOBS")
  echo "building heartprep heartsim haptics_bench in $BUILD_DIR" >&2
  if [ "$BUILD_DIR" = "$repo/build/release" ]; then
    [ -f "$BUILD_DIR/CMakeCache.txt" ] || cmake --preset release >&2
    cmake --build --preset release --target heartprep heartsim haptics_bench "${jobs[@]}" >&2
  else
    [ -f "$BUILD_DIR/CMakeCache.txt" ] || cmake -S "$repo" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >&2
    cmake --build "$BUILD_DIR" --target heartprep heartsim haptics_bench "${jobs[@]}" >&2
  fi
fi
HEARTSIM="${HEARTSIM:-$BUILD_DIR/runtime/heartsim}"
if [ -z "${HEARTPREP:-}" ]; then
  HEARTPREP="$BUILD_DIR/tools/heartprep/heartprep"
  [ -f "$HEARTPREP" ] || HEARTPREP="$BUILD_DIR/tools/heartprep"
fi
HAPTICS_BENCH="${HAPTICS_BENCH:-$BUILD_DIR/tests/bench/haptics_bench}"
for b in "$HEARTSIM" "$HEARTPREP" "$HAPTICS_BENCH"; do
  [ -x "$b" ] && [ ! -d "$b" ] || { echo "run_haptics_bench: no binary $b; build it (drop --no-build) or set BUILD_DIR" >&2; exit 1; }
done
if ! "$HEARTSIM" run --help 2>/dev/null | grep -q -- --replay-tolerance; then
  echo "run_haptics_bench: $HEARTSIM has no --record/--replay-tolerance; rebuild it" >&2
  exit 1
fi

mkdir -p "$out/logs" "$out/rec" "$out/scenarios"
out="$(cd "$out" && pwd)"
report="$out/haptics_bench.md"
: >"$report"
say() { printf '%s\n' "$*" | tee -a "$report"; }

# The 1-minute load average, sampled every 5 s for the whole run (load.txt), and per session.
load1() { cut -d' ' -f1 /proc/loadavg; }
( while sleep 5; do printf '%s %s\n' "$(date +%T)" "$(cut -d' ' -f1-3 /proc/loadavg)"; done ) >"$out/load.txt" &
sampler=$!
trap 'kill "$sampler" 2>/dev/null || true' EXIT

gl_renderer="$("$HEARTSIM" info 2>/dev/null | sed -n 's/^ *renderer[: ]*//Ip' | head -1 || true)"
say "# heartsim haptics benchmark ($(date '+%F %T'))"
say ""
say "- machine: $(nproc) cores, $(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1); GL: ${gl_renderer:-unavailable}"
say "- uptime at start: $(uptime)"
say "- sessions: ${seconds} s (parts period, interp); gl search recording ${k_steps} steps; K = $refresh"
say "- binaries: $HEARTSIM, $HAPTICS_BENCH"
say ""

declare -A load_of wall_of
# run_logged NAME CMD...: runs CMD (output to logs/NAME.log), keeps its load and wall time; on a
# failure prints the log's tail and stops.
run_logged() {
  local name="$1"; shift
  local log="$out/logs/$name.log" before t0 t1 rc=0
  before="$(load1)"
  t0="$(date +%s.%N)"
  printf '%s\n' "$*" >"$log"
  "$@" >>"$log" 2>&1 || rc=$?
  t1="$(date +%s.%N)"
  load_of[$name]="$before→$(load1)"
  wall_of[$name]="$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.1f", b - a }')"
  if [ "$rc" != 0 ]; then
    echo "run_haptics_bench: $name failed (exit $rc); the end of $log:" >&2
    tail -n 20 "$log" >&2
    return "$rc"
  fi
}

# ---- scenarios ------------------------------------------------------------------------------
phantom_nii="$repo/samples/phantom.nii.gz"
[ -f "$phantom_nii" ] || { echo "run_haptics_bench: $phantom_nii missing" >&2; exit 1; }
tiny="$out/scenarios/phantom1k.h5"
phantom="$out/scenarios/phantom12k.h5"
pat1="$out/scenarios/pat1.h5"
pat1_nii="$data/hvsmr16_pat1/training_axial_crop_pat1-label.nii.gz"
prep_flags=(--cavity 2 --anchor-border --gravity 0 0 0)
[ -f "$tiny" ] || run_logged prep_phantom1k "$HEARTPREP" build "$phantom_nii" -o "$tiny" "${prep_flags[@]}" --particles 1000
[ -f "$phantom" ] || run_logged prep_phantom12k "$HEARTPREP" build "$phantom_nii" -o "$phantom" "${prep_flags[@]}" --particles 12000
have_pat1=0
if want period; then
  if [ -f "$pat1_nii" ]; then
    [ -f "$pat1" ] || run_logged prep_pat1 "$HEARTPREP" build "$pat1_nii" -o "$pat1" --cavity 2 --gravity 0 0 0
    have_pat1=1
  else
    echo "run_haptics_bench: $pat1_nii not found (--data): the pat1 row is skipped" >&2
  fi
fi

press="$repo/samples/haptics/press_phantom.csv"
grab="$repo/samples/haptics/grab_phantom.csv"
two_hands=(--device "simulated:$press" --device "scripted:$grab")
step_ms() { sed -n 's/^cpu backend: .*; step \([0-9.e+-]*\) ms.*/\1/p;s/^gl backend: .*; step \([0-9.e+-]*\) ms.*/\1/p' "$1" | head -1; }

# csv_table CSV COLUMN... : a Markdown table of the named columns of haptics_bench's CSV (first
# column renamed by the map in $label_of; a column "load" is taken from load_of).
declare -A label_of
csv_table() {
  local csv="$1"; shift
  local cols="$*" labels="" name
  for name in "${!label_of[@]}"; do labels+="$name=${label_of[$name]}|"; done
  local loads=""
  for name in "${!load_of[@]}"; do loads+="$name=${load_of[$name]} (${wall_of[$name]} s)|"; done
  awk -F, -v cols="$cols" -v labels="$labels" -v loads="$loads" '
    BEGIN { n = split(cols, want, " "); split(labels, l, "|"); for (i in l) { split(l[i], kv, "="); lab[kv[1]] = kv[2] }
            split(loads, m, "|"); for (i in m) { p = index(m[i], "="); if (p) ld[substr(m[i], 1, p - 1)] = substr(m[i], p + 1) } }
    /^#/ { next }
    !header { for (i = 1; i <= NF; i++) idx[$i] = i; header = 1
              line = "|"; sep = "|"
              for (j = 1; j <= n; j++) { h = want[j]; gsub(/_/, " ", h); line = line " " h " |"; sep = sep "---|" }
              print line; print sep; next }
    { line = "|"
      for (j = 1; j <= n; j++) {
        c = want[j]
        if (c == "load") v = ($1 in ld) ? ld[$1] : "—"
        else if (c == "recording") v = ($1 in lab) ? lab[$1] : $1
        else { gsub(/_/, " ", c); v = (c in idx) ? $(idx[c]) : "?" }
        if (v == "") v = "—"
        line = line " " v " |" }
      print line }' "$csv"
}

# ---- part period: period and latency --------------------------------------------------------
if want period; then
  recs=()
  run_logged idle "$HEARTSIM" run "$tiny" --headless --backend cpu --device "scripted:$grab" --instrument grabber \
    --seconds "$seconds" --record "$out/rec/idle.h5"
  recs+=("$out/rec/idle.h5"); label_of[idle]="idle (1000 particles, one scripted grabber)"
  run_logged simload "$HEARTSIM" run "$phantom" --headless --backend cpu "${two_hands[@]}" --interpolation hold \
    --seconds "$seconds" --record "$out/rec/simload.h5"
  recs+=("$out/rec/simload.h5"); label_of[simload]="simulation load (phantom 12k, headless)"
  if command -v xvfb-run >/dev/null; then
    dt="$(step_ms "$out/logs/simload.log")"
    steps="$(awk -v s="$seconds" -v dt="$dt" 'BEGIN { n = s * 1000 / dt; printf "%d", (n == int(n)) ? n : int(n) + 1 }')"
    # The window ends after --steps; the timeout only guards against a window that never closes.
    limit="$(awk -v s="$seconds" 'BEGIN { printf "%d", 120 + 40 * s }')"
    if run_logged fullload timeout "$limit" xvfb-run -a -s "-screen 0 1280x800x24" "$HEARTSIM" run "$phantom" --backend cpu \
        "${two_hands[@]}" --interpolation hold --steps "$steps" --record "$out/rec/fullload.h5"; then
      recs+=("$out/rec/fullload.h5"); label_of[fullload]="full load (phantom 12k, window under Xvfb, $steps steps)"
    else
      echo "run_haptics_bench: the window run failed or did not end after --steps $steps within ${limit} s (logs/fullload.log); row skipped" >&2
    fi
  else
    echo "run_haptics_bench: xvfb-run not found (apt-get install xvfb): the full-load row is skipped" >&2
  fi
  if [ "$have_pat1" = 1 ]; then
    run_logged pat1 "$HEARTSIM" run "$pat1" --headless --backend cpu --device "simulated:$repo/samples/haptics/press_pat1.csv" \
      --device "scripted:$repo/samples/haptics/grab_pat1.csv" --seconds "$seconds" --record "$out/rec/pat1.h5"
    recs+=("$out/rec/pat1.h5"); label_of[pat1]="pat1 (30k, headless)"
  fi
  "$HAPTICS_BENCH" --part timing "${recs[@]}" >"$out/period.txt"
  "$HAPTICS_BENCH" --part timing --format csv --no-header "${recs[@]}" >"$out/period.csv"
  say "## Period and latency (haptic thread 1000 Hz, target p99 ≤ 1.5 ms; latency target ≤ 2 steps)"
  say ""
  csv_table "$out/period.csv" recording particles dt_ms RTF step_wall_ms load periods period_p50_ms period_p99_ms period_p99.9_ms \
    period_max_ms periods_\>1.5_ms overruns latency_p50_ms latency_p99_ms latency_max_ms lat_steps_p50 lat_steps_p99 \
    lat_steps_max | tee -a "$report"
  say ""
  say "load: 1-minute load average before → after the session (its wall time). RTF: simulated / wall time;"
  say "step wall ms: mean wall time per simulation step. lat steps: steps from the first step using a pose to"
  say "the first forces published from it (1 = that step's own forces)."
  say "Every column and the latency definitions: $out/period.txt (haptics_bench's header)."
  say ""
fi

# ---- part interp: hold against extrapolate -------------------------------------------------
if want interp; then
  if [ ! -f "$out/rec/simload.h5" ] || ! want period; then
    run_logged simload "$HEARTSIM" run "$phantom" --headless --backend cpu "${two_hands[@]}" --interpolation hold \
      --seconds "$seconds" --record "$out/rec/simload.h5"
  fi
  run_logged extrapolate "$HEARTSIM" run "$phantom" --headless --backend cpu "${two_hands[@]}" --interpolation extrapolate \
    --seconds "$seconds" --record "$out/rec/extrapolate.h5"
  # Open loop: both runs replay the same device motion (hand 0's recorded poses of the hold session
  # as a pose script), so only the rendering between updates differs, not what the hand did.
  open_loop=(--device "scripted:$out/rec/simload.h5@0" --device "scripted:$grab")
  run_logged hold_open "$HEARTSIM" run "$phantom" --headless --backend cpu "${open_loop[@]}" --instrument probe --instrument grabber \
    --interpolation hold --seconds "$seconds" --record "$out/rec/hold_open.h5"
  run_logged extrapolate_open "$HEARTSIM" run "$phantom" --headless --backend cpu "${open_loop[@]}" --instrument probe --instrument grabber \
    --interpolation extrapolate --seconds "$seconds" --record "$out/rec/extrapolate_open.h5"
  label_of[simload]="closed loop, hold"; label_of[extrapolate]="closed loop, extrapolate"
  label_of[hold_open]="open loop, hold"; label_of[extrapolate_open]="open loop, extrapolate"
  recs=("$out/rec/simload.h5" "$out/rec/extrapolate.h5" "$out/rec/hold_open.h5" "$out/rec/extrapolate_open.h5")
  [ -f "$out/rec/fullload.h5" ] && want period && recs+=("$out/rec/fullload.h5") && label_of[fullload]="closed loop, hold, full load (window)"
  [ -f "$out/rec/pat1.h5" ] && want period && recs+=("$out/rec/pat1.h5") && label_of[pat1]="closed loop, hold, pat1 (30k)"
  "$HAPTICS_BENCH" --part force --per-hand "${recs[@]}" >"$out/interp.txt"
  "$HAPTICS_BENCH" --part force --per-hand --format csv --no-header "${recs[@]}" >"$out/interp.csv"
  say "## Force between simulation updates: hold against extrapolate"
  say ""
  csv_table "$out/interp.csv" recording hand interpolation RTF load ticks_compared err_rms_N err_max_N ref_rms_N err_rms_rel \
    err_max_rel ref_roughness | tee -a "$report"
  say ""
  say "Error of the force before safety at each device tick against the published simulation forces linearly"
  say "interpolated at the tick (non-causal reference), ticks with safety gain 1 inside the published range;"
  say "rel = error / RMS reference force. Phantom 12k, headless, cpu. Closed loop: hand 0 the simulated probe"
  say "(press sample, moved by the rendered force), hand 1 the scripted grabber. Open loop: hand 0 replays the"
  say "closed-loop hold session's device poses (scripted:simload.h5@0), the same in both runs. ref roughness:"
  say "RMS second / first difference of the published samples (≪ 1 smooth; ≥ 1.4 alternating sample to sample)."
  say ""
fi

# ---- part picking: force error against the picking refresh K --------------------------------
if want picking; then
  if ! "$HEARTSIM" info >"$out/logs/gl_info.log" 2>&1; then
    echo "run_haptics_bench: no OpenGL 4.3 device (heartsim info failed, logs/gl_info.log): the K rows are skipped" >&2
    say "## Picking refresh K: skipped (no OpenGL device)"
  else
    # A probe (hand 0 only) pressed 4.5 mm posterior into the phantom's anterior RV wall (the press
    # sample's start) over 0.3 s, then sliding ±3 mm along z, 3 mm per 0.3 s (10 mm/s), for two
    # minutes (the last row is held): the pose script runs in wall time, and the llvmpipe
    # simulation ~40× slower than real time, so the tool moves ~0.1–0.2 mm per step, where a
    # stale picking buffer shows. The session is --k-steps steps (heartsim's --seconds is not
    # used: the step count fixes the gesture whatever the speed).
    probe="$out/scenarios/k_probe.csv"
    awk 'BEGIN { print "# time_ms, x, y, z, qw, qx, qy, qz (run_haptics_bench.sh: press, then slide along z)"
      print "0, -24.6, -42.0, 2.7, 1, 0, 0, 0"; t = 300; print t ", -24.6, -37.5, 2.7, 1, 0, 0, 0"
      for (i = 0; i < 400; i++) { t += 300; z = (i % 4 == 0) ? 5.7 : (i % 4 == 2) ? -0.3 : 2.7
        printf "%d, -24.6, -37.5, %.1f, 1, 0, 0, 0\n", t, z } }' >"$probe"
    run_logged k_search "$HEARTSIM" run "$phantom" --headless --backend gl --contact search --device "scripted:$probe" \
      --steps "$k_steps" --record "$out/rec/k_search.h5"
    csv="$out/picking.csv"
    echo "contact,K,steps,compared,identical,max_df_N,rms_df_N,largest_N,wall_ms" >"$csv"
    replay_row() {  # $1 = name, $2 = contact, $3 = K, rest: options
      local name="$1" contact="$2" k="$3"; shift 3
      run_logged "$name" "$HEARTSIM" run "$phantom" --headless --backend gl --contact "$contact" "$@" \
        --replay "$out/rec/k_search.h5" --replay-tolerance 1e9
      sed -nE 's/^replay: ([0-9]+) steps in ([0-9.e+-]+) ms; ([0-9]+) forces compared, ([0-9]+) bit for bit identical; max \|Δf\| ([0-9.e+-]+) N, rms ([0-9.e+-]+) N \(largest recorded force ([0-9.e+-]+) N.*/\1,\3,\4,\5,\6,\7,\2/p' \
        "$out/logs/$name.log" | head -1 | sed "s/^/$contact,$k,/" >>"$csv"
      [ "$(tail -1 "$csv" | cut -d, -f1)" = "$contact" ] || { echo "run_haptics_bench: no replay line in logs/$name.log" >&2; exit 1; }
    }
    replay_row k_replay_search search —
    for k in ${refresh//,/ }; do replay_row "k_replay_picking_$k" picking "$k" --picking-refresh "$k"; done
    replay_row k_replay_direct direct —
    steps_k="$(sed -n 's/.*simulation: \([0-9]*\) steps.*/\1/p' "$out/logs/k_search.log" | head -1)"
    rtf_k="$(sed -n 's/.*real-time factor \([0-9.e+-]*\)).*/\1/p' "$out/logs/k_search.log" | head -1)"
    say "## Picking refresh K (gl on ${gl_renderer:-?}; NOT GPU timings)"
    say ""
    motion="(h5dump not found)"
    command -v h5dump >/dev/null && motion="$(h5dump -d /steps/tool_position_mm -y -w 0 "$out/rec/k_search.h5" 2>/dev/null | grep -E '^ *-?[0-9]' | tr -d ' ' |
      awk -F, 'NR % 2 == 1 { if (n) { d = sqrt(($1 - x) ^ 2 + ($2 - y) ^ 2 + ($3 - z) ^ 2); s += d; if (d > m) m = d } x = $1; y = $2; z = $3; n++ }
               END { if (n > 1) printf "mean %.3g mm, max %.3g mm", s / (n - 1), m; else print "?" }' || true)"
    say "Reference: a session recorded with --backend gl --contact search (${steps_k:-?} steps in ${wall_of[k_search]} s wall, real-time"
    say "factor ${rtf_k:-?}, load ${load_of[k_search]}), one scripted probe pressed into the phantom's anterior wall and sliding"
    say "along it (tool motion per step: ${motion}); each row replays its tool poses (--replay, --replay-tolerance 1e9)"
    say "and compares every step's probe force with the recorded one (one force request per step: K counts steps)."
    say ""
    say "| contact | K | steps | forces compared | bit-identical | max \\|Δf\\| N | rms \\|Δf\\| N | max / largest force | rms / largest force | replay wall ms |"
    say "|---|---|---|---|---|---|---|---|---|---|"
    awk -F, 'NR > 1 { printf "| %s | %s | %s | %s | %s | %s | %s | %.3g | %.3g | %s |\n", $1, $2, $3, $4, $5, $6, $7, ($8 > 0 ? $6 / $8 : 0), ($8 > 0 ? $7 / $8 : 0), $9 }' \
      "$csv" | tee -a "$report"
    say ""
    say "largest recorded probe force: $(awk -F, 'NR == 2 { print $8 }' "$csv") N. search against its own recording is the replay's noise floor."
    say ""
    "$HAPTICS_BENCH" --format csv --no-header "$out/rec/k_search.h5" >"$out/k_search.csv"
    label_of[k_search]="gl search session (llvmpipe)"
    say "The gl session's device thread and latency (llvmpipe steps are slow, so the latency in ms is large):"
    say ""
    csv_table "$out/k_search.csv" recording particles dt_ms RTF step_wall_ms load periods period_p50_ms period_p99_ms period_max_ms \
      overruns latency_p50_ms latency_p99_ms latency_max_ms lat_steps_p50 lat_steps_p99 lat_steps_max | tee -a "$report"
    say ""
  fi
fi

say "- uptime at end: $(uptime)"
say "- load average (1, 5, 15 min) sampled every 5 s: $out/load.txt; min/max 1-min: $(awk 'NR == 1 { lo = hi = $2 } { if ($2 < lo) lo = $2; if ($2 > hi) hi = $2 } END { if (NR) printf "%s / %s", lo, hi; else print "—" }' "$out/load.txt")"
echo "wrote $report (logs, recordings and CSV in $out)" >&2
