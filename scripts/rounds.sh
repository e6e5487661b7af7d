#!/usr/bin/env bash
# What the measuring scripts in rounds share (sourced by scripts/perf_rounds.sh and
# scripts/vecenv_rounds.sh, with `rounds` and `seconds` set from their arguments): the
# two arguments checked (exit 2 naming the argument and its value), and `pin`, the
# command prefix that runs a measurement on core 1 (nothing on a one-core machine or
# without taskset).
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
