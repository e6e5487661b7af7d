#!/usr/bin/env bash
# Installs what building and testing Paddock needs on a fresh Debian/Ubuntu machine:
# a C/C++ compiler and pkg-config (libzmq and SQLite are built from source by cargo) and
# libsodium (ZeroMQ's CURVE encryption). Safe to run again: it only installs what is
# missing. Sourced by the other scripts.
set -euo pipefail

need_apt=()
command -v cc >/dev/null 2>&1 || need_apt+=(build-essential)
command -v c++ >/dev/null 2>&1 || need_apt+=(g++)
command -v pkg-config >/dev/null 2>&1 || need_apt+=(pkg-config)
if ! { [ -f /usr/lib/x86_64-linux-gnu/libsodium.a ] || [ -f /usr/lib/libsodium.a ] ||
    pkg-config --exists libsodium 2>/dev/null; }; then
    need_apt+=(libsodium-dev)
fi
if ((${#need_apt[@]})); then
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    echo "installing ${need_apt[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    # a fresh machine may have no package lists yet: install, and on failure update first
    $SUDO apt-get install -y -qq "${need_apt[@]}" >/dev/null 2>&1 ||
        { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq "${need_apt[@]}"; }
fi

if ! command -v cargo >/dev/null 2>&1; then
    if [ -x "$HOME/.cargo/bin/cargo" ]; then
        export PATH="$HOME/.cargo/bin:$PATH"
    else
        echo "error: Rust (cargo) is not installed; install it from https://rustup.rs and run again" >&2
        exit 1
    fi
fi
