#!/usr/bin/python3
"""heartprep speed and accuracy benchmark (docs/benchmarks.md). Not a test: it prints Markdown tables and
writes CSV files, and never fails on a time.

Part A, build: `heartprep build CASE --cavity 2 --anchor-border` on every real case and on a
256^3 phantom; median wall time over the repetitions, per-stage times (the `stages` line heartprep
prints), peak RSS (GNU time %M), particles, springs, triangles.

Part B, surface: our `heartprep surface` against 3D Slicer's default pipeline in VTK (pad 1 voxel,
vtkDiscreteFlyingEdges3D, vtkWindowedSincPolyDataFilter 20 iterations, pass band 0.01) on sphere
and shell phantoms with analytic truth, and on the real cases (mesh-to-mesh distance only).

Part 2 (packing, simulation surface, mapping: `--parts part2`, or any of stages, batch, mapping):
- stages: `heartprep build CASE --cavity 2 --anchor-border` on every real case at the default
  spacing (30 000 particles); medians of the pack, simsurface and map stage times (the `stages`
  line, 1 ms resolution) and of their sum, against the target of 1 s on 2 cores.
- batch: `heartprep batch FOLDER -o OUT -j N --options "--cavity 2 --anchor-border"` on a temporary
  folder of symlinks to the real cases, -j 1 and -j 2, from an empty OUT, then a second run on the
  same OUT (resumed: every case reused); wall time and cases per minute.
- mapping: runs the C++ program mapping_bench (tests/bench/mapping_bench.cpp; target mapping_bench,
  found beside heartprep's build or given by --mapping-bench): mapping error under a reference
  deformation against particle spacing.

Run it with Debian's /usr/bin/python3: python3-vtk9 and python3-numpy are installed for that
interpreter only (a pyenv python3 earlier in PATH does not see them).
"""

import argparse
import csv
import glob
import math
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import time

from bench_common import write_csv

try:
    import numpy as np
    import vtk
    from vtk.util import numpy_support
except ImportError as error:  # tell the user which script installs what is missing
    sys.exit(f"heartprep_bench: {error}; run scripts/install-deps.sh --bench and use /usr/bin/python3")

# LPS = diag(-1, -1, 1) * RAS: ITK (and so heartprep) reports LPS, NIfTI's qform/sform give RAS.
RAS_TO_LPS = np.diag([-1.0, -1.0, 1.0])

# Slicer's default smoothing factor 0.5 -> windowed-sinc pass band 10^(-4*0.5).
SLICER_PASS_BAND = 10.0 ** (-4.0 * 0.5)
SLICER_ITERATIONS = 20


# ---------------------------------------------------------------------------------------------
# Running heartprep


def run_timed(cmd, rss_file=None):
    """Runs cmd; returns (wall seconds, stdout, peak RSS in MiB or None).

    The wall time is taken around the process here; GNU time only supplies the peak RSS (its
    %M is in KiB), written to a file so it never mixes with heartprep's own stderr."""
    if rss_file:
        cmd = ["/usr/bin/time", "-f", "%M", "-o", rss_file] + cmd
    start = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    rss = None
    if rss_file:
        with open(rss_file) as f:
            rss = int(f.read().strip().splitlines()[-1]) / 1024.0
    return wall, proc.stdout, rss


def parse_build_stdout(out):
    """Pulls the figures out of heartprep build's summary (see tools/heartprep/pipeline.cpp)."""
    row = {}
    m = re.search(r"^stages\s+(.*)$", out, re.M)
    if not m:
        raise RuntimeError("no 'stages' line in heartprep output:\n" + out)
    # "hash 0.00 s, read 0.04 s, ..., critical step 0.48 s, total 0.91 s"
    for name, sec in re.findall(r"([a-z][a-z ]*?) ([0-9.]+) s", m.group(1)):
        row["stage " + name.strip()] = float(sec)
    m = re.search(r"^surface\s+(\d+) vertices, (\d+) triangles", out, re.M)
    row["triangles"] = int(m.group(2)) if m else 0
    m = re.search(r"^lattice\s+spacing ([0-9.]+) mm.*?; (\d+) particles \((\d+) anchored\), (\d+) springs", out, re.M)
    row["spacing mm"], row["particles"], row["anchored"], row["springs"] = (
        float(m.group(1)), int(m.group(2)), int(m.group(3)), int(m.group(4)))
    m = re.search(r"\(Lanczos, (\d+) iterations\)", out)
    row["Lanczos iterations"] = int(m.group(1)) if m else 0
    return row


