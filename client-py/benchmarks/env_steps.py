"""Env-steps per second from Python: one env, and a 64-env vector env in one session,
both with full 1080-beam scans, through a broker and a worker on loopback.

The f1tenth_gym reference steps about 3,300 steps/s for one car in-process on this
machine (its scan is the cost); the goal for the 64-env vector env is 20x that.

    python benchmarks/env_steps.py [--endpoint tcp://HOST:PORT] [--seconds 5] [--map M]
    python benchmarks/env_steps.py --endpoint in-process    # the simulator in this process

With a local server (no --endpoint) it also reports the CPU time that this process and
each thread of the server spent (Linux): env-steps per CPU-second is the figure of
everything pinned to one core (``taskset -c 1 python benchmarks/env_steps.py``) without
needing that core to be otherwise idle, and the split per step shows where the time
goes (``paddock-worker``: the simulation and the reply; ``paddock-broker``: forwarding).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

import paddock
from paddock.server import TRANSPORTS

REFERENCE_STEPS_PER_S = 3300.0


def server_threads(pid: int) -> dict[str, float]:
    """CPU seconds of each thread name of process ``pid`` so far (the kernel's exact
    run time per thread, /proc/PID/task/TID/schedstat)."""
    out: dict[str, float] = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                name = f.read().strip()
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                ns = int(f.read().split()[0])
        except OSError:
            continue  # the thread ended
        out[name] = out.get(name, 0.0) + ns / 1e9
    return out


def cpu_seconds(pid: int | None) -> tuple[float, dict[str, float]]:
    """CPU seconds of this process, and of each thread name of process ``pid``."""
    return time.process_time(), server_threads(pid) if pid is not None else {}


def measure(env, n: int, seconds: float, server_pid: int | None = None) -> tuple[float, float, dict]:
    """Env-steps per second of wall time; per CPU-second of this process and the server
    ``server_pid`` (0 when not measured); and the CPU milliseconds per step of this
    process (``client``) and of each server thread name."""
    env.reset(seed=0)
    # standing cars: every step runs the dynamics and the full scan, and none crashes
    actions = np.zeros((n, 2), dtype=np.float32) if n > 1 else np.zeros(2, dtype=np.float32)
    for _ in range(20):
        env.step(actions)
    steps = 0
    client0, server0 = cpu_seconds(server_pid)
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(20):
            env.step(actions)
        steps += 20
    wall = time.perf_counter() - t0
    client1, server1 = cpu_seconds(server_pid)
    split = {"client": client1 - client0}
    split.update({k: v - server0.get(k, 0.0) for k, v in server1.items()})
    cpu = sum(split.values())
    # in-process, everything runs in this process: its CPU time is the whole cost
    whole = server_pid is not None or env.unwrapped.session.conn.endpoint == paddock.IN_PROCESS
    per_cpu = steps * n / cpu if whole and cpu > 0 else 0.0
    ms = {k: round(1e3 * v / steps, 4) for k, v in split.items() if v > 0}
    return steps * n / wall, per_cpu, ms


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--endpoint", default=None, help="broker client endpoint (default: local serve)")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--threads", type=int, default=0, help="worker threads of a local serve")
    ap.add_argument("--transport", default="auto", choices=TRANSPORTS,
                    help="how a local serve listens (default: auto, see paddock.LocalServer)")
    ap.add_argument("--map", default="lakeside",
                    help="map name, map directory or map YAML (default: lakeside)")
    args = ap.parse_args(argv)
    server = None
    endpoint = args.endpoint
    pid = None
    if endpoint is None:
        server = paddock.LocalServer(threads=args.threads, transport=args.transport).start()
        endpoint = server.endpoint
        pid = server.process.pid if os.path.exists("/proc/self/stat") else None
    try:
        kw = dict(map=args.map, num_beams=1080, time_limit=36000.0, laps=100)
        single = paddock.F110Env(endpoint, **kw)
        try:
            one, one_cpu, one_ms = measure(single, 1, args.seconds, pid)
        finally:
            single.close()
        vec = paddock.make_vec(args.envs, endpoint, **kw)
        try:
            many, many_cpu, many_ms = measure(vec, args.envs, args.seconds, pid)
        finally:
            vec.close()
    finally:
        if server is not None:
            server.stop()
    result = {"env_steps_per_s_1": one, f"env_steps_per_s_{args.envs}": many,
              "reference_steps_per_s": REFERENCE_STEPS_PER_S,
              "ratio_1": one / REFERENCE_STEPS_PER_S, f"ratio_{args.envs}": many / REFERENCE_STEPS_PER_S,
              "env_steps_per_cpu_s_1": one_cpu, f"env_steps_per_cpu_s_{args.envs}": many_cpu,
              "cpu_ms_per_step_1": one_ms, f"cpu_ms_per_step_{args.envs}": many_ms}
    print(f"| envs | env-steps/s | vs f1tenth_gym ({REFERENCE_STEPS_PER_S:.0f}/s) |")
    print("|---:|---:|---:|")
    print(f"| 1 | {one:,.0f} | {one / REFERENCE_STEPS_PER_S:.2f}x |")
    print(f"| {args.envs} | {many:,.0f} | {many / REFERENCE_STEPS_PER_S:.2f}x |")
    if pid is not None or endpoint == paddock.IN_PROCESS:
        print(f"per CPU-second of client and server: 1 env {one_cpu:,.0f}, "
              f"{args.envs} envs {many_cpu:,.0f} env-steps")
        print(f"CPU ms per {args.envs}-env step: " +
              ", ".join(f"{k} {v:.3f}" for k, v in sorted(many_ms.items())))
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
