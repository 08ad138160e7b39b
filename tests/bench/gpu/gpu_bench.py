"""heartsim on a GPU machine (docs/benchmarks.md, "On a GPU"). Run through gpu_bench.sh, from the
unpacked bundle (make-bundle.sh), which sets the library path and NVIDIA's EGL vendor file.
Not a test: it prints Markdown tables, writes CSV files under --out, and fails only when a program
fails or the gl backend disagrees with the cpu backend.

1. The machine: GPU (nvidia-smi -L), CPU, heartsim info (the EGL platform and renderer).
2. Sørensen & Mosegaard's Table 1 at the paper's 20,270 particles, the gl and cpu speed and the
   picking-buffer comparison (runtime_bench.py on the phantom at 0.5 mm voxels, --particles 20270),
   and gl = cpu on the same gesture (positions within 1e-4 of the model's size).
3. gl at 30k, 100k, 300k and 1M particles: substeps/s and the real-time factor, headless, no
   rendering, the same phantom built with --gravity 0 0 0 --no-visual (the rest-state balance of a
   1M model takes minutes and changes nothing in a step's cost).
4. The cpu backend at 30k particles on 1, 2, 4, 8 and 16 cores (taskset: TBB takes the affinity).
"""

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import time

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, here)
from bench_common import md_table, read_stats, run, write_csv  # noqa: E402

RAN = re.compile(r"ran (\d+) steps \((\d+) substeps\), ([0-9.e+-]+) ms simulated in ([0-9.e+-]+) ms wall: "
                 r"([0-9.e+-]+) substeps/s, real-time factor ([0-9.e+-]+)")


def log(text):
    print(text, flush=True)


def headless_run(heartsim, h5, backend, seconds, work, tag, prefix=()):
    stats = os.path.join(work, f"{tag}.stats.csv")
    cmd = list(prefix) + [heartsim, "run", h5, "--headless", "--backend", backend, "--seconds", str(seconds),
                          "--stats", "--stats-csv", stats]
    wall, text = run(cmd, os.path.join(work, f"{tag}.log"), timeout=300)
    m = RAN.search(text)
    if not m:
        raise RuntimeError(f"{tag}: no 'ran N steps' line in heartsim's output:\n{text[-2000:]}")
    s = read_stats(stats)
    step = s["simulation step"]
    return {"steps": int(m.group(1)), "substeps": int(m.group(2)), "simulated_ms": float(m.group(3)),
            "wall_ms": float(m.group(4)), "substeps_per_s": float(m.group(5)), "real_time_factor": float(m.group(6)),
            "step_pass_substeps_per_s": float(step["step_pass_substeps_per_s"] or 0) or None,
            "substep_ms": float(step["mean_ms"]), "timing": step["timing"], "particles": int(step["particles"]),
            "renderer": step["renderer"], "process_s": wall}


