#!/usr/bin/env python3
"""A finite-element reference for the force a rigid sphere feels pressed into a block (CalculiX).

The problem of tests/bench/hertz_bench.cpp as a continuum: a rigid, frictionless sphere of radius R
pressed along the axis of a cylinder of tissue (height --size, radius --size/sqrt(pi): the cross
section of the --size cube; bottom fixed, sides and top free, no gravity) to the depths d/R given,
depth zero where the sphere first touches the flat top. Axisymmetric, large deformations
(*STEP, NLGEOM), compressible neo-Hookean tissue

    W = C10 (I1_bar - 3) + (J - 1)^2 / D1,   C10 = mu/2 = E / (4 (1 + nu)),   D1 = 2/K = 6 (1 - 2 nu) / E,

which is linear elasticity (E, nu) at small strain. Mesh: CAX8R quads (8-node, reduced integration,
axisymmetric), structured in two blocks: a square of side 0.9 R under the contact point, uniform
with elements of --element-size / --refine mm, and around it a band of rays from the square's edge
to the cylinder's bottom and side, the elements growing geometrically along the rays to
--outer-size / --refine mm. The sphere is a layer of CAX8R elements whose nodes all move with it
(a prescribed rigid translation), its outer face the master surface of a node-to-surface penalty
contact with the nodes of the tissue's top face (no friction; linear pressure-overclosure with a
slope of --contact-stiffness N/mm^3, so the penetration is pressure / slope; the largest is
printed). Each depth is a step, in increments of --increment of it at most (larger ones leave
CalculiX's Newton iterations in a contact state they cannot leave for nu = 0.25 near d = 0.33 R).

The force is the total vertical reaction of the fixed bottom (CalculiX prints the reactions of
axisymmetric models for a 2-degree segment; they are scaled by 180), checked against that of the
sphere's nodes. Output, to stdout and --csv:

    nu,d_over_R,depth_mm,force_N,force_over_hertz

with Hertz F = 4/3 E/(1 - nu^2) sqrt(R) d^1.5. At small depth F/F_Hertz tends to 1 (to within the
mesh's error and the block's finite size, under 1 % here); with depth it falls for nearly
incompressible tissue and rises for compressible: at d/R = 0.1, 0.2, 0.3, 0.4 it is 0.973, 0.956,
0.940, 0.925 for nu = 0.49 and 1.031, 1.041, 1.048, 1.052 for nu = 0.25 (--refine 1 and 2 agree to
0.1 %).

Usage: fe_indentation.py [--nu 0.25,0.49] [--E-kpa 10] [--radius 5] [--size 60]
                         [--depths 0.1,0.2,0.3,0.4] [--refine 1] [--element-size 0.2] [--outer-size 3]
                         [--contact-stiffness 10] [--increment 0.1] [--threads 2] [--csv FILE] [--workdir DIR] [--ccx ccx]
--workdir keeps the decks (.inp) and CalculiX's results (.dat, .frd, .sta); without it they go to a
temporary folder, removed after a run that succeeds. Needs only Python's standard library and
CalculiX's ccx (Debian: calculix-ccx; scripts/install-deps.sh installs it).
"""

import argparse
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time


def fail(message, code=2):
    print(f"fe_indentation: {message}", file=sys.stderr)
    sys.exit(code)


def number_list(text, option):
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        fail(f"{option} takes numbers separated by commas, not '{text}'")
    if not values:
        fail(f"{option} takes at least one number")
    return values


def geometric(first, length, last):
    """Cumulative fractions 0..1 of `length` split into segments growing geometrically from about
    `first` to about `last`."""
    if last <= first * 1.0001 or length <= last:
        n = max(1, round(length / first))
        return [i / n for i in range(n + 1)]
    ratio = (length - first) / (length - last)
    n = max(1, round(1 + math.log(last / first) / math.log(ratio)))
    # The ratio that makes n segments starting at `first` sum to `length` (bisection).
    lo, hi = 1.0 + 1e-9, 10.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        total = first * (mid ** n - 1) / (mid - 1)
        lo, hi = (mid, hi) if total < length else (lo, mid)
    ratio = 0.5 * (lo + hi)
    sizes = [first * ratio ** i for i in range(n)]
    scale = length / sum(sizes)
    fractions, s = [0.0], 0.0
    for h in sizes:
        s += h * scale
        fractions.append(s / length)
    fractions[-1] = 1.0
    return fractions


