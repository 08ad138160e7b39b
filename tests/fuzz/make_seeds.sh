#!/usr/bin/env bash
# Writes the seed corpora tests/fuzz/corpus/<target>/ from our own tools and samples (nothing
# from ../shared/data: its licence is not stated). Needs the release build (heartprep, heartsim).
# The seeds are committed; rerun this after a format change and commit what it writes.
#   tests/fuzz/make_seeds.sh [BUILD_DIR]   (default build/release)
set -euo pipefail
cd "$(dirname "$0")/../.."
build="${1:-build/release}"
heartprep="$build/tools/heartprep"
heartsim="$build/runtime/heartsim"
corpus=tests/fuzz/corpus
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

rm -rf "$corpus"
mkdir -p "$corpus"/{fuzz_volume_nii,fuzz_volume_nii_gz,fuzz_volume_nrrd,fuzz_volume_mha,fuzz_scenario,fuzz_recording}
mkdir -p "$corpus"/{fuzz_trajectory,fuzz_trajectory_run,fuzz_pose_script,fuzz_simulated_device,fuzz_batch_manifest,fuzz_label_table}

# Label maps: the phantom heart at 16 voxels along its longest axis in every format the writer
# knows (.nrrd, .seg.nrrd and .mha gzip-compressed), a thick shell and a sphere.
for name in heart16.nii heart16.nii.gz heart16.nrrd heart16.seg.nrrd heart16.mha heart16.mhd; do
  "$heartprep" phantom -o "$work/$name" --size 16 >/dev/null
done
"$heartprep" phantom -o "$work/shell12.nii" --shape shell --size 12 >/dev/null
"$heartprep" phantom -o "$work/sphere10.mha" --shape sphere --size 10 >/dev/null
# Uncompressed single files from the .mhd/.raw pair: a MetaImage with its data inline, and a NRRD
# with the gzip encoding replaced by raw (the header up to its blank line, then the same voxels).
sed 's/^ElementDataFile = .*/ElementDataFile = LOCAL/' "$work/heart16.mhd" > "$work/heart16-raw.mha"
cat "$work/heart16.raw" >> "$work/heart16-raw.mha"
sed -n '1,/^$/p' "$work/heart16.nrrd" | sed 's/^encoding: gzip$/encoding: raw/' > "$work/heart16-raw.nrrd"
cat "$work/heart16.raw" >> "$work/heart16-raw.nrrd"

cp "$work/heart16.nii" "$work/shell12.nii" "$corpus/fuzz_volume_nii/"
# The nii_gz target gzips what it is given unless it is gzip already: both kinds of seed.
cp "$work/heart16.nii.gz" "$work/shell12.nii" "$corpus/fuzz_volume_nii_gz/"
cp "$work/heart16.nrrd" "$work/heart16.seg.nrrd" "$work/heart16-raw.nrrd" "$corpus/fuzz_volume_nrrd/"
cp "$work/heart16.mha" "$work/sphere10.mha" "$work/heart16-raw.mha" "$corpus/fuzz_volume_mha/"

# Scenarios: the phantom at 12 voxels built with 30 particles three ways (every group; no visual
# mesh with slice packing; the tangent-space mapping, unsupported and unbalanced), the visual
# surface decimated by 90 % to keep the files near 100 KB.
"$heartprep" phantom -o "$work/heart12.nii.gz" --size 12 >/dev/null
"$heartprep" build "$work/heart12.nii.gz" -o "$corpus/fuzz_scenario/full.h5" --particles 30 --cavity 2 --decimate 0.9 -q
"$heartprep" build "$work/heart12.nii.gz" -o "$corpus/fuzz_scenario/slices-no-visual.h5" --particles 30 --no-visual --packing slices -q
"$heartprep" build "$work/heart12.nii.gz" -o "$corpus/fuzz_scenario/tangent-imaged.h5" --particles 30 --mapping tangent --decimate 0.9 \
  --rest-state imaged --support none --allow-free -q
# The planners' seeds: the phantom at 24 voxels with an 8 mm VSD carved at a septum point, and the
# same scenario without its defect (plan-incision only).
mkdir -p "$corpus/fuzz_planners"
"$heartprep" phantom -o "$work/heart24.nii.gz" --vsd-diameter 0 --size 24 >/dev/null
"$heartprep" build "$work/heart24.nii.gz" -o "$corpus/fuzz_planners/vsd.h5" --defect vsd --at=-21.1,-1.1,-1.5 --diameter 8 --particles 30 \
  --decimate 0.9 -q
cp "$corpus/fuzz_scenario/full.h5" "$corpus/fuzz_planners/"

# Recordings: 20 ms of the samples' scripted grab and simulated press on the full scenario, both
# hands, and the grab alone.
"$heartsim" run "$corpus/fuzz_scenario/full.h5" --headless --backend cpu --seconds 0.02 \
  --device scripted:samples/haptics/grab_phantom.csv --device simulated:samples/haptics/press_phantom.csv \
  --record "$corpus/fuzz_recording/two-hands.h5" >/dev/null
