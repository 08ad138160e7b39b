#!/usr/bin/env python3
"""The real-time benchmark's two-handed gesture for one heart, from its rest positions:
a 3 mm probe pressing the most anterior particle (least y, LPS) 13 mm along +y from 11 mm in
front of it, and a 3 mm grabber pulling the most inferior particle (least z) 10 mm inferior,
both over the first 100 ms, then held. Used by run_realtime_bench.sh and run_mass_scale_bench.sh.

Usage: press_and_grab_gesture.py REST.txt OUT.csv
REST.txt: /particles/rest_position as `h5dump -d /particles/rest_position -y -w 0` prints it."""
import re
import sys

values = [float(v) for v in re.findall(r"-?\d+\.?\d*(?:[eE][-+]?\d+)?", open(sys.argv[1]).read())]
points = [values[i:i + 3] for i in range(0, len(values) - 2, 3)]
front = min(points, key=lambda p: p[1])
low = min(points, key=lambda p: p[2])
with open(sys.argv[2], "w") as f:
    f.write("# probe pressing the most anterior particle, grabber pulling the most inferior one (tests/bench/press_and_grab_gesture.py)\n")
    f.write("time_ms, hand, kind, x, y, z, qw, qx, qy, qz, ax, ay, az, grab\n")
    f.write(f"0, 0, probe, {front[0]}, {front[1] - 11}, {front[2]}, 1, 0, 0, 0, 3, 3, 3, 0\n")
    f.write(f"100, 0, probe, {front[0]}, {front[1] + 2}, {front[2]}, 1, 0, 0, 0, 3, 3, 3, 0\n")
    f.write(f"0, 1, grabber, {low[0]}, {low[1]}, {low[2]}, 1, 0, 0, 0, 3, 3, 3, 1\n")
    f.write(f"100, 1, grabber, {low[0]}, {low[1]}, {low[2] - 10}, 1, 0, 0, 0, 3, 3, 3, 1\n")
