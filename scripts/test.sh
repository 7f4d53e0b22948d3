#!/usr/bin/env bash
# Runs every check and test of twill: formatting, clippy (pedantic, warnings are errors), and
# the whole workspace's tests (unit, integration and workspace-level tests in tests/). The GPU
# tests run on lavapipe (installed by setup.sh) when the machine has no GPU; they fail rather
# than skip when no Vulkan adapter is found. The viewer's window test runs under Xvfb (xvfb-run,
# also installed by setup.sh) and fails when it is missing. Last, every fuzz target (fuzz/) runs
# for a few seconds on its corpus (scripts/fuzz.sh), so a crash on a known input fails.
set -euo pipefail
cd "$(dirname "$0")/.."
# In CI a skipped GPU or window test would let a broken renderer pass: refuse the skip switch.
if [ -n "${CI:-}" ] && [ -n "${TWILL_ALLOW_NO_GPU:-}" ]; then
  echo "error: TWILL_ALLOW_NO_GPU is set while CI is set; CI runs every GPU and window test" >&2
  exit 2
fi
# Goldens are blessed by hand (scripts/bless-goldens.sh), never by a test run.
if [ -n "${TWILL_BLESS:-}" ]; then
  echo "error: TWILL_BLESS is set; bless goldens with scripts/bless-goldens.sh, not the test command" >&2
  exit 2
fi
bash scripts/setup.sh
export PATH="$HOME/.cargo/bin:$PATH"
# Mesa wants a runtime directory; give it a private one when the session has none.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d)
  export XDG_RUNTIME_DIR
  chmod 700 "$XDG_RUNTIME_DIR"
fi

# Skipped GPU and window tests (only possible with TWILL_ALLOW_NO_GPU=1 outside CI) note
# themselves in this file (twill_renderer::gpu::report_skip); the run ends with them in a banner,
# since the test harness hides a passing test's output.
skip_log="$PWD/target/skipped-tests.txt"
mkdir -p target
rm -f "$skip_log"
export TWILL_SKIP_LOG="$skip_log"
print_skips() {
  if [ -s "$skip_log" ]; then
    echo "=================================================================="
    echo "SKIPPED: $(wc -l <"$skip_log") GPU or window test(s) did not run (TWILL_ALLOW_NO_GPU=1):"
    cat "$skip_log"
    echo "=================================================================="
  fi
}
trap print_skips EXIT

echo "== cargo fmt --check"
cargo fmt --all --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --locked
# Embree, the ray caster ours is measured against (`twill bench raycast --embree`), is an
# optional feature: lint it, and check that it and our caster agree hit for hit.
echo "== Embree comparison (feature embree)"
cargo clippy -p twill-precompute --features embree --all-targets --locked -- -D warnings
cargo test -p twill-precompute --features embree --locked --lib raycast::embree
echo "== fuzz targets (scripts/fuzz.sh, ${TWILL_FUZZ_SECONDS:-5} s each)"
cargo fmt --manifest-path fuzz/Cargo.toml --check
bash scripts/fuzz.sh "${TWILL_FUZZ_SECONDS:-5}"