"$heartsim" run "$corpus/fuzz_scenario/full.h5" --headless --backend cpu --seconds 0.02 \
  --device scripted:samples/haptics/grab_phantom.csv --record "$corpus/fuzz_recording/one-hand.h5" >/dev/null
# A scalpel on a scripted device, its blade lowered at 5 ms and drawn 4 mm superior.
printf '0,-12,-30,-2,0.5,-0.5,-0.5,-0.5,0\n5,-12,-30,-2,0.5,-0.5,-0.5,-0.5,1\n25,-12,-30,2,0.5,-0.5,-0.5,-0.5,1\n' > "$work/cut.csv"
"$heartsim" run "$corpus/fuzz_scenario/full.h5" --headless --backend cpu --seconds 0.02 \
  --device scripted:"$work/cut.csv" --instrument scalpel --record "$corpus/fuzz_recording/scalpel.h5" >/dev/null

# CSV files: the samples.
cp samples/probe_and_grab_phantom.csv samples/probe_and_grab_pat1.csv "$corpus/fuzz_trajectory/"
# Scalpel scripts, aimed at fuzz_trajectory_run's block (4 × 4 × 4 particles 1.5 mm apart, centred
# on the origin, so ±2.25 mm): a blade drawn through it while the other hand holds its top, lifted,
# lowered again over the same cut and drawn back, turned into a probe and back; blades of the
# shortest (1e-3 mm) and the longest (500 mm) semi-axis, a plunge along the blade, a turning
# blade, a blade a kilometre away; and blades a trajectory refuses (NaN, zero, infinite, 1e30).
mkdir -p "$corpus/fuzz_trajectory_run"
cat > "$corpus/fuzz_trajectory/scalpel_cut.csv" <<'CSV'
time_ms, hand, kind, x, y, z, qw, qx, qy, qz, ax, ay, az, grab
0,  0, scalpel, 0.1, -5, -4, 1, 0, 0, 0, 1, 0.2, 4, 1
2,  0, scalpel, 0.1,  5, -4, 1, 0, 0, 0, 1, 0.2, 4, 1
3,  0, scalpel, 0.1,  5, -4, 1, 0, 0, 0, 1, 0.2, 4, 0
4,  0, scalpel, 0.1,  5, -4, 1, 0, 0, 0, 1, 0.2, 4, 1
6,  0, scalpel, 0.1, -5, -4, 1, 0, 0, 0, 1, 0.2, 4, 1
7,  0, probe,   0.1, -5, -4, 1, 0, 0, 0, 1, 1, 1, 0
8,  0, scalpel, -1.4, -5, -4, 0.92388, 0, 0, 0.38268, 1, 0.2, 4, 1
10, 0, scalpel, -1.4,  5, -4, 0.92388, 0, 0, 0.38268, 1, 0.2, 4, 1
0,  1, grabber, 0, 0, 2.25, 1, 0, 0, 0, 2, 2, 1, 1
10, 1, grabber, 0, 0, 4.25, 1, 0, 0, 0, 2, 2, 1, 1
CSV
cat > "$corpus/fuzz_trajectory/scalpel_blades.csv" <<'CSV'
time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab
0,0,scalpel,0.1,-3,-1.5,1,0,0,0,0.001,0.001,0.001,1
1,0,scalpel,0.1,3,-1.5,1,0,0,0,0.001,0.001,0.001,1
2,0,scalpel,0.1,3,-600,1,0,0,0,500,500,500,1
3,0,scalpel,0.1,-3,-600,1,0,0,0,500,500,500,1
4,0,scalpel,-0.7,0.2,-9,1,0,0,0,1,0.2,3,1
5,0,scalpel,-0.7,0.2,-1,1,0,0,0,1,0.2,3,1
6,0,scalpel,0.8,-4,0,0.7071,0.7071,0,0,1,0.2,4,1
7,0,scalpel,0.8,-4,0,0,1,0,0,1,0.2,4,1
8,0,scalpel,1e6,-1e6,1e6,1,0,0,0,500,1,500,1
9,0,scalpel,-1e6,1e6,-1e6,0,0,1,0,500,1,500,1
0,1,scalpel,-0.2,0,-3,0.5,0.5,0.5,0.5,1,0.2,4,1
9,1,scalpel,-0.2,0,3,0.5,-0.5,0.5,0.5,1,0.2,4,0
CSV
printf 'time_ms,hand,kind,x,y,z,qw,qx,qy,qz,ax,ay,az,grab\n0,0,scalpel,0.1,-3,-3,1,0,0,0,1,0.2,nan,1\n1,0,scalpel,0.1,3,-3,1,0,0,0,1,0.2,4,1\n' \
  > "$corpus/fuzz_trajectory/scalpel_nan.csv"
printf '0,0,scalpel,0.1,-3,-3,1,0,0,0,1,0.2,0,1\n1,0,scalpel,0.1,3,-3,1,0,0,0,1,0.2,-0,1\n' > "$corpus/fuzz_trajectory/scalpel_zero.csv"
printf '0,0,scalpel,0.1,-3,-3,1,0,0,0,1,0.2,1e30,1\n1,0,scalpel,0.1,3,-3,1,0,0,0,inf,0.2,4,1\n2,0,scalpel,nan,3,-3,1,0,0,0,1,0.2,4,1\n' \
  > "$corpus/fuzz_trajectory/scalpel_huge.csv"
