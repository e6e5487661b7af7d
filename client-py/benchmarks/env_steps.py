"""Env-steps per second from Python: one env, and a 64-env vector env in one session,
both with full 1080-beam scans, through a broker and a worker on loopback.

The f1tenth_gym reference steps about 3,300 steps/s for one car in-process on this
machine (its scan is the cost); the goal for the 64-env vector env is 20x that.

    python benchmarks/env_steps.py [--endpoint tcp://HOST:PORT] [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import paddock

REFERENCE_STEPS_PER_S = 3300.0


def measure(env, n: int, seconds: float) -> float:
    env.reset(seed=0)
    # standing cars: every step runs the dynamics and the full scan, and none crashes
    actions = np.zeros((n, 2), dtype=np.float32) if n > 1 else np.zeros(2, dtype=np.float32)
    for _ in range(20):
        env.step(actions)
    steps = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(20):
            env.step(actions)
        steps += 20
    return steps * n / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--endpoint", default=None, help="broker client endpoint (default: local serve)")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--threads", type=int, default=0, help="worker threads of a local serve")
    args = ap.parse_args(argv)
    server = None
    endpoint = args.endpoint
    if endpoint is None:
        server = paddock.LocalServer(threads=args.threads).start()
        endpoint = server.endpoint
    try:
        kw = dict(num_beams=1080, time_limit=36000.0, laps=100)
        single = paddock.F110Env(endpoint, **kw)
        try:
            one = measure(single, 1, args.seconds)
        finally:
            single.close()
        vec = paddock.make_vec(args.envs, endpoint, **kw)
        try:
            many = measure(vec, args.envs, args.seconds)
        finally:
            vec.close()
    finally:
        if server is not None:
            server.stop()
    result = {"env_steps_per_s_1": one, f"env_steps_per_s_{args.envs}": many,
              "reference_steps_per_s": REFERENCE_STEPS_PER_S,
              "ratio_1": one / REFERENCE_STEPS_PER_S, f"ratio_{args.envs}": many / REFERENCE_STEPS_PER_S}
    print(f"| envs | env-steps/s | vs f1tenth_gym ({REFERENCE_STEPS_PER_S:.0f}/s) |")
    print("|---:|---:|---:|")
    print(f"| 1 | {one:,.0f} | {one / REFERENCE_STEPS_PER_S:.2f}x |")
    print(f"| {args.envs} | {many:,.0f} | {many / REFERENCE_STEPS_PER_S:.2f}x |")
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
