#!/usr/bin/env bash
# Installs the Debian 12 packages heartsim needs. Idempotent: packages already present are not
# reinstalled. Run as root.
#   scripts/install-deps.sh           build and test
#   scripts/install-deps.sh --bench   also the benchmarks' peers and tools (tests/bench/)
set -euo pipefail

packages=(
  # toolchain
  build-essential cmake ninja-build pkg-config git
  # geometry and volumes
  libcgal-dev libeigen3-dev libtbb-dev libinsighttoolkit5-dev libgdcm-tools zlib1g-dev
  # files and command line
  libassimp-dev libhdf5-dev hdf5-tools libcli11-dev libssl-dev nlohmann-json3-dev
  # OpenGL through EGL/epoxy, window through GLFW; Mesa for headless llvmpipe (the runtime);
  # libpng for screenshots
  libepoxy-dev libegl-dev libgl-dev libglfw3-dev libegl-mesa0 libgl1-mesa-dri libpng-dev
  # the window's HUD and help (Dear ImGui with its GLFW and OpenGL3 backends)
  libimgui-dev
  # the live link to 3D Slicer (heartsim run --igtl; optional at build time: without it --igtl is refused)
  libopenigtlink-dev
  # tests
  googletest libgtest-dev
  # CalculiX: the felt force's finite-element reference (tests/bench/fe_indentation.py), which
  # tests/test_fe_indentation.cpp checks against Hertz and tests/bench/run_hertz_bench.sh uses
  calculix-ccx
  # the sanitizer job (scripts/run-sanitizers.sh): clang with AddressSanitizer, UBSan and
  # libFuzzer's runtime; llvm for llvm-symbolizer (readable stacks in sanitizer reports)
  clang libclang-rt-14-dev llvm
  # window tests (heartsim's GLFW window under a virtual X server, driven by real input events)
  xvfb xauth xdotool
  # the cluster workflow (workflow/Snakefile) and its tests; procps's kill ends a job's process
  # group in the tests' stand-in for Slurm (the shell's own kill cannot)
  snakemake procps
  # ParaView opens our files (tests/test_paraview.cpp runs tests/vtk_open.py under /usr/bin/python3
  # and tests/paraview_open.py under pvpython): VTK's Python module with the XDMF readers, and
  # ParaView itself. python3-vtk9 (VTK 9.1) has no XDMF reader and conflicts with python3-paraview
  # (it is removed), whose VTK (9.2) has them and serves the benchmarks too.
  python3 python3-paraview
)
if [ "${1:-}" = "--bench" ]; then
  packages+=(
    python3-numpy                       # with VTK (python3-paraview, above): the surface peer, flying edges + windowed sinc
    python3-matplotlib                  # the plots of docs/benchmarks.md (tests/bench/plot_benchmarks.py)
    time                                # GNU /usr/bin/time -f %M: peak memory of a run
    libbullet-dev                       # the solver peer: Bullet's btSoftBody
  )
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
  echo "install-deps: missing packages: ${missing[*]}; run this script as root" >&2
  exit 1
fi

echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}"
