#!/usr/bin/env bash
# Coverage-guided fuzzing of Radiant's inputs with libFuzzer, on stable Rust.
#
#   tools/fuzz.sh build                  build the targets (instrumented; fuzz/target/)
#   tools/fuzz.sh run TARGET SECONDS     fuzz one target; its corpus grows in fuzz/corpus/TARGET
#   tools/fuzz.sh smoke [SECONDS]        each target SECONDS (default 10) from its seeds alone,
#                                        as CI runs it; fails on any finding
#   tools/fuzz.sh replay TARGET FILE...  run the target once on each file (a crash's reproducer)
#
# Targets: gltf texture sky csv checkpoint (fuzz/fuzz_targets/). cargo-fuzz needs nightly for
# its sanitizer flags; libFuzzer's coverage needs only rustc's stable `-C passes=sancov-module`
# and LLVM's sanitizer-coverage options, which is all this script adds (no AddressSanitizer:
# safe Rust's findings are panics, hangs, overflows and runaway allocations, which libFuzzer
# reports without it). Each run stops on a panic, an input that takes over 10 s, more than
# 2 GiB resident or one allocation over 2 GiB, and saves the input in fuzz/artifacts/TARGET/.
# Seeds: fuzz/seeds/TARGET (tools/make_fuzz_seeds.py), fuzz/regressions/TARGET (what once
# failed), and tests/bad_inputs for glTF.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGETS=(gltf texture sky csv checkpoint)
TRIPLE=$(rustc -vV | sed -n 's/^host: //p')
BIN=fuzz/target/$TRIPLE/release

build() {
  echo "== building the fuzz targets (instrumented, fuzz/target)" >&2
  # --target keeps the instrumentation off build scripts and proc macros.
  RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing" \
    cargo build --manifest-path fuzz/Cargo.toml --release --locked --target "$TRIPLE" --bins
}

# The seed directories of a target: its seeds, every input that once failed it (kept
# verbatim in fuzz/regressions/TARGET, each with its fix and a corpus test), and for glTF the
# bad-input corpus.
seeds() {
  local t=$1
  echo "fuzz/seeds/$t"
  [ -d "fuzz/regressions/$t" ] && echo "fuzz/regressions/$t"
  [ "$t" = gltf ] && echo tests/bad_inputs
  return 0
}

# fuzz TARGET SECONDS CORPUS: libFuzzer from CORPUS (written) and the seeds (read only).
fuzz() {
  local t=$1 secs=$2 corpus=$3
  mkdir -p "$corpus" "fuzz/artifacts/$t"
  # An address-space ceiling above libFuzzer's own limits: the process is stopped before the
  # machine is, whatever the target allocates.
  (
    ulimit -v $((6 * 1024 * 1024))
    "$BIN/$t" "$corpus" $(seeds "$t") \
      -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=2048 \
      -max_len=65536 -print_final_stats=1 -artifact_prefix="fuzz/artifacts/$t/" \
      $([ -f "fuzz/dicts/$t.dict" ] && echo "-dict=fuzz/dicts/$t.dict") ${FUZZ_ARGS:-}
  )
}

case "${1:-}" in
  build) build ;;
  run)
    [ $# -ge 3 ] || { echo "usage: tools/fuzz.sh run TARGET SECONDS" >&2; exit 2; }
    [ -x "$BIN/$2" ] || build
    fuzz "$2" "$3" "fuzz/corpus/$2"
    ;;
  smoke)
    secs=${2:-10}
    build
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    for t in "${TARGETS[@]}"; do
      echo "== fuzz smoke: $t for $secs s" >&2
      log="$tmp/$t.log"
      if ! fuzz "$t" "$secs" "$tmp/$t" >"$log" 2>&1; then
        tail -40 "$log" >&2
        echo "fuzz target $t found a failure; the input is in fuzz/artifacts/$t/" >&2
        exit 1
      fi
      grep -E '^stat::number_of_executed_units|^Done ' "$log" >&2 || true
    done
    ;;
  replay)
    [ $# -ge 3 ] || { echo "usage: tools/fuzz.sh replay TARGET FILE..." >&2; exit 2; }
    t=$2
    shift 2
    [ -x "$BIN/$t" ] || build
    "$BIN/$t" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=2048 "$@"
    ;;
  *)
    sed -n '2,/^set -euo/p' "$0" | grep '^#' | sed 's/^# \{0,1\}//'
    exit 2
    ;;
esac
