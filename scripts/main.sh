#!/usr/bin/env bash
# The main job: builds Paddock, then tunes the pure-pursuit driver with CMA-ES on the
# default map, embedded (no broker); results and plots go to tune-out/.
# Extra arguments go to the command, e.g. `scripts/main.sh --map quarry`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
echo "building paddock (release; the first build takes a few minutes)..." >&2
cargo build --release --locked -q -p paddock
exec "$CARGO_TARGET_DIR/release/paddock" tune "$@"
