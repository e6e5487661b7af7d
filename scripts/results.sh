#!/usr/bin/env bash
# The README's results table: every driver on every shipped map, benchmark B1 (time
# trial) and B3 (head to head against default pure pursuit), default parameters.
# Usage: scripts/results.sh [EPISODES]   (default 20; prints a markdown table)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
cargo build --release --locked -q -p paddock
P="$CARGO_TARGET_DIR/release/paddock"
N="${1:-20}"
drivers=(pure-pursuit follow-the-gap lattice rrt-star mlp)
maps=(lakeside quarry harbour)
echo "| task | map | driver | opponent | episodes | lap time [s] | success | crash | win |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for task in b1 b3; do
    for map in "${maps[@]}"; do
        for d in "${drivers[@]}"; do
            "$P" benchmark "$task" --driver "$d" --map "$map" --episodes "$N" --seed 1 --markdown-row
        done
    done
done
