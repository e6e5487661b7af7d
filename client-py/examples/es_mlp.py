"""Train an MLP driver with evolution strategies through the vector env.

The driver is a small numpy MLP: the LIDAR scan (min-pooled to a few sectors, clipped
at 10 m) and the speed in, ``[steer, speed]`` out. OpenAI-style ES with antithetic
pairs: every generation, each of the ``2 * pairs`` envs of ONE vector env session
drives one perturbed copy of the weights from the same seeded start; the weights move
along the rank-weighted perturbations. The reward (progress in metres, a lap bonus and
a crash penalty) is computed on the worker. Training stops when the mean driver
completes a lap.

    python examples/es_mlp.py --endpoint tcp://127.0.0.1:5555
    python examples/es_mlp.py --quick          # two tiny generations (tests)
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import paddock

SECTORS = 18
HIDDEN = 16


class Mlp:
    """Weights of many MLPs at once: ``theta`` is ``(members, size)``."""

    n_in = SECTORS + 1
    shapes = [(n_in, HIDDEN), (HIDDEN,), (HIDDEN, 2), (2,)]
    size = sum(int(np.prod(s)) for s in shapes)

    @classmethod
    def act(cls, theta: np.ndarray, obs: dict[str, np.ndarray], steer_max: float) -> np.ndarray:
        n = theta.shape[0]
        scans = np.minimum(obs["scans"][:, 0, :], 10.0) / 10.0
        feats = scans.reshape(n, SECTORS, -1).min(axis=2)
        x = np.concatenate([feats, obs["linear_vels_x"][:, :1] / 5.0], axis=1)
        parts, k = [], 0
        for s in cls.shapes:
            m = int(np.prod(s))
            parts.append(theta[:, k:k + m].reshape((n,) + s))
            k += m
        w1, b1, w2, b2 = parts
        h = np.tanh(np.einsum("ni,nih->nh", x, w1) + b1)
        out = np.tanh(np.einsum("nh,nho->no", h, w2) + b2)
        steer = out[:, 0] * steer_max
        speed = 2.5 + 1.5 * out[:, 1]
        return np.stack([steer, speed], axis=1).astype(np.float32)


def evaluate(env: paddock.F110VectorEnv, theta: np.ndarray, seed: int, max_steps: int,
             steer_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Total reward and completed laps of each member, all from the same start."""
    n = theta.shape[0]
    obs, _ = env.reset(seed=[seed] * n)
    total = np.zeros(n)
    laps = np.zeros(n, dtype=int)
    alive = np.ones(n, dtype=bool)
    for _ in range(max_steps):
        obs, rew, term, trunc, info = env.step(Mlp.act(theta, obs, steer_max))
        total += np.where(alive, rew, 0.0)
        laps = np.where(alive, info["laps"], laps)
        alive &= ~(term | trunc)
        if not alive.any():
            break
    return total, laps


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--endpoint", default=None)
    ap.add_argument("--map", default="lakeside")
    ap.add_argument("--pairs", type=int, default=16, help="antithetic pairs per generation")
    ap.add_argument("--generations", type=int, default=150)
    ap.add_argument("--sigma", type=float, default=0.1)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--frame-skip", type=int, default=10)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.pairs, args.generations, args.time_limit = 2, 2, 2.0
    n = 2 * args.pairs
    rng = np.random.default_rng(0)
    theta = rng.normal(0.0, 0.1, Mlp.size)
    # envs 0..n-1 drive the perturbed members, env n the current mean driver
    env = paddock.make_vec(n + 1, args.endpoint, map=args.map, num_beams=SECTORS * 6,
                           time_limit=args.time_limit, frame_skip=args.frame_skip,
                           reward={"progress": 1.0, "collision": -20.0, "lap": 50.0, "time": 0.0})
    steer_max = float(env.single_action_space.high[0])
    max_steps = int(np.ceil(args.time_limit / (0.01 * args.frame_skip))) + 1
    t0 = time.monotonic()
    history = []
    lapped = False
    try:
        for g in range(args.generations):
            eps = rng.normal(size=(args.pairs, Mlp.size))
            members = np.concatenate([theta + args.sigma * eps, theta - args.sigma * eps, theta[None]])
            fitness, laps = evaluate(env, members, seed=g, max_steps=max_steps, steer_max=steer_max)
            history.append(float(fitness[n]))
            print(f"generation {g + 1}: members best {fitness[:n].max():.1f} mean "
                  f"{fitness[:n].mean():.1f}; mean driver {fitness[n]:.1f} (laps {laps[n]})", flush=True)
            if laps[n] >= 1:
                lapped = True
                break
            ranks = np.argsort(np.argsort(fitness[:n])) / (n - 1) - 0.5
            grad = ((ranks[:args.pairs] - ranks[args.pairs:]) @ eps) / (args.pairs * args.sigma)
            theta = theta + args.lr * grad
    finally:
        env.close()
    result = {"generations": len(history), "lapped": lapped, "final_score": history[-1],
              "seconds": time.monotonic() - t0}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