def parse_surface_stdout(out):
    """`time     marching cubes 0.01 s, smoothing 0.02 s, decimation 0.00 s` (10 ms resolution)."""
    m = re.search(r"^time\s+marching cubes ([0-9.]+) s, smoothing ([0-9.]+) s", out, re.M)
    if not m:
        raise RuntimeError("no 'time' line in heartprep surface output:\n" + out)
    return float(m.group(1)), float(m.group(2))


# ---------------------------------------------------------------------------------------------
# Meshes: reading, frames, measures


def polydata_arrays(poly):
    """Points (n,3) and triangles (m,3) of a triangle-only vtkPolyData."""
    points = numpy_support.vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64)
    polys = poly.GetPolys()
    offsets = numpy_support.vtk_to_numpy(polys.GetOffsetsArray())
    if not np.all(np.diff(offsets) == 3):
        raise RuntimeError("mesh has non-triangle cells")
    tris = numpy_support.vtk_to_numpy(polys.GetConnectivityArray()).reshape(-1, 3)
    return points, tris


def read_ply(path):
    reader = vtk.vtkPLYReader()
    reader.SetFileName(path)
    reader.Update()
    return reader.GetOutput()


def area_volume(points, tris):
    """Surface area and enclosed volume (divergence theorem). The signed sum over all closed
    components gives outer minus inner for a shell when orientation is consistent; abs() makes
    it independent of whether a pipeline orients outwards or inwards."""
    a, b, c = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1).sum()
    volume = abs(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    return area, volume


def nifti_geometry(path):
    """VTK's NIfTI reader puts point (i,j,k) at (i,j,k)*spacing (origin 0) and gives the qform
    as a matrix from that frame to RAS. Returns (4x4 VTK-frame -> LPS, dims, spacing)."""
    reader = vtk.vtkNIFTIImageReader()
    reader.SetFileName(path)
    reader.UpdateInformation()
    if reader.GetQFac() < 0:
        # The reader then reverses the slice order; our inputs (phantoms, HVSMR) all have qfac +1,
        # so rather than handle a case we cannot check here, we refuse it.
        raise RuntimeError(f"{path}: qfac -1 not handled by this benchmark")
    q = reader.GetQFormMatrix() or reader.GetSFormMatrix()
    m = np.array([[q.GetElement(r, c) for c in range(4)] for r in range(4)])
    to_lps = np.eye(4)
    to_lps[:3, :] = RAS_TO_LPS @ m[:3, :]
    info = reader.GetOutputInformation(0)
    extent = info.Get(vtk.vtkStreamingDemandDrivenPipeline.WHOLE_EXTENT())
    dims = [extent[1] - extent[0] + 1, extent[3] - extent[2] + 1, extent[5] - extent[4] + 1]
    spacing = info.Get(vtk.vtkDataObject.SPACING())
    origin = info.Get(vtk.vtkDataObject.ORIGIN())
    if any(abs(o) > 1e-9 for o in origin):
        raise RuntimeError(f"{path}: VTK reader origin {origin} != 0, frame assumption broken")
    return to_lps, dims, spacing


def to_lps(points, matrix):
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def vtk_slicer_pipeline(path):
    """3D Slicer's default closed-surface conversion (vtkBinaryLabelmapToClosedSurfaceConversionRule):
    pad one voxel so the surface closes at the border, discrete flying edges on label 1,
    windowed-sinc smoothing. Slicer's decimation (factor 0) and normals are left out, as ours
    has none either. Returns (polydata, times dict). Only Update() calls are timed."""
    times = {}
    reader = vtk.vtkNIFTIImageReader()
    reader.SetFileName(path)
    t = time.perf_counter()
    reader.Update()
    times["read"] = time.perf_counter() - t

    pad = vtk.vtkImageConstantPad()
    pad.SetInputConnection(reader.GetOutputPort())
    ext = reader.GetOutput().GetExtent()
    pad.SetOutputWholeExtent(ext[0] - 1, ext[1] + 1, ext[2] - 1, ext[3] + 1, ext[4] - 1, ext[5] + 1)
    pad.SetConstant(0)
    t = time.perf_counter()
    pad.Update()
    times["pad"] = time.perf_counter() - t

    fe = vtk.vtkDiscreteFlyingEdges3D()
    fe.SetInputConnection(pad.GetOutputPort())
    fe.SetValue(0, 1)
    fe.ComputeGradientsOff()
    fe.ComputeNormalsOff()
    fe.ComputeScalarsOff()
    t = time.perf_counter()
    fe.Update()
    times["flying edges"] = time.perf_counter() - t

    sinc = vtk.vtkWindowedSincPolyDataFilter()
    sinc.SetInputConnection(fe.GetOutputPort())
    sinc.SetNumberOfIterations(SLICER_ITERATIONS)
    sinc.SetPassBand(SLICER_PASS_BAND)
    sinc.BoundarySmoothingOff()
    sinc.FeatureEdgeSmoothingOff()
    sinc.NonManifoldSmoothingOn()
    sinc.NormalizeCoordinatesOn()
    t = time.perf_counter()
    sinc.Update()
    times["smoothing"] = time.perf_counter() - t
    out = vtk.vtkPolyData()
    out.DeepCopy(sinc.GetOutput())
    return out, times


def analytic_truth(shape, radius, inner):
    """(distance function of LPS points, area, volume). The phantom's centre is the LPS origin."""
    if shape == "sphere":
        dist = lambda p: np.abs(np.linalg.norm(p, axis=1) - radius)
        return dist, 4 * math.pi * radius ** 2, 4 / 3 * math.pi * radius ** 3
    dist = lambda p: np.minimum(np.abs(np.linalg.norm(p, axis=1) - radius),
                                np.abs(np.linalg.norm(p, axis=1) - inner))
    return dist, 4 * math.pi * (radius ** 2 + inner ** 2), 4 / 3 * math.pi * (radius ** 3 - inner ** 3)


def mesh_to_mesh(points_from, poly_to, samples, rng):
    """|distance| from a random subset of points to the surface poly_to (vtkImplicitPolyDataDistance
    finds the nearest point on the triangles, not the nearest vertex)."""
    idx = rng.choice(len(points_from), size=min(samples, len(points_from)), replace=False)
    implicit = vtk.vtkImplicitPolyDataDistance()
    implicit.SetInput(poly_to)
    d = np.array([abs(implicit.EvaluateFunction(*points_from[i])) for i in idx])
    return d


def poly_from_arrays(points, tris):
    poly = vtk.vtkPolyData()
    pts = vtk.vtkPoints()
    pts.SetData(numpy_support.numpy_to_vtk(np.ascontiguousarray(points), deep=True))
    poly.SetPoints(pts)
    cells = vtk.vtkCellArray()
    offsets = numpy_support.numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(tris) + 1, 3, dtype=np.int64), deep=True)
    conn = numpy_support.numpy_to_vtkIdTypeArray(np.ascontiguousarray(tris.ravel().astype(np.int64)), deep=True)
    cells.SetData(offsets, conn)
    poly.SetPolys(cells)
    return poly


