#!/usr/bin/env bash
# The Python client's venv: pinned dependencies and the package installed in editable
# mode from this checkout. Sourced by scripts/python.sh and scripts/vecenv_rounds.sh (run
# from the checkout's root); sets VENV.
#
# PADDOCK_VENV overrides the venv (default ~/.cache/paddock/venv); PYTHON the interpreter
# that creates it (default python3).
VENV="${PADDOCK_VENV:-$HOME/.cache/paddock/venv}"
_py="${PYTHON:-python3}"
_pins=(pyzmq==27.3.0 protobuf==7.36.2 gymnasium==1.4.0 numpy==2.4.6 cma==4.5.0 pytest==9.2.0
       cyclonedds==11.0.1 rosbags==0.11.9 mcap==1.6.0
       pygame==2.6.1 moviepy==2.2.1 onnx==1.23.2 onnxruntime==1.32.0 pettingzoo==1.27.0)

_stamp="$VENV/.paddock-stamp"
# A venv whose creation was interrupted (Ctrl-C, a stopped run) can have its python but
# no pip: made again from scratch, with its stamp gone.
if ! "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
    echo "venv.sh: creating the venv $VENV" >&2
    rm -f "$_stamp"
    "$_py" -m venv --clear "$VENV" || {
        echo "venv.sh: error: could not create the venv $VENV" >&2
        return 1
    }
fi
# install only when the pins, the package metadata or the checkout (the editable
# install points into it) changed; the stamp is written only after both installs
# succeeded, whether or not the caller stops on errors
_want="$( { printf '%s\n' "${_pins[@]}" "$(pwd -P)"; cat client-py/pyproject.toml; } | sha256sum | cut -d' ' -f1)"
if [ ! -f "$_stamp" ] || [ "$(cat "$_stamp")" != "$_want" ]; then
    rm -f "$_stamp"
    if ! "$VENV/bin/python" -m pip install -q --disable-pip-version-check "${_pins[@]}" ||
        ! "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps -e client-py; then
        echo "venv.sh: error: installing the Python packages into $VENV failed (above)" >&2
        unset _py _pins _stamp _want
        return 1
    fi
    echo "$_want" > "$_stamp"
fi
unset _py _pins _stamp _want