class Mesh:
    """2-D quadratic quads in the (r, z) plane: corner grids joined by midside nodes."""

    def __init__(self):
        self.nodes = []  # (r, z)
        self.elements = []  # 8 node ids (1-based), counter-clockwise corners then midsides
        self.edge_mid = {}

    def node(self, r, z):
        self.nodes.append((r, z))
        return len(self.nodes)

    def mid(self, a, b):
        key = (min(a, b), max(a, b))
        if key not in self.edge_mid:
            (ra, za), (rb, zb) = self.nodes[a - 1], self.nodes[b - 1]
            self.edge_mid[key] = self.node(0.5 * (ra + rb), 0.5 * (za + zb))
        return self.edge_mid[key]

    def quad(self, a, b, c, d):
        self.elements.append((a, b, c, d, self.mid(a, b), self.mid(b, c), self.mid(c, d), self.mid(d, a)))
        return len(self.elements)


def build_tissue(mesh, height, cylinder, inner, fine, coarse):
    """The tissue: the fine square [0, inner] x [height - inner, height] and the band of rays
    around it. Returns the element ids."""
    m = max(2, round(inner / fine))
    grid = [[mesh.node(inner * i / m, height - inner + inner * j / m) for j in range(m + 1)] for i in range(m + 1)]
    elements = [mesh.quad(grid[i][j], grid[i + 1][j], grid[i + 1][j + 1], grid[i][j + 1]) for i in range(m) for j in range(m)]
    # The square's outer edge (bottom edge r = 0 -> inner, then the side z up to the top) and the
    # cylinder's (bottom r = 0 -> cylinder, then the side up to the top), 2m segments each.
    inner_path = [grid[i][0] for i in range(m + 1)] + [grid[m][j] for j in range(1, m + 1)]
    outer_points = [(cylinder * i / m, 0.0) for i in range(m + 1)] + [(cylinder, height * j / m) for j in range(1, m + 1)]
    mean_length = sum(math.dist(mesh.nodes[p - 1], q) for p, q in zip(inner_path, outer_points)) / len(inner_path)
    fractions = geometric(fine, mean_length, coarse)
    rays = []
    for p, (qr, qz) in zip(inner_path, outer_points):
        pr, pz = mesh.nodes[p - 1]
        rays.append([p] + [mesh.node(pr + t * (qr - pr), pz + t * (qz - pz)) for t in fractions[1:]])
    for k in range(2 * m):
        for l in range(len(fractions) - 1):
            # Ray k to ray k + 1 runs counter-clockwise about the contact point; outward is along l.
            a, b, c, d = rays[k][l], rays[k][l + 1], rays[k + 1][l + 1], rays[k + 1][l]
            elements.append(mesh.quad(a, b, c, d))
    return elements


def build_sphere(mesh, height, radius, segment, reach):
    """A layer of elements inside the sphere's surface, from its bottom point (0, height) to the
    angle where the surface is `reach` from the axis. Returns (element ids, the face label of the
    outer surface)."""
    top = math.asin(min(0.99, reach / radius))
    n = max(4, math.ceil(top * radius / segment))
    thickness = 0.1 * radius
    outer, inner = [], []
    for k in range(n + 1):
        phi = top * k / n
        outer.append(mesh.node(radius * math.sin(phi), height + radius - radius * math.cos(phi)))
        inner.append(mesh.node((radius - thickness) * math.sin(phi), height + radius - (radius - thickness) * math.cos(phi)))
    elements = [mesh.quad(outer[k], outer[k + 1], inner[k + 1], inner[k]) for k in range(n)]
    return elements, "S1"


