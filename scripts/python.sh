#!/usr/bin/env bash
# The Python client (client-py): a venv with pinned dependencies, the package installed
# in editable mode, and its tests against a real `paddock serve` that the fixtures start
# on a free loopback port and stop. Then the ROS 2 interop tests (bridge/interop): the
# same binary's `paddock bridge` nodes against Eclipse Cyclone DDS, loopback only, and its
# recordings against third-party bag software (rosbags writes rosbag2 bags, the mcap
# library reads MCAP files).
#
#   scripts/python.sh              # build paddock (release), set up the venv, run pytest
#   scripts/python.sh -k env -x    # extra arguments go to the client-py pytest run
#
# PADDOCK_VENV overrides the venv (default ~/.cache/paddock/venv); CARGO_TARGET_DIR is
# honoured (default: scripts/setup.sh's per-checkout directory); PADDOCK_BIN skips the
# cargo build and uses that binary (and the in-process simulator's library beside it, or
# PADDOCK_EMBED_LIB).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${PADDOCK_BIN:-}" ]; then
    source scripts/setup.sh
fi

source scripts/venv.sh

if [ -z "${PADDOCK_BIN:-}" ]; then
    cargo build --release --locked -q -p paddock -p paddock-embed
    PADDOCK_BIN="$(cd "$CARGO_TARGET_DIR/release" && pwd)/paddock"
fi
export PADDOCK_BIN
echo "python.sh: testing client-py against $PADDOCK_BIN serve"
(cd client-py && "$VENV/bin/python" -m pytest -q tests "$@")
echo "python.sh: testing ROS 2 interop of $PADDOCK_BIN bridge against Cyclone DDS"
exec "$VENV/bin/python" -m pytest -q bridge/interop
