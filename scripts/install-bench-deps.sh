#!/usr/bin/env bash
# Installs what tests/bench/ needs beyond the build (Debian 12). Idempotent, run as root.
#   python3-vtk9   the peer pipeline (3D Slicer's: discrete flying edges + windowed-sinc) and
#                  the PLY / NIfTI readers and distance filters used for the accuracy figures
#   python3-numpy  vertex arithmetic on the meshes
#   time           GNU /usr/bin/time, whose -f %M gives the peak resident set size of a run
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# The benchmark runs the release heartprep, so the build dependencies come first.
bash "$here/install-deps.sh"

packages=(python3 python3-vtk9 python3-numpy time)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-bench-deps: all ${#packages[@]} packages present"
  exit 0
fi

if [ "$(id -u)" -ne 0 ]; then
  echo "install-bench-deps: missing packages: ${missing[*]}; run this script as root" >&2
  exit 1
fi

echo "install-bench-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}"
