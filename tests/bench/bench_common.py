"""Helpers shared by the benchmark drivers in tests/bench (heartprep_bench.py, runtime_bench.py,
gpu/gpu_bench.py): running a program, reading heartsim's --stats-csv, Markdown tables, CSV."""
import csv
import math
import subprocess
import time


def write_csv(path, rows):
    """Writes dict rows to `path` as CSV; the columns are every key in first-seen order."""
    keys = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print(f"\nwrote {path}")


def run(cmd, log=None, timeout=None):
    """Runs `cmd`, stdout and stderr together; returns (wall seconds, output). `log` gets the
    command line and the output. RuntimeError with the output's end when it exits non-zero."""
    start = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=timeout)
    wall = time.perf_counter() - start
    if log:
        with open(log, "w") as f:
            f.write(" ".join(cmd) + "\n\n" + proc.stdout)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-4000:]}")
    return wall, proc.stdout


def read_stats(path):
    """--stats-csv → {pass: row} (rows keep the run's columns)."""
    with open(path, newline="") as f:
        return {r["pass"]: r for r in csv.DictReader(f)}


def fmt(v):
    if v is None or v == "":
        return "—"
    if isinstance(v, float):
        if v == 0:
            return "0"
        if math.isnan(v):
            return "—"
        if abs(v) >= 1000:
            return f"{v:,.0f}".replace(",", " ")
        if abs(v) >= 10:
            return f"{v:.1f}"
        if abs(v) >= 0.01:
            return f"{v:.3g}"
        return f"{v:.2g}"
    return str(v)


def md_table(header, rows):
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print("| " + " | ".join(fmt(v) for v in r) + " |")
