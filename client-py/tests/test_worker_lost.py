"""A worker killed mid-episode.

With another worker connected, the broker rebuilds the session there by replaying its
log: the episode goes on, only delayed, and its observations are bit-identical to an
uninterrupted run. With no other worker, the env raises SessionLost (naming the lost
session) instead of hanging, once the broker has declared the worker dead.
"""

from __future__ import annotations

import signal
import subprocess
import time

import numpy as np
import pytest

import paddock
from _cluster import cluster
from paddock import errors
from paddock.transport import Connection

ACTION = np.array([0.05, 1.5], dtype=np.float32)


def _hosting_worker(front: str, procs: list[subprocess.Popen]) -> subprocess.Popen:
    """The worker process that hosts the one open session (worker ids name the pid)."""
    with Connection(front, timeout=5.0) as c:
        hosts = [w for w in c.status().workers if w.env_sessions == 1]
    assert len(hosts) == 1, hosts
    for p in procs:
        if f"-{p.pid}-" in hosts[0].worker_id:
            return p
    pytest.fail(f"no worker process matches {hosts[0].worker_id}")


def _observations(env: paddock.F110Env, steps: int, kill_after: int | None = None,
                  kill=None) -> list[dict[str, np.ndarray]]:
    obs, _ = env.reset(seed=7)
    out = [obs]
    for k in range(steps):
        if k == kill_after and kill is not None:
            kill()
        obs, _, terminated, truncated, _ = env.step(ACTION)
        out.append(obs)
        assert not (terminated or truncated), f"the episode ended at step {k}"
    return out


def test_worker_killed_mid_episode_the_session_moves_to_another_worker() -> None:
    with cluster(2) as (front, procs):
        env = paddock.F110Env(front, num_beams=32, timeout=20.0)
        victim = _hosting_worker(front, procs)

        def kill() -> None:
            victim.send_signal(signal.SIGKILL)
            victim.wait()

        got = _observations(env, 40, kill_after=25, kill=kill)
        with Connection(front, timeout=5.0) as c:
            status = c.status()
        assert status.sessions_replayed == 1
        assert status.sessions_lost == 0
        assert len(status.workers) == 1 and status.workers[0].env_sessions == 1
        env.close()
        # the same seed and actions in a fresh session, never interrupted
        again = paddock.F110Env(front, num_beams=32, timeout=20.0)
        want = _observations(again, 40)
        again.close()
        assert len(got) == len(want)
        for k, (a, b) in enumerate(zip(got, want)):
            for key in b:
                assert np.array_equal(a[key], b[key]), f"step {k}: {key} differs"
                assert a[key].tobytes() == b[key].tobytes(), f"step {k}: {key} bits differ"


def test_worker_killed_with_no_other_worker_raises_session_lost() -> None:
    with cluster(1) as (front, procs):
        env = paddock.F110Env(front, num_beams=32, timeout=20.0)
        env.reset(seed=1)
        env.step(ACTION)
        procs[0].send_signal(signal.SIGKILL)
        procs[0].wait()
        t0 = time.monotonic()
        with pytest.raises(errors.SessionLost, match="lost"):
            for _ in range(100):
                env.step(ACTION)
        # 3 s until the worker is declared dead, then 5 s for another worker
        assert time.monotonic() - t0 < 15.0
        with Connection(front, timeout=5.0) as c:
            assert c.status().sessions_lost == 1
        env.close()
