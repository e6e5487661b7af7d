#!/usr/bin/env bash
# Runs every check and test of Paddock: formatting, clippy, the Rust test suites
# (unit, conformance against f1tenth_gym, end-to-end across real broker and worker
# processes, CURVE keys, the Docker deployment), then the Python client's tests.
# Installs what it needs first.
#
# The conformance tests read ../shared (the f1tenth_gym reference vectors and the real
# race tracks) beside this checkout; set PADDOCK_SHARED to point elsewhere.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh

export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-never}"

echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
# In the release profile, as the tests below: the C libraries' builds (SQLite, zstd) and
# the proc macros are then built once for both (the lints are the same).
cargo clippy --workspace --all-targets --release --locked -- -D warnings
echo "== cargo test (release: the conformance and simulator tests step millions of times)"
cargo test --workspace --release --locked
echo "== benchmarks compile"
cargo bench --workspace --locked --no-run
echo "== Python client (pytest against a real paddock serve)"
bash scripts/python.sh
