#!/usr/bin/env bash
# Peer benchmark: lightmapper.h (https://github.com/ands/lightmapper, not part of this repo)
# bakes the builtin Cornell box on Mesa's software OpenGL (llvmpipe, headless EGL), and its
# per-surface means are compared with the Mitsuba reference as Radiant's
# metrics::compare_surfaces does.
#
# Usage: tools/lightmapper_cornell.sh HEADER_DIR [driver args...]
#   HEADER_DIR: a directory holding lightmapper.h (e.g. a clone of ands/lightmapper).
#   driver args: see tools/lightmapper_cornell.c (--density, --texels, --bounces,
#   --hemisphere, --interpolation-passes, --interpolation-threshold, --no-interpolation, ...).
# Builds into $OUT (default /tmp/lightmapper_cornell); writes surfaces.csv there; prints the
# driver's log (stderr) and the error table.
set -euo pipefail
if [ $# -lt 1 ] || [ ! -f "$1/lightmapper.h" ]; then
    echo "usage: $0 HEADER_DIR [args]   (HEADER_DIR must contain lightmapper.h)" >&2
    exit 2
fi
header_dir=$(cd "$1" && pwd)
shift
here=$(cd "$(dirname "$0")" && pwd)
out=${OUT:-/tmp/lightmapper_cornell}
mkdir -p "$out"
# Asserts stay on (no -DNDEBUG): lightmapper.h checks its storage bounds with assert.
gcc -O2 -std=gnu11 -w -I "$header_dir" -o "$out/lightmapper_cornell" \
    "$here/lightmapper_cornell.c" -lEGL -lOpenGL -lm
if [ -d "$header_dir/.git" ]; then
    echo "lightmapper.h: $(git -C "$header_dir" rev-parse HEAD 2>/dev/null || echo '?')" >&2
fi
echo "lightmapper.h sha256: $(sha256sum "$header_dir/lightmapper.h" | cut -d' ' -f1)" >&2
export LIBGL_ALWAYS_SOFTWARE=1 GALLIUM_DRIVER=llvmpipe
start=$(date +%s.%N)
"$out/lightmapper_cornell" "$@" > "$out/surfaces.csv"
end=$(date +%s.%N)
echo "process wall time: $(awk "BEGIN{printf \"%.2f\", $end - $start}") s" >&2
python3 "$here/surface_error.py" "$out/surfaces.csv"
