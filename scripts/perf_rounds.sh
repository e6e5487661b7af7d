#!/usr/bin/env bash
# The simulator's speed now against an earlier build, measured back to back on this
# machine: `paddock perf` (one world on the default map, 1 and 2 cars, each with its
# 1080-beam scans) run by both builds in turn, round after round, pinned to one core, so
# that a busy host slows both alike. Prints one markdown row per run, then the medians
# and their ratios (docs/performance-scan.md records such tables).
#
# Usage: scripts/perf_rounds.sh [BASE] [ROUNDS] [SECONDS]
#   BASE     the build to compare with, any git revision (default 4acddcb: the code of
#            the day the per-core goals of docs/performance-scan.md were set)
#   ROUNDS   rounds of both builds and both car counts (default 5)
#   SECONDS  `paddock perf --seconds` per run (default 2)
# The base is built once, in a git worktree under the cargo target directory, and kept
# there for the next run. Extra `paddock perf` flags for both builds: $PERF_ARGS (for
# example PERF_ARGS="--map quarry"); for the head build only: $HEAD_ARGS (flags an older
# base lacks, for example HEAD_ARGS="--scan-path avx" to time the AVX2 code path on a CPU
# that also has AVX-512).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh

base="${1:-4acddcb}"
rounds="${2:-5}"
seconds="${3:-2}"
source scripts/rounds.sh
rev="$(base_rev "$base")"

cargo build --release --locked -q -p paddock
head_bin="$CARGO_TARGET_DIR/release/paddock"

# The base: its own worktree and target directory (see base_build in scripts/rounds.sh).
base_bin="$(base_build "$rev" paddock paddock)"

runs="$(mktemp)"
trap 'rm -f "$runs"' EXIT
# shellcheck disable=SC2086  # PERF_ARGS is a list of flags
for r in $(seq 1 "$rounds"); do
    for agents in 1 2; do
        for build in base head; do
            bin="$base_bin" extra=""
            [ "$build" = head ] && bin="$head_bin" extra="${HEAD_ARGS:-}"
            json="$("${pin[@]}" "$bin" perf --agents "$agents" --seconds "$seconds" --json ${PERF_ARGS:-} $extra)"
            printf '%s\t%s\t%s\t%s\n' "$r" "$agents" "$build" "$json" >>"$runs"
            echo "round $r/$rounds, $agents car(s), $build: done" >&2
        done
    done
done

python3 - "$runs" "$base (${rev:0:12})" "$(git rev-parse --short=12 HEAD)" <<'EOF'
import json
import signal
import statistics
import sys

# quiet on a closed pipe (`| head`), as a Unix tool
signal.signal(signal.SIGPIPE, signal.SIG_DFL)

path, base, head = sys.argv[1:4]
rows = []
with open(path) as f:
    for line in f:
        r, agents, build, doc = line.rstrip("\n").split("\t", 3)
        rows.append((int(r), int(agents), build, json.loads(doc)))

def cell(d, key, scale, digits=1):
    v = d.get(key)
    return "-" if v is None else f"{v / scale:,.{digits}f}"

# the base may be older than the report's CPU and path fields: the head's first run names them
first = next(d for _, _, b, d in rows if b == "head")
print(f"CPU: {first.get('cpu', 'not reported')}; map: {first.get('map', 'not reported')}; "
      f"head's scan path: {first.get('scan_path', 'not reported')}; head {head} against base {base}")
print()
print("| round | cars | build | agent-steps/s with scans (k) | rays/s (M) | without scans (M agent-steps/s) |")
print("| ---: | ---: | --- | ---: | ---: | ---: |")
for r, agents, build, d in rows:
    print(f"| {r} | {agents} | {build} | {cell(d, 'agent_steps_per_s_scan', 1e3)} | "
          f"{cell(d, 'rays_per_s', 1e6)} | {cell(d, 'agent_steps_per_s_noscan', 1e6, 2)} |")
print()
print("| cars | figure | base median | head median | head / base |")
print("| ---: | --- | ---: | ---: | ---: |")
for agents in sorted({a for _, a, _, _ in rows}):
    for key, name, scale, digits in (
            ("agent_steps_per_s_scan", "agent-steps/s with scans (k)", 1e3, 1),
            ("rays_per_s", "rays/s (M)", 1e6, 1),
            ("agent_steps_per_s_noscan", "without scans (M)", 1e6, 2)):
        med = {}
        for build in ("base", "head"):
            vals = [d[key] for _, a, b, d in rows if a == agents and b == build and d.get(key)]
            med[build] = statistics.median(vals) if vals else None
        if med["base"] is None or med["head"] is None:
            continue
        print(f"| {agents} | {name} | {med['base'] / scale:,.{digits}f} | "
              f"{med['head'] / scale:,.{digits}f} | "
              f"{med['head'] / med['base']:.2f}x |")
EOF
