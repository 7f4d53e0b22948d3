#!/usr/bin/env bash
# RUSTC_WRAPPER for scripts/fuzz.sh: adds libFuzzer's instrumentation (TWILL_FUZZ_RUSTFLAGS) to
# the twill crates and the fuzz targets (fuzz/fuzz_targets/*.rs) only; every other crate is
# compiled as cargo asks.
set -euo pipefail
rustc=$1
shift
instrument=false
prev=""
for arg in "$@"; do
  if [ "$prev" = "--crate-name" ]; then
    case "$arg" in twill_precompute | twill_renderer) instrument=true ;; esac
  fi
  case "$arg" in fuzz_targets/*.rs | */fuzz/fuzz_targets/*.rs) instrument=true ;; esac
  prev=$arg
done
if $instrument; then
  # shellcheck disable=SC2086 # the flags are separate words
  exec "$rustc" "$@" $TWILL_FUZZ_RUSTFLAGS
fi
exec "$rustc" "$@"
