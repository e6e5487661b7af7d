#!/usr/bin/env bash
# Builds the Python wheel that carries the `paddock` binary: the client package
# (client-py) and the release binary as the wheel's script, which pip installs into the
# environment's bin/, so `pip install paddock-*.whl` is all a Python user needs for
# `endpoint=None`. The binary is the release build (reused when already built), with its
# debug info stripped.
#
#   scripts/wheel.sh [OUT_DIR]     # default dist/; prints the wheel's path
#
# The wheel also carries the in-process simulator (the paddock-embed library, for
# `endpoint=paddock.IN_PROCESS`), built the same way.
#
# PADDOCK_BIN: package this binary instead of building one; PADDOCK_EMBED_LIB: this
# library (default: the libpaddock_embed.so beside PADDOCK_BIN).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-dist}"
if [ -z "${PADDOCK_BIN:-}" ]; then
    source scripts/setup.sh
    echo "wheel.sh: building paddock and paddock-embed (release)..." >&2
    cargo build --release --locked -q -p paddock -p paddock-embed
    PADDOCK_BIN="$CARGO_TARGET_DIR/release/paddock"
fi
embed="${PADDOCK_EMBED_LIB:-$(dirname "$PADDOCK_BIN")/libpaddock_embed.so}"
if [ ! -f "$embed" ]; then
    echo "wheel.sh: no $embed: build it with cargo build --release -p paddock-embed" >&2
    exit 1
fi
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
if command -v strip >/dev/null 2>&1; then
    strip --strip-debug -o "$stage/paddock" "$PADDOCK_BIN"
    strip --strip-debug -o "$stage/libpaddock_embed.so" "$embed"
else
    cp "$PADDOCK_BIN" "$stage/paddock"
    cp "$embed" "$stage/libpaddock_embed.so"
fi
"${PYTHON:-python3}" scripts/build_wheel.py --binary "$stage/paddock" \
    --embed "$stage/libpaddock_embed.so" --out "$out"
