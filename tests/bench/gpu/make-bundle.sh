#!/usr/bin/env bash
# Packs what the GPU benchmark needs into one archive for a machine with nothing installed (no
# package registry, no HDF5, no ITK, no GL loader): heartsim, heartprep and h5dump, every shared
# library they load except glibc's own (libc, libm, libdl, libpthread, librt, libresolv, the
# loader), the GL loader libraries from Debian's libglvnd packages (libegl1, libglvnd0, libopengl0,
# libgl1, libglx0, libgles2: epoxy opens them at run time, so ldd does not list them) and the
# benchmark scripts. The GPU's own driver (NVIDIA's libEGL_nvidia and its vendor file) is the
# machine's. docs/benchmarks.md, "On a GPU".
#
#   tests/bench/gpu/make-bundle.sh [-o OUT.tar.gz]        default build/gpu-bundle/heartsim-gpu.tar.gz
#
# Needs a release build (cmake --preset release && cmake --build --preset release), hdf5-tools
# (h5dump) and apt-get download (or GL_DEBS=DIR holding the six .deb files). At most 64 MiB:
# larger is an error. tests/bench/gpu/check-bundle.sh proves it runs in a root with glibc alone.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
out="$repo/build/gpu-bundle/heartsim-gpu.tar.gz"
while [ $# -gt 0 ]; do
  case "$1" in
    -o|--output) out="$2"; shift 2 ;;
    -h|--help) sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "make-bundle: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

heartsim="${HEARTSIM:-$repo/build/release/runtime/heartsim}"
heartprep="${HEARTPREP:-$repo/build/release/tools/heartprep}"
h5dump="$(command -v h5dump || true)"
for tool in "$heartsim" "$heartprep"; do
  [ -x "$tool" ] || { echo "make-bundle: $tool missing; build first: cmake --preset release && cmake --build --preset release" >&2; exit 1; }
done
[ -n "$h5dump" ] || { echo "make-bundle: h5dump missing; apt-get install hdf5-tools (scripts/install-deps.sh --bench)" >&2; exit 1; }

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
root="$work/heartsim-gpu"
mkdir -p "$root/bin" "$root/lib" "$root/bench"

# The GL loader, from Debian's packages.
debs="${GL_DEBS:-}"
if [ -z "$debs" ]; then
  debs="$work/debs"
  mkdir -p "$debs"
  (cd "$debs" && apt-get download libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >/dev/null 2>"$work/apt.log") || {
    echo "make-bundle: apt-get download of the GL loader packages failed (no network? give GL_DEBS=DIR):" >&2
    cat "$work/apt.log" >&2
    exit 1
  }
fi
for deb in "$debs"/*.deb; do dpkg-deb -x "$deb" "$work/gl"; done
cp -a "$work"/gl/usr/lib/x86_64-linux-gnu/lib*.so* "$root/lib/"

# glibc's libraries stay the machine's: they must match its kernel and its GPU driver.
is_glibc() {
  case "$(basename "$1")" in
    libc.so.*|libm.so.*|libdl.so.*|libpthread.so.*|librt.so.*|libresolv.so.*|libutil.so.*|ld-linux*|linux-vdso*) return 0 ;;
  esac
  return 1
}

install -m 755 "$heartsim" "$heartprep" "$h5dump" "$root/bin/"
strip --strip-unneeded "$root/bin/heartsim" "$root/bin/heartprep" 2>/dev/null || true

# Every library the programs and the GL loader need, to a fixed point.
changed=1
while [ "$changed" = 1 ]; do
  changed=0
  for object in "$root"/bin/* "$root"/lib/*.so*; do
    [ -L "$object" ] && continue
    while read -r path; do
      [ -n "$path" ] || continue
      is_glibc "$path" && continue
      name="$(basename "$path")"
      if [ ! -e "$root/lib/$name" ]; then
        cp -L "$path" "$root/lib/$name"
        changed=1
      fi
    done < <(LD_LIBRARY_PATH="$root/lib" ldd "$object" 2>/dev/null | awk '$2 == "=>" && $3 ~ /^\// {print $3}')
  done
done
missing="$(for object in "$root"/bin/* "$root"/lib/*.so*; do LD_LIBRARY_PATH="$root/lib" ldd "$object" 2>/dev/null | grep "not found" || true; done | sort -u)"
[ -z "$missing" ] || { echo "make-bundle: libraries not found:" >&2; echo "$missing" >&2; exit 1; }

cp "$repo/tests/bench/gpu/gpu_bench.sh" "$repo/tests/bench/gpu/gpu_bench.py" "$repo/tests/bench/gpu/gpu_surgery.py" "$repo/tests/bench/runtime_bench.py" \
   "$repo/tests/bench/bench_common.py" "$repo/scripts/check-closure.py" "$root/bench/"
chmod 755 "$root/bench/gpu_bench.sh"
{
  echo "heartsim GPU bundle: $(cd "$repo" && git describe --always --dirty 2>/dev/null || echo unknown)"
  "$heartsim" --version 2>/dev/null | head -1 || true
  echo "built on $(. /etc/os-release && echo "$PRETTY_NAME"), $(ldd --version | head -1)"
  echo "run: tar -xzf heartsim-gpu.tar.gz -C /tmp && /tmp/heartsim-gpu/bench/gpu_bench.sh"
} >"$root/VERSION"

mkdir -p "$(dirname "$out")"
tar -C "$work" -czf "$out.part" heartsim-gpu
mv "$out.part" "$out"
size=$(stat -c %s "$out")
limit=$((64 * 1024 * 1024))
if [ "$size" -gt "$limit" ]; then
  echo "make-bundle: $out is $((size / 1048576)) MiB, over the 64 MiB a GPU machine takes" >&2
  exit 1
fi
echo "wrote $out: $((size / 1048576)).$(( (size % 1048576) * 10 / 1048576 )) MiB, $(ls "$root/lib" | wc -l) libraries (glibc's excepted)"
