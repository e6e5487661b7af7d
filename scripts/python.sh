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

VENV="${PADDOCK_VENV:-$HOME/.cache/paddock/venv}"
PY="${PYTHON:-python3}"
PINS=(pyzmq==27.3.0 protobuf==7.36.2 gymnasium==1.4.0 numpy==2.4.6 cma==4.5.0 pytest==9.2.0
      cyclonedds==11.0.1 rosbags==0.11.9 mcap==1.6.0
      pygame==2.6.1 moviepy==2.2.1 onnx==1.23.2 onnxruntime==1.32.0 pettingzoo==1.27.0)

if [ ! -x "$VENV/bin/python" ]; then
    echo "python.sh: creating the venv $VENV"
    "$PY" -m venv "$VENV"
fi
# install only when the pins, the package metadata or the checkout (the editable
# install points into it) changed
stamp="$VENV/.paddock-stamp"
want="$( { printf '%s\n' "${PINS[@]}" "$(pwd -P)"; cat client-py/pyproject.toml; } | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check "${PINS[@]}"
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps -e client-py
    echo "$want" > "$stamp"
fi

if [ -z "${PADDOCK_BIN:-}" ]; then
    cargo build --release --locked -q -p paddock -p paddock-embed
    PADDOCK_BIN="$(cd "$CARGO_TARGET_DIR/release" && pwd)/paddock"
fi
export PADDOCK_BIN
echo "python.sh: testing client-py against $PADDOCK_BIN serve"
(cd client-py && "$VENV/bin/python" -m pytest -q tests "$@")
echo "python.sh: testing ROS 2 interop of $PADDOCK_BIN bridge against Cyclone DDS"
exec "$VENV/bin/python" -m pytest -q bridge/interop
