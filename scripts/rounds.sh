#!/usr/bin/env bash
# What the measuring scripts in rounds share (sourced by scripts/perf_rounds.sh,
# scripts/vecenv_rounds.sh and scripts/ab_rounds.sh, with `rounds` and `seconds` set from
# their arguments): the two arguments checked (exit 2 naming the argument and its value),
# `pin`, the command prefix that runs a measurement on core 1 (nothing on a one-core
# machine or without taskset), `base_rev`, a base revision's commit, and `base_build`, an
# earlier build's artifact.
if ! [[ "$rounds" =~ ^[1-9][0-9]{0,2}$ ]]; then
    echo "error: ROUNDS = '$rounds' must be a whole number from 1 to 999" >&2
    exit 2
fi
if ! [[ "$seconds" =~ ^[0-9]+(\.[0-9]+)?$ ]] || ! awk "BEGIN { exit !($seconds > 0) }"; then
    echo "error: SECONDS = '$seconds' must be a positive number of seconds" >&2
    exit 2
fi
pin=()
if command -v taskset >/dev/null 2>&1 && [ "$(nproc)" -gt 1 ]; then
    pin=(taskset -c 1)
fi

# base_build REV PACKAGE ARTIFACT: builds PACKAGE at the commit REV (a full hash) in its
# own git worktree and target directory under the cargo target directory (its outputs must
# not overwrite this checkout's; third-party crates are reused from this checkout's
# directory on first use), copies target/release/ARTIFACT beside the worktree and prints
# that copy's path. Built once per commit and artifact, kept for the next run.
base_build() {
    local rev="$1" package="$2" artifact="$3"
    local tree="$CARGO_TARGET_DIR/perf-base/${rev:0:12}"
    local target="$CARGO_TARGET_DIR/perf-base/target"
    local out="$tree.$artifact"
    if [ ! -e "$out" ]; then
        if [ ! -d "$tree" ] || [ "$(git -C "$tree" rev-parse HEAD 2>/dev/null)" != "$rev" ]; then
            rm -rf "$tree"
            git worktree prune
            git worktree add --detach --quiet "$tree" "$rev"
        fi
        if [ ! -d "$target" ]; then
            mkdir -p "$target"
            cp -a "$CARGO_TARGET_DIR/release" "$target/release" 2>/dev/null || true
            # every paddock crate is built again from the base's sources (as
            # scripts/setup.sh seeds a new checkout's directory)
            find "$target" -path '*/.fingerprint/paddock-*' -prune -exec rm -rf {} + 2>/dev/null || true
        fi
        echo "building $package of the base ${rev:0:12} in $tree" >&2
        (cd "$tree" && CARGO_TARGET_DIR="$target" cargo build --release --locked -q -p "$package")
        cp "$target/release/$artifact" "$out"
    fi
    printf '%s\n' "$out"
}

# base_rev BASE: the full hash of the commit BASE names (any git revision); exits 2
# naming BASE if it names none, or if PADDOCK_SCAN_PATH is set and the base's build would
# not read it (it predates the variable: its scans would take the widest path, the head's
# the one named, and the two would not be comparable).
base_rev() {
    local rev
    rev="$(git rev-parse --verify --quiet "$1^{commit}")" || {
        echo "error: BASE = '$1' is not a commit of this repository (a shallow clone may lack it: git fetch --unshallow)" >&2
        exit 2
    }
    if [ -n "${PADDOCK_SCAN_PATH:-}" ] &&
        ! git cat-file -e "$rev:worker/src/scan_path.rs" 2>/dev/null; then
        echo "error: PADDOCK_SCAN_PATH = '$PADDOCK_SCAN_PATH' is set, but BASE = '$1' predates the variable (its build would scan on its widest path); give a later base, or with scripts/perf_rounds.sh HEAD_ARGS=\"--scan-path ...\" instead" >&2
        exit 2
    fi
    printf '%s\n' "$rev"
}