# ---------------------------------------------------------------------------------------------
# Output


def fmt(v):
    if isinstance(v, float):
        if v == 0:
            return "0"
        if abs(v) >= 1000:
            return f"{v:.0f}"
        if abs(v) >= 1:
            return f"{v:.3g}" if abs(v) < 10 else f"{v:.1f}"
        return f"{v:.3f}" if abs(v) >= 0.01 else f"{v:.2g}"
    return str(v)


def print_table(title, rows, keys):
    print(f"\n### {title}\n")
    print("| " + " | ".join(keys) + " |")
    print("|" + "---|" * len(keys))
    for r in rows:
        print("| " + " | ".join(fmt(r.get(k, "")) for k in keys) + " |")


def median_rows(raw, group_key):
    """Medians over repetitions of every numeric column, per group."""
    groups = {}
    for r in raw:
        groups.setdefault(r[group_key], []).append(r)
    out = []
    for name, rs in groups.items():
        m = {group_key: name, "reps": len(rs)}
        for k in rs[0]:
            if k in (group_key, "rep"):
                continue
            vals = [r[k] for r in rs if isinstance(r.get(k), (int, float))]
            m[k] = statistics.median(vals) if vals else rs[0][k]
            if k in ("wall s", "surface s") and vals:
                # The minimum is the least disturbed run: other jobs on a shared machine only add time.
                m["min " + k] = min(vals)
        out.append(m)
    return out