def write_deck(path, args, nu, depths_mm):
    mesh = Mesh()
    height = args.size
    cylinder = args.size / math.sqrt(math.pi)
    fine = args.element_size / args.refine
    coarse = args.outer_size / args.refine
    inner = 0.9 * args.radius
    tissue = build_tissue(mesh, height, cylinder, inner, fine, coarse)
    sphere, sphere_face = build_sphere(mesh, height, args.radius, 0.5 * fine, inner)
    sphere_nodes = sorted({n for e in sphere for n in mesh.elements[e - 1]})
    tissue_nodes = sorted({n for e in tissue for n in mesh.elements[e - 1]})
    eps = 1e-9 * height
    bottom = [n for n in tissue_nodes if abs(mesh.nodes[n - 1][1]) < eps]
    axis = [n for n in tissue_nodes if abs(mesh.nodes[n - 1][0]) < eps]
    # The tissue's top faces: the element edges with both corners on z = height (face k joins
    # corners k and k + 1: S1..S4).
    top_faces = []
    for e in tissue:
        corners = mesh.elements[e - 1][:4]
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]
            if abs(mesh.nodes[a - 1][1] - height) < eps and abs(mesh.nodes[b - 1][1] - height) < eps:
                top_faces.append((e, f"S{k + 1}"))

    E = args.E_kpa * 1e-3  # N/mm^2
    c10 = E / (4 * (1 + nu))
    d1 = 6 * (1 - 2 * nu) / E

    def rows(values, per_line=8):
        values = list(values)
        return "".join(", ".join(str(v) for v in values[i:i + per_line]) + "\n" for i in range(0, len(values), per_line))

    with open(path, "w") as f:
        f.write(f"** fe_indentation.py: sphere R = {args.radius} mm into a cylinder r = {cylinder:.4f}, h = {height} mm, "
                f"E = {args.E_kpa} kPa, nu = {nu}\n")
        f.write("*NODE\n")
        for i, (r, z) in enumerate(mesh.nodes, 1):
            f.write(f"{i}, {r:.10g}, {z:.10g}, 0\n")
        for name, ids in (("TISSUE", tissue), ("SPHERE", sphere)):
            f.write(f"*ELEMENT, TYPE=CAX8R, ELSET={name}\n")
            for e in ids:
                f.write(f"{e}, " + ", ".join(str(n) for n in mesh.elements[e - 1]) + "\n")
        f.write("*NSET, NSET=NBOTTOM\n" + rows(bottom))
        f.write("*NSET, NSET=NAXIS\n" + rows(axis))
        f.write("*NSET, NSET=NSPHERE\n" + rows(sphere_nodes))
        f.write("*SURFACE, NAME=STISSUE, TYPE=ELEMENT\n")
        for e, face in top_faces:
            f.write(f"{e}, {face}\n")
        f.write("*SURFACE, NAME=SSPHERE, TYPE=ELEMENT\n")
        for e in sphere:
            f.write(f"{e}, {sphere_face}\n")
        f.write("*MATERIAL, NAME=TISSUE\n*HYPERELASTIC, NEO HOOKE\n")
        f.write(f"{c10:.10g}, {d1:.10g}\n")
        f.write("*MATERIAL, NAME=RIGID\n*ELASTIC\n1e3, 0.3\n")
        f.write("*SOLID SECTION, ELSET=TISSUE, MATERIAL=TISSUE\n*SOLID SECTION, ELSET=SPHERE, MATERIAL=RIGID\n")
        # No *FRICTION: frictionless. Node-to-surface: each node of the tissue's top face against the
        # sphere's (quadratic) face; a tension of 1e-7 N/mm^2 at most within 0.01 mm of it.
        f.write("*SURFACE INTERACTION, NAME=FRICTIONLESS\n*SURFACE BEHAVIOR, PRESSURE-OVERCLOSURE=LINEAR\n")
        f.write(f"{args.contact_stiffness:.10g}, 1e-7, 0.01\n")
        f.write("*CONTACT PAIR, INTERACTION=FRICTIONLESS, TYPE=NODE TO SURFACE\nSTISSUE, SSPHERE\n")
        f.write("*BOUNDARY\nNBOTTOM, 1, 2\nNAXIS, 1, 1\nNSPHERE, 1, 1\n")
        for d in depths_mm:
            # Each step presses from the last depth to the next (the sphere's displacement is total),
            # in increments of --increment of the step at most; printed at the step's end (every
            # 1000th increment otherwise).
            f.write(f"*STEP, NLGEOM, INC=1000\n*STATIC\n{args.increment:g}, 1.0, 1e-6, {args.increment:g}\n")
            f.write(f"*BOUNDARY\nNSPHERE, 2, 2, {-d:.10g}\n")
            f.write("*NODE PRINT, NSET=NBOTTOM, TOTALS=ONLY, FREQUENCY=1000\nRF\n")
            f.write("*NODE PRINT, NSET=NSPHERE, TOTALS=ONLY, FREQUENCY=1000\nRF\n")
            f.write("*CONTACT PRINT, FREQUENCY=1000\nCDIS\n")
            f.write("*END STEP\n")
    return len(tissue), len(mesh.nodes)


