#!/usr/bin/env bash
# Proves that the GPU bundle (make-bundle.sh) runs where nothing is installed: a root folder that
# holds only glibc (libc, libm, libdl, libpthread, librt, the loader), /bin/sh and the bundle,
# entered with chroot. In it: heartprep writes a phantom and builds a scenario, heartsim runs it on
# the cpu backend and writes its state, h5dump reads the state. Then Mesa's EGL driver (the part
# a GPU machine's own driver plays: a vendor library and its vendor file, as NVIDIA's) is added
# and heartsim info and a gl run go through the bundle's GL loader, on EGL's device platform
# (HEARTSIM_EGL=device) and on the surfaceless one. Needs root (chroot).
#
#   tests/bench/gpu/check-bundle.sh [BUNDLE.tar.gz]     default build/gpu-bundle/heartsim-gpu.tar.gz
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
bundle="${1:-$repo/build/gpu-bundle/heartsim-gpu.tar.gz}"
[ -f "$bundle" ] || { echo "check-bundle: $bundle missing; run tests/bench/gpu/make-bundle.sh first" >&2; exit 1; }
[ "$(id -u)" = 0 ] || { echo "check-bundle: needs root (chroot)" >&2; exit 1; }

root="$(mktemp -d)"
trap 'rm -rf "$root"' EXIT
lib=/lib/x86_64-linux-gnu
# Debian's merged /usr: /lib is /usr/lib (Mesa looks for its DRI drivers under /usr/lib/...).
mkdir -p "$root/lib64" "$root/usr$lib" "$root/bin" "$root/tmp" "$root/dev" "$root/proc"
ln -s usr/lib "$root/lib"
cp -L /lib64/ld-linux-x86-64.so.2 "$root/lib64/"
for name in libc.so.6 libm.so.6 libdl.so.2 libpthread.so.0 librt.so.1 libresolv.so.2; do cp -L "$lib/$name" "$root$lib/"; done
# A static shell would need nothing; Debian's dash needs libc alone.
cp -L /bin/dash "$root/bin/sh"
touch "$root/dev/null" && mount --bind /dev/null "$root/dev/null"
mount -t proc proc "$root/proc"
trap 'umount "$root/dev/null" "$root/proc" 2>/dev/null || true; rm -rf "$root"' EXIT
tar -xzf "$bundle" -C "$root/tmp"
b=/tmp/heartsim-gpu
env_in="LD_LIBRARY_PATH=$b/lib"

inside() { chroot "$root" /usr/bin/env -i "$env_in" "$@"; }
mkdir -p "$root/usr/bin" && cp -L /usr/bin/env "$root/usr/bin/"

echo "== a root with glibc and the bundle only: $(cd "$root" && find . -type f | wc -l) files"
inside $b/bin/heartprep phantom -o /tmp/phantom.nii.gz --voxel 2
inside $b/bin/heartprep build /tmp/phantom.nii.gz -o /tmp/phantom.h5 --particles 3000 -q
inside $b/bin/heartsim run /tmp/phantom.h5 --headless --backend cpu --steps 20 --save-state /tmp/state.h5 | head -3
inside $b/bin/h5dump -H -d /positions /tmp/state.h5 | grep -q "DATASPACE  SIMPLE" && echo "h5dump reads the state: /positions"
set +e
no_gl="$(inside $b/bin/heartsim info 2>&1)"
code=$?
set -e
echo "heartsim info with no GPU driver: exit $code: $no_gl"
[ "$code" = 3 ] || { echo "check-bundle: expected exit 3 (no usable OpenGL) without a driver" >&2; exit 1; }

# The driver: Mesa's EGL vendor library, its DRI driver and what they load, and its vendor file.
mesa_egl="$(ls $lib/libEGL_mesa.so.0 2>/dev/null || true)"
if [ -z "$mesa_egl" ]; then
  echo "check-bundle: no Mesa EGL here ($lib/libEGL_mesa.so.0); the driver half is skipped"
  exit 0
fi
mkdir -p "$root/usr/share/glvnd/egl_vendor.d" "$root$lib/dri"
cp /usr/share/glvnd/egl_vendor.d/50_mesa.json "$root/usr/share/glvnd/egl_vendor.d/"
cp -L $lib/dri/swrast_dri.so "$root$lib/dri/"
for object in "$mesa_egl" $lib/dri/swrast_dri.so; do
  cp -L "$object" "$root$lib/" 2>/dev/null || true
  ldd "$object" | awk '$2 == "=>" && $3 ~ /^\// {print $3}' | while read -r dep; do
    [ -e "$root$lib/$(basename "$dep")" ] || [ -e "$root/tmp/heartsim-gpu/lib/$(basename "$dep")" ] || cp -L "$dep" "$root$lib/"
  done
done
env_in="LD_LIBRARY_PATH=$b/lib:$lib"
for platform in device surfaceless; do
  echo "== with a driver (Mesa's, as a GPU machine has NVIDIA's), HEARTSIM_EGL=$platform"
  chroot "$root" /usr/bin/env -i "$env_in" HEARTSIM_EGL=$platform $b/bin/heartsim info | head -3
  chroot "$root" /usr/bin/env -i "$env_in" HEARTSIM_EGL=$platform $b/bin/heartsim run /tmp/phantom.h5 --headless --backend gl --steps 20 | head -3
done
echo "check-bundle: the bundle runs with glibc alone, and OpenGL through its own GL loader"
