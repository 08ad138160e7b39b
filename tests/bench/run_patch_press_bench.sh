#!/usr/bin/env bash
# A probe pressed on each real heart's sewn patch (docs/benchmarks.md "Closing a defect"): for every
# case that tests/bench/run_repair_bench.sh repaired in DIR (CASE.vsd.h5, its plan CASE.repair.csv
# and the saved state CASE.repaired.h5), the plan played again, then hand 0 takes a 2 mm ball that
# comes in along the way the patch faced the tissue and stops 1 mm into a patch vertex, held there
# 300 ms. --at middle (the default) presses the vertex nearest the patch's middle, over the opening;
# --at rim the vertex nearest the midpoint of the first two stitches, where the patch lies on the
# tissue, and the same ball is pressed to the same place on the heart without a patch for comparison.
# Prints a Markdown table from the saved state: the force on the probe and its part straight back,
# how near the nearest patch vertex lies to the ball's centre (no nearer than 2.25 mm: the ball grown
# by half the patch's thickness), how far the patch moved, with --at rim the force on the ball
# without the patch and the smallest gap from a patch vertex under the ball to the detailed surface
# along the way the ball came (the contact keeps it half the patch's thickness, 0.25 mm; below zero
# the patch has gone into the tissue), the closure check (a 10 mmHg leak test, as documented) and
# watchdog events.
# Usage: tests/bench/run_patch_press_bench.sh [--from DIR (default build/repair-bench)] [--backend cpu|gl] [--at middle|rim]
set -euo pipefail
cd "$(dirname "$0")/../.."
from=build/repair-bench backend=cpu at=middle
while [ $# -gt 0 ]; do
  case "$1" in
    --from) from="$2"; shift 2 ;;
    --backend) backend="$2"; shift 2 ;;
    --at) at="$2"; shift 2 ;;
    -h|--help) sed -n 2,16p "$0"; exit 0 ;;
    *) echo "run_patch_press_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
