#!/usr/bin/env bash
# The felt force against Hertz and against a finite-element reference (docs/benchmarks.md "Felt
# force against Hertz"): tests/bench/fe_indentation.py computes the sphere pressed into the block
# with CalculiX (axisymmetric neo-Hookean, large deformations) for nu = 0.25 (the lattice's) and
# nu = 0.49 (nearly incompressible tissue), then hertz_bench presses the lattice at the default
# spacing (1.935 mm for the 60 mm block) and prints its table with the FE force for both and the
# measured force's error against each.
# Usage: tests/bench/run_hertz_bench.sh [BUILD_DIR]   (default build/release)
# Environment: REFINE (fe_indentation.py's --refine, default 1), OUT (the CSV and tables, default
#   BUILD_DIR/hertz-bench), HERTZ_ARGS (more hertz_bench options, e.g. "--spacings 3,default").
# Needs CalculiX's ccx (scripts/install-deps.sh --bench).
set -euo pipefail
cd "$(dirname "$0")/../.."
build="${1:-build/release}"
out="${OUT:-$build/hertz-bench}"
refine="${REFINE:-1}"
if ! command -v ccx >/dev/null; then
  echo "run_hertz_bench: CalculiX's ccx is not on the PATH: install it with scripts/install-deps.sh --bench" >&2
  exit 1
fi
cmake --build "$build" --target hertz_bench >/dev/null
mkdir -p "$out"
python3 tests/bench/fe_indentation.py --nu 0.25,0.49 --refine "$refine" --csv "$out/fe_indentation.csv" \
  --workdir "$out/calculix"
# shellcheck disable=SC2086  # HERTZ_ARGS is a list of options
"$build/tests/bench/hertz_bench" --spacings default --reference "$out/fe_indentation.csv" ${HERTZ_ARGS:-} |
  tee "$out/hertz_bench.md"
