"""Helpers shared by the benchmark drivers in tests/bench (heartprep_bench.py, runtime_bench.py)."""
import csv


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
