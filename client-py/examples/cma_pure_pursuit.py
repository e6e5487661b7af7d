"""Tune the pure-pursuit driver with pycma over batch rollouts on a broker.

Each generation asks CMA-ES for ``popsize`` parameter vectors (in the driver's bounds,
scaled to [0, 1]) and evaluates all of them on the same seeded starts with ONE
``client.rollouts`` call, so the broker spreads the episodes over its workers. The cost
is the lap time, or for a car that does not finish, the time limit plus the distance
it did not cover.

    python examples/cma_pure_pursuit.py --endpoint tcp://127.0.0.1:5555
    python examples/cma_pure_pursuit.py            # starts a local `paddock serve`
    python examples/cma_pure_pursuit.py --quick    # two small generations (tests)
"""

from __future__ import annotations

import argparse
import json
import time

import cma
import numpy as np

import paddock


def cost(r: paddock.RolloutResults, time_limit: float) -> np.ndarray:
    """Mean cost per parameter vector over the seeds (lower is better)."""
    unfinished = time_limit + np.maximum(0.0, 100.0 - r.progress)
    return np.where(r.finished, r.lap_time, unfinished).mean(axis=1)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--endpoint", default=None, help="broker client endpoint (default: local serve)")
    ap.add_argument("--map", default="lakeside")
    ap.add_argument("--generations", type=int, default=15)
    ap.add_argument("--popsize", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="2 generations of 4 on 2 seeds")
    args = ap.parse_args(argv)
    if args.quick:
        args.generations, args.popsize, args.seeds = 2, 4, 2

    defaults, lo, hi = paddock.driver_defaults("pure-pursuit")
    seeds = list(range(1, args.seeds + 1))
    t0 = time.monotonic()
    with paddock.Client(args.endpoint) as client:
        base = cost(client.rollouts("pure-pursuit", defaults, seeds, map=args.map,
                                    time_limit=args.time_limit), args.time_limit)[0]
        es = cma.CMAEvolutionStrategy(((defaults - lo) / (hi - lo)).tolist(), 0.15,
                                      {"bounds": [0.0, 1.0], "popsize": args.popsize,
                                       "seed": 1, "verbose": -9})
        episodes = 0
        for g in range(args.generations):
            xs = es.ask()
            params = lo + np.asarray(xs) * (hi - lo)
            r = client.rollouts("pure-pursuit", params, seeds, map=args.map, time_limit=args.time_limit)
            episodes += r.lap_time.size
            c = cost(r, args.time_limit)
            es.tell(xs, c.tolist())
            print(f"generation {g + 1}/{args.generations}: best {c.min():.3f} s, "
                  f"mean {c.mean():.3f} s, finished {r.finished.mean():.0%}", flush=True)
        best = lo + np.asarray(es.result.xbest) * (hi - lo)
        result = {"default_cost": float(base), "best_cost": float(es.result.fbest),
                  "best_params": best.tolist(), "episodes": episodes,
                  "seconds": time.monotonic() - t0}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
