#!/usr/bin/env bash
# The main job: builds Paddock and runs it on the default map, embedded (no broker).
# Extra arguments go to the command, e.g. `scripts/main.sh --map quarry`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/paddock/target}"
cargo build --release --locked -p paddock
exec "$CARGO_TARGET_DIR/release/paddock" demo "$@"
