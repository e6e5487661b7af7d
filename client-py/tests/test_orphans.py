"""No orphans: the `paddock serve` an env starts for itself (endpoint=None) ends when the
learner's process ends, even when that process is killed with SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

PARENT = textwrap.dedent("""
    import sys, time
    import gymnasium as gym
    import paddock  # registers the envs
    env = gym.make("paddock/F110-v0", num_beams=108, time_limit=5.0, threads=1)
    env.reset(seed=1)
    env.step(env.action_space.sample())
    print(env.unwrapped._owned.server.process.pid, flush=True)
    time.sleep(600)
""")


def gone(pid: int) -> bool:
    """Whether process ``pid`` has exited (a zombie nobody reaped counts as exited)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True
    return stat.rsplit(")", 1)[1].split()[0] in ("Z", "X")


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_serve_ends_with_its_parent(tmp_path: Path, sig: signal.Signals) -> None:
    script = tmp_path / "learner.py"
    script.write_text(PARENT)
    err = tmp_path / "learner.err"
    with open(err, "wb") as errf:
        learner = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path,
                                   stdout=subprocess.PIPE, stderr=errf)
    serve = 0
    try:
        assert learner.stdout is not None
        line = learner.stdout.readline()
        assert line.strip(), f"the learner did not start its env: {err.read_text()[-3000:]}"
        serve = int(line)
        assert not gone(serve), "the server runs while its learner does"
        os.kill(learner.pid, sig)
        learner.wait(timeout=30)
        deadline = time.monotonic() + 15.0
        while not gone(serve) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert gone(serve), f"`paddock serve` (pid {serve}) outlived its killed parent"
    finally:
        if learner.poll() is None:
            learner.kill()
            learner.wait()
        if serve and not gone(serve):
            os.kill(serve, signal.SIGKILL)
