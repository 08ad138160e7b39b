#!/usr/bin/env python3
"""Does the patch in a saved heartsim state close its septal defect? An independent check of
libmodel/surgery/closure.h (docs/closure.md), with its own code and, where it can, other methods:

  - the tissue's voxels by the parity of crossings along rays parallel to the world's z axis
    (heartsim: the winding number along rows of a grid turned to the defect's frame);
  - the patch's voxels by points sampled on its triangles (heartsim: the distance to each triangle);
  - the wall's thickness and the rim by ray-triangle intersection in 3D (Moller-Trumbore); the
    wall's intervals by parity, the rim's surface by the triangles' normals.

The region, the flood fill, its seeds and its targets are defined as heartsim defines them: the
cylinder rho <= D/2 + margin from mid-wall (s = 0) to s_top, 2 mm above both the highest rim point
+ thickness and the patch's highest point over the cylinder + thickness/2; 6-connected, from the
opening at mid-wall (s < 1 mm, rho < D/2 - voxel) to the region's top layer (s >= s_top - voxel).
Blood that reaches the patch's side around the septum, through the far side, has not passed the
patch: nothing below mid-wall is in the region.

Reads the state with h5dump (Debian package hdf5-tools); standard library only.
  /visual/positions float32 [V,3], /visual/triangles int32 [F,3] (else the scenario's, the file named
  by the state's root attribute `scenario`, looked up beside the state);
  /patch/leak_test_positions float32 [P,3] (the patch after heartsim's leak test; else
  /patch/positions, the patch as it lies), /patch/triangles int32 [Q,3], /patch attribute
  thickness_mm (no /patch: no patch);
  the defect: /patch attributes defect_centre, defect_axis, defect_diameter_mm (the deformed frame)
  when present, else the scenario's /source attributes of the same names (the rest frame).
The axis is turned to point toward the patch's side (the side its vertices' mean lies on).

The verdict is its own, never heartsim's: yes only where a rim point meets the wall, the patch
covers the opening (every point of the opening's disc has the patch over it along the axis, within
the wall's reach: from the wall's far face to the rim's radius above the highest rim point; by
rays through points on rings of the disc) and the fill finds no way out. A patch laid away from
the opening is no closure even where tissue beyond it caps the region.

Prints `defect closed: yes`, `defect closed: no (why)` or `defect closed: cannot tell: why` (no
rim point meets the wall, or the wall does not hold the defect's centre on at least half the lines
along the axis: the centre is not where the wall is), `reached voxels: N` and
the share of the opening covered, and when open where the leak passes the rim (`leak passes the
rim at (x, y, z) mm`, heartsim's ClosureResult::leak_mm by its own rays: the way's voxels at the
rim's radius with tissue, not patch, below them; or that it goes through the patch; or, where the
fill finds no way out but the patch does not cover the opening, the middle of the uncovered part);
exits 0 when closed, 1 when open, 2 on bad input (a patch's positions missing, empty or not
finite among them), 3 when it cannot tell.

Usage: scripts/check-closure.py STATE.h5 [--scenario FILE] [--voxel-mm 0.25] [--margin-mm 5]
                                         [--rim-offset-mm 0.5]
"""

import argparse
import math
import os
import re
import subprocess
import sys


class BadInput(Exception):
    pass


class CannotTell(Exception):
    """The check cannot say whether the defect is closed (no rim point meets the wall)."""


# --- reading HDF5 through h5dump ---------------------------------------------------------------

def h5dump(path, *arguments):
    """h5dump's text for one object, or None when the object does not exist."""
    try:
        run = subprocess.run(["h5dump", "-y", "-w", "0", "-m", "%.17g", *arguments, path],
                             capture_output=True, text=True)
    except FileNotFoundError:
        raise BadInput("h5dump not found: install hdf5-tools")
    if run.returncode != 0:
        return None
    return run.stdout


def parse_values(text, where):
    """The values between `DATA {` and its closing brace: numbers, or quoted strings."""
    start = text.find("DATA {")
    if start < 0:
        raise BadInput(f"{where}: h5dump printed no data")
    body = text[start + len("DATA {"):text.find("}", start + len("DATA {"))]
    strings = re.findall(r'"((?:[^"\\]|\\.)*)"', body)
    if strings:
        return strings
    try:
        return [float(token) for token in re.split(r"[\s,]+", body.strip()) if token]
    except ValueError:
        raise BadInput(f"{where}: values that are not numbers")