# Planned views (the `# view:` line): the surgeon's eye as plan-operation writes it, plan-incision's
# camera at a distance, and views the reader refuses (the eye on the point, no --view, two lines).
printf '# view: --view surgeon --eye -84.5,51.3,61.2 --look-at -25.5,-1.1,-1.5\n0,0,probe,0,0,0,1,0,0,0,1,1,1,0\n' \
  > "$corpus/fuzz_trajectory/view_surgeon.csv"
printf '# view: --view anterior --look-at 37,-45.5,21.1,75\n0,0,probe,0,0,0,1,0,0,0,1,1,1,0\n' > "$corpus/fuzz_trajectory/view_distance.csv"
printf '# view: --view surgeon --eye 1,2,3 --look-at 1,2,3\n# view: --look-at 1,2,3\n0,0,probe,0,0,0,1,0,0,0,1,1,1,0\n' \
  > "$corpus/fuzz_trajectory/view_refused.csv"
cp "$corpus"/fuzz_trajectory/*.csv "$corpus/fuzz_trajectory_run/"
cp samples/haptics/grab_phantom.csv samples/haptics/grab_pat1.csv "$corpus/fuzz_pose_script/"
cp samples/haptics/press_phantom.csv samples/haptics/press_pat1.csv "$corpus/fuzz_simulated_device/"
# A batch manifest with a header, a comment, a blank line, ids, quoted options and an option
# containing a comma.
cat > "$corpus/fuzz_batch_manifest/cases.csv" <<'CSV'
input,case_id,options
# the shipped phantom twice, once with its own options
phantom.nii.gz
phantom.nii.gz,phantom-cavity,"--cavity 2 --anchor-border"

/data/labelmaps/pat1-label.nii.gz,pat1,"--gravity 0,0.00981,0 --particles 20000 --mapping 'tangent'"
CSV
printf 'a.nii\nb.nrrd,b\n' > "$corpus/fuzz_batch_manifest/plain.csv"

# Label tables in the three layouts read_label_table knows (formats/label_table.h), with a
# comment, a blank line and an underscore that stands for a blank.
printf '# Color table file\n0 Background 0 0 0 0\n1 blood_pool 255 0 0 255\n\n2 Myocardium 0 255 0 255\n' \
  > "$corpus/fuzz_label_table/slicer.ctbl"
printf '# ITK-SNAP Label Description File\n    0     0    0    0        0  0  0    "Clear Label"\n    1   255    0    0        1  1  1    "blood pool"\n    2     0  255    0        1  1  1    "Myocardium"\n' \
  > "$corpus/fuzz_label_table/itksnap.txt"
printf 'LabelValue,Name,Color_R,Color_G,Color_B,Color_A\n0,Background,0,0,0,0\n1,blood pool,255,0,0,255\n2,"Myocardium",0,255,0,255\n' \
  > "$corpus/fuzz_label_table/slicer.csv"
# Strokes for fuzz_incision's box (12 × 12 × 8 mm): per stroke a byte (poses − 2), then per pose the
# blade's tip and end, each coordinate a little-endian uint16 over −4 to 16 mm.
mkdir -p "$corpus/fuzz_incision"
python3 - "$corpus/fuzz_incision" <<'PY'
import struct, sys
def coordinate(v): return struct.pack('<H', max(0, min(65535, round((v + 4) / 20 * 65535))))
def stroke(poses):
    out = bytes([len(poses) - 2])
    for tip, end in poses:
        for c in tip + end: out += coordinate(c)
    return out
folder = sys.argv[1]
open(folder + '/through.bin', 'wb').write(stroke([((5.9, -2, -2), (5.9, -2, 10)), ((5.9, 14, -2), (5.9, 14, 10))]))
open(folder + '/slit.bin', 'wb').write(stroke([((5.9, -2, 4), (5.9, -2, 10)), ((5.9, 14, 4), (5.9, 14, 10))]))
open(folder + '/bent_then_cross.bin', 'wb').write(
    stroke([((5.9, -2, 2), (5.9, -2, 6)), ((6.4, 6, 2), (6.4, 6, 6)), ((5.9, 14, 2), (5.9, 14, 6))]) +
    stroke([((-2, 6.1, 5), (-2, 6.1, 10)), ((14, 6.1, 5), (14, 6.1, 10))]))
open(folder + '/saw.bin', 'wb').write(stroke([((3, -2, 4), (3, -2, 10)), ((3, 8, 4), (3, 8, 10)), ((3, 2, 4), (3, 2, 10)), ((3, 10, 4), (3, 10, 10))]))
PY
# ParaView's descriptions written beside the HDF5 seeds are not inputs of any reader.
rm -f "$corpus"/*/*.xmf2
du -ab "$corpus" | sort -k2
