"""Two builds of the simulator side by side in one process: the same vector env stepped by
each build's ``libpaddock_embed`` in turn, a short block of steps at a time, so that a
host whose speed drifts by a fifth within minutes slows both builds alike.

    python benchmarks/ab_steps.py --base BASE.so --head HEAD.so [--seconds 30]
        [--envs 64] [--block-ms 20] [--map lakeside] [--clock cpu|wall] [--json]

Each build gets its own copy of the library (two different files: the loader keeps one
copy per file) and its own vector env of the same worlds, seeds and actions (cars driving
at a constant speed and steering angle, reset where they crash). Blocks go in the order
base, head, head, base, base, head, ..., each timed by this process's CPU time (precise
on Linux; everything runs in this process). Each pair of neighbouring blocks gives the
ratio of the two builds' times per step; the report is the median of those ratios with
its 95 % confidence interval (by the ranks of a binomial, no assumption about the
host's noise), each build's env-steps per CPU-second over all its blocks, and the share
of pairs in which the head was the faster. Pin it to one core (``taskset -c 1``);
``scripts/ab_rounds.sh`` builds the two libraries and does. ``--clock wall`` times the
blocks by the clock instead, for a run on several cores (the copies on the library's
threads, where CPU time would count their waits too); the host's other load then
counts, so give it the cores.

Where each build's worlds and arrays land in memory moves a run's ratio by up to about
2 % (two copies of one build measured 0.999-1.020x in five runs): compare builds over
several runs, with the libraries made in either order (``--load-first``), as
``scripts/ab_rounds.sh`` does, not by one run's interval.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import statistics
import time

import numpy as np

import paddock


def vector_env(library: str, envs: int, kw: dict):
    """A vector env whose simulator is the library at ``library`` (an in-process session
    runs the file that ``$PADDOCK_EMBED_LIB`` names when it is made, each file loaded
    once: its own copy)."""
    if not os.path.isfile(library):
        raise SystemExit(f"error: --base/--head = {library!r} is not a file")
    os.environ["PADDOCK_EMBED_LIB"] = os.path.abspath(library)
    env = paddock.make_vec(envs, paddock.IN_PROCESS, **kw)
    env.reset(seed=0)
    return env


CLOCKS = {"cpu": time.process_time_ns, "wall": time.perf_counter_ns}


def steps_of(env, actions: np.ndarray, n: int, clock=time.process_time_ns) -> float:
    """Seconds of ``n`` steps by ``clock`` (this process's CPU time by default)."""
    t0 = clock()
    for _ in range(n):
        env.step(actions)
    return (clock() - t0) / 1e9


def median_interval(values: list[float]) -> tuple[float, float, float]:
    """The median of ``values`` and its 95 % confidence interval by order statistics."""
    v = sorted(values)
    n = len(v)
    half = 1.96 * math.sqrt(n) / 2
    lo = max(0, math.floor(n / 2 - half))
    hi = min(n - 1, math.ceil(n / 2 + half))
    return statistics.median(v), v[lo], v[hi]


def main(argv: list[str] | None = None) -> dict:
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # quiet on a closed pipe
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the base build's libpaddock_embed")
    ap.add_argument("--head", required=True, help="the head build's libpaddock_embed")
    ap.add_argument("--seconds", type=float, default=30.0, help="total measuring time (default 30)")
    ap.add_argument("--envs", type=int, default=64, help="worlds of the vector env (default 64)")
    ap.add_argument("--block-ms", type=float, default=20.0,
                    help="milliseconds of one block of steps, by --clock (default 20)")
    ap.add_argument("--map", default="lakeside", help="map name, directory or YAML (default lakeside)")
    ap.add_argument("--load-first", choices=("base", "head"), default="base",
                    help="which build's library and worlds are made first (default base)")
    ap.add_argument("--clock", choices=tuple(CLOCKS), default="cpu",
                    help="time blocks by this process's CPU time (default; pinned to one core) "
                         "or by the clock (wall: on several cores)")
    ap.add_argument("--json", action="store_true", help="one JSON object instead of the table")
    args = ap.parse_args(argv)
    for name in ("seconds", "block_ms"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            ap.error(f"--{name.replace('_', '-')} = {value!r} must be a positive number")
    if not 1 <= args.envs <= 4096:
        ap.error(f"--envs = {args.envs} must be from 1 to 4096")
    if args.block_ms * 1e-3 * 8 > args.seconds:
        ap.error(f"--seconds = {args.seconds} leaves fewer than four pairs of {args.block_ms} ms blocks")

    kw = dict(map=args.map, num_beams=1080, time_limit=36000.0, laps=100)
    first, second = ("base", "head") if args.load_first == "base" else ("head", "base")
    builds = {first: vector_env(getattr(args, first), args.envs, kw)}
    builds[second] = vector_env(getattr(args, second), args.envs, kw)
    actions = np.tile(np.array([0.05, 3.0], dtype=np.float32), (args.envs, 1))
    try:
        # warm both up, and size a block from the base's speed
        clock = CLOCKS[args.clock]
        for env in builds.values():
            steps_of(env, actions, 20, clock)
        per_step = steps_of(builds["base"], actions, 20, clock) / 20
        block = max(1, round(args.block_ms * 1e-3 / max(per_step, 1e-9)))
        spent = {"base": 0.0, "head": 0.0}
        count = {"base": 0, "head": 0}
        ratios = []  # head's time per step over the base's, one per pair of blocks
        start = clock()
        k = 0
        while (clock() - start) / 1e9 < args.seconds:
            order = ("base", "head") if k % 2 == 0 else ("head", "base")
            took = {}
            for b in order:
                took[b] = steps_of(builds[b], actions, block, clock)
                spent[b] += took[b]
                count[b] += block
            if took["base"] > 0:
                ratios.append(took["head"] / took["base"])
            k += 1
    finally:
        for env in builds.values():
            env.close()
    med, lo, hi = median_interval(ratios)
    rate = {b: count[b] * args.envs / spent[b] for b in builds}
    per = "cpu_s" if args.clock == "cpu" else "wall_s"
    result = {
        "envs": args.envs, "map": args.map, "block_steps": block, "pairs": len(ratios),
        "load_first": args.load_first, "clock": args.clock,
        f"env_steps_per_{per}": rate,
        "head_time_over_base_median": med, "head_time_over_base_ci95": [lo, hi],
        "head_speed_over_base": 1 / med, "head_speed_over_base_ci95": [1 / hi, 1 / lo],
        "head_faster_share": sum(r < 1 for r in ratios) / len(ratios),
    }
    if args.json:
        print(json.dumps(result))
        return result
    print(f"{args.envs} envs on {args.map}, {len(ratios)} pairs of {block}-step blocks")
    print()
    unit = "CPU-s" if args.clock == "cpu" else "s"
    print(f"| build | env-steps per {unit} | head / base (speed), median of pairs | 95 % interval | head faster in |")
    print("| --- | ---: | ---: | ---: | ---: |")
    print(f"| base | {rate['base']:,.0f} | | | |")
    print(f"| head | {rate['head']:,.0f} | {1 / med:.4f}x | {1 / hi:.4f}-{1 / lo:.4f}x | "
          f"{result['head_faster_share']:.0%} of pairs |")
    return result


if __name__ == "__main__":
    main()