def parse_dat(path, steps):
    """Per step (each one unit of total time long): the vertical reaction of the bottom and of the
    sphere (2-degree segment) and the largest penetration, from the .dat file at the step's end."""
    bottom, sphere, penetration = [None] * steps, [None] * steps, [0.0] * steps

    def step_of(time):
        k = round(time) - 1
        return k if abs(time - (k + 1)) < 1e-6 and 0 <= k < steps else None

    with open(path) as f:
        lines = f.read().splitlines()
    i = 0
    while i < len(lines):
        total = re.match(r"\s*total force \(fx,fy,fz\) for set (\S+) and time\s+(\S+)", lines[i])
        contact = re.match(r"\s*relative contact displacement .* and time\s+(\S+)", lines[i])
        if total:
            k = step_of(float(total.group(2)))
            j = i + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            if k is not None and j < len(lines):
                fy = float(lines[j].split()[1])
                if total.group(1) == "NBOTTOM":
                    bottom[k] = fy
                elif total.group(1) == "NSPHERE":
                    sphere[k] = fy
            i = j + 1
        elif contact:
            k = step_of(float(contact.group(1)))
            j = i + 1
            while j < len(lines) and (not lines[j].strip() or re.match(r"\s*\d+\s+[-+.\dEe]+\s+[-+.\dEe]+\s+[-+.\dEe]+\s*$", lines[j])):
                if k is not None and lines[j].strip():
                    # slave node, normal (negative: penetration), tangential 1, 2
                    penetration[k] = max(penetration[k], -float(lines[j].split()[1]))
                j += 1
            i = j
        else:
            i += 1
    return bottom, sphere, penetration


