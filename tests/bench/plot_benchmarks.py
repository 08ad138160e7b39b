#!/usr/bin/python3
"""Draws the benchmark plots of docs/benchmarks.md from the CSV files the benchmarks write, with
matplotlib (Agg backend, PNG):

    plot_benchmarks.py accuracy ACCURACY.csv OUT.png
        "The detailed mesh on real hearts: run time against error" (tests/bench/run_accuracy_bench.sh,
        docs/images/run-time-vs-error.png). ACCURACY.csv: accuracy_bench table's output, columns
        case,label,particles,wall_s,simulated_s,wall_s_per_simulated_s,mean_error_mm,max_error_mm;
        the reference run of each case has error 0 and is left out. Two panels, both log-log: mean
        and max vertex error against the cpu wall time per simulated second; one colour per case,
        the default builds joined in particle order (10k, 30k, 100k), the 30k keep + tangent
        build a hollow marker.
    plot_benchmarks.py mass-scale MASS_SCALE.csv OUT.png
        "Mass scaling: run time against error" (tests/bench/run_mass_scale_bench.sh,
        docs/images/mass-scale.png). MASS_SCALE.csv: mass_scale_bench's output, columns
        case,particles,mass_scale,...,real_time_factor,...,ramp_error,... Real-time factor (log)
        against the force deviation during the gesture (%): one colour per case, one marker per
        S, joined in S order.

The plots in docs/images were drawn from the CSV beside each: docs/images/mass-scale.csv is the
benchmark's own output for the run docs/benchmarks.md tabulates; docs/images/run-time-vs-error.csv
holds the figures of docs/benchmarks.md's run-time-against-error table, transcribed into
accuracy_bench's columns, because the CSV of that run was not kept and the benchmark takes longer
than a redraw should (about 10 minutes on 2 cores); run_accuracy_bench.sh replaces it with its own.

Lines starting with `#` in a CSV are comments. Benchmarks only: no test runs this (it needs
Debian's python3-matplotlib, which `scripts/install-deps.sh --bench` installs).
"""
import csv
import sys

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullFormatter
except ImportError as error:
    sys.exit(f"plot_benchmarks: no matplotlib ({error}): install python3-matplotlib (scripts/install-deps.sh --bench)")

# One colour per case, in the order the cases first appear (matplotlib's tab10).
COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#7f7f7f"]

plt.rcParams.update({
    "font.size": 12,
    "axes.titlesize": 13,
    "axes.labelsize": 12,
    "legend.fontsize": 10.5,
    "xtick.labelsize": 11,
    "ytick.labelsize": 11,
    "axes.grid": True,
    "grid.color": "#d0d0d0",
    "grid.linewidth": 0.7,
    "savefig.dpi": 110,
})


def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(line for line in f if line.strip() and not line.startswith("#")))


def plain_number(value, _position=None):
    """0.5, 1, 2, 10: a tick label without an exponent."""
    return f"{value:g}"


def shorten(particles):
    """10000 -> 10k, 29997 -> 30k (the build's requested count)."""
    return f"{round(int(particles) / 10000) * 10}k" if int(particles) >= 5000 else str(particles)


