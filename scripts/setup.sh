#!/usr/bin/env bash
# Prepares a fresh Debian/Ubuntu machine for building and testing twill: checks the Rust
# toolchain (1.95 or newer, with rustfmt and clippy) and installs the system packages the build
# and the tests need when they are missing. Safe to run again; does nothing when all is present.
set -euo pipefail

# mesa-vulkan-drivers + libvulkan1: lavapipe (software Vulkan) for the GPU tests on machines
# without a GPU. The viewer's window (winit on X11) loads libX11, libXcursor, libXrandr, libXi
# and libxkbcommon-x11 at run time; xvfb (with xauth, which xvfb-run needs and xvfb only
# recommends) gives its test (tests/viewer_window.rs) a display. g++: libfuzzer-sys compiles
# libFuzzer (C++) for the fuzz targets (scripts/fuzz.sh). slurm-wlm + munge: the sharded-bake
# test (tests/slurm_bake.rs) starts a single-node Slurm cluster on this machine. libembree-dev:
# Embree 3, the ray caster ours is measured against (feature `embree`).
need_packages=(pkg-config mesa-vulkan-drivers libvulkan1 xvfb xauth libx11-6 libxcursor1 libxrandr2 libxi6
  libxkbcommon-x11-0 g++ slurm-wlm munge libembree-dev)

missing=()
for pkg in "${need_packages[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  sudo_cmd=""
  [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  [ -x "$HOME/.cargo/bin/cargo" ] && export PATH="$HOME/.cargo/bin:$PATH"
fi
if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found. Install Rust 1.95 or newer (https://rustup.rs), then run this again." >&2
  exit 1
fi
version=$(rustc --version | awk '{print $2}')
if [ "$(printf '%s\n1.95.0\n' "$version" | sort -V | head -1)" != "1.95.0" ]; then
  echo "setup: rustc $version is too old; twill needs 1.95 or newer (rustup update)." >&2
  exit 1
fi
if command -v rustup >/dev/null 2>&1; then
  rustup component list --installed 2>/dev/null | grep -q '^rustfmt' || rustup component add rustfmt
  rustup component list --installed 2>/dev/null | grep -q '^clippy' || rustup component add clippy
fi
