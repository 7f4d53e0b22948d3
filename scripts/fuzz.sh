#!/usr/bin/env bash
# Builds twill's fuzz targets (fuzz/, one per file loader) and runs each on a copy of its seed
# corpus: scripts/fuzz.sh [SECONDS] [TARGET...] (default 5 seconds each, every target).
#
# cargo-fuzz is not needed: the targets are built with `cargo build --release` and the flags that
# `cargo fuzz build -s none` uses (libFuzzer's coverage instrumentation, no sanitizer, stable
# Rust). A RUSTC_WRAPPER (scripts/fuzz-rustc.sh) adds those flags only to the twill crates and
# the fuzz crate; dependencies are built normally, which keeps the build short. The build goes to
# target/fuzz. New corpus entries and crash files go to a scratch folder (FUZZ_WORK, default a
# temporary folder that is removed), never into the committed corpus in fuzz/corpus/.
#
# Fails (non-zero exit) when a target crashes, panics, runs out of memory (2 GiB) or
# time (10 s per input); the input is then kept in the scratch folder and named in the output.
# Prints the executions of every target.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$HOME/.cargo/bin:$PATH"

seconds=${1:-5}
shift || true
all_targets=(scene_toml mitsuba hair wif png_pattern bake_file obj gltf)
if (($#)); then targets=("$@"); else targets=("${all_targets[@]}"); fi
for t in "${targets[@]}"; do
  [ -f "fuzz/fuzz_targets/$t.rs" ] || { echo "fuzz.sh: unknown target $t (${all_targets[*]})" >&2; exit 2; }
done
case "$seconds" in '' | *[!0-9]*) echo "fuzz.sh: SECONDS must be a whole number, not $seconds" >&2; exit 2 ;; esac

echo "== building fuzz targets (target/fuzz)"
export TWILL_FUZZ_RUSTFLAGS="--cfg fuzzing -Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares -Cdebug-assertions"
RUSTC_WRAPPER="$PWD/scripts/fuzz-rustc.sh" CARGO_TARGET_DIR="$PWD/target/fuzz" \
  cargo build --release --locked --manifest-path fuzz/Cargo.toml --bins
bin_dir="$PWD/target/fuzz/release"

work=${FUZZ_WORK:-}
if [ -z "$work" ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
failed=()
for t in "${targets[@]}"; do
  corpus="$work/corpus/$t"
  artifacts="$work/artifacts/$t"
  mkdir -p "$corpus" "$artifacts"
  cp -n fuzz/corpus/"$t"/* "$corpus"/ 2>/dev/null || true
  log="$work/$t.log"
  echo "== fuzzing $t for ${seconds} s (corpus: $(find "$corpus" -type f | wc -l) files)"
  # TMPDIR: the glTF target writes its buffer files there.
  mkdir -p "$work/tmp"
  status=0
  TMPDIR="$work/tmp" "$bin_dir/$t" "$corpus" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 \
    -max_len=65536 -artifact_prefix="$artifacts/" -print_final_stats=1 >"$log" 2>&1 || status=$?
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || true)
  echo "   $t: ${runs:-?} executions, corpus now $(find "$corpus" -type f | wc -l) files, exit status $status"
  if ((status != 0)); then
    failed+=("$t")
    tail -n 40 "$log" >&2
    ls "$artifacts"/* >&2 2>/dev/null || true
  fi
done
if ((${#failed[@]})); then
  echo "fuzz.sh: ${failed[*]} failed; inputs kept in $work/artifacts (reproduce: target/fuzz/release/TARGET FILE)" >&2
  trap - EXIT
  exit 1
fi
echo "fuzz.sh: ${#targets[@]} targets ran ${seconds} s each without a finding"
