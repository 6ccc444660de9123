#!/usr/bin/env bash
# Radiant's whole test suite, as CI runs it: formatting, lints, every test.
#
# Everything here runs on the CPU. Needs: the Rust toolchain pinned in rust-toolchain.toml
# (1.95.0, with rustfmt and clippy) and a C compiler for build scripts. Builds once, in the dev
# profile (dependencies optimised, see Cargo.toml), and reuses that build for all tests.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '\n== %s\n' "$*"; }

if ! command -v cargo >/dev/null 2>&1; then
  echo "cargo not found: install Rust with rustup (https://rustup.rs), then run this again." >&2
  exit 1
fi
if ! command -v cc >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "installing a C compiler (build-essential)"
    apt-get update -qq && apt-get install -y -qq --no-install-recommends build-essential
  else
    echo "no C compiler: run 'sudo apt-get install build-essential', then this again." >&2
    exit 1
  fi
fi

say "cargo fmt --check"
cargo fmt --all --check

say "cargo clippy (all targets, warnings are errors)"
cargo clippy --workspace --all-targets --locked -- -D warnings

say "cargo test (workspace)"
cargo test --workspace --locked --no-fail-fast
