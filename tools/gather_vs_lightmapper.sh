#!/usr/bin/env bash
# Side by side on this machine's software rasterisers, in one run: Radiant's GPU hemicube gather
# (`radiant bake --method gpu-hemicube`, Vulkan on lavapipe) against lightmapper.h (OpenGL on
# llvmpipe, through tools/lightmapper_cornell.sh), both baking the builtin Cornell box, each
# configuration run RUNS times in turn (A B C ... A B C ...), whole-process wall time and the
# mean per-surface error against the Mitsuba reference (metrics::compare_surfaces, and its copy
# in tools/surface_error.py).
#
# Usage: tools/gather_vs_lightmapper.sh HEADER_DIR [RUNS]
#   HEADER_DIR holds lightmapper.h (git clone https://github.com/ands/lightmapper; not part of
#   this repository). Radiant's binary is target/release/radiant (cargo build --release).
# Prints one line per run, then each configuration's median time and its error.
set -euo pipefail
if [ $# -lt 1 ] || [ ! -f "$1/lightmapper.h" ]; then
    echo "usage: $0 HEADER_DIR [RUNS]   (HEADER_DIR must contain lightmapper.h)" >&2
    exit 2
fi
header_dir=$1
runs=${2:-3}
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/.." && pwd)
radiant=$root/target/release/radiant
if [ ! -x "$radiant" ]; then
    echo "$radiant is missing: run cargo build --release first" >&2
    exit 2
fi
work=$(mktemp -d /tmp/gather_vs_lightmapper.XXXXXX)
trap 'rm -rf "$work"' EXIT

# name|command (run in $root; prints nothing we need: the error is read afterwards)
configs=(
    "radiant gpu-hemicube (defaults: 16², ~10k texels)|$radiant bake --builtin cornell-box --method gpu-hemicube --out $work/r1"
    "radiant gpu-hemicube (16², 50 texels/m)|$radiant bake --builtin cornell-box --method gpu-hemicube --texel-density 50 --out $work/r2"
    "lightmapper.h (defaults: 64², 5 080 texels, 12 bounces)|env OUT=$work/l1 $here/lightmapper_cornell.sh $header_dir"
    "lightmapper.h (32², 5 080 texels, 12 bounces)|env OUT=$work/l2 $here/lightmapper_cornell.sh $header_dir --hemisphere 32"
)

error_of() {
    case $1 in
    0) python3 -c "import json,sys; print('%.3f' % (100 * json.load(open('$work/r1/report.json'))['error_vs_reference']['mean_rel']))" ;;
    1) python3 -c "import json,sys; print('%.3f' % (100 * json.load(open('$work/r2/report.json'))['error_vs_reference']['mean_rel']))" ;;
    2) python3 "$here/surface_error.py" "$work/l1/surfaces.csv" | sed -n 's/.*mean_rel \([0-9.]*\) %.*/\1/p' ;;
    3) python3 "$here/surface_error.py" "$work/l2/surfaces.csv" | sed -n 's/.*mean_rel \([0-9.]*\) %.*/\1/p' ;;
    esac
}

declare -A times
for ((r = 1; r <= runs; r++)); do
    for i in "${!configs[@]}"; do
        name=${configs[$i]%%|*}
        cmd=${configs[$i]#*|}
        start=$(date +%s.%N)
        (cd "$root" && $cmd >"$work/log_$i" 2>&1) || {
            echo "failed: $name (log below)" >&2
            cat "$work/log_$i" >&2
            exit 1
        }
        end=$(date +%s.%N)
        t=$(awk "BEGIN{printf \"%.2f\", $end - $start}")
        times[$i]="${times[$i]:-} $t"
        echo "run $r  $(printf '%-58s' "$name") $t s  $(error_of "$i") % mean from Mitsuba"
    done
done
echo
echo "median of $runs runs:"
for i in "${!configs[@]}"; do
    name=${configs[$i]%%|*}
    median=$(echo "${times[$i]}" | tr ' ' '\n' | sed '/^$/d' | sort -g | awk '{a[NR]=$1} END{print (NR%2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}')
    echo "  $(printf '%-58s' "$name") $median s  $(error_of "$i") %"
done
