#!/usr/bin/env bash
# Runs every check and test of Paddock: formatting, clippy, the Rust test suites
# (unit, conformance against f1tenth_gym, end-to-end across real broker and worker
# processes, CURVE keys, the Docker deployment), then the Python client's tests.
# Installs what it needs first.
#
# Everything is built first; then the tests run in three tracks at once, because most of
# them wait (on processes, sockets, real-time loops) rather than compute:
#   timed   the end-to-end and ROS 2 bridge suites (paddock-e2e, paddock-bridge), which
#           time failure detection and real-time loops: normal priority, one binary at
#           a time as before (a test that times a real-time loop belongs there);
#   python  the Python client's and the ROS 2 interop tests (scripts/python.sh): nice 10;
#   rest    every other crate's tests, mostly computation: nice 19, so they take only the
#           cycles the other two leave.
# Each track's output is printed when it ends (timed, python, rest); the script fails if
# any track failed, and names it.
#
# The conformance tests read ../shared (the f1tenth_gym reference vectors and the real
# race tracks) beside this checkout; set PADDOCK_SHARED to point elsewhere.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh

export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-never}"

logs="$(mktemp -d)"
# Background jobs run in process groups of their own (set -m while starting them), so
# that an interrupted or failed run stops them with everything they started.
trap 'for p in $(jobs -p); do kill -- -"$p" 2>/dev/null || true; done; rm -rf "$logs"' EXIT
since() { echo "$(($(date +%s) - $1)) s"; }
start=$(date +%s)

# The Python venv (pip downloads, mostly) is set up while cargo builds.
set -m
(nice -n 10 bash -c 'source scripts/venv.sh' >"$logs/venv" 2>&1) &
venv_pid=$!
set +m

echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
# In the release profile, as the tests below: the C libraries' builds (SQLite, zstd)
# and the proc macros are then built once for both (the lints are the same).
cargo clippy --workspace --all-targets --release --locked -- -D warnings
echo "== build (release: the conformance and simulator tests step millions of times)"
# The timed track (below) runs its test executables itself: the build lists them (cargo's
# JSON messages on stdout, its progress and diagnostics on stderr as usual).
timed=(paddock-e2e paddock-bridge)
listed="$(cargo test --workspace --release --locked --no-run --message-format=json-render-diagnostics |
    python3 scripts/test_executables.py "${timed[@]}")"
mapfile -t timed_tests <<<"$listed"
echo "== benchmarks compile"
cargo bench --workspace --locked --no-run
# the binary and the in-process simulator's library that the Python tests load
cargo build --release --locked -p paddock -p paddock-embed
if ! wait "$venv_pid"; then
    cat "$logs/venv" >&2
    echo "error: setting up the Python venv failed (above)" >&2
    exit 1
fi
echo "== built in $(since "$start")"

# The rest track selects crates with --workspace and --exclude, which keeps their build
# as it is; the timed track runs its test executables itself (in their package's folder,
# as cargo does): a cargo test of only those packages would unify features differently
# and build 25 crates again.
not_timed=()
for m in "${timed[@]}"; do not_timed+=(--exclude "$m"); done
run_timed() {
    local rc=0 line dir exe
    for line in "${timed_tests[@]}"; do
        dir="${line%%$'\t'*}" exe="${line#*$'\t'}"
        echo "     Running $exe"
        (cd "$dir" && "$exe") || rc=1
    done
    return "$rc"
}

echo "== tests: the timed, python and rest tracks at once"
tests_start=$(date +%s)
declare -A pid took
track() { # name, command...
    local name="$1"
    shift
    (
        local began rc=0
        began=$(date +%s)
        "$@" >"$logs/$name" 2>&1 || rc=$?
        echo "$(($(date +%s) - began))" >"$logs/$name.s"
        exit "$rc"
    ) &
    pid[$name]=$!
}
set -m
track timed run_timed
track python env PADDOCK_BIN="$CARGO_TARGET_DIR/release/paddock" nice -n 10 bash scripts/python.sh
track rest nice -n 19 cargo test --workspace --release --locked "${not_timed[@]}"
set +m

failed=()
for name in timed python rest; do
    rc=0
    wait "${pid[$name]}" || rc=$?
    took[$name]="$(cat "$logs/$name.s" 2>/dev/null || echo '?') s"
    echo "== track $name: $([ "$rc" = 0 ] && echo passed || echo "FAILED (exit $rc)") in ${took[$name]}"
    cat "$logs/$name"
    [ "$rc" = 0 ] || failed+=("$name")
done
echo "== tests ran in $(since "$tests_start") (timed ${took[timed]}, python ${took[python]}, rest ${took[rest]}); all in $(since "$start")"
if ((${#failed[@]})); then
    echo "error: the ${failed[*]} track(s) failed (their output is above)" >&2
    exit 1
fi
