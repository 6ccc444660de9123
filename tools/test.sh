#!/usr/bin/env bash
# Radiant's whole test suite, as CI runs it: formatting, lints, the API docs' links, every test.
#
# Needs: the Rust toolchain pinned in rust-toolchain.toml (1.95.0, with rustfmt and clippy), a C
# and C++ compiler for build scripts and libFuzzer, a Vulkan driver for the GPU tests: with no GPU, Mesa's
# software rasteriser lavapipe (Debian: mesa-vulkan-drivers), Mesa's GL drivers for the GL
# backend test (libegl-mesa0 libgl1-mesa-dri), and Xvfb and xwd for the window
# test (Debian: xvfb x11-apps). As root with apt, this script
# installs what is missing; otherwise it says what to install. Builds once, in the dev profile
# (dependencies optimised, see Cargo.toml), and reuses that build for all tests.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '\n== %s\n' "$*"; }

if ! command -v cargo >/dev/null 2>&1; then
  echo "cargo not found: install Rust with rustup (https://rustup.rs), then run this again." >&2
  exit 1
fi
# A C++ compiler too: the fuzz smoke builds libFuzzer (libfuzzer-sys).
if ! command -v cc >/dev/null 2>&1 || ! command -v c++ >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "installing C and C++ compilers (build-essential)"
    apt-get update -qq && apt-get install -y -qq --no-install-recommends build-essential
  else
    echo "no C or C++ compiler: run 'sudo apt-get install build-essential', then this again." >&2
    exit 1
  fi
fi

have_vulkan() {
  { compgen -G '/usr/share/vulkan/icd.d/*.json' >/dev/null ||
    compgen -G '/etc/vulkan/icd.d/*.json' >/dev/null; } &&
    # No `grep -q`: it would close the pipe early, and pipefail would count that as failure.
    { ldconfig -p 2>/dev/null | grep 'libvulkan\.so\.1' >/dev/null; }
}
if ! have_vulkan; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "installing Mesa's software Vulkan driver (lavapipe) for the GPU tests"
    apt-get update -qq && apt-get install -y -qq --no-install-recommends mesa-vulkan-drivers libvulkan1
  else
    echo "the GPU tests need a Vulkan driver. With no GPU, install Mesa's lavapipe:" >&2
    echo "  sudo apt-get install mesa-vulkan-drivers libvulkan1" >&2
    exit 1
  fi
fi
# The GL backend test renders through Mesa's llvmpipe GL (EGL, surfaceless), as a machine
# without a Vulkan driver would.
have_gl() {
  { ldconfig -p 2>/dev/null | grep 'libEGL_mesa\.so\.0' >/dev/null; } &&
    compgen -G '/usr/lib/*/dri/swrast_dri.so' >/dev/null
}
if ! have_gl; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "installing Mesa's GL drivers (llvmpipe through EGL) for the GL backend test"
    apt-get update -qq && apt-get install -y -qq --no-install-recommends libegl1 libegl-mesa0 libgl1-mesa-dri
  else
    echo "the GL backend test needs Mesa's GL drivers. Install them with:" >&2
    echo "  sudo apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri" >&2
    exit 1
  fi
fi
# The window test runs the viewer under its own Xvfb and screenshots it with xwd; winit loads
# the X11 client libraries at run time.
have_x11_tools() {
  command -v Xvfb >/dev/null 2>&1 && command -v xwd >/dev/null 2>&1 &&
    { ldconfig -p 2>/dev/null | grep 'libxkbcommon-x11\.so\.0' >/dev/null; } &&
    { ldconfig -p 2>/dev/null | grep 'libXcursor\.so\.1' >/dev/null; }
}
if ! have_x11_tools; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    say "installing Xvfb and xwd for the window test"
    apt-get update -qq && apt-get install -y -qq --no-install-recommends \
      xvfb x11-apps libxkbcommon-x11-0 libxcursor1 libxi6 libxrandr2
  else
    echo "the window test needs Xvfb and xwd. Install them with:" >&2
    echo "  sudo apt-get install xvfb x11-apps libxkbcommon-x11-0 libxcursor1 libxi6 libxrandr2" >&2
    exit 1
  fi
fi
# Vulkan, not the GL fallback; Mesa wants a private runtime directory.
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ]; then
  XDG_RUNTIME_DIR="$(mktemp -d)"
  chmod 700 "$XDG_RUNTIME_DIR"
  export XDG_RUNTIME_DIR
fi
# Debian 12's validation layers predate the SPIR-V wgpu 30 writes and report false errors.
if dpkg -s vulkan-validationlayers >/dev/null 2>&1; then
  export WGPU_VALIDATION="${WGPU_VALIDATION:-0}"
fi

# The Khronos glTF validator for the export test (npm); without npm the test says it did not
# validate.
if command -v npm >/dev/null 2>&1 && [ ! -d target/gltf-validator/node_modules/gltf-validator ]; then
  say "installing the Khronos glTF validator (npm gltf-validator) into target/gltf-validator"
  npm install --silent --prefix target/gltf-validator gltf-validator@2.0.0-dev.3.10 ||
    echo "npm could not install gltf-validator: the export test will say it did not validate" >&2
fi

say "cargo fmt --check"
cargo fmt --all --check
cargo fmt --manifest-path fuzz/Cargo.toml --check

say "cargo clippy (all targets, warnings are errors)"
cargo clippy --workspace --all-targets --locked -- -D warnings

say "cargo doc (broken or private links are errors)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked

say "cargo test (workspace)"
cargo test --workspace --locked --no-fail-fast

# libFuzzer on stable Rust, its own instrumented build in fuzz/target: a regression in an
# importer is caught here, long runs are tools/fuzz.sh's `run`.
say "fuzz smoke: each input's target for 10 s from its seeds (tools/fuzz.sh)"
bash tools/fuzz.sh smoke 10