def dataspace(text):
    match = re.search(r"DATASPACE\s+SIMPLE\s*\{\s*\(([^)]*)\)", text)
    if not match:
        return ()
    return tuple(int(d) for d in match.group(1).split(","))


def read_dataset(path, name, columns, integer=False):
    """Rows of `columns` values of dataset `name`, or None when it does not exist."""
    text = h5dump(path, "-d", name)
    if text is None:
        return None
    shape = dataspace(text)
    if len(shape) != 2 or shape[1] != columns:
        raise BadInput(f"{path}: {name} has shape {shape}, expected [N, {columns}]")
    values = parse_values(text, f"{path}: {name}") if shape[0] else []
    if len(values) != shape[0] * columns:
        raise BadInput(f"{path}: {name}: read {len(values)} values, expected {shape[0] * columns}")
    for v in values:
        if not math.isfinite(v):
            raise BadInput(f"{path}: {name} holds a value that is not finite")
    if integer:
        values = [int(v) for v in values]
    return [tuple(values[r * columns:(r + 1) * columns]) for r in range(shape[0])]


def read_attribute(path, name):
    """The values of attribute `name` ("/object/attribute"), or None when it does not exist."""
    text = h5dump(path, "-a", name)
    if text is None:
        return None
    return parse_values(text, f"{path}: attribute {name}")


def read_vector(path, name):
    values = read_attribute(path, name)
    if values is None:
        return None
    if len(values) != 3 or not all(isinstance(v, float) and math.isfinite(v) for v in values):
        raise BadInput(f"{path}: attribute {name} must hold 3 finite numbers")
    return tuple(values)


def read_number(path, name):
    values = read_attribute(path, name)
    if values is None:
        return None
    if len(values) != 1 or not isinstance(values[0], float) or not math.isfinite(values[0]):
        raise BadInput(f"{path}: attribute {name} must be one finite number")
    return values[0]


# --- vectors -----------------------------------------------------------------------------------

def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


def norm(a):
    return math.sqrt(dot(a, a))


def ray_triangle(origin, direction, a, b, c):
    """Moller-Trumbore: the ray parameter where origin + t direction meets triangle abc, or None."""
    e1, e2 = sub(b, a), sub(c, a)
    p = cross(direction, e2)
    det = dot(e1, p)
    if det == 0.0:
        return None
    inverse = 1.0 / det
    tv = sub(origin, a)
    u = dot(tv, p) * inverse
    if u < 0.0 or u > 1.0:
        return None
    q = cross(tv, e1)
    v = dot(direction, q) * inverse
    if v < 0.0 or u + v > 1.0:
        return None
    return dot(e2, q) * inverse


# --- the check ---------------------------------------------------------------------------------

def wall_thickness(positions, triangles, centre, axis, u, v, rim_radius, reach):
    """The median length of the tissue intervals (parity of crossings) of eight lines along the
    axis at rim_radius, each the interval containing or nearest the wall's middle; and each line's
    distance from the centre to its interval along the axis (0 where the interval holds it)."""
    distances = []
    lengths = []
    for line in range(8):
        angle = 2.0 * math.pi * (line + 0.37) / 8.0
        offset = (rim_radius * math.cos(angle), rim_radius * math.sin(angle))
        origin = tuple(centre[i] + offset[0] * u[i] + offset[1] * v[i] for i in range(3))
        hits = []
        for t in triangles:
            a, b, c = positions[t[0]], positions[t[1]], positions[t[2]]
            # Skip triangles whose projection across the axis cannot hold the line's point.
            da, db, dc = sub(a, origin), sub(b, origin), sub(c, origin)
            ua, ub, uc = dot(da, u), dot(db, u), dot(dc, u)
            if min(ua, ub, uc) > 0.0 or max(ua, ub, uc) < 0.0:
                continue
            va, vb, vc = dot(da, v), dot(db, v), dot(dc, v)
            if min(va, vb, vc) > 0.0 or max(va, vb, vc) < 0.0:
                continue
            hit = ray_triangle(origin, axis, a, b, c)
            if hit is not None:
                hits.append(hit)
        if not hits or len(hits) % 2:
            continue
        hits.sort()
        best = None
        for low, high in zip(hits[0::2], hits[1::2]):
            distance = max(low, -high, 0.0)
            if best is None or distance < best[0]:
                best = (distance, high - low)
        if best[0] <= reach:
            lengths.append(best[1])
            distances.append(best[0])
    if not lengths:
        raise BadInput("no wall around the defect at (%.4g, %.4g, %.4g) mm" % centre)
    lengths.sort()
    middle = len(lengths) // 2
    return (lengths[middle] if len(lengths) % 2 else 0.5 * (lengths[middle - 1] + lengths[middle])), distances


