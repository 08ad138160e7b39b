#!/usr/bin/python3
"""heartsim runtime benchmark (docs/benchmarks.md "heartsim runtime"). Not a test: it prints Markdown tables and
writes CSV files, and never fails on a time. Run through tests/bench/run_runtime_bench.sh.

For the phantom (samples/phantom.nii.gz) and every real case (DATA/*/*-label.nii.gz, skipped
with a message if absent; read in place, never copied) it builds a scenario with
`heartprep build CASE --cavity 2 --anchor-border`, writes a scripted probe + grab trajectory for
it (below), and runs `heartsim run X.h5 --headless --steps N --trajectory T --stats-csv ...`:

- table1: Sørensen & Mosegaard's Table 1 (MMVR 2006) per backend: simulation substep, particle normals, visualisation
  step (frames from --screenshot-every at --size), picking buffer, force buffer (+ the cpu
  backend's position upload). gl runs this with --contact picking (K = 1) so every row is filled.
- speed: steps per second of gl and cpu, headless without rendering, --contact direct.
- contact (gl only): --contact direct | search | picking with --picking-refresh K = 1, 2, 4, 8;
  time of the picking-buffer pass (the "picking buffer" row: render + collect, or the search
  pass) and the final probe force (--save-state, read with h5dump) against search and direct.

The trajectory: hand 0 a probe (semi-axes 1.5 h, 1.2 h, 1.8 h for spacing h, its tool +z, the
picking camera's axis, pointing along world -x, into the tissue) at the right-most free particle
next to an anchor (the right-most particle when the scenario has no anchors; the instruments then
fall with the model, 1/2 g t^2), pressing in by 0.5 h + 2 h over the first half of the run, then
sliding --slide-mm along world z (towards the
model's middle) over the second half at that depth; hand 1 a grabber
(radius 1.5 h) at the left-most such particle, pulling 3 mm along -x over the run. N is a
multiple of 8 so the last force request (the compared one) comes K - 1 requests after the last
picking-buffer render for every K: the stalest case.

Every run's --stats-csv, state file, stdout and screenshot are kept under OUT/runs/CASE/.
"""

import argparse
import glob
import math
import os
import platform
import re
import subprocess
import sys

from bench_common import md_table, read_stats, run, write_csv

try:
    import numpy as np
except ImportError as error:
    sys.exit(f"runtime_bench: {error}; install python3-numpy and use /usr/bin/python3")

FLOAT = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?|[-+]?nan|[-+]?inf")


# ---------------------------------------------------------------------------------------------
# HDF5 through h5dump (Debian hdf5-tools; h5py is not assumed)


