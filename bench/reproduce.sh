#!/usr/bin/env bash
# Regenerates docs/reproduction/: the paper's studies (Figs. 3-5) on shared parts, paper sensor,
# r̄ = 0.18 mm, 500 candidates. Usage: bench/reproduce.sh [OUT_DIR] (default docs/reproduction)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-docs/reproduction}
M=../shared/meshes
VPP=${VPP:-.venv/bin/vpp}
[ -d "$M" ] || { echo "reproduce: $M not found (the shared meshes)"; exit 2; }
COMMON=(--profile paper --candidates 500 --resolution 0.18 --time-limit 30 -q)
run() {  # name file units
  local name=$1 file=$2 units=$3
  mkdir -p "$OUT/$name"
  echo "== $name: resolution sweep"
  /usr/bin/time -f "$name sweep: %e s wall, %M KiB peak" \
    "$VPP" study resolution "$M/$file" --units "$units" "${COMMON[@]}" --plots "$OUT/$name/sweep"
  echo "== $name: decimation study"
  /usr/bin/time -f "$name decimation: %e s wall, %M KiB peak" \
    "$VPP" study decimation "$M/$file" --units "$units" "${COMMON[@]}" --plots "$OUT/$name/decimation"
}
run hirth hirth_sample_small.stl mm
run gears gears_planetary.stl mm
run featuretype featuretype.STL in
run turbineblade turbineblade.ply mm
# Fig. 4: the simulated point cloud of a plan, both formulations (PLY not kept: 100s of MB)
for f in density visibility; do
  /usr/bin/time -f "gears point cloud $f: %e s wall, %M KiB peak" \
    "$VPP" plan "$M/gears_planetary.stl" "${COMMON[@]}" --formulation "$f" \
    --point-cloud "/tmp/gears-$f.ply" --plots "$OUT/gears/plan-$f"
done
