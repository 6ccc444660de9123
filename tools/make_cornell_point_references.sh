#!/usr/bin/env bash
# Regenerates the point references of the builtin Cornell box in assets/reference/:
# Mitsuba 3 radiance meters 1 mm off 24 surface points (quad centres and five probes),
# 2^20 samples each, with the bitterli RGB materials (scalar_rgb) and with the measured
# spectra (scalar_spectral). Needs `pip install mitsuba numpy` (the scalar variants need no
# LLVM) and the shared references (default ../shared/refs). About 15 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
refs="${1:-../shared/refs}"
work="$(mktemp -d)"
mkdir -p "$work/mitsuba/out" "$work/cornell"
cp "$refs/mitsuba/cornell_mitsuba.py" "$work/mitsuba/"
cp "$refs/cornell/cornell_box_scene.json" "$work/cornell/"
spp=1048576
python3 "$work/mitsuba/cornell_mitsuba.py" points --variant scalar_rgb --materials bitterli --spp "$spp"
python3 "$work/mitsuba/cornell_mitsuba.py" points --variant scalar_spectral --materials spectral --spp "$spp"
cp "$work/mitsuba/out/point_radiance_bitterli_scalar_rgb_${spp}spp.csv" assets/reference/cornell_points_rgb_mitsuba.csv
cp "$work/mitsuba/out/point_radiance_spectral_scalar_spectral_${spp}spp.csv" assets/reference/cornell_points_spectral_mitsuba.csv
rm -rf "$work"
echo "wrote assets/reference/cornell_points_{rgb,spectral}_mitsuba.csv"
