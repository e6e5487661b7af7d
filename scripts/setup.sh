#!/usr/bin/env bash
# Installs what building and testing Paddock needs on a fresh Debian/Ubuntu machine:
# a C/C++ compiler and pkg-config (libzmq and SQLite are built from source by cargo) and
# libsodium (ZeroMQ's CURVE encryption). Safe to run again: it only installs what is
# missing, and picks the cargo target directory (below). Sourced by the other scripts.
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

# The cargo target directory: $CARGO_TARGET_DIR when set, else one per checkout under
# ~/.cache/paddock/targets (named by the checkout's path), kept across runs. Checkouts never
# share one: cargo judges an artifact fresh by file times, with paths relative to each
# package, so a second checkout in the same directory can link the first one's stale build
# of a crate (tests then ran another tree's code and found its files). A new checkout's
# directory starts as a copy of the most recently used one (or of the older shared
# ~/.cache/paddock/target) with the fingerprints of this workspace's own crates removed:
# third-party crates are reused, every paddock crate is built again from this checkout.
# Only the four most recently used directories are kept, none unused for 7 days.
if [ -z "${CARGO_TARGET_DIR:-}" ]; then
    _root="$(pwd -P)"
    _targets="$HOME/.cache/paddock/targets"
    export CARGO_TARGET_DIR="$_targets/$(basename "$_root")-$(printf '%s' "$_root" | sha256sum | cut -c1-12)"
    if [ ! -d "$CARGO_TARGET_DIR" ]; then
        mkdir -p "$_targets"
        # disk: keep the three most recently used besides this one, none unused for a week
        find "$_targets" -mindepth 1 -maxdepth 1 -type d -mtime +7 -exec rm -rf {} + 2>/dev/null || true
        ls -1td "$_targets"/*/ 2>/dev/null | tail -n +4 | while read -r _old; do rm -rf "$_old"; done || true
        _seed="$(ls -1td "$_targets"/*/ 2>/dev/null | head -n 1 || true)"
        if [ -z "$_seed" ] && [ -d "$HOME/.cache/paddock/target/release" ]; then
            _seed="$HOME/.cache/paddock/target"
        fi
        if [ -n "$_seed" ]; then
            echo "setup.sh: new build directory $CARGO_TARGET_DIR (third-party crates from $_seed)" >&2
            _tmp="$CARGO_TARGET_DIR.tmp.$$"
            rm -rf "$_tmp"
            cp -a "$_seed/." "$_tmp/" 2>/dev/null || true
            find "$_tmp" -path '*/.fingerprint/paddock-*' -prune -exec rm -rf {} + 2>/dev/null || true
            mv "$_tmp" "$CARGO_TARGET_DIR" 2>/dev/null || rm -rf "$_tmp"
        fi
        mkdir -p "$CARGO_TARGET_DIR"
    fi
    touch "$CARGO_TARGET_DIR"
    unset _root _targets _seed _tmp
fi