case "$at" in middle|rim) ;; *) echo "run_patch_press_bench: --at takes middle or rim, not '$at'" >&2; exit 2 ;; esac
ls "$from"/*.repaired.h5 >/dev/null 2>&1 || { echo "run_patch_press_bench: no repaired heart in $from: run tests/bench/run_repair_bench.sh first" >&2; exit 1; }
heartsim=${HEARTSIM:-build/release/runtime/heartsim}
if [ -z "${HEARTSIM:-}" ]; then cmake --build --preset release --target heartsim >/dev/null; fi
if [ "$at" = rim ]; then
  echo "| case | force on the probe, N (straight back) | without the patch, N (straight back) | nearest patch vertex to its centre, mm | patch moved, mm | smallest gap to the surface under the ball, mm | defect closed, largest rim gap | watchdog |"
  echo "|---|---|---|---|---|---|---|---|"
else
  echo "| case | force on the probe, N (straight back) | nearest patch vertex to its centre, mm | patch moved, mm | defect closed, largest rim gap | watchdog |"
  echo "|---|---|---|---|---|---|"
fi
for state in "$from"/*.repaired.h5; do
  case=$(basename "$state" .repaired.h5)
  python3 - "$heartsim" "$backend" "$from" "$case" "$at" <<'PY'
import importlib.util, math, re, shutil, subprocess, sys
heartsim, backend, where, case, at = sys.argv[1:]
spec = importlib.util.spec_from_file_location("check_closure", "scripts/check-closure.py")
closure = importlib.util.module_from_spec(spec)
spec.loader.exec_module(closure)  # its h5dump reader


def rotate(q, v):  # v by the unit quaternion q = (w, x, y, z)
    w, u = q[0], q[1:]
    t = [2 * c for c in closure.cross(u, v)]
    c = closure.cross(u, t)
    return tuple(v[k] + w * t[k] + c[k] for k in range(3))


def sub(a, b):
    return tuple(a[k] - b[k] for k in range(3))


def ray_hit(origin, direction, a, b, c):
    """How far along `direction` from `origin` the ray meets triangle (a, b, c), or None."""
    e1, e2 = sub(b, a), sub(c, a)
    p = closure.cross(direction, e2)
    det = closure.dot(e1, p)
    if abs(det) < 1e-12:
        return None
    s = sub(origin, a)
    u = closure.dot(s, p) / det
    q = closure.cross(s, e1)
    v = closure.dot(direction, q) / det
    if u < 0 or v < 0 or u + v > 1:
        return None
    return closure.dot(e2, q) / det


plan = f"{where}/{case}.repair.csv"
rows = [l.split(",") for l in open(plan) if l.strip() and not l.startswith("#") and not l.startswith("time")]
end = max(float(r[0]) for r in rows)
patch_row = next(r for r in rows if r[2].strip() == "patch")
facing = rotate([float(v) for v in patch_row[6:10]], (0.0, 0.0, 1.0))
sewn = closure.read_dataset(f"{where}/{case}.repaired.h5", "/patch/positions", 3)
if at == "rim":
    anchors = closure.read_dataset(f"{where}/{case}.repaired.h5", "/patch/stitch_anchor", 3)
    target = [(anchors[0][k] + anchors[1][k]) / 2 for k in range(3)]
else:
    target = [sum(p[k] for p in sewn) / len(sewn) for k in range(3)]
pressed = min(sewn, key=lambda p: math.dist(p, target))
radius, half = 2.0, 0.25
away = [pressed[k] - facing[k] * (radius + half + 6.0) for k in range(3)]
inside = [pressed[k] - facing[k] * (radius + half - 1.0) for k in range(3)]
probe = ""
for t, p in ((end + 20, away), (end + 320, inside), (end + 620, inside)):
    probe += f"{t:.3f}, 0, probe, {p[0]:.6f}, {p[1]:.6f}, {p[2]:.6f}, 1, 0, 0, 0, {radius}, {radius}, {radius}, 0\n"
suffix = "" if at == "middle" else f".{at}"


def run(trajectory, state):
    done = subprocess.run([heartsim, "run", f"{where}/{case}.vsd.h5", "--headless", "--backend", backend, "--trajectory", trajectory,
                           "--seconds", f"{(end + 620) / 1000:.3f}", "--leak-test", "10", "--save-state", state], capture_output=True, text=True)
    text = done.stdout + done.stderr
    if done.returncode != 0:
        sys.exit(f"{case}: heartsim run failed:\n{text}")
    return text


press = f"{where}/{case}.press{suffix}.csv"
shutil.copy(plan, press)
with open(press, "a") as out:
    out.write(probe)
state = f"{where}/{case}.pressed{suffix}.h5"
text = run(press, state)
force = closure.read_dataset(state, "/instrument_forces", 3)[0]
back = -closure.dot(force, facing)
pressed_patch = closure.read_dataset(state, "/patch/positions", 3)
nearest = min(math.dist(p, inside) for p in pressed_patch)
moved = max(math.dist(a, b) for a, b in zip(sewn, pressed_patch))
verdict = re.search(r"defect closed: (yes|no), largest rim gap ([0-9.]+) mm", text)
watchdog = re.search(r"watchdog: (\d+) events", text)
cells = [f"{closure.norm(force):.2g} ({back:.2g})"]
if at == "rim":
    bare = f"{where}/{case}.press-bare.csv"
    with open(bare, "w") as out:
        out.write("time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n" + probe)
    run(bare, f"{where}/{case}.pressed-bare.h5")
    without = closure.read_dataset(f"{where}/{case}.pressed-bare.h5", "/instrument_forces", 3)[0]
    cells.append(f"{closure.norm(without):.2g} ({-closure.dot(without, facing):.2g})")
    # The gap under the ball: from each patch vertex within the ball's radius of its axis, along the
    # way it came, to the first surface triangle ahead (or behind, when it has gone in).
    surface = closure.read_dataset(state, "/visual/positions", 3)
    triangles = closure.read_dataset(f"{where}/{case}.vsd.h5", "/visual/triangles", 3, integer=True)
    near = {v for v, s in enumerate(surface) if math.dist(s, inside) < radius + 4.0}
    local = [t for t in triangles if t[0] in near or t[1] in near or t[2] in near]
    gap = math.inf
    for p in pressed_patch:
        d = sub(p, inside)
        along = closure.dot(d, facing)
        if closure.dot(d, d) - along * along > radius * radius:
            continue
        hits = [h for t in local if (h := ray_hit(p, facing, surface[t[0]], surface[t[1]], surface[t[2]])) is not None and abs(h) < 3.0]
        if hits:
            gap = min(gap, min(hits, key=abs))
    cells.append(f"{nearest:.3f}")
    cells.append(f"{moved:.2f}")
    cells.append(f"{gap:.2f}" if math.isfinite(gap) else "none under it")
else:
    cells += [f"{nearest:.3f}", f"{moved:.2f}"]
cells.append(f"{verdict.group(1)}, {verdict.group(2)} mm")
cells.append(watchdog.group(1) if watchdog else "0")
print(f"| {case} | " + " | ".join(cells) + " |", flush=True)
PY
done
