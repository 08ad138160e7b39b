"""Surgery on the real hearts on a GPU machine (docs/benchmarks.md "Cutting" and "Closing a defect").
Run through gpu_bench.sh, which sets the library path and NVIDIA's EGL vendor file:

    /tmp/heartsim-gpu/bench/gpu_bench.sh surgery --data DIR [--out DIR]

DIR holds one folder per case with its *label.nii.gz (as ../shared/data/real). Per case, headless on
the gl and the cpu backend (all the machine's cores), each against the same heart as long without
instruments:
  incision  heartprep build (30k particles), plan-incision's ventriculotomy (--seconds as planned):
            the real-time factors, whether the detailed mesh opened, the springs cut;
  repair    heartprep build --defect vsd, plan-repair's repair: the real-time factors, the patch's
            step, heartsim's closure verdict and check-closure.py's on the saved state.
Then max |x_gl − x_cpu| of the final particles (and the patch), read with h5dump. Prints Markdown
tables; fails only when a program fails. Standard library only.
"""

import argparse
import os
import re
import subprocess
import sys


here = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [here, os.path.dirname(here)]  # the bundle keeps bench_common.py beside it, the repository one folder up
from bench_common import md_table, run  # noqa: E402

LABELS = {"mmwhs_ct1002": ["--labels", "mmwhs"], "mmwhs_wh": ["--labels", "mmwhs-ordinal"]}
SEPTUM = {"hvsmr16_pat0": "40.7,-14.4,-10.4", "hvsmr16_pat1": "11.4,-25.6,5.2", "hvsmr16_pat5": "26.8,-17.3,-4.9",
          "hvsmr16_pat6": "26.9,-12.1,-20.0"}
RTF = re.compile(r"real-time factor ([0-9.e+-]+)")


def dataset(h5dump, path, name):
    """A float dataset of a state file, its values in order (h5dump's text)."""
    text = subprocess.run([h5dump, "-d", name, "-y", "-w", "0", "-m", "%.9g", path], stdout=subprocess.PIPE, text=True).stdout
    body = text[text.index("DATA {") + 6:text.rindex("}")]
    return [float(v) for v in re.findall(r"-?[0-9.]+(?:e[-+]?[0-9]+)?", body)]


def largest_difference(h5dump, a, b, name):
    return max(abs(x - y) for x, y in zip(dataset(h5dump, a, name), dataset(h5dump, b, name)))