def run_case(args, nu, workdir):
    depths_mm = [d * args.radius for d in args.depths]
    deck = os.path.join(workdir, f"indent_nu{nu:g}_r{args.refine:g}")
    elements, nodes = write_deck(deck + ".inp", args, nu, depths_mm)
    start = time.monotonic()
    with open(deck + ".log", "w") as log:
        env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), CCX_NPROC_EQUATION_SOLVER=str(args.threads))
        result = subprocess.run([args.ccx, "-i", os.path.basename(deck)], cwd=workdir, stdout=log, stderr=subprocess.STDOUT, env=env)
    seconds = time.monotonic() - start
    with open(deck + ".log") as log:
        text = log.read()
    if result.returncode != 0 or "*ERROR" in text:
        errors = [l for l in text.splitlines() if "ERROR" in l][:5]
        fail(f"ccx failed on {deck}.inp (exit {result.returncode}): {' | '.join(errors) or text[-500:]}; log in {deck}.log", 1)
    return parse_dat(deck + ".dat", len(depths_mm)) + (seconds, elements, nodes)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--nu", default="0.25,0.49", help="Poisson's ratios, comma separated (default 0.25,0.49)")
    p.add_argument("--E-kpa", type=float, default=10.0, dest="E_kpa", help="Young's modulus, kPa (default 10)")
    p.add_argument("--radius", type=float, default=5.0, help="sphere radius R, mm (default 5)")
    p.add_argument("--size", type=float, default=60.0, help="block size, mm: the cylinder's height; its radius is size/sqrt(pi) (default 60)")
    p.add_argument("--depths", default="0.1,0.2,0.3,0.4", help="depths d/R, comma separated (default 0.1,0.2,0.3,0.4)")
    p.add_argument("--refine", type=float, default=1.0, help="divides every element size (default 1)")
    p.add_argument("--element-size", type=float, default=0.2, help="element size under the contact, mm, before --refine (default 0.2)")
    p.add_argument("--outer-size", type=float, default=3.0, help="largest element size along the rays, mm, before --refine (default 3)")
    p.add_argument("--contact-stiffness", type=float, default=10.0, help="penalty slope, N/mm^3 (default 10)")
    p.add_argument("--increment", type=float, default=0.1, help="largest increment, a fraction of each depth step (default 0.1)")
    p.add_argument("--threads", type=int, default=2, help="ccx threads (default 2)")
    p.add_argument("--csv", help="write the table here too")
    p.add_argument("--workdir", help="folder for the CalculiX decks and results (default: a temporary one, removed)")
    p.add_argument("--ccx", default="ccx", help="the CalculiX executable (default ccx)")
    args = p.parse_args()
    nus = number_list(args.nu, "--nu")
    args.depths = sorted(number_list(args.depths, "--depths"))
    for nu in nus:
        if not -1 < nu < 0.5:
            fail(f"--nu {nu}: Poisson's ratio must lie in (-1, 0.5)")
    for d in args.depths:
        if not 0 < d < 0.8:
            fail(f"--depths {d}: d/R must lie in (0, 0.8)")
    if not 0 < args.increment <= 1:
        fail(f"--increment {args.increment}: a fraction of a step, in (0, 1]")
    for name in ("E_kpa", "radius", "size", "refine", "element_size", "outer_size", "contact_stiffness"):
        if getattr(args, name) <= 0:
            fail(f"--{name.replace('_', '-')} must be positive, not {getattr(args, name)}")
    if args.size < 4 * args.radius:
        fail(f"--size {args.size} mm: the block must be at least 4 sphere radii ({4 * args.radius} mm)")
    if shutil.which(args.ccx) is None:
        fail(f"CalculiX's '{args.ccx}' is not on the PATH: install it with scripts/install-deps.sh --bench (Debian package calculix-ccx)", 3)

    own = args.workdir is None
    workdir = tempfile.mkdtemp(prefix="fe_indentation.") if own else args.workdir
    os.makedirs(workdir, exist_ok=True)
    rows = []
    E = args.E_kpa * 1e-3
    for nu in nus:
        bottom, sphere, penetration, seconds, elements, nodes = run_case(args, nu, workdir)
        if None in bottom or None in sphere:
            fail(f"ccx printed no reaction at the end of step {bottom.index(None) + 1 if None in bottom else sphere.index(None) + 1} "
                 f"(nu = {nu}); see {workdir}", 1)
        print(f"# nu = {nu:g}, refine {args.refine:g}: {elements} CAX8R elements, {nodes} nodes, ccx {seconds:.1f} s", file=sys.stderr)
        for k, d in enumerate(args.depths):
            depth = d * args.radius
            force = 180.0 * bottom[k]
            hertz = 4.0 / 3.0 * E / (1 - nu * nu) * math.sqrt(args.radius) * depth ** 1.5
            print(f"#   d/R {d:g}: bottom {force:.6g} N, sphere {-180.0 * sphere[k]:.6g} N, largest penetration "
                  f"{penetration[k]:.2g} mm ({100 * penetration[k] / depth:.2g}% of d)", file=sys.stderr)
            if abs(force + 180.0 * sphere[k]) > 1e-3 * abs(force):
                fail(f"nu = {nu}, d/R = {d}: the bottom's reaction ({force:.6g} N) and the sphere's ({-180.0 * sphere[k]:.6g} N) "
                     f"differ: not in equilibrium; see {workdir}", 1)
            rows.append((nu, d, depth, force, force / hertz))
    if own:
        shutil.rmtree(workdir, ignore_errors=True)
    lines = ["nu,d_over_R,depth_mm,force_N,force_over_hertz"] + [f"{nu:g},{d:g},{depth:.6g},{f:.6g},{r:.5f}" for nu, d, depth, f, r in rows]
    print("\n".join(lines))
    if args.csv:
        with open(args.csv, "w") as f:
            f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
