#!/usr/bin/env bash
# A real engine renders Radiant's export (issue 53): bakes the Cornell box (or SCENE.glb's
# source) with `radiant bake --export`, builds the Bevy client in examples/bevy_client (its own
# workspace, outside CI: the first build takes 15-20 minutes on 2 cores), captures its frame
# headless on lavapipe, and compares it with `radiant render`'s frame from the same camera
# (`--reference-image`: radiance, no SSAO, no bloom, 4x4 supersampled; surfaces with the
# emitter's pixels left out).
#
#   bash tools/bevy_client.sh [OUT_DIR] [SIZE]     # defaults: target/bevy_client, 128x128
#
# Needs: Vulkan (apt-get install mesa-vulkan-drivers libvulkan1 gives lavapipe).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/bevy_client}
size=${2:-128x128}
mkdir -p "$out"
out=$(cd "$out" && pwd)
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}

t0=$(date +%s)
echo "== building radiant (release)"
cargo build --release --bin radiant
echo "== building the Bevy client (examples/bevy_client)"
t1=$(date +%s)
cargo build --manifest-path examples/bevy_client/Cargo.toml  # dev: Bevy itself at opt-level 2 (its Cargo.toml)
t2=$(date +%s)
echo "   Bevy client built in $((t2 - t1)) s"

echo "== baking and exporting the Cornell box"
./target/release/radiant bake --builtin cornell-box --out "$out/bake" --export "$out/cornell.glb" \
    | tail -n 2

echo "== Bevy renders the export (headless, $size)"
t3=$(date +%s)
examples/bevy_client/target/debug/radiant_bevy_client "$out/cornell.glb" "$out/bevy.exr" \
    --size "$size" --supersample 4
t4=$(date +%s)
echo "   Bevy frame in $((t4 - t3)) s"

echo "== radiant render's frame against Bevy's"
./target/release/radiant render --builtin cornell-box --out "$out/render" \
    --reference-image "$out/bevy.exr" | grep -E "whole image|surfaces" || true
python3 - "$out/render/render.json" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))["path_traced_reference"]
s = r["surfaces"]
print(f"Bevy vs radiant render, surfaces: {100*s['rel_l1_4x4']:.2f} % over 4x4 blocks, "
      f"{100*s['rel_l1']:.2f} % per pixel, bias {100*s['mean_bias']:+.2f} %")
EOF
echo "total $(( $(date +%s) - t0 )) s"
