#!/usr/bin/env bash
# heartsim's GPU benchmark, from the bundle that tests/bench/gpu/make-bundle.sh writes, on a machine
# with nothing installed but glibc, python3 with numpy, and the GPU's driver:
#
#   tar -xzf heartsim-gpu.tar.gz -C /tmp && /tmp/heartsim-gpu/bench/gpu_bench.sh [--out DIR] [--quick]
#   /tmp/heartsim-gpu/bench/gpu_bench.sh surgery --data DIR [--out DIR]   (the incision and the repair on real hearts)
#
# It sets the library path to the bundle's libraries (then NVIDIA's driver folders where they
# exist) and points libglvnd at NVIDIA's EGL vendor file where there is one, then runs
# gpu_bench.py (its --help: what it measures). Within 8 minutes on a 16-core machine with an H100.
set -euo pipefail

bench="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$bench")"
libs="$root/lib"
for dir in /usr/local/nvidia/lib64 /usr/local/nvidia/lib /usr/lib/x86_64-linux-gnu/nvidia; do
  [ -d "$dir" ] && libs="$libs:$dir"
done
export LD_LIBRARY_PATH="$libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export PATH="$root/bin:$PATH"
if [ -z "${__EGL_VENDOR_LIBRARY_FILENAMES:-}" ]; then
  for vendor in /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json /usr/share/glvnd/egl_vendor.d/10_nvidia.json \
                /etc/glvnd/egl_vendor.d/10_nvidia.json; do
    if [ -f "$vendor" ]; then export __EGL_VENDOR_LIBRARY_FILENAMES="$vendor"; break; fi
  done
fi
echo "bundle: $(head -1 "$root/VERSION" 2>/dev/null || echo unknown); EGL vendor file: ${__EGL_VENDOR_LIBRARY_FILENAMES:-the default folders of libglvnd}"
python=""
for candidate in python3 /usr/bin/python3 /opt/torch/.venv/bin/python3; do
  if command -v "$candidate" >/dev/null && "$candidate" -c "import numpy" 2>/dev/null; then python="$candidate"; break; fi
done
[ -n "$python" ] || { echo "gpu_bench: no python3 with numpy (python3-numpy)" >&2; exit 1; }
if [ "${1:-}" = surgery ]; then  # the incision and the repair on real hearts: gpu_surgery.py --help
  shift
  exec "$python" -u "$bench/gpu_surgery.py" --heartsim "$root/bin/heartsim" --heartprep "$root/bin/heartprep" --h5dump "$root/bin/h5dump" "$@"
fi
exec "$python" -u "$bench/gpu_bench.py" --heartsim "$root/bin/heartsim" --heartprep "$root/bin/heartprep" "$@"
