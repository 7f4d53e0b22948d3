#!/usr/bin/env bash
# Re-blesses the golden images (tests/goldens/) from the current code, and shows what changed.
# The only way to bless: the tests honour TWILL_BLESS only outside CI, and this script refuses
# to run in CI. Before overwriting, each golden test saves the previous golden and its
# difference from the new image under target/golden-diffs/ (NAME.previous.png, NAME.diff.png)
# and prints the metric between them; look at them before committing the new goldens.
# Usage: bash scripts/bless-goldens.sh [TEST-NAME-FILTER]
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -n "${CI:-}" ]; then
  echo "error: refusing to bless golden images in CI (CI is set)" >&2
  exit 2
fi
export PATH="$HOME/.cargo/bin:$PATH"
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  XDG_RUNTIME_DIR=$(mktemp -d)
  export XDG_RUNTIME_DIR
  chmod 700 "$XDG_RUNTIME_DIR"
fi
rm -rf target/golden-diffs
# The viewer's golden comes from the `twill` binary beside the tests (tests/lib.rs
# twill_binary), which `cargo test -p twill-tests` does not rebuild: build it first, or a stale
# binary blesses the old picture.
cargo build --locked -p twill-app
TWILL_BLESS=1 cargo test --locked -p twill-tests --test gpu_render --test viewer_window -- --nocapture "${1:-}" 2>&1 \
  | grep -E "golden (written|blessed)|previous golden|^test result|FAILED|panicked" || true
echo
echo "== goldens changed (git):"
git status --short tests/goldens
echo "== previous goldens and differences: target/golden-diffs/"
ls target/golden-diffs 2>/dev/null || echo "(none: no golden existed before)"