def factor(text):
    m = RTF.search(text)
    return float(m.group(1)) if m else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--heartsim", required=True)
    ap.add_argument("--heartprep", required=True)
    ap.add_argument("--h5dump", default="h5dump")
    ap.add_argument("--closure-script", default=os.path.join(here, "check-closure.py"))
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", default="/tmp/heartsim-gpu-surgery")
    ap.add_argument("--particles", type=int, default=0, help="heartprep's budget (default: its own, 30k): smaller checks the script")
    ap.add_argument("--only", choices=["incision", "repair"], help="one of the two (default: both)")
    ap.add_argument("--cases", default="", help="comma-separated case folders (default: every one)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    hs, out = args.heartsim, args.out
    env = dict(os.environ, PATH=os.path.dirname(os.path.abspath(args.h5dump)) + os.pathsep + os.environ["PATH"])
    incisions, repairs = [], []
    budget = ["--particles", str(args.particles)] if args.particles else []
    for case in sorted(os.listdir(args.data)):
        if args.cases and case not in args.cases.split(","):
            continue
        labels = [f for f in os.listdir(os.path.join(args.data, case)) if f.endswith("label.nii.gz")]
        if not labels:
            continue
        label = os.path.join(args.data, case, labels[0])
        options = LABELS.get(case, [])
        for what in [args.only] if args.only else ("incision", "repair"):
            h5 = os.path.join(out, f"{case}.{what}.h5")
            defect = ["--defect", "vsd"] + ([f"--at={SEPTUM[case]}"] if case in SEPTUM else []) if what == "repair" else []
            run([args.heartprep, "build", label, "-o", h5, "-q"] + budget + options + defect, os.path.join(out, f"{case}.{what}.build.log"))
            csv = os.path.join(out, f"{case}.{what}.csv")
            _, plan = run([hs, f"plan-{what}", h5, "-o", csv])
            seconds = re.search(r"--seconds ([0-9.]+)", plan).group(1)
            row = {"case": case}
            for backend in ("gl", "cpu"):
                state = os.path.join(out, f"{case}.{what}.{backend}.state.h5")
                _, text = run([hs, "run", h5, "--headless", "--backend", backend, "--seconds", seconds, "--trajectory", csv,
                               "--save-state", state], os.path.join(out, f"{case}.{what}.{backend}.log"))
                _, without = run([hs, "run", h5, "--headless", "--backend", backend, "--seconds", seconds])
                row[backend] = f"{factor(text):.3g} / {factor(without):.3g}"
                row[f"{backend}_watchdog"] = len(re.findall(r"^watchdog:", text, re.M))
                if what == "incision":
                    row[f"{backend}_opened"] = "yes" if "mesh opened along" in text else "no"
                    cut = re.search(r"opened along \d+ stroke\(s\): \d+ vertices, (\d+) triangles", text)
                    row[f"{backend}_triangles"] = cut.group(1) if cut else "-"
                else:
                    verdict = re.search(r"defect closed: (yes|no), largest rim gap ([0-9.]+)", text)
                    row[f"{backend}_closed"] = f"{verdict.group(1)}, {verdict.group(2)} mm" if verdict else "?"
                    step = re.search(r"took ([0-9.e+-]+) ms each .*: ([0-9.]+) % of the wall", text)
                    row[f"{backend}_patch"] = f"{float(step.group(1)):.3f} ({step.group(2)} %)" if step else "-"
                    gpu = re.search(r"the GPU spent ([0-9.e+-]+) ms on each of the patch's \d+ steps it ran \(([0-9.]+) % of the wall", text)
                    row[f"{backend}_gpu"] = f"{float(gpu.group(1)):.4f} ({gpu.group(2)} %)" if gpu else "-"
                    check = subprocess.run([sys.executable, args.closure_script, state, "--scenario", h5], stdout=subprocess.PIPE,
                                           stderr=subprocess.STDOUT, text=True, env=env).stdout
                    m = re.search(r"defect closed: (yes|no)", check)
                    row[f"{backend}_independent"] = m.group(1) if m else "?"
            gl, cpu = (os.path.join(out, f"{case}.{what}.{b}.state.h5") for b in ("gl", "cpu"))
            row["dx"] = f"{largest_difference(args.h5dump, gl, cpu, '/positions'):.2g}"
            if what == "repair":
                row["dx"] += f" / {largest_difference(args.h5dump, gl, cpu, '/patch/positions'):.2g}"
            (incisions if what == "incision" else repairs).append(row)
            print(row, flush=True)
    print("\nIncision: real-time factor with / without instruments, the mesh opened, its triangles, watchdog events\n")
    md_table(["case", "gl", "cpu", "opened gl / cpu", "triangles gl / cpu", "watchdog gl / cpu", "max |x_gl − x_cpu| mm"],
             [[r["case"], r["gl"], r["cpu"], f"{r['gl_opened']} / {r['cpu_opened']}", f"{r['gl_triangles']} / {r['cpu_triangles']}",
               f"{r['gl_watchdog']} / {r['cpu_watchdog']}", r["dx"]] for r in incisions])
    print("\nRepair: real-time factor with / without the patch, its step (share of the wall), the verdicts\n")
    md_table(["case", "gl", "gl patch: host ms (share)", "gl patch pass: GPU ms (share)", "cpu", "cpu patch step ms", "closed gl / cpu",
              "independent gl / cpu", "watchdog gl / cpu", "max |x_gl − x_cpu| tissue / patch mm"],
             [[r["case"], r["gl"], r["gl_patch"], r["gl_gpu"], r["cpu"], r["cpu_patch"], f"{r['gl_closed']} / {r['cpu_closed']}",
               f"{r['gl_independent']} / {r['cpu_independent']}", f"{r['gl_watchdog']} / {r['cpu_watchdog']}", r["dx"]] for r in repairs])
    return 0


if __name__ == "__main__":
    sys.exit(main())