# ---------------------------------------------------------------------------------------------
# Parts


def real_cases(data_dir):
    if not os.path.isdir(data_dir):
        print(f"\nreal cases: {data_dir} absent, skipped (the data is not part of the repository)")
        return []
    cases = sorted(glob.glob(os.path.join(data_dir, "*", "*-label.nii.gz")))
    if not cases:
        print(f"\nreal cases: no *-label.nii.gz under {data_dir}, skipped")
    return cases


def bench_build(args, work, cases):
    raw = []
    for case in cases:
        name = os.path.basename(case).replace("-label.nii.gz", "").replace(".nii.gz", "")
        for rep in range(args.reps):
            out = os.path.join(work, f"{name}.h5")
            wall, stdout, rss = run_timed([args.heartprep, "build", case, "-o", out, "--cavity", "2", "--anchor-border", "--verbose"]
                                          + args.build_extra, os.path.join(work, "rss.txt"))
            row = {"case": name, "rep": rep + 1, "wall s": wall, "peak RSS MiB": rss}
            row.update(parse_build_stdout(stdout))
            raw.append(row)
            print(f"  build {name} rep {rep + 1}: {wall:.2f} s, {rss:.0f} MiB", file=sys.stderr)
    return raw


def bench_critical_step(args, work, case):
    """The critical step (Lanczos on M^-1 K) once dominated the build; how it scales with the
    particle budget tells whether it is the iteration count or the per-iteration cost."""
    raw = []
    name = os.path.basename(case).replace("-label.nii.gz", "")
    for budget in (10000, 30000, 100000):
        for rep in range(args.reps):
            wall, stdout, rss = run_timed([args.heartprep, "build", case, "--verbose", "-o", os.path.join(work, "cs.h5"),
                                           "--cavity", "2", "--anchor-border", "--particles", str(budget)],
                                          os.path.join(work, "rss.txt"))
            row = {"case/budget": f"{name} / {budget}", "rep": rep + 1, "wall s": wall, "peak RSS MiB": rss}
            row.update(parse_build_stdout(stdout))
            raw.append(row)
            print(f"  critical step {name} budget {budget} rep {rep + 1}: {wall:.2f} s", file=sys.stderr)
    return raw


