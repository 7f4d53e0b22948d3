#!/usr/bin/env bash
# Runs every check and test of twill: formatting, clippy (pedantic, warnings are errors), and
# the whole workspace's tests (unit, integration and workspace-level tests in tests/).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$HOME/.cargo/bin:$PATH"

echo "== cargo fmt --check"
cargo fmt --all --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --locked