def rim_top(positions, triangles, centre, axis, u, v, rim_radius, start, reach, samples=72):
    """The highest tissue surface facing the patch's side (its normal, by the triangles' order,
    along +axis) met by rays along -axis from s = start at rim_radius, each ray's first such
    surface, kept where it lies within `reach` of the centre; None when no ray finds one."""
    down = scale(axis, -1.0)
    facing = []
    for t in triangles:
        a, b, c = positions[t[0]], positions[t[1]], positions[t[2]]
        if dot(cross(sub(b, a), sub(c, a)), axis) > 0.0:
            facing.append((a, b, c))
    best = None
    for sample in range(samples):
        angle = 2.0 * math.pi * (sample + 0.29) / samples
        offset = (rim_radius * math.cos(angle), rim_radius * math.sin(angle))
        origin = tuple(centre[i] + offset[0] * u[i] + offset[1] * v[i] + start * axis[i] for i in range(3))
        nearest = None
        for a, b, c in facing:
            hit = ray_triangle(origin, down, a, b, c)
            if hit is not None and hit >= 0.0 and (nearest is None or hit < nearest):
                nearest = hit
        if nearest is None:
            continue
        s = start - nearest
        if rim_radius * rim_radius + s * s <= reach * reach:
            best = s if best is None else max(best, s)
    return best


def covered_share(patch_positions, patch_triangles, centre, axis, u, v, radius, spacing, low, high):
    """The share of the opening's disc (rho <= radius) that the patch covers within the wall's
    reach: sample points on rings `spacing` apart (the edge's ring included), each covered where a
    line through it along the axis meets a patch triangle (Moller-Trumbore) at a height s in
    [low, high]. Triangles are binned by the cells of `spacing` their shadow across the axis spans
    (those over the disc). Also the mean of the uncovered points (relative to the centre, across the
    axis), or None."""
    bins = {}
    flat = []
    edge = math.floor(radius / spacing) + 1  # the cells over the disc: [-edge, edge] each way
    for t in patch_triangles:
        corners = [patch_positions[t[m]] for m in range(3)]
        shadow = [(dot(sub(p, centre), u), dot(sub(p, centre), v)) for p in corners]
        flat.append(corners)
        i0, i1 = (min(edge, max(-edge, math.floor(f(x for x, _ in shadow) / spacing))) for f in (min, max))
        j0, j1 = (min(edge, max(-edge, math.floor(f(y for _, y in shadow) / spacing))) for f in (min, max))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                bins.setdefault((i, j), []).append(len(flat) - 1)
    rings = max(1, math.ceil(radius / spacing))
    samples = covered = 0
    missed = [0.0, 0.0]
    for ring in range(rings + 1):
        r = radius * ring / rings
        around = max(1, math.ceil(2.0 * math.pi * r / spacing))
        for k in range(around):
            angle = 2.0 * math.pi * (k + 0.31) / around
            a, b = r * math.cos(angle), r * math.sin(angle)
            origin = tuple(centre[m] + a * u[m] + b * v[m] for m in range(3))
            samples += 1
            hit = False
            for t in bins.get((math.floor(a / spacing), math.floor(b / spacing)), ()):
                s = ray_triangle(origin, axis, *flat[t])
                if s is not None and low <= s <= high:
                    hit = True
                    break
            if hit:
                covered += 1
            else:
                missed[0] += a
                missed[1] += b
    uncovered = samples - covered
    return covered / samples, (missed[0] / uncovered, missed[1] / uncovered) if uncovered else None


def fill(queue, marks, allowed, steps):
    """Breadth first from the voxels in `queue` to every neighbour (index + a step) that `allowed`
    admits: marks each in `marks`, appends it to `queue`, and returns `queue`."""
    for index in queue:
        marks[index] = 1
    head = 0
    while head < len(queue):
        index = queue[head]
        head += 1
        for step in steps:
            other = index + step
            if not marks[other] and allowed(other):
                marks[other] = 1
                queue.append(other)
    return queue


