#!/usr/bin/env bash
# A 64-env Python vector env against the simulator's own rate for the same worlds, on one
# core: per round, the worker bench `worlds_step` (the 64 worlds stepped by
# `Worlds::step` alone: same map, LIDAR, seeds and standing cars), then
# `client-py/benchmarks/env_steps.py` with the simulator in the learner's process and
# through a local `paddock serve`, everything pinned to core 1. Prints one markdown row
# per round: each figure in env-steps (agent-steps) per CPU-second, and each vector env's
# share of the simulator's rate in the same round (docs/performance-vecenv.md records such
# tables).
#
# PADDOCK_SCAN_PATH=avx measures all three on the AVX2 code path on a CPU that also has
# AVX-512 (the bench, the in-process library and the server's worker read it).
#
# Usage: scripts/vecenv_rounds.sh [ROUNDS] [SECONDS]
#   ROUNDS   rounds of the three measurements (default 3)
#   SECONDS  env_steps.py --seconds per phase (default 3)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
source scripts/venv.sh

rounds="${1:-3}"
seconds="${2:-3}"
source scripts/rounds.sh

cargo build --release --locked -q -p paddock -p paddock-embed
# --workspace, not -p paddock-worker: the workspace's features, so the third-party crates
# that scripts/test.sh built are reused instead of built again for one package's features
bench="$(cargo bench --workspace --locked --bench env_session --no-run 2>&1 |
    sed -n 's/.*(\(.*env_session-[0-9a-f]*\)).*/\1/p' | tail -n 1)"
if [ ! -x "$bench" ]; then
    echo "error: the env_session bench was not built" >&2
    exit 1
fi
export PADDOCK_BIN="$CARGO_TARGET_DIR/release/paddock"
export PADDOCK_EMBED_LIB="$CARGO_TARGET_DIR/release/libpaddock_embed.so"

runs="$(mktemp)"
trap 'rm -f "$runs"' EXIT
for r in $(seq 1 "$rounds"); do
    # criterion's "time: [low estimate high]" of the one bench asked for
    sim="$("${pin[@]}" "$bench" --bench --warm-up-time 1 --measurement-time 3 worlds_step 2>&1 |
        sed -n 's/.*time: *\[[^ ]* [^ ]* \([0-9.]*\) \([^ ]*\) .*/\1 \2/p' | head -n 1)"
    inproc="$("${pin[@]}" "$VENV/bin/python" client-py/benchmarks/env_steps.py \
        --seconds "$seconds" --endpoint in-process | tail -n 1)"
    served="$("${pin[@]}" "$VENV/bin/python" client-py/benchmarks/env_steps.py \
        --seconds "$seconds" | tail -n 1)"
    printf '%s\t%s\t%s\t%s\n' "$r" "$sim" "$inproc" "$served" >>"$runs"
    echo "round $r/$rounds: done" >&2
done

"$VENV/bin/python" - "$runs" <<'EOF'
import json
import signal
import sys

signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # quiet on a closed pipe
ENVS = 64
UNIT = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}

print("| round | simulator (`worlds_step`) | in-process, env-steps per CPU-s | share | "
      "local server, env-steps per CPU-s | share | server CPU ms per step: client, broker, worker |")
print("| ---: | ---: | ---: | ---: | ---: | ---: | --- |")
with open(sys.argv[1]) as f:
    for line in f:
        r, sim, inproc, served = line.rstrip("\n").split("\t")
        value, unit = sim.split()
        seconds = float(value) * UNIT[unit]
        rate = ENVS / seconds
        a, b = json.loads(inproc), json.loads(served)
        ia, sb = a[f"env_steps_per_cpu_s_{ENVS}"], b[f"env_steps_per_cpu_s_{ENVS}"]
        ms = b[f"cpu_ms_per_step_{ENVS}"]
        split = ", ".join(f"{ms.get(k, 0.0):.3f}" for k in ("client", "paddock-broker", "paddock-worker"))
        print(f"| {r} | {seconds * 1e3:.3f} ms per 64-env step: {rate:,.0f} | {ia:,.0f} | "
              f"{ia / rate:.0%} | {sb:,.0f} | {sb / rate:.0%} | {split} |")
EOF