def bench_surface_phantoms(args, work):
    raw = []
    # 1 and 0.5 mm are the phantoms; 0.25 mm (and 0.125 mm for the sphere) are there for
    # timing only: heartprep prints its stage times to 10 ms, which the small grids do not reach.
    voxels = {"sphere": [1.0, 0.5, 0.25, 0.125], "shell": [1.0, 0.5, 0.25]}
    for shape in ("sphere", "shell"):
        for voxel in voxels[shape]:
            name = f"{shape} {voxel:g} mm"
            path = os.path.join(work, f"{shape}-{voxel:g}.nii.gz")
            cmd = [args.heartprep, "phantom", "--shape", shape, "--radius", "20", "--voxel", str(voxel), "-o", path]
            if shape == "shell":
                cmd += ["--inner-radius", "12"]
            run_timed(cmd)
            matrix, dims, spacing = nifti_geometry(path)
            # Cross-check (not a fit): the phantom is defined centred on the LPS origin; the
            # image geometry's grid centre must map there too, or the analytic truth is off.
            grid_centre = to_lps(np.array([[(d - 1) / 2 * s for d, s in zip(dims, spacing)]]), matrix)[0]
            if np.linalg.norm(grid_centre) > 1e-3:
                print(f"  warning: {name}: grid centre at LPS {grid_centre}, not the origin", file=sys.stderr)
            dist, area_true, volume_true = analytic_truth(shape, 20.0, 12.0)

            for rep in range(args.reps):
                ply = os.path.join(work, f"{shape}-{voxel:g}.ply")
                wall, stdout, _ = run_timed([args.heartprep, "surface", path, "-o", ply])
                mc, smooth = parse_surface_stdout(stdout)
                ours = read_ply(ply)  # already LPS
                pts, tris = polydata_arrays(ours)
                raw.append(measure("heartprep", name, rep, pts, tris, dist, area_true, volume_true,
                                   {"extract s": mc, "smooth s": smooth, "surface s": mc + smooth, "wall s": wall}))

                start = time.perf_counter()
                poly, t = vtk_slicer_pipeline(path)
                wall = time.perf_counter() - start
                pts, tris = polydata_arrays(poly)
                pts = to_lps(pts, matrix)
                raw.append(measure("VTK (Slicer)", name, rep, pts, tris, dist, area_true, volume_true,
                                   {"read s": t["read"], "extract s": t["pad"] + t["flying edges"],
                                    "smooth s": t["smoothing"],
                                    "surface s": t["pad"] + t["flying edges"] + t["smoothing"], "wall s": wall}))
                print(f"  surface {name} rep {rep + 1}", file=sys.stderr)
            row_dims = f"{dims[0]}x{dims[1]}x{dims[2]}"
            for r in raw[-2 * args.reps:]:
                r["grid"] = row_dims
    return raw


def measure(pipeline, name, rep, pts, tris, dist, area_true, volume_true, times):
    d = dist(pts)
    area, volume = area_volume(pts, tris)
    row = {"phantom": name, "pipeline": pipeline, "rep": rep + 1, "triangles": len(tris),
           "mean dist mm": float(d.mean()), "max dist mm": float(d.max()),
           "area err %": 100 * (area - area_true) / area_true, "volume err %": 100 * (volume - volume_true) / volume_true}
    row.update(times)
    return row


def bench_surface_real(args, work, cases):
    raw = []
    rng = np.random.default_rng(1)
    for case in cases:
        name = os.path.basename(case).replace("-label.nii.gz", "")
        matrix, dims, spacing = nifti_geometry(case)
        dist_rows = {}
        for rep in range(args.reps):
            ply = os.path.join(work, f"{name}.ply")
            # --min-island 0: VTK keeps every island, so ours must too for a like-for-like mesh.
            wall, stdout, _ = run_timed([args.heartprep, "surface", case, "-o", ply, "--min-island", "0"])
            mc, smooth = parse_surface_stdout(stdout)
            ours = read_ply(ply)
            p_ours, t_ours = polydata_arrays(ours)
            raw.append({"case": name, "pipeline": "heartprep", "rep": rep + 1, "triangles": len(t_ours),
                        "extract s": mc, "smooth s": smooth, "surface s": mc + smooth, "wall s": wall})
            start = time.perf_counter()
            poly, t = vtk_slicer_pipeline(case)
            wall = time.perf_counter() - start
            p_vtk, t_vtk = polydata_arrays(poly)
            raw.append({"case": name, "pipeline": "VTK (Slicer)", "rep": rep + 1, "triangles": len(t_vtk),
                        "read s": t["read"], "extract s": t["pad"] + t["flying edges"], "smooth s": t["smoothing"],
                        "surface s": t["pad"] + t["flying edges"] + t["smoothing"], "wall s": wall})
            print(f"  surface {name} rep {rep + 1}", file=sys.stderr)
        # Distances once (the meshes are deterministic): both in LPS.
        p_vtk = to_lps(p_vtk, matrix)
        vtk_lps = poly_from_arrays(p_vtk, t_vtk)
        d1 = mesh_to_mesh(p_ours, vtk_lps, args.samples, rng)
        d2 = mesh_to_mesh(p_vtk, ours, args.samples, rng)
        both = np.concatenate([d1, d2])
        dist_rows = {"ours->VTK mean mm": float(d1.mean()), "VTK->ours mean mm": float(d2.mean()),
                     "symmetric mean mm": float(both.mean()), "symmetric p99 mm": float(np.percentile(both, 99)),
                     "symmetric max mm": float(both.max())}
        for r in raw[-2 * args.reps:]:
            r.update(dist_rows)
    return raw