def check(positions, triangles, patch_positions, patch_triangles, thickness, centre, axis, diameter,
          voxel, margin, rim_offset):
    radius = 0.5 * diameter
    # A frame across the axis.
    helper = (1.0, 0.0, 0.0) if abs(axis[0]) < 0.9 else (0.0, 1.0, 0.0)
    u = cross(axis, helper)
    u = scale(u, 1.0 / norm(u))
    v = cross(axis, u)
    wall, distances = wall_thickness(positions, triangles, centre, axis, u, v, radius + rim_offset, radius + margin)

    # The region's top: 2 mm above the patch lying on the rim and above the patch's highest point
    # over the cylinder (the triangles with a corner within the cylinder's radius plus their
    # longest edge across the axis).
    cylinder = radius + margin
    rim = rim_top(positions, triangles, centre, axis, u, v, radius + rim_offset, 0.5 * wall + margin,
                  radius + margin + 0.5 * wall)
    if rim is None:
        raise CannotTell("no rim point meets the wall: no tissue surface facing the patch's side %.3g mm from the axis "
                         "within %.3g mm of the defect's centre (is the centre in the opening?)"
                         % (radius + rim_offset, radius + margin + 0.5 * wall))
    # The centre must lie within the wall: on at least half the lines along the axis the wall's
    # interval holds it. A centre in the blood (beyond the patch, say) seeds a fill that says
    # nothing about the patch.
    held = sum(1 for d in distances if d == 0.0)
    if 2 * held < len(distances):
        raise CannotTell("the defect's centre is not in the wall: %d of %d lines along the axis %.3g mm from it meet the wall "
                         "there; the median lies %.3g mm from it (is the centre in the opening?)"
                         % (held, len(distances), radius + rim_offset, sorted(distances)[len(distances) // 2]))
    surface = max(rim, 0.0)
    # The patch covers the opening where every point of its disc has the patch over it along the
    # axis within the wall's reach: from the wall's far face to the rim's radius above the highest
    # rim point, plus half the thickness.
    low_reach, high_reach = -0.5 * wall, surface + radius + rim_offset + 0.5 * thickness
    covered, uncovered = covered_share(patch_positions, patch_triangles, centre, axis, u, v, radius, voxel, low_reach, high_reach)
    top = surface + thickness + 2.0
    for t in patch_triangles:
        corners = [sub(patch_positions[t[m]], centre) for m in range(3)]
        heights = [dot(p, axis) for p in corners]
        flat = [(dot(p, u), dot(p, v)) for p in corners]
        edge = max(math.hypot(flat[m][0] - flat[m - 1][0], flat[m][1] - flat[m - 1][1]) for m in range(3))
        if min(math.hypot(*f) for f in flat) <= cylinder + edge:
            top = max(top, max(heights) + 0.5 * thickness + 2.0)

    # The region: the cylinder rho <= cylinder, 0 <= s <= top, on a grid aligned with the world's
    # axes spanning its bounding box, one layer more all round. Coordinates relative to the centre.
    low, count = [], []
    for m in range(3):
        spread = cylinder * math.sqrt(max(0.0, 1.0 - axis[m] * axis[m]))
        lo = min(0.0, top * axis[m]) - spread
        hi = max(0.0, top * axis[m]) + spread
        first = math.floor(lo / voxel) - 1
        low.append((first + 0.5) * voxel)
        count.append(math.ceil(hi / voxel) + 1 - first + 1)
    nx, ny, nz = count
    if nx * ny * nz > 50_000_000:
        raise BadInput(f"--voxel-mm {voxel} makes a grid of {nx}x{ny}x{nz} voxels; use a coarser one")
    coordinate = [[low[m] + i * voxel for i in range(count[m])] for m in range(3)]
    nn = nx * ny
    region = bytearray(nn * nz)
    seeds, tops = bytearray(nn * nz), bytearray(nn * nz)
    used_columns = bytearray(nn)
    seed_below, seed_radius = max(1.0, voxel), radius - voxel
    for k in range(nz):
        z = coordinate[2][k]
        for j in range(ny):
            y = coordinate[1][j]
            row = j * nx + k * nn
            for i in range(nx):
                offset = (coordinate[0][i], y, z)
                s = dot(offset, axis)
                if s < 0.0 or s > top:
                    continue
                across = dot(offset, offset) - s * s
                if across > cylinder * cylinder:
                    continue
                index = row + i
                region[index] = 1
                used_columns[j * nx + i] = 1
                if s < seed_below and across < seed_radius * seed_radius:
                    seeds[index] = 1
                if s >= top - voxel:
                    tops[index] = 1
    voxels = sum(region)
    blocked = bytearray(nn * nz)

    # The tissue: the parity of crossings along z-rays through every column (x_i + dx, y_j + dy)
    # that holds region voxels. Every triangle of the mesh counts: a crossing below the grid flips
    # the parity of the whole column. dx, dy keep the rays off vertices and edges.
    dx, dy = voxel * 0.0071 * math.sqrt(5.0), voxel * 0.0043 * math.sqrt(7.0)
    columns = {}
    for t in triangles:
        a, b, c = (sub(positions[t[m]], centre) for m in range(3))
        low_x, high_x = min(a[0], b[0], c[0]), max(a[0], b[0], c[0])
        low_y, high_y = min(a[1], b[1], c[1]), max(a[1], b[1], c[1])
        i0 = max(0, math.ceil((low_x - dx - low[0]) / voxel))
        i1 = min(nx - 1, math.floor((high_x - dx - low[0]) / voxel))
        j0 = max(0, math.ceil((low_y - dy - low[1]) / voxel))
        j1 = min(ny - 1, math.floor((high_y - dy - low[1]) / voxel))
        if i0 > i1 or j0 > j1:
            continue
        area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if area == 0.0:
            continue
        for j in range(j0, j1 + 1):
            y = coordinate[1][j] + dy
            for i in range(i0, i1 + 1):
                if not used_columns[j * nx + i]:
                    continue
                x = coordinate[0][i] + dx
                wa = ((b[0] - x) * (c[1] - y) - (b[1] - y) * (c[0] - x)) / area
                wb = ((c[0] - x) * (a[1] - y) - (c[1] - y) * (a[0] - x)) / area
                wc = 1.0 - wa - wb
                if wa < 0.0 or wb < 0.0 or wc < 0.0:
                    continue
                columns.setdefault(j * nx + i, []).append(wa * a[2] + wb * b[2] + wc * c[2])
    for column, hits in columns.items():
        hits.sort()
        inside, next_hit = False, 0
        for k in range(nz):
            while next_hit < len(hits) and hits[next_hit] < coordinate[2][k]:
                inside = not inside
                next_hit += 1
            if inside:
                blocked[column + k * nn] = 1

    # The patch: every voxel within the blocking reach of a point sampled on it. Samples lie on a
    # barycentric grid whose cells are at most a quarter voxel across, so every point of the patch
    # is within `cover` of one; the reach, sqrt(r^2 + cover^2) with r = thickness/2 + sqrt(3)/2
    # voxel (heartsim's), then holds every voxel within r of the patch's interior.
    patch = bytearray(nn * nz)  # the patch's voxels (tissue's as well where the two overlap)
    if patch_triangles:
        r = 0.5 * thickness + 0.5 * math.sqrt(3.0) * voxel
        for t in patch_triangles:
            a, b, c = (sub(patch_positions[t[m]], centre) for m in range(3))
            longest = max(norm(sub(b, a)), norm(sub(c, b)), norm(sub(a, c)))
            steps = max(1, math.ceil(longest / (0.25 * voxel)))
            cover = longest / steps
            reach = math.sqrt(r * r + cover * cover)
            for p in range(steps + 1):
                for q in range(steps + 1 - p):
                    wa, wb = p / steps, q / steps
                    wc = 1.0 - wa - wb
                    point = tuple(wa * a[m] + wb * b[m] + wc * c[m] for m in range(3))
                    ranges = []
                    for m in range(3):
                        first = max(0, math.ceil((point[m] - reach - low[m]) / voxel))
                        last = min(count[m] - 1, math.floor((point[m] + reach - low[m]) / voxel))
                        ranges.append(range(first, last + 1))
                    for k in ranges[2]:
                        ez = (coordinate[2][k] - point[2]) ** 2
                        for j in ranges[1]:
                            eyz = ez + (coordinate[1][j] - point[1]) ** 2
                            if eyz > reach * reach:
                                continue
                            row = j * nx + k * nn
                            for i in ranges[0]:
                                if eyz + (coordinate[0][i] - point[0]) ** 2 <= reach * reach:
                                    blocked[row + i] = 1
                                    patch[row + i] = 1

    # The flood fill, 6-connected over the free region voxels, from the opening at mid-wall to the
    # region's top layer. The grid's outer layers hold no region voxel, so no step leaves the grid.
    queue = [index for index in range(nn * nz) if seeds[index] and not blocked[index]]
    if not queue:
        raise BadInput("the opening is not open at mid-wall: no free voxel within %.4g mm of the axis at "
                       "0 <= s < %.4g mm" % (seed_radius, seed_below))
    if not any(tops[index] and not blocked[index] for index in range(nn * nz)):
        raise BadInput("no free voxel on the patch's side of the defect: the region's top layer "
                       "(%.4g mm above the wall's middle) is all tissue or patch" % top)
    visited = bytearray(nn * nz)
    fill(queue, visited, lambda other: region[other] and not blocked[other], (1, -1, nx, -nx, nn, -nn))
    reached = len(queue)
    out = [index for index in range(nn * nz) if visited[index] and tops[index]]
    sealed = not out
    leak = None
    if not sealed:
        leak = where_it_leaks(out, visited, region, blocked, patch, patch_triangles, centre, axis, u, v, low, voxel, nx, nn,
                              radius + rim_offset, top)
    elif uncovered is not None:
        leak = tuple(centre[m] + uncovered[0] * u[m] + uncovered[1] * v[m] for m in range(3))
    return sealed and covered == 1.0, sealed, covered, (low_reach, high_reach), reached, voxels, wall, top, leak


def where_it_leaks(out, visited, region, blocked, patch, has_patch, centre, axis, u, v, low, voxel, nx, nn, rim, top, bins=72):
    """Where the leak passes the rim (world mm), or None where its way never passes it: the way is
    the reached voxels outside the rim's circle that a fill back from the reached top layer reaches
    without coming inside it; of those within half a voxel of the rim's radius, the ones with tissue,
    not patch, the first thing below them along the axis (a ray marched in half voxels) are its way
    under the patch. Their share of the region's voxels at the rim's radius over each rim arc, times
    the region's height, is the way's height there; the widest arc and its neighbours as wide
    (within a voxel, and at least half as wide) give the angle, their voxels' mean the height; as
    wide all round, the widest arc. No patch: the defect's centre."""
    if not has_patch:
        return centre
    def centre_of(index):  # a voxel's centre (relative to the defect's centre)
        k, rest = divmod(index, nn)
        j, i = divmod(rest, nx)
        return (low[0] + i * voxel, low[1] + j * voxel, low[2] + k * voxel)

    def rho(index):  # a voxel centre's distance from the axis
        point = centre_of(index)
        return math.hypot(dot(point, u), dot(point, v))

    # Back from the top through the reached voxels outside the rim's circle (less half a voxel): a
    # pocket under the patch sealed farther out is not on the way.
    inside = rim - 0.5 * voxel
    way = fill(list(out), bytearray(len(visited)), lambda other: visited[other] and rho(other) >= inside, (1, -1, nx, -nx, nn, -nn))

    def at(point):  # the voxel holding a point (relative to the centre), or None outside the grid
        i, j, k = (math.floor((point[m] - low[m]) / voxel + 0.5) for m in range(3))
        if i < 0 or j < 0 or k < 0 or i >= nx or j >= nn // nx or k * nn >= len(region):
            return None
        return i + j * nx + k * nn

    def arc_of(point):  # the rim arc a point lies over, or None off the rim's radius
        a, b = dot(point, u), dot(point, v)
        if abs(math.hypot(a, b) - rim) > 0.5 * voxel:
            return None
        return min(bins - 1, int((math.atan2(b, a) + math.pi) / (2.0 * math.pi) * bins))

    # The region's voxels at the rim's radius per arc: the way's share of them, times the region's
    # height, is the way's height there, whatever the grid's slant to the arc.
    band = [0] * bins
    for index in range(len(region)):
        if region[index]:
            arc = arc_of(centre_of(index))
            if arc is not None:
                band[arc] += 1
    count, height = [0] * bins, [0.0] * bins
    for index in way:
        point = centre_of(index)
        s = dot(point, axis)
        arc = arc_of(point)
        if arc is None:
            continue
        below, under_patch = 0.5 * voxel, False
        while s - below >= 0.0:
            other = at(sub(point, scale(axis, below)))
            if other is None:
                break
            if blocked[other]:
                under_patch = not patch[other]
                break
            below += 0.5 * voxel
        if not under_patch:
            continue
        count[arc] += 1
        height[arc] += s
    if not any(count):
        return None
    wide = [count[arc] * top / band[arc] if band[arc] else 0.0 for arc in range(bins)]
    widest = max(range(bins), key=lambda arc: wide[arc])
    as_wide = max(wide[widest] - voxel, 0.5 * wide[widest])

    def joins(arc):
        return count[arc % bins] > 0 and wide[arc % bins] >= as_wide

    first = last = widest
    while last - first + 1 < bins and joins(first - 1):
        first -= 1
    while last - first + 1 < bins and joins(last + 1):
        last += 1
    if last - first + 1 >= bins:  # as wide all round: at the widest arc
        first = last = widest
    arcs = [arc % bins for arc in range(first, last + 1)]
    turn = -math.pi + (0.5 * (first + last) + 0.5) * 2.0 * math.pi / bins
    s = sum(height[arc] for arc in arcs) / max(1, sum(count[arc] for arc in arcs))
    return tuple(centre[m] + rim * math.cos(turn) * u[m] + rim * math.sin(turn) * v[m] + s * axis[m] for m in range(3))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("state", help="a heartsim state file (.h5)")
    parser.add_argument("--scenario", help="the scenario file (default: the state's root attribute `scenario`, beside it)")
    parser.add_argument("--voxel-mm", type=float, default=0.25)
    parser.add_argument("--margin-mm", type=float, default=None,
                        help="the fill's cylinder reaches this far beyond the opening's edge (default: the state's /patch attribute "
                             "margin_mm, heartsim's, else 5)")
    parser.add_argument("--rim-offset-mm", type=float, default=None,
                        help="how far outside the opening the wall is measured (default: the state's /patch attribute "
                             "rim_offset_mm, where heartsim measured it, else 0.5)")
    arguments = parser.parse_args()
    try:
        if arguments.margin_mm is None:
            stored = read_number(arguments.state, "/patch/margin_mm") if os.path.exists(arguments.state) else None
            arguments.margin_mm = stored if stored is not None else 5.0
        if arguments.rim_offset_mm is None:
            stored = read_number(arguments.state, "/patch/rim_offset_mm") if os.path.exists(arguments.state) else None
            arguments.rim_offset_mm = stored if stored is not None else 0.5
        if not (arguments.voxel_mm > 0.0) or not (arguments.margin_mm >= 0.0) or not (arguments.rim_offset_mm >= 0.0):
            raise BadInput("--voxel-mm must be positive, --margin-mm and --rim-offset-mm at least 0")
        state = arguments.state
        if not os.path.isfile(state):
            raise BadInput(f"{state}: no such file")
        scenario = arguments.scenario
        if scenario is None:
            name = read_attribute(state, "/scenario")
            if name and isinstance(name[0], str) and name[0]:
                scenario = os.path.join(os.path.dirname(os.path.abspath(state)), name[0])

        def from_scenario(what):
            if scenario is None or not os.path.isfile(scenario):
                raise BadInput(f"{state}: {what} is not in the state, and its scenario file "
                               f"({scenario or 'unnamed'}) cannot be found: name it with --scenario")
            return scenario

        positions = read_dataset(state, "/visual/positions", 3)
        if positions is None:
            raise BadInput(f"{state}: no /visual/positions (the deformed detailed mesh)")
        triangles = read_dataset(state, "/visual/triangles", 3, integer=True)
        if triangles is None:
            source = from_scenario("/visual/triangles")
            triangles = read_dataset(source, "/visual/triangles", 3, integer=True)
            if triangles is None:
                raise BadInput(f"{source}: no /visual/triangles")
        if not positions or not triangles:
            raise BadInput(f"{state}: the tissue mesh is empty")
        for t in triangles:
            if min(t) < 0 or max(t) >= len(positions):
                raise BadInput(f"{state}: a tissue triangle names vertex {max(t) if max(t) >= len(positions) else min(t)}, "
                               f"outside /visual/positions ({len(positions)} rows)")

        # The patch as it lies must be whole (finite, read by read_dataset, and not empty) even
        # where the one after the leak test is checked: a state whose patch is broken is refused.
        laid = read_dataset(state, "/patch/positions", 3)
        tested = read_dataset(state, "/patch/leak_test_positions", 3)
        patch_triangles = read_dataset(state, "/patch/triangles", 3, integer=True) or []
        if (tested is not None or patch_triangles) and not laid:
            raise BadInput(f"{state}: /patch/positions is {'missing' if laid is None else 'empty'}: a patch needs its vertices")
        if tested is not None and len(tested) != len(laid):
            raise BadInput(f"{state}: /patch/leak_test_positions has {len(tested)} rows, /patch/positions {len(laid)}")
        patch_positions = tested or laid or []
        for t in patch_triangles:
            if min(t) < 0 or max(t) >= len(patch_positions):
                raise BadInput(f"{state}: a patch triangle names a vertex outside /patch/positions ({len(patch_positions)} rows)")
        thickness = 0.0
        if patch_triangles:
            thickness = read_number(state, "/patch/thickness_mm")
            if thickness is None or thickness < 0.0:
                raise BadInput(f"{state}: /patch needs the attribute thickness_mm (a number of mm >= 0)")

        centre = read_vector(state, "/patch/defect_centre")
        axis = read_vector(state, "/patch/defect_axis")
        diameter = read_number(state, "/patch/defect_diameter_mm")
        frame = "the state's /patch (deformed)"
        if centre is None or axis is None or diameter is None:
            source = from_scenario("the defect's frame (/patch defect_centre, defect_axis, defect_diameter_mm)")
            centre = read_vector(source, "/source/defect_centre")
            axis = read_vector(source, "/source/defect_axis")
            diameter = read_number(source, "/source/defect_diameter_mm")
            if centre is None or axis is None or diameter is None:
                raise BadInput(f"{source}: /source has no defect (defect_centre, defect_axis, defect_diameter_mm)")
            frame = "the scenario's /source (rest)"
        if abs(norm(axis) - 1.0) > 1e-3:
            raise BadInput("the defect's axis is not a unit vector")
        if not diameter > 0.0:
            raise BadInput("the defect's diameter is not positive")
        if patch_positions:
            mean = tuple(sum(p[m] for p in patch_positions) / len(patch_positions) for m in range(3))
            if dot(sub(mean, centre), axis) < 0.0:
                axis = scale(axis, -1.0)

        print("defect: centre (%.4g, %.4g, %.4g) mm, axis toward the patch (%.4g, %.4g, %.4g), diameter %.4g mm, from %s"
              % (*centre, *axis, diameter, frame))
        closed, sealed, covered, reach, reached, voxels, wall, top, leak = check(
            positions, triangles, patch_positions, patch_triangles, thickness, centre, axis, diameter, arguments.voxel_mm,
            arguments.margin_mm, arguments.rim_offset_mm)
    except BadInput as error:
        print(f"check-closure: {error}", file=sys.stderr)
        return 2
    except CannotTell as why:
        print(f"defect closed: cannot tell: {why}")
        return 3
    print(f"wall thickness: {wall:.4g} mm; patch: {len(patch_triangles)} triangles, {thickness:.4g} mm thick")
    print(f"region: {voxels} voxels of {arguments.voxel_mm:g} mm, from mid-wall to {top:.4g} mm")
    print(f"reached voxels: {reached}")
    print("opening covered by the patch: %.1f %% (within %.3g to %.3g mm of the wall's middle along the axis)" % (100.0 * covered, *reach))
    if closed:
        print("defect closed: yes")
    elif not patch_triangles:
        print("defect closed: no (no patch)")
    elif covered < 1.0:
        print("defect closed: no (the patch does not cover the opening: it covers %.1f %% of it within the wall's reach%s)"
              % (100.0 * covered, "" if sealed else "; a way out of the opening passes it"))
    else:
        print("defect closed: no (a way out of the opening passes the patch)")
    if not closed and patch_triangles and sealed:
        print("leak: the fill found no way out, but the patch leaves the opening uncovered around (%.2f, %.2f, %.2f) mm" % leak)
    elif not closed and patch_triangles:
        print("leak passes the rim at (%.2f, %.2f, %.2f) mm" % leak if leak is not None else "leak does not pass the rim: through the patch")
    return 0 if closed else 1


if __name__ == "__main__":
    sys.exit(main())
