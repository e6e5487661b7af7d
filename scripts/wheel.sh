#!/usr/bin/env bash
# Builds the Python wheel that carries the `paddock` binary: the client package
# (client-py) and the release binary as the wheel's script, which pip installs into the
# environment's bin/, so `pip install paddock-*.whl` is all a Python user needs for
# `endpoint=None`. The binary is the release build (reused when already built), with its
# debug info stripped.
#
#   scripts/wheel.sh [OUT_DIR]     # default dist/; prints the wheel's path
#
# PADDOCK_BIN: package this binary instead of building one.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-dist}"
if [ -z "${PADDOCK_BIN:-}" ]; then
    source scripts/setup.sh
    echo "wheel.sh: building paddock (release)..." >&2
    cargo build --release --locked -q -p paddock
    PADDOCK_BIN="$CARGO_TARGET_DIR/release/paddock"
fi
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
if command -v strip >/dev/null 2>&1; then
    strip --strip-debug -o "$stage/paddock" "$PADDOCK_BIN"
else
    cp "$PADDOCK_BIN" "$stage/paddock"
fi
"${PYTHON:-python3}" scripts/build_wheel.py --binary "$stage/paddock" --out "$out"
