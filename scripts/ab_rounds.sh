#!/usr/bin/env bash
# This checkout's simulator against an earlier build's, side by side in one process:
# `client-py/benchmarks/ab_steps.py` steps the same 64-env vector env with each build's
# libpaddock_embed in turn, a 20 ms block at a time, pinned to one core, and reports the
# median ratio of their times per step over all pairs of blocks with its 95 % interval.
# Blocks that short see the same host speed, so a change of a few per cent is told apart
# on a host whose speed drifts by a fifth within minutes, where `scripts/perf_rounds.sh`
# (whole processes a few seconds each) cannot. The uncommitted changes of this checkout
# are part of the head: to measure a change, leave it uncommitted and give BASE=HEAD.
#
# Where each build's worlds land in memory moves one run's ratio by up to about 2 %, so
# the script makes several runs, the two libraries loaded in either order in turn, and
# reports each run, the median and range of the runs' ratios, and the mean ratio of each
# load order and of the two (the figure to take where the order biases the runs).
#
# Usage: scripts/ab_rounds.sh [BASE] [ROUNDS] [SECONDS]
#   BASE     the build to compare with, any git revision (default HEAD)
#   ROUNDS   runs of ab_steps.py (default 6); each run loads both libraries afresh
#   SECONDS  CPU seconds of each run (default 20)
# Extra ab_steps.py flags: $AB_ARGS (for example AB_ARGS="--map Spa --envs 8"). The base
# must speak the same embedding ABI as this checkout's client (ab_steps.py says if not).
# PADDOCK_SCAN_PATH=avx times both builds on the AVX2 code path on a CPU that also has
# AVX-512 (a base from before that variable is refused while it is set).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
source scripts/venv.sh

base="${1:-HEAD}"
rounds="${2:-6}"
seconds="${3:-20}"
source scripts/rounds.sh
rev="$(base_rev "$base")"

cargo build --release --locked -q -p paddock-embed
base_lib="$(base_build "$rev" paddock-embed libpaddock_embed.so)"
# the head's library as a file of its own (the loader keeps one copy per file, and a
# build during the run must not change it)
head_lib="$(mktemp --suffix=.so)"
runs="$(mktemp)"
trap 'rm -f "$head_lib" "$runs"' EXIT
cp "$CARGO_TARGET_DIR/release/libpaddock_embed.so" "$head_lib"

head="$(git rev-parse --short=12 HEAD)"
git diff --quiet HEAD -- . || head="$head with uncommitted changes"
# shellcheck disable=SC2086  # AB_ARGS is a list of flags
for r in $(seq 1 "$rounds"); do
    first=base
    [ $((r % 2)) = 0 ] && first=head
    "${pin[@]}" "$VENV/bin/python" client-py/benchmarks/ab_steps.py --json --load-first "$first" \
        --base "$base_lib" --head "$head_lib" --seconds "$seconds" ${AB_ARGS:-} >>"$runs"
    echo "run $r/$rounds ($first loaded first): done" >&2
done

"$VENV/bin/python" - "$runs" "$head" "$base (${rev:0:12})" <<'PY'
import json
import signal
import statistics
import sys

signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # quiet on a closed pipe
path, head, base = sys.argv[1:4]
runs = [json.loads(line) for line in open(path) if line.strip()]
print(f"head {head} against base {base}: {runs[0]['envs']} envs on {runs[0]['map']}, "
      f"side by side in one process")
print()
print("| run | loaded first | pairs | base, env-steps per CPU-s | head | head / base (speed), median of pairs | 95 % interval | head faster in |")
print("| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
for i, r in enumerate(runs, 1):
    lo, hi = r["head_speed_over_base_ci95"]
    rate = r["env_steps_per_cpu_s"]
    print(f"| {i} | {r['load_first']} | {r['pairs']} | {rate['base']:,.0f} | {rate['head']:,.0f} | "
          f"{r['head_speed_over_base']:.4f}x | {lo:.4f}-{hi:.4f}x | {r['head_faster_share']:.0%} |")
speeds = [r["head_speed_over_base"] for r in runs]
print()
print(f"head / base over the runs: median {statistics.median(speeds):.4f}x, "
      f"range {min(speeds):.4f}-{max(speeds):.4f}x")
# The library loaded first can read slower by itself (about 1 % on a Zen 3 guest, two
# copies of one build): the mean over each load order, then of the two, cancels that.
order = {f: [r["head_speed_over_base"] for r in runs if r["load_first"] == f]
         for f in ("base", "head")}
if order["base"] and order["head"]:
    means = {f: statistics.fmean(v) for f, v in order.items()}
    print(f"by load order: base first {means['base']:.4f}x, head first {means['head']:.4f}x, "
          f"their mean {(means['base'] + means['head']) / 2:.4f}x")
PY