def bench_part2_stages(args, work, cases):
    """Part 2: the stages after the layout (pack, simsurface, map), timed inside `heartprep build`."""
    raw = []
    for case in cases:
        name = os.path.basename(case).replace("-label.nii.gz", "").replace(".nii.gz", "")
        name = re.sub(r"^.*_(pat\d+)$", r"\1", name)  # training_axial_crop_pat0 -> pat0
        for rep in range(args.reps):
            out = os.path.join(work, f"{name}.h5")
            wall, stdout, rss = run_timed([args.heartprep, "build", case, "-o", out, "--cavity", "2", "--anchor-border", "--verbose"],
                                          os.path.join(work, "rss.txt"))
            row = {"case": name, "rep": rep + 1, "wall s": wall, "peak RSS MiB": rss}
            row.update(parse_build_stdout(stdout))
            for stage in ("pack", "simsurface", "map"):
                if "stage " + stage not in row:
                    raise RuntimeError(f"no '{stage}' stage in heartprep's stages line:\n" + stdout)
            row["pack+simsurface+map s"] = row["stage pack"] + row["stage simsurface"] + row["stage map"]
            m = re.search(r"^simsurface\s+(\d+) triangles over (\d+) boundary particles", stdout, re.M)
            row["simsurface triangles"] = int(m.group(1)) if m else 0
            m = re.search(r"^mapping\s+(\d+) visual vertices", stdout, re.M)
            row["visual vertices"] = int(m.group(1)) if m else 0
            raw.append(row)
            print(f"  stages {name} rep {rep + 1}: pack {row['stage pack']:.3f} s, simsurface {row['stage simsurface']:.3f} s, "
                  f"map {row['stage map']:.3f} s (load {os.getloadavg()[0]:.2f})", file=sys.stderr)
    return raw


def bench_batch(args, work, cases):
    """Part 2: `heartprep batch` on a folder of symlinks to the real cases (the data is not copied)."""
    folder = os.path.join(work, "batch-input")
    shutil.rmtree(folder, ignore_errors=True)
    os.makedirs(folder)
    for case in cases:
        os.symlink(os.path.abspath(case), os.path.join(folder, os.path.basename(case)))
    raw = []
    for jobs in (1, 2):
        for rep in range(args.reps):
            out = os.path.join(work, f"batch-j{jobs}")
            shutil.rmtree(out, ignore_errors=True)
            cmd = [args.heartprep, "batch", folder, "-o", out, "-j", str(jobs), "--options", "--cavity 2 --anchor-border"]
            for run in ("fresh", "resumed"):
                wall, _, _ = run_timed(cmd)
                with open(os.path.join(out, "summary.csv"), newline="") as f:
                    status = [r["status"] for r in csv.DictReader(f)]
                raw.append({"run": f"-j {jobs}, {run}", "rep": rep + 1, "cases": len(status),
                            "built": status.count("built"), "reused": status.count("reused"),
                            "failed": status.count("failed"), "wall s": wall,
                            "cases per minute": 60.0 * len(status) / wall})
                print(f"  batch -j {jobs} {run} rep {rep + 1}: {wall:.2f} s, {status.count('built')} built, "
                      f"{status.count('reused')} reused, {status.count('failed')} failed (load {os.getloadavg()[0]:.2f})",
                      file=sys.stderr)
    shutil.rmtree(folder, ignore_errors=True)
    return raw


def find_mapping_bench(args):
    if args.mapping_bench:
        return args.mapping_bench
    build = os.path.dirname(os.path.dirname(os.path.abspath(args.heartprep)))  # <build>/tools/heartprep
    candidate = os.path.join(build, "tests", "bench", "mapping_bench")
    return candidate if os.access(candidate, os.X_OK) else None