def measured(what, rows, extra, run_it):
    """Appends one headless run's figures and `extra` to `rows`, logged; False (logged with the
    reason) when the run failed."""
    try:
        r = run_it()
    except (RuntimeError, subprocess.TimeoutExpired) as error:
        log(f"{what}: {error}")
        return False
    r.update(extra)
    rows.append(r)
    log(f"{what}: {r['particles']} particles, {r['substeps_per_s']:.0f} substeps/s, real-time factor {r['real_time_factor']:.3g}")
    return True


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--heartsim", required=True)
    ap.add_argument("--heartprep", required=True)
    ap.add_argument("--out", default="/tmp/heartsim-gpu-bench")
    ap.add_argument("--quick", action="store_true", help="small sizes and short runs: a check of the script, not figures")
    ap.add_argument("--sizes", default="30000,100000,300000,1000000")
    ap.add_argument("--threads", default="1,2,4,8,16")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per gl run (cpu: half)")
    ap.add_argument("--skip", default="", help="comma-separated parts to skip: table1, sizes, threads")
    args = ap.parse_args()
    skip = set(p for p in args.skip.split(",") if p)
    sizes = [int(n) for n in args.sizes.split(",") if n]
    threads = [int(n) for n in args.threads.split(",") if n]
    seconds = args.seconds
    voxel = "0.5"
    table1_particles = "20270"
    if args.quick:
        sizes, threads, seconds, voxel, table1_particles = [3000, 8000], [1, 2], 0.05, "1", "3000"
    out = os.path.abspath(args.out)
    work = os.path.join(out, "work")
    os.makedirs(work, exist_ok=True)
    t0 = time.time()

    # 1. The machine.
    gpu = "no nvidia-smi"
    if shutil.which("nvidia-smi"):
        gpu = subprocess.run(["nvidia-smi", "-L"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True).stdout.strip()
    cpu = platform.machine()
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    _, info = run([args.heartsim, "info"])
    log(f"GPU: {gpu}\nCPU: {os.cpu_count()} × {cpu}\n\nheartsim info:\n{info.strip()}\n")
    renderer = next((l.split(None, 1)[1] for l in info.splitlines() if l.startswith("renderer")), "?")
    egl = next((l.split(None, 1)[1] for l in info.splitlines() if l.startswith("platform")), "?")

    label = os.path.join(work, "phantom.nii.gz")
    run([args.heartprep, "phantom", "-o", label, "--voxel", voxel], os.path.join(work, "phantom.log"))
    status = 0

    # 2. Table 1, speed, contact, gl = cpu at the paper's particle count.
    if "table1" not in skip:
        log(f"== Table 1 at {table1_particles} particles (runtime_bench.py) [{time.time() - t0:.0f} s]")
        cmd = [sys.executable, os.path.join(here, "runtime_bench.py"), "--heartsim", args.heartsim, "--heartprep", args.heartprep,
               "--label", f"phantom{table1_particles}={label}", "--prep-args", f"--particles {table1_particles}",
               "--out", os.path.join(out, "runtime"), "--steps", "48" if args.quick else "400", "--size", "640x480"]
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=400)
        print(proc.stdout, flush=True)
        if proc.returncode != 0:
            log(f"runtime_bench.py exited {proc.returncode} (1: gl and cpu disagree)")
            status = 1

    # 3. gl at growing sizes.
    rows = []
    scenarios = {}
    if "sizes" not in skip or "threads" not in skip:
        wanted = sorted(set(sizes if "sizes" not in skip else []) | ({sizes[0]} if "threads" not in skip else set()))
        for n in wanted:
            h5 = os.path.join(work, f"phantom{n}.h5")
            took, _ = run([args.heartprep, "build", label, "-o", h5, "--particles", str(n), "--gravity", "0", "0", "0", "--no-visual",
                           "-q"], os.path.join(work, f"build{n}.log"), timeout=400)
            scenarios[n] = h5
            log(f"built {n}-particle budget scenario in {took:.1f} s [{time.time() - t0:.0f} s]")
    if "sizes" not in skip:
        log(f"== gl at {', '.join(str(n) for n in sizes)} particles")
        for n in sizes:
            if not measured(f"gl at {n}", rows, {"budget": n},
                            lambda: headless_run(args.heartsim, scenarios[n], "gl", seconds, work, f"gl{n}")):
                status = 1
        write_csv(os.path.join(out, "gpu_sizes.csv"), rows)
        print(f"\ngl backend on {renderer} ({egl}), headless, no rendering, {seconds} s simulated per run\n")
        md_table(["particles", "substep ms", "steps", "substeps", "substeps/s", "step-pass substeps/s", "real-time factor", "wall s"],
                 [[r["particles"], r["substep_ms"], r["steps"],
                   r["substeps"], r["substeps_per_s"], r["step_pass_substeps_per_s"], r["real_time_factor"], r["wall_ms"] / 1e3]
                  for r in rows])

    # 4. The cpu backend by cores.
    if "threads" not in skip:
        n = sizes[0]
        have = os.cpu_count() or 1
        log(f"\n== cpu at {n} particles on {', '.join(str(t) for t in threads)} cores [{time.time() - t0:.0f} s]")
        cpu_rows = []
        for t in threads:
            if t > have:
                log(f"{t} cores: the machine has {have}, skipped")
                continue
            prefix = ["taskset", "-c", f"0-{t - 1}"] if shutil.which("taskset") else []
            if not measured(f"cpu on {t} cores", cpu_rows, {"cores": t},
                            lambda: headless_run(args.heartsim, scenarios[n], "cpu", seconds / 2, work, f"cpu{n}_t{t}", prefix)):
                status = 1
        write_csv(os.path.join(out, "cpu_threads.csv"), cpu_rows)
        base = cpu_rows[0]["substeps_per_s"] if cpu_rows else 1
        print(f"\ncpu backend at {n} particles (budget), {cpu}, cores chosen with taskset\n")
        md_table(["cores", "particles", "substeps/s", "speed-up", "real-time factor"],
                 [[r["cores"], r["particles"], r["substeps_per_s"], r["substeps_per_s"] / base, r["real_time_factor"]] for r in cpu_rows])

    log(f"\ntotal {time.time() - t0:.0f} s")
    return status


if __name__ == "__main__":
    sys.exit(main())