def accuracy(csv_path, out_path):
    rows = [r for r in read_rows(csv_path) if float(r["mean_error_mm"]) > 0]
    if not rows:
        sys.exit(f"plot_benchmarks: {csv_path}: no run with an error (only references?)")
    cases = list(dict.fromkeys(r["case"] for r in rows))
    figure, axes = plt.subplots(1, 2, figsize=(12, 6.2))
    panels = [("mean_error_mm", "mean vertex error against the 300k run, mm", "Mean error"),
              ("max_error_mm", "max vertex error against the 300k run, mm", "Max error")]
    for axis, (column, label, title) in zip(axes, panels):
        for index, case in enumerate(cases):
            colour = COLOURS[index % len(COLOURS)]
            mine = [r for r in rows if r["case"] == case]
            defaults = sorted((r for r in mine if r["label"] == "defaults"), key=lambda r: int(r["particles"]))
            xs = [float(r["wall_s_per_simulated_s"]) for r in defaults]
            ys = [float(r[column]) for r in defaults]
            axis.plot(xs, ys, "-s", color=colour, markersize=7, linewidth=1.8, label=case)
            for r, x, y in zip(defaults, xs, ys):
                axis.annotate(shorten(r["particles"]), (x, y), textcoords="offset points", xytext=(5, 5), fontsize=9,
                              color=colour)
            for r in mine:
                if r["label"] != "defaults":
                    axis.plot(float(r["wall_s_per_simulated_s"]), float(r[column]), "s", markersize=8, markerfacecolor="white",
                              markeredgecolor=colour, markeredgewidth=1.8)
        axis.set_xscale("log")
        axis.set_yscale("log")
        axis.xaxis.set_major_formatter(FuncFormatter(plain_number))
        axis.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 3.0, 5.0, 7.0)))
        axis.yaxis.set_major_formatter(FuncFormatter(plain_number))
        axis.yaxis.set_minor_formatter(NullFormatter())
        axis.grid(True, which="minor", color="#ececec", linewidth=0.5)
        axis.set_xlabel("cpu wall time per simulated second, s (log)")
        axis.set_ylabel(label + " (log)")
        axis.set_title(title)
    handles, labels = axes[0].get_legend_handles_labels()
    handles += [Line2D([], [], linestyle="-", marker="s", color="#444444", markersize=7),
                Line2D([], [], linestyle="none", marker="s", markersize=8, markerfacecolor="white", markeredgecolor="#444444",
                       markeredgewidth=1.8)]
    labels += ["defaults: 10k, 30k, 100k particles", "30k, --thin-walls keep --mapping tangent"]
    figure.legend(handles, labels, loc="lower center", ncol=3, bbox_to_anchor=(0.5, 0.0))
    figure.suptitle("The detailed mesh on real hearts: run time against error (0.3 s press and grab)", fontsize=14)
    figure.tight_layout(rect=(0, 0.1, 1, 1))  # room for the legend below the panels
    figure.savefig(out_path)
    print(f"plot_benchmarks: wrote {out_path}", file=sys.stderr)


def mass_scale(csv_path, out_path):
    rows = read_rows(csv_path)
    if not rows:
        sys.exit(f"plot_benchmarks: {csv_path}: no rows")
    cases = list(dict.fromkeys(r["case"] for r in rows))
    scales = sorted({float(r["mass_scale"]) for r in rows})
    markers = dict(zip(scales, "os^Dvp*hX"))  # one marker per S, the same on every case's line
    figure, axis = plt.subplots(figsize=(10, 6))
    for index, case in enumerate(cases):
        colour = COLOURS[index % len(COLOURS)]
        mine = sorted((r for r in rows if r["case"] == case), key=lambda r: float(r["mass_scale"]))
        xs = [float(r["real_time_factor"]) for r in mine]
        ys = [100 * float(r["ramp_error"]) for r in mine]
        axis.plot(xs, ys, "-", color=colour, linewidth=1.8)
        for r, x, y in zip(mine, xs, ys):
            axis.plot(x, y, markers[float(r["mass_scale"])], color=colour, markersize=7)
    axis.axvline(1.0, color="#555555", linestyle="--", linewidth=1.2)
    axis.set_xscale("log", base=2)
    axis.xaxis.set_major_locator(FixedLocator([0.25, 0.3, 0.4, 0.5, 0.7, 1, 1.5, 2, 3, 4, 6, 8]))
    axis.xaxis.set_major_formatter(FuncFormatter(plain_number))
    axis.xaxis.set_minor_formatter(NullFormatter())
    axis.set_ylim(bottom=-2)  # the S = 1 points (deviation 0) shown whole
    axis.set_xlabel("real-time factor: simulated s per wall s, cpu backend, 2 cores (log)")
    axis.set_ylabel("force deviation from S = 1 during the gesture,\n% of the largest S = 1 force")
    axis.set_title("Mass scaling: real-time factor against the force deviation, per case and S")
    case_handles = [Line2D([], [], color=COLOURS[i % len(COLOURS)], linewidth=1.8) for i in range(len(cases))]
    case_handles.append(Line2D([], [], color="#555555", linestyle="--", linewidth=1.2))
    first = axis.legend(case_handles, cases + ["real time (factor 1)"], loc="upper left", title="case")
    axis.add_artist(first)
    scale_handles = [Line2D([], [], linestyle="none", marker=markers[s], color="#444444", markersize=7) for s in scales]
    axis.legend(scale_handles, [f"S = {s:g}" for s in scales], loc="upper left", bbox_to_anchor=(0.27, 1.0),
                title="mass scale")
    figure.tight_layout()
    figure.savefig(out_path)
    print(f"plot_benchmarks: wrote {out_path}", file=sys.stderr)


def main(argv):
    plots = {"accuracy": accuracy, "mass-scale": mass_scale}
    if len(argv) != 4 or argv[1] not in plots:
        sys.exit("usage: plot_benchmarks.py accuracy ACCURACY.csv OUT.png\n"
                 "       plot_benchmarks.py mass-scale MASS_SCALE.csv OUT.png")
    plots[argv[1]](argv[2], argv[3])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
