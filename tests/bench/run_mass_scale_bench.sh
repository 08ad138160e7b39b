#!/usr/bin/env bash
# Run time against error with the mass scale S as the knob (docs/benchmarks.md "Mass scaling: run
# time against error"): every case in ../shared/data/real built with heartprep's defaults (30k
# particles, E = 10 kPa; MM-WHS CT 1002's myocardium is label 205: --tissue=205), the standard press-and-grab
# gesture of tests/bench/press_and_grab_gesture.py (a 3 mm probe pressing the most anterior particle 13 mm
# along +y from 11 mm in front of it, a 3 mm grabber pulling the most inferior particle 10 mm inferior,
# both over the first 100 ms, then held), run on the cpu backend at S = 1, 2, 4, 8, 16 by
# tests/bench/mass_scale_bench.cpp. Writes OUT/mass_scale.csv, prints a Markdown table, and draws
# OUT/mass_scale.svg (real-time factor against the force's deviation during the gesture).
# Usage: tests/bench/run_mass_scale_bench.sh [--seconds S] [--out DIR] [--data DIR]
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=3 out=build/mass-scale-bench data=../shared/data/real
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    -h|--help) sed -n 2,11p "$0"; exit 0 ;;
    *) echo "run_mass_scale_bench: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -d "$data" ]; then echo "run_mass_scale_bench: $data is absent: nothing to measure" >&2; exit 0; fi
cmake --build --preset release --target heartprep mass_scale_bench >/dev/null
mkdir -p "$out"
rm -f "$out/mass_scale.csv"
heartprep=build/release/tools/heartprep bench=build/release/tests/bench/mass_scale_bench
for label in "$data"/*/*label.nii.gz; do
  case=$(basename "$(dirname "$label")")
  tissue=""
  [ "$case" = mmwhs_ct1002 ] && tissue="--tissue=205"
  [ -f "$out/$case.h5" ] || $heartprep build "$label" -o "$out/$case.h5" -q $tissue
  h5dump -d /particles/rest_position -y -w 0 -o "$out/$case.rest.txt" "$out/$case.h5" >/dev/null
  python3 tests/bench/press_and_grab_gesture.py "$out/$case.rest.txt" "$out/$case.csv"
  echo "$case" >&2
  $bench "$out/$case.h5" "$out/$case.csv" "$seconds" 300 "$case" "$out/mass_scale.csv" >&2
done
python3 - "$out/mass_scale.csv" "$out/mass_scale.svg" <<'PY'
import csv, math, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print("| case | particles | S | step ms × substeps | substeps per simulated ms | real-time factor | watchdog events | force deviation during the gesture | after settling |")
print("|---|---|---|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['case']} | {r['particles']} | {r['mass_scale']} | {float(r['dt_ms']):.4g} × {r['substeps']} | {float(r['substeps_per_simulated_ms']):.3g} | "
          f"{float(r['real_time_factor']):.2f} | {r['watchdog_events']} | {100 * float(r['ramp_error']):.1f} % | {100 * float(r['settled_error']):.2f} % |")
# The plot: real-time factor (x, log) against the deviation during the gesture (y), one line per case.
W, H, L, B = 640, 400, 70, 50
cases = sorted({r["case"] for r in rows})
xs = [float(r["real_time_factor"]) for r in rows]
ys = [100 * float(r["ramp_error"]) for r in rows]
x0, x1 = math.log10(min(xs) / 1.2), math.log10(max(xs) * 1.2)
y1 = max(ys + [1.0]) * 1.1
def px(x): return L + (math.log10(x) - x0) / (x1 - x0) * (W - L - 20)
def py(y): return H - B - y / y1 * (H - B - 20)
colours = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf"]
svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
       f'<rect width="{W}" height="{H}" fill="white"/>',
       f'<line x1="{L}" y1="{H-B}" x2="{W-20}" y2="{H-B}" stroke="black"/><line x1="{L}" y1="20" x2="{L}" y2="{H-B}" stroke="black"/>',
       f'<text x="{(L+W)/2}" y="{H-12}" text-anchor="middle">real-time factor, cpu backend (log scale)</text>',
       f'<text x="16" y="{(H-B)/2}" transform="rotate(-90 16 {(H-B)/2})" text-anchor="middle">force deviation from S = 1 during the gesture, %</text>']
for tick in [0.25, 0.5, 1, 2, 4, 8]:
    if 10 ** x0 <= tick <= 10 ** x1:
        svg.append(f'<line x1="{px(tick)}" y1="{H-B}" x2="{px(tick)}" y2="{H-B+5}" stroke="black"/><text x="{px(tick)}" y="{H-B+18}" text-anchor="middle">{tick:g}</text>')
if 10 ** x0 <= 1 <= 10 ** x1:
    svg.append(f'<line x1="{px(1)}" y1="20" x2="{px(1)}" y2="{H-B}" stroke="#888" stroke-dasharray="4 4"/>')
for k in range(6):
    y = y1 * k / 5
    svg.append(f'<line x1="{L-5}" y1="{py(y)}" x2="{L}" y2="{py(y)}" stroke="black"/><text x="{L-8}" y="{py(y)+4}" text-anchor="end">{y:.0f}</text>')
for i, c in enumerate(cases):
    pts = [(float(r["real_time_factor"]), 100 * float(r["ramp_error"]), r["mass_scale"]) for r in rows if r["case"] == c]
    colour = colours[i % len(colours)]
    svg.append('<polyline fill="none" stroke="%s" points="%s"/>' % (colour, " ".join(f"{px(x):.1f},{py(y):.1f}" for x, y, _ in pts)))
    for x, y, s in pts:
        svg.append(f'<circle cx="{px(x):.1f}" cy="{py(y):.1f}" r="3" fill="{colour}"/><text x="{px(x)+5:.1f}" y="{py(y)-5:.1f}" font-size="10">{s}</text>')
    svg.append(f'<text x="{L+10}" y="{30+16*i}" fill="{colour}">{c}</text>')
svg.append("</svg>")
open(sys.argv[2], "w").write("\n".join(svg) + "\n")
PY
echo "wrote $out/mass_scale.csv and $out/mass_scale.svg" >&2