def h5_values(path, name, attribute=False):
    """The numbers of one dataset or attribute, flattened, as float64 (h5dump -m %.17g)."""
    cmd = ["h5dump", "-y", "-w", "0", "-m", "%.17g", "-a" if attribute else "-d", name, path]
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if proc.returncode != 0 or "DATA {" not in proc.stdout:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr}{proc.stdout[:2000]}")
    text = proc.stdout.split("DATA {", 1)[1].split("}", 1)[0]
    return np.array([float(v) for v in FLOAT.findall(text)], dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Running the programs


def load_average():
    try:
        return " ".join(open("/proc/loadavg").read().split()[:3])
    except OSError:
        return "?"


# ---------------------------------------------------------------------------------------------
# Scenario and trajectory


def scenario_geometry(h5):
    rest = h5_values(h5, "/particles/rest_position").reshape(-1, 3)
    anchored = h5_values(h5, "/particles/anchored").astype(bool)
    index = h5_values(h5, "/particles/lattice_index").reshape(-1, 3).astype(np.int64)
    spacing = float(h5_values(h5, "/lattice/spacing", attribute=True)[0])
    dt = float(h5_values(h5, "/solver/dt_ms", attribute=True)[0])
    gravity = h5_values(h5, "/solver/gravity", attribute=True)[:3]
    return rest, anchored, index, spacing, dt, gravity


def instrument_sites(rest, anchored, index):
    """(right, left) particle indices: extreme x among free particles with an anchored lattice
    neighbour (26-neighbourhood), or among all particles when there is none."""
    candidates = np.zeros(len(rest), dtype=bool)
    if anchored.any():
        low = index.min(axis=0) - 1
        shape = tuple(index.max(axis=0) - low + 2)
        grid = np.zeros(shape, dtype=bool)
        i = index - low
        grid[i[anchored, 0], i[anchored, 1], i[anchored, 2]] = True
        near = np.zeros(len(rest), dtype=bool)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    if dx or dy or dz:
                        near |= grid[i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz]
        candidates = near & ~anchored
    if not candidates.any():
        candidates[:] = True
    ids = np.nonzero(candidates)[0]
    return int(ids[np.argmax(rest[ids, 0])]), int(ids[np.argmin(rest[ids, 0])])


def write_trajectory(path, h5, steps, slide_mm):
    rest, anchored, index, spacing, dt, gravity = scenario_geometry(h5)
    right, left = instrument_sites(rest, anchored, index)
    falls = not anchored.any()
    r = 1.5 * spacing
    probe_axes = (r, 0.8 * r, 1.2 * r)
    q_probe = (math.sqrt(0.5), 0.0, -math.sqrt(0.5), 0.0)  # tool +z -> world -x
    start = rest[right] + np.array([probe_axes[2] + 0.5 * spacing, 0, 0])
    press = 0.5 * spacing + 2.0 * spacing
    # Slide along z towards the model's middle (away from the border slice the anchors sit on).
    slide_dir = 1.0 if rest[:, 2].mean() > rest[right, 2] else -1.0
    lines = ["# runtime_bench.py: probe pressing then sliding (hand 0), grabber pulling (hand 1)",
             "time_ms, hand, kind, x, y, z, qw, qx, qy, qz, ax, ay, az, grab"]
    half = steps // 2
    keys = sorted(set(list(range(0, steps + 1, 10)) + [half, steps]))
    for step in keys:
        t = step * dt
        fall = 0.5 * gravity * t * t if falls else np.zeros(3)
        lateral = np.array([0, 0, slide_dir * slide_mm * max(0.0, (step - half) / (steps - half))])
        p = start + fall + lateral + np.array([-press * min(1.0, step / half), 0, 0])
        g = rest[left] + fall - np.array([3.0 * step / steps, 0, 0])
        lines.append(f"{t:.9g}, 0, probe, {p[0]:.9g}, {p[1]:.9g}, {p[2]:.9g}, "
                     f"{q_probe[0]:.17g}, {q_probe[1]:.17g}, {q_probe[2]:.17g}, {q_probe[3]:.17g}, "
                     f"{probe_axes[0]:.9g}, {probe_axes[1]:.9g}, {probe_axes[2]:.9g}, 0")
        lines.append(f"{t:.9g}, 1, grabber, {g[0]:.9g}, {g[1]:.9g}, {g[2]:.9g}, 1, 0, 0, 0, {r:.9g}, {r:.9g}, {r:.9g}, 1")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return {"particles": len(rest), "anchored": int(anchored.sum()), "spacing_mm": spacing, "dt_ms": dt,
            "falls": falls, "slide_mm_per_step": slide_mm / (steps - half)}


def read_state(path):
    return {"positions": h5_values(path, "/positions").reshape(-1, 3),
            "forces": h5_values(path, "/instrument_forces").reshape(2, 3),
            "particles": h5_values(path, "/instrument_particles").astype(int)}


# ---------------------------------------------------------------------------------------------
# Output


def mean_ms(stats, name):
    row = stats.get(name)
    if not row or int(row["calls"]) == 0:
        return None
    return float(row["mean_ms"])


# ---------------------------------------------------------------------------------------------


def main():
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--heartsim", required=True)
    ap.add_argument("--heartprep", required=True)
    ap.add_argument("--out", default="/tmp/heartsim-runtime-bench", help="results folder (CSV files, scenarios, runs)")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(repo), "shared/data/real"),
                    help="folder of real cases (*/ *-label.nii.gz)")
    ap.add_argument("--cases", default="", help="comma-separated names to keep (phantom, pat1, ...); default all")
    ap.add_argument("--steps", type=int, default=200, help="solver steps per run (rounded up to a multiple of 8)")
    ap.add_argument("--backends", default="gl,cpu")
    ap.add_argument("--parts", default="table1,speed,contact")
    ap.add_argument("--size", default="320x240", help="frame size of the table-1 runs (visualisation step)")
    ap.add_argument("--frames", type=int, default=8, help="rendered frames in a table-1 run (--screenshot-every steps/frames)")
    ap.add_argument("--slide-mm", type=float, default=2.0, help="probe slide over the second half of the run")
    ap.add_argument("--refresh", default="1,2,4,8", help="picking refresh K values")
    ap.add_argument("--label", action="append", default=[], metavar="NAME=PATH",
                    help="a label map to run instead of the phantom and the real cases (repeatable)")
    ap.add_argument("--prep-args", default="", help="more heartprep build options, e.g. '--particles 20270'")
    args = ap.parse_args()

    steps = max(8, (args.steps + 7) // 8 * 8)
    parts = set(args.parts.split(","))
    backends = [b for b in args.backends.split(",") if b]
    refresh = [int(k) for k in args.refresh.split(",") if k]
    keep = set(c for c in args.cases.split(",") if c)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)

    # Which device runs it (heartsim info: EGL surfaceless, the same context heartsim run gets).
    renderer = "unavailable"
    try:
        _, info = run([args.heartsim, "info"])
        print(info.strip())
        m = re.search(r"^\s*renderer\s*[:=]?\s*(.+)$", info, re.M | re.I)
        renderer = m.group(1).strip() if m else info.strip().splitlines()[0]
    except RuntimeError as error:
        print(f"heartsim info failed (no OpenGL?): {error}")
        if "gl" in backends:
            print("the gl backend will fail too; run with --backends cpu")
    start_load = load_average()
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    print(f"\nmachine: {platform.node()}, {os.cpu_count()} CPUs, {cpu}; "
          f"load average {start_load} at the start; GL renderer: {renderer}")
    print(f"steps per run {steps}, frame size {args.size}, {args.frames} frames per table-1 run\n")

    cases = [("phantom", os.path.join(repo, "samples/phantom.nii.gz"))]
    real = sorted(glob.glob(os.path.join(args.data, "*", "*-label.nii.gz")))
    if args.label:
        cases = [tuple(item.split("=", 1)) for item in args.label]
        if any(len(c) != 2 or not c[0] for c in cases):
            sys.exit("runtime_bench: --label takes NAME=PATH")
    elif not real:
        print(f"real cases: no *-label.nii.gz under {args.data}, skipped")
    for path in [] if args.label else real:
        name = os.path.basename(path).replace("-label.nii.gz", "")
        cases.append((re.sub(r"^training_axial_crop_", "", name), path))
    if keep:
        cases = [c for c in cases if c[0] in keep]

    table1, speed, contact, agreement = [], [], [], []
    for name, label in cases:
        work = os.path.join(out, "runs", name)
        os.makedirs(work, exist_ok=True)
        h5 = os.path.join(out, "scenarios", name + ".h5")
        os.makedirs(os.path.dirname(h5), exist_ok=True)
        run([args.heartprep, "build", label, "-o", h5, "--cavity", "2", "--anchor-border", "-q"] + args.prep_args.split(),
            os.path.join(work, "heartprep.log"))
        traj = os.path.join(work, "trajectory.csv")
        geo = write_trajectory(traj, h5, steps, args.slide_mm)
        print(f"{name}: {geo['particles']} particles, {geo['anchored']} anchored, h {geo['spacing_mm']:.3g} mm, "
              f"dt {geo['dt_ms']:.4g} ms{', falls (no anchors)' if geo['falls'] else ''}; load {load_average()}")

        def heartsim(tag, backend, extra, state=False):
            stats = os.path.join(work, f"{tag}.stats.csv")
            cmd = [args.heartsim, "run", h5, "--headless", "--backend", backend, "--steps", str(steps),
                   "--trajectory", traj, "--stats", "--stats-csv", stats] + extra
            if state:
                cmd += ["--save-state", os.path.join(work, f"{tag}.state.h5")]
            run(cmd, os.path.join(work, f"{tag}.log"))
            return read_stats(stats)

        if "table1" in parts:
            for backend in backends:
                extra = ["--screenshot", os.path.join(work, f"table1_{backend}.png"),
                         "--screenshot-every", str(max(1, steps // args.frames)), "--size", args.size]
                if backend == "gl":
                    extra += ["--contact", "picking", "--picking-refresh", "1"]
                s = heartsim(f"table1_{backend}", backend, extra)
                any_row = next(iter(s.values()))
                vis = s["visualisation step"]
                table1.append({
                    "case": name, "backend": backend, "renderer": any_row["renderer"], "particles": int(any_row["particles"]),
                    "contact": any_row["contact"], "size": args.size,
                    "simulation_substep_ms": mean_ms(s, "simulation step"), "substeps": int(s["simulation step"]["calls"]),
                    "normals_ms": mean_ms(s, "particle normals"), "visualisation_ms": mean_ms(s, "visualisation step"),
                    "frames": int(vis["calls"]), "position_upload_ms": mean_ms(s, "position upload"),
                    "picking_ms": mean_ms(s, "picking buffer"), "force_ms": mean_ms(s, "force buffer"),
                    "force_requests": int(s["force buffer"]["calls"]), "timing": s["simulation step"]["timing"],
                    "steps_per_s": float(any_row["steps_per_s"])})

        states = {}
        if "speed" in parts or "contact" in parts:
            for backend in backends if "speed" in parts else ["gl"]:
                s = heartsim(f"speed_{backend}", backend, [], state=True)
                row = next(iter(s.values()))
                states[backend] = read_state(os.path.join(work, f"speed_{backend}.state.h5"))
                sub = float(row["step_pass_substeps_per_s"])
                speed.append({
                    "case": name, "backend": backend, "renderer": row["renderer"], "particles": int(row["particles"]),
                    "steps": int(row["steps"]), "substeps": int(row["substeps"]), "dt_ms": geo["dt_ms"],
                    "wall_ms": float(row["wall_ms"]), "steps_per_s": float(row["steps_per_s"]),
                    "substeps_per_s": float(row["substeps_per_s"]), "step_pass_substeps_per_s": sub or None,
                    "real_time_factor": float(row["steps_per_s"]) * geo["dt_ms"] * 1e-3})
            if "gl" in states and "cpu" in states:
                # The same gesture on both backends (tests/test_runtime_backend.cpp's criterion: positions within
                # 1e-4 of the model's size).
                rest = h5_values(h5, "/particles/rest_position").reshape(-1, 3)
                size = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))
                dx = float(np.abs(states["gl"]["positions"] - states["cpu"]["positions"]).max())
                moved = float(np.abs(states["cpu"]["positions"] - rest).max())
                fg, fc = states["gl"]["forces"], states["cpu"]["forces"]
                df = [float(np.linalg.norm(fg[h] - fc[h]) / max(np.linalg.norm(fc[h]), 1e-30)) for h in range(2)]
                agree = dx <= 1e-4 * size
                agreement.append({"case": name, "particles": geo["particles"], "size_mm": size, "max_displacement_mm": moved,
                                  "max_position_diff_mm": dx, "relative_to_size": dx / size, "probe_force_rel_diff": df[0],
                                  "grab_force_rel_diff": df[1], "agrees": agree})

        if "contact" in parts and "gl" in backends:
            runs = [("direct", 1, "speed_gl")]
            modes = [("search", 1)] + [("picking", k) for k in refresh]
            for mode, k in modes:
                tag = f"contact_{mode}" + (f"_k{k}" if mode == "picking" else "")
                heartsim(tag, "gl", ["--contact", mode] + (["--picking-refresh", str(k)] if mode == "picking" else []), state=True)
                states[tag] = read_state(os.path.join(work, f"{tag}.state.h5"))
                runs.append((mode, k, tag))
            states["speed_gl"] = states["gl"]
            ref_search = states["contact_search"]["forces"][0]
            ref_direct = states["speed_gl"]["forces"][0]
            for mode, k, tag in runs:
                s = read_stats(os.path.join(work, f"{tag}.stats.csv"))
                st = states[tag]
                f = st["forces"][0]

                def rel(a, b):
                    n = np.linalg.norm(b)
                    return float(np.linalg.norm(a - b) / n) if n > 0 else (0.0 if np.linalg.norm(a) == 0 else float("inf"))

                contact.append({
                    "case": name, "mode": mode, "K": k if mode == "picking" else "",
                    "picking_ms": mean_ms(s, "picking buffer"), "picking_calls": int(s["picking buffer"]["calls"]),
                    "force_ms": mean_ms(s, "force buffer"), "simulation_substep_ms": mean_ms(s, "simulation step"),
                    "probe_force_n": float(np.linalg.norm(f)), "probe_particles": int(st["particles"][0]),
                    "rel_diff_vs_search": rel(f, ref_search), "rel_diff_vs_direct": rel(f, ref_direct),
                    "grab_rel_diff_vs_direct": rel(st["forces"][1], states["speed_gl"]["forces"][1]),
                    "max_position_diff_vs_direct_mm": float(np.abs(st["positions"] - states["speed_gl"]["positions"]).max()),
                    "slide_mm_per_step": geo["slide_mm_per_step"]})

    end_load = load_average()
    print(f"\nload average {start_load} at the start, {end_load} at the end")
    print(f"GL renderer: {renderer}" + ("  (Mesa llvmpipe is a CPU rasteriser: trends only, not GPU figures)" if "llvmpipe" in renderer else ""))

    if table1:
        write_csv(os.path.join(out, "runtime_table1.csv"), table1)
        print(f"\nTable 1: mean ms per call ({steps} steps; visualisation at {args.size}; gl: GPU timer queries, "
              f"--contact picking K = 1; cpu: wall clock for the step and force rows)\n")
        md_table(["case", "backend", "particles", "simulation substep", "particle normals", "visualisation step", "position upload",
                  "picking buffer", "force buffer", "substeps", "frames", "force requests"],
                 [[r["case"], r["backend"], r["particles"], r["simulation_substep_ms"], r["normals_ms"], r["visualisation_ms"],
                   r["position_upload_ms"], r["picking_ms"], r["force_ms"], r["substeps"], r["frames"], r["force_requests"]]
                  for r in table1])
    if speed:
        write_csv(os.path.join(out, "runtime_speed.csv"), speed)
        print(f"\nSpeed: headless, no rendering, --contact direct, {steps} steps of the probe + grab script\n")
        by = {(r["case"], r["backend"]): r for r in speed}
        rows = []
        for name, _ in cases:
            g, c = by.get((name, "gl")), by.get((name, "cpu"))
            ref = g or c
            if not ref:
                continue
            rows.append([name, ref["particles"], ref["substeps"] / ref["steps"], ref["dt_ms"],
                         g and g["steps_per_s"], g and g["step_pass_substeps_per_s"], c and c["steps_per_s"],
                         c and c["step_pass_substeps_per_s"], (g["steps_per_s"] / c["steps_per_s"]) if g and c else None,
                         g and g["real_time_factor"], c and c["real_time_factor"]])
        md_table(["case", "particles", "substeps/step", "dt ms", "gl steps/s", "gl substeps/s (step pass)", "cpu steps/s",
                  "cpu substeps/s (step pass)", "gl / cpu", "gl real-time factor", "cpu real-time factor"], rows)
    if agreement:
        write_csv(os.path.join(out, "runtime_gl_cpu.csv"), agreement)
        print(f"\ngl = cpu: the speed runs' final states ({steps} steps of the same gesture); agrees when max |x_gl − x_cpu| "
              f"≤ 1e-4 of the model's size (tests/test_runtime_backend.cpp)\n")
        md_table(["case", "particles", "size mm", "max displacement mm", "max |x_gl − x_cpu| mm", "of the size",
                  "probe |ΔF|/|F|", "grab |ΔF|/|F|", "agrees"],
                 [[r["case"], r["particles"], r["size_mm"], r["max_displacement_mm"], r["max_position_diff_mm"],
                   r["relative_to_size"], r["probe_force_rel_diff"], r["grab_force_rel_diff"], "yes" if r["agrees"] else "NO"]
                  for r in agreement])
    if contact:
        write_csv(os.path.join(out, "runtime_contact.csv"), contact)
        print(f"\nContact (gl): picking-buffer row per force request (render + collect; search: its pass), final probe force "
              f"after {steps} steps (the last request {steps - 1}: K − 1 after the last render), probe sliding "
              f"{contact[0]['slide_mm_per_step']:.3g} mm/step in the second half\n")
        md_table(["case", "mode", "K", "picking buffer ms", "force buffer ms", "simulation substep ms", "probe |F| N",
                  "contact particles", "rel. diff vs search", "rel. diff vs direct", "max |Δx| vs direct mm"],
                 [[r["case"], r["mode"], r["K"], r["picking_ms"], r["force_ms"], r["simulation_substep_ms"], r["probe_force_n"],
                   r["probe_particles"], r["rel_diff_vs_search"], r["rel_diff_vs_direct"], r["max_position_diff_vs_direct_mm"]]
                  for r in contact])
    return 0 if all(r["agrees"] for r in agreement) else 1


if __name__ == "__main__":
    sys.exit(main())
