#!/usr/bin/env bash
# A probe pressed on each real heart's sewn patch (docs/benchmarks.md "Closing a defect"): for every
# case that tests/bench/run_repair_bench.sh repaired in DIR (CASE.vsd.h5, its plan CASE.repair.csv
# and the saved state CASE.repaired.h5), the plan played again, then hand 0 takes a 2 mm ball that
# comes in along the way the patch faced the tissue and stops 1 mm into the patch vertex nearest the
# patch's middle (over the opening), held there 300 ms. Prints a Markdown table from the saved state:
# the force on the probe and its part straight back, how near the nearest patch vertex lies to the
# ball's centre (no nearer than 2.25 mm: the ball grown by half the patch's thickness), how far the
# patch moved, the closure check (the default 10 mmHg leak test) and watchdog events.
# Usage: tests/bench/run_patch_press_bench.sh [--from DIR (default build/repair-bench)] [--backend cpu|gl]
set -euo pipefail
cd "$(dirname "$0")/../.."
from=build/repair-bench backend=cpu
while [ $# -gt 0 ]; do
  case "$1" in
    --from) from="$2"; shift 2 ;;
    --backend) backend="$2"; shift 2 ;;
    -h|--help) sed -n 2,10p "$0"; exit 0 ;;
    *) echo "run_patch_press_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
ls "$from"/*.repaired.h5 >/dev/null 2>&1 || { echo "run_patch_press_bench: no repaired heart in $from: run tests/bench/run_repair_bench.sh first" >&2; exit 1; }
heartsim=${HEARTSIM:-build/release/runtime/heartsim}
if [ -z "${HEARTSIM:-}" ]; then cmake --build --preset release --target heartsim >/dev/null; fi
echo "| case | force on the probe, N (straight back) | nearest patch vertex to its centre, mm | patch moved, mm | defect closed, largest rim gap | watchdog |"
echo "|---|---|---|---|---|---|"
for state in "$from"/*.repaired.h5; do
  case=$(basename "$state" .repaired.h5)
  python3 - "$heartsim" "$backend" "$from" "$case" <<'PY'
import importlib.util, math, re, shutil, subprocess, sys
heartsim, backend, where, case = sys.argv[1:]
spec = importlib.util.spec_from_file_location("check_closure", "scripts/check-closure.py")
closure = importlib.util.module_from_spec(spec)
spec.loader.exec_module(closure)  # its h5dump reader


def rotate(q, v):  # v by the unit quaternion q = (w, x, y, z)
    w, u = q[0], q[1:]
    t = [2 * c for c in closure.cross(u, v)]
    c = closure.cross(u, t)
    return tuple(v[k] + w * t[k] + c[k] for k in range(3))


plan = f"{where}/{case}.repair.csv"
rows = [l.split(",") for l in open(plan) if l.strip() and not l.startswith("#") and not l.startswith("time")]
end = max(float(r[0]) for r in rows)
patch_row = next(r for r in rows if r[2].strip() == "patch")
facing = rotate([float(v) for v in patch_row[6:10]], (0.0, 0.0, 1.0))
sewn = closure.read_dataset(f"{where}/{case}.repaired.h5", "/patch/positions", 3)
middle = [sum(p[k] for p in sewn) / len(sewn) for k in range(3)]
pressed = min(sewn, key=lambda p: math.dist(p, middle))
radius, half = 2.0, 0.25
away = [pressed[k] - facing[k] * (radius + half + 6.0) for k in range(3)]
inside = [pressed[k] - facing[k] * (radius + half - 1.0) for k in range(3)]
press = f"{where}/{case}.press.csv"
shutil.copy(plan, press)
with open(press, "a") as out:
    for t, p in ((end + 20, away), (end + 320, inside), (end + 620, inside)):
        out.write(f"{t:.3f}, 0, probe, {p[0]:.6f}, {p[1]:.6f}, {p[2]:.6f}, 1, 0, 0, 0, {radius}, {radius}, {radius}, 0\n")
state = f"{where}/{case}.pressed.h5"
run = subprocess.run([heartsim, "run", f"{where}/{case}.vsd.h5", "--headless", "--backend", backend, "--trajectory", press,
                      "--seconds", f"{(end + 620) / 1000:.3f}", "--save-state", state], capture_output=True, text=True)
text = run.stdout + run.stderr
if run.returncode != 0:
    sys.exit(f"{case}: heartsim run failed:\n{text}")
force = closure.read_dataset(state, "/instrument_forces", 3)[0]
back = -closure.dot(force, facing)
pressed_patch = closure.read_dataset(state, "/patch/positions", 3)
nearest = min(math.dist(p, inside) for p in pressed_patch)
moved = max(math.dist(a, b) for a, b in zip(sewn, pressed_patch))
verdict = re.search(r"defect closed: (yes|no), largest rim gap ([0-9.]+) mm", text)
watchdog = re.search(r"watchdog: (\d+) events", text)
print(f"| {case} | {closure.norm(force):.2g} ({back:.2g}) | {nearest:.3f} | {moved:.2f} | {verdict.group(1)}, {verdict.group(2)} mm | "
      f"{watchdog.group(1) if watchdog else 0} |")
PY
done
