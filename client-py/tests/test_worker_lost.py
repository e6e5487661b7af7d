"""A worker killed mid-episode: the env raises SessionLost (naming the lost session)
instead of hanging, once the broker has declared the worker dead."""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import time

import numpy as np
import pytest

import paddock
from paddock import errors
from paddock.server import find_paddock, free_port
from paddock.transport import Connection


def test_worker_killed_mid_episode_raises_session_lost() -> None:
    binary = find_paddock()
    front, back = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as state:
        broker = subprocess.Popen([binary, "broker", "--bind", front, "--workers", back,
                                   "--state", state], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        worker = subprocess.Popen([binary, "worker", "--connect", back, "--threads", "1",
                                   "--maps", os.path.join(state, "worker-maps")],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            with Connection(front, timeout=1.0) as c:
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline:
                    try:
                        if len(c.status().workers) > 0:
                            break
                    except errors.BrokerUnavailable:
                        pass
                    time.sleep(0.1)
                else:
                    pytest.fail("the worker never registered")
            env = paddock.F110Env(front, num_beams=32, timeout=20.0)
            env.reset(seed=1)
            env.step(np.array([0.0, 1.0], dtype=np.float32))
            worker.send_signal(signal.SIGKILL)
            worker.wait()
            t0 = time.monotonic()
            with pytest.raises(errors.SessionLost, match="lost"):
                for _ in range(100):
                    env.step(np.array([0.0, 1.0], dtype=np.float32))
            assert time.monotonic() - t0 < 15.0
            env.close()
        finally:
            for p in (worker, broker):
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
                    try:
                        p.wait(timeout=10)
                    except subprocess.TimeoutExpired:
                        p.kill()
                        p.wait()