def machine_description():
    model = "?"
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    with open("/proc/meminfo") as f:
        mem_kib = int(f.readline().split()[1])
    smp = vtk.vtkSMPTools()
    return (f"nproc {os.cpu_count()} (affinity {len(os.sched_getaffinity(0))}), CPU {model}, "
            f"memory {mem_kib / 1024 / 1024:.1f} GiB, kernel {platform.release()}, "
            f"VTK {vtk.vtkVersion.GetVTKVersion()} (SMP backend {smp.GetBackend()}, "
            f"{smp.GetEstimatedNumberOfThreads()} threads), load average {os.getloadavg()[0]:.2f}")


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    repo = os.path.dirname(os.path.dirname(here))
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--heartprep", default=os.environ.get("HEARTPREP", os.path.join(repo, "build/release/tools/heartprep")))
    ap.add_argument("--out", default="/tmp/heartsim-bench", help="results folder (CSV files and scratch)")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(repo), "shared/data/real"),
                    help="folder of real cases (*/ *-label.nii.gz)")
    ap.add_argument("--reps", type=int, default=3, help="repetitions per measurement (median reported)")
    ap.add_argument("--samples", type=int, default=20000, help="vertices per direction for mesh-to-mesh distance")
    ap.add_argument("--parts", default="build,critical,surface,real",
                    help="comma list of: build, critical, surface, real (part 1); stages, batch, mapping (part 2; "
                         "'part2' = all three)")
    ap.add_argument("--mapping-bench", default=os.environ.get("MAPPING_BENCH"),
                    help="mapping_bench binary (default: <heartprep's build>/tests/bench/mapping_bench)")
    args = ap.parse_args()
    args.build_extra = []
    parts = set(args.parts.split(","))
    if "part2" in parts:
        parts |= {"stages", "batch", "mapping"}
    if not os.access(args.heartprep, os.X_OK):
        sys.exit(f"heartprep_bench: no heartprep at {args.heartprep}; build it or pass --heartprep / HEARTPREP")
    os.makedirs(args.out, exist_ok=True)
    work = os.path.join(args.out, "work")
    os.makedirs(work, exist_ok=True)

    print("## heartprep benchmark\n")
    print(f"machine: {machine_description()}")
    print(f"heartprep: {args.heartprep}; repetitions: {args.reps}; results: {args.out}")
    cases = real_cases(args.data)

    if "build" in parts:
        phantom = os.path.join(work, "phantom-256.nii.gz")
        run_timed([args.heartprep, "phantom", "--size", "256", "-o", phantom])
        raw = bench_build(args, work, cases + [phantom])
        write_csv(os.path.join(args.out, "build_raw.csv"), raw)
        med = median_rows(raw, "case")
        write_csv(os.path.join(args.out, "build.csv"), med)
        stage_keys = [k for k in med[0] if k.startswith("stage ") and k != "stage total"]
        print_table("heartprep build, median of %d (seconds; RSS MiB)" % args.reps, med,
                    ["case", "wall s", "min wall s", "stage total"] + stage_keys + ["peak RSS MiB"])
        print_table("heartprep build: model size", med,
                    ["case", "triangles", "spacing mm", "particles", "anchored", "springs", "Lanczos iterations"])
        for r in med:
            top = max(stage_keys, key=lambda k: r[k])
            print(f"- {r['case']}: dominant stage '{top[6:]}' {r[top]:.2f} s of {r['stage total']:.2f} s "
                  f"({100 * r[top] / max(r['stage total'], 1e-9):.0f}%); wall {r['wall s']:.2f} s "
                  f"({'under' if r['wall s'] < 3 else 'OVER'} the 3 s target)")

    if "critical" in parts and cases:
        case = next((c for c in cases if "pat1" in c), cases[0])
        raw = bench_critical_step(args, work, case)
        write_csv(os.path.join(args.out, "critical_step_raw.csv"), raw)
        med = median_rows(raw, "case/budget")
        write_csv(os.path.join(args.out, "critical_step.csv"), med)
        print_table("critical time step vs particle budget, median of %d" % args.reps, med,
                    ["case/budget", "particles", "springs", "Lanczos iterations", "stage critical step", "stage total",
                     "wall s"])

    if "surface" in parts:
        raw = bench_surface_phantoms(args, work)
        write_csv(os.path.join(args.out, "surface_phantoms_raw.csv"), raw)
        for r in raw:
            r["key"] = f"{r['phantom']}|{r['pipeline']}"
        med = median_rows(raw, "key")
        for r in med:
            r["phantom"], r["pipeline"] = r.pop("key").split("|")
        write_csv(os.path.join(args.out, "surface_phantoms.csv"), med)
        print_table("surface accuracy vs analytic phantoms (times: median of %d, s)" % args.reps, med,
                    ["phantom", "grid", "pipeline", "triangles", "mean dist mm", "max dist mm", "area err %",
                     "volume err %", "extract s", "smooth s", "surface s", "min surface s", "read s", "wall s"])

    if "real" in parts and cases:
        raw = bench_surface_real(args, work, cases)
        write_csv(os.path.join(args.out, "surface_real_raw.csv"), raw)
        for r in raw:
            r["key"] = f"{r['case']}|{r['pipeline']}"
        med = median_rows(raw, "key")
        for r in med:
            r["case"], r["pipeline"] = r.pop("key").split("|")
        write_csv(os.path.join(args.out, "surface_real.csv"), med)
        print_table("surface on real cases (times: median of %d, s)" % args.reps, med,
                    ["case", "pipeline", "triangles", "extract s", "smooth s", "surface s", "min surface s", "read s",
                     "wall s"])
        print_table("heartprep vs VTK mesh distance on real cases (%d sampled vertices each way, mm)" % args.samples,
                    [r for r in med if r["pipeline"] == "heartprep"],
                    ["case", "ours->VTK mean mm", "VTK->ours mean mm", "symmetric mean mm", "symmetric p99 mm",
                     "symmetric max mm"])

    if "stages" in parts and cases:
        raw = bench_part2_stages(args, work, cases)
        write_csv(os.path.join(args.out, "part2_stages_raw.csv"), raw)
        med = median_rows(raw, "case")
        for r in med:
            rs = [x["pack+simsurface+map s"] for x in raw if x["case"] == r["case"]]
            r["min pack+simsurface+map s"] = min(rs)
            r["max pack+simsurface+map s"] = max(rs)
            r["target 1 s"] = "met" if r["pack+simsurface+map s"] < 1.0 else "MISSED"
        write_csv(os.path.join(args.out, "part2_stages.csv"), med)
        print_table("pack, simsurface and map inside heartprep build, median of %d (seconds)" % args.reps, med,
                    ["case", "particles", "simsurface triangles", "visual vertices", "stage pack", "stage simsurface",
                     "stage map", "pack+simsurface+map s", "min pack+simsurface+map s", "max pack+simsurface+map s",
                     "target 1 s", "stage total", "wall s"])

    if "batch" in parts and cases:
        raw = bench_batch(args, work, cases)
        write_csv(os.path.join(args.out, "part2_batch_raw.csv"), raw)
        med = median_rows(raw, "run")
        for r in med:
            r["min wall s"] = min(x["wall s"] for x in raw if x["run"] == r["run"])
        write_csv(os.path.join(args.out, "part2_batch.csv"), med)
        print_table("heartprep batch on the %d real cases, median of %d" % (len(cases), args.reps), med,
                    ["run", "cases", "built", "reused", "failed", "wall s", "min wall s", "cases per minute"])

    if "mapping" in parts:
        binary = find_mapping_bench(args)
        if not binary:
            print("\nmapping: no mapping_bench binary; build it (cmake --build build/release --target mapping_bench) "
                  "or pass --mapping-bench; skipped")
        else:
            cmd = [binary, "--out", args.out]
            cmd += ["--real", args.data] if cases else ["--no-real"]
            print(f"\n$ {' '.join(cmd)}\n", flush=True)
            subprocess.run(cmd, check=True)
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
