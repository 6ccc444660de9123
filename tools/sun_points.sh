#!/usr/bin/env bash
# The light map against the path tracer at sunlit, shadowed, shadow-edge and contact points of
# a scene lit by a sun (issue: sunlight per texel). Defaults to Crytek Sponza with its sun.
#
#   tools/sun_points.sh [SCENE.gltf] [OUT_DIR] [PER_CLASS] [REFERENCE_SECONDS]
#
# 1. picks PER_CLASS points of each class (examples/sun_points.rs; tools/sponza_sun_points.csv is
#    its output for Sponza, PER_CLASS 16, seed 1);
# 2. path-traces them (`radiant reference --points`, REFERENCE_SECONDS at most, 0.5 % target);
# 3. bakes with `--points` and `--reference-points` under /usr/bin/time -v (time, peak RSS);
# 4. prints the figures per class (tools/points_by_class.py).
# Needs a release build: cargo build --release --examples.
set -euo pipefail
cd "$(dirname "$0")/.."
scene="${1:-../shared/scenes/sponza/Sponza_sun.gltf}"
out="${2:-/tmp/radiant-sun-points}"
per_class="${3:-16}"
seconds="${4:-600}"
mkdir -p "$out"
points="$out/points_in.csv"
if [ "$scene" = "../shared/scenes/sponza/Sponza_sun.gltf" ] && [ "$per_class" = 16 ]; then
  cp tools/sponza_sun_points.csv "$points"
else
  target/release/examples/sun_points "$scene" "$points" "$per_class" 1
fi
if [ ! -f "$out/reference/points.csv" ]; then
  target/release/radiant reference "$scene" --out "$out/reference" --points "$points" \
    --no-surfaces --target-error 0.005 --time-limit "$seconds"
fi
/usr/bin/time -v target/release/radiant bake "$scene" --out "$out/bake" --points "$points" \
  --reference-points "$out/reference/points.csv" 2> "$out/bake.time" | tail -4
grep -E "Elapsed|Maximum resident" "$out/bake.time"
python3 tools/points_by_class.py "$points" "$out/bake/points.csv" "$out/reference/points.csv"
