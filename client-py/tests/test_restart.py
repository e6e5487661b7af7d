"""A broker restart loses no batch rollout (issue 17, item 5).

A real `paddock serve` is killed (SIGKILL) while ``Client.rollouts`` runs and started
again on the same endpoint and state directory: the client finds another broker instance
answering, sends the batch again and returns the same results as an uninterrupted run. A
server killed for good raises :class:`paddock.errors.BrokerNotAnswering` (a transport
error naming the endpoint) within seconds, not a scenario error after the batch's wait.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from paddock import Client, errors
from paddock.resume import RESEND, ResumePolicy, Watch
from paddock.server import find_paddock, free_port, stop_process
from paddock.transport import Connection

DRIVER = "follow-the-gap"
SEEDS = list(range(6))
TIME_LIMIT = 6.0


class Serve:
    """`paddock serve` on a fixed endpoint and state directory, restartable."""

    def __init__(self, state: str) -> None:
        self.endpoint = f"tcp://127.0.0.1:{free_port()}"
        self.state = state
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.process = subprocess.Popen(
            [find_paddock(), "serve", "--bind", self.endpoint, "--state", self.state, "--threads", "2", "--parent-pid", str(os.getpid())],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        with Connection(self.endpoint, timeout=1.0) as c:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                assert self.process.poll() is None, "paddock serve exited"
                with contextlib.suppress(errors.BrokerUnavailable):
                    if len(c.status().workers) > 0:
                        return
                time.sleep(0.1)
        pytest.fail(f"paddock serve at {self.endpoint} had no worker after 60 s")

    def kill9(self) -> None:
        assert self.process is not None
        self.process.send_signal(signal.SIGKILL)
        self.process.wait()

    def stop(self) -> None:
        if self.process is not None:
            stop_process(self.process)


@contextlib.contextmanager
def serve() -> Iterator[Serve]:
    with tempfile.TemporaryDirectory() as state:
        s = Serve(state)
        s.start()
        try:
            yield s
        finally:
            s.stop()


def _params() -> np.ndarray:
    from paddock import driver_defaults

    default, lo, hi = driver_defaults(DRIVER)
    return np.stack([lo + (hi - lo) * f for f in (0.3, 0.5, 0.7)])


def _run_in_thread(client: Client, params: np.ndarray) -> tuple[threading.Thread, dict]:
    out: dict = {}

    def run() -> None:
        try:
            out["results"] = client.rollouts(DRIVER, params, SEEDS, time_limit=TIME_LIMIT)
        except Exception as e:  # noqa: BLE001 - handed to the test's thread
            out["error"] = e
        out["ended"] = time.monotonic()

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t, out


def _tasks_done(endpoint: str) -> int:
    with Connection(endpoint, timeout=5.0) as c:
        return int(c.status().tasks_done)


def _wait_mid_batch(endpoint: str, t: threading.Thread, before: int) -> None:
    """Until the server has run some of the batch's tasks (more than ``before + 1`` in
    all) and has some left."""
    with Connection(endpoint, timeout=2.0) as c:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert t.is_alive(), "the batch ended before the server could be killed: make it longer"
            with contextlib.suppress(errors.BrokerUnavailable):
                s = c.status()
                if s.tasks_done >= before + 2 and s.queue_depth + s.tasks_in_flight > 0:
                    return
            time.sleep(0.02)
    pytest.fail("the batch never ran on the server")


def test_rollouts_outlive_a_server_killed_mid_batch_and_restarted() -> None:
    params = _params()
    with serve() as s:
        with Client(s.endpoint, timeout=5.0) as client:
            expected = client.rollouts(DRIVER, params, SEEDS, time_limit=TIME_LIMIT)
        before = _tasks_done(s.endpoint)
        with Client(s.endpoint, timeout=5.0) as client:
            t, out = _run_in_thread(client, params)
            _wait_mid_batch(s.endpoint, t, before)
            s.kill9()
            s.start()
            t.join(120)
            assert not t.is_alive(), "the batch did not end after the restart"
            assert "error" not in out, f"the batch failed: {out.get('error')!r}"
    got = out["results"]
    assert [e.SerializeToString() for e in got.episodes] == \
        [e.SerializeToString() for e in expected.episodes], "results differ after the restart"
    np.testing.assert_array_equal(got.lap_time, expected.lap_time)


def test_rollouts_raise_broker_not_answering_when_the_server_is_gone() -> None:
    params = _params()
    with serve() as s:
        with Client(s.endpoint, timeout=3.0) as client:
            t, out = _run_in_thread(client, params)
            _wait_mid_batch(s.endpoint, t, 0)
            s.kill9()
            killed = time.monotonic()
            t.join(60)
            assert not t.is_alive(), "the client still waits a minute after the server died"
    e = out.get("error")
    assert isinstance(e, errors.BrokerNotAnswering), repr(e)
    assert isinstance(e, errors.BrokerUnavailable)
    assert s.endpoint in str(e) and "does not answer" in str(e), str(e)
    # quiet (3 s) + the client's timeout (3 s), and slack for a loaded machine
    assert out["ended"] - killed < 20, f"took {out['ended'] - killed:.1f} s"


def test_watch_sends_again_when_another_instance_answers() -> None:
    w = Watch(ResumePolicy(quiet=3, answer_within=10, ping_every=1, max_resends=1), 0.0)
    w.opened(0.0, "a")
    assert w.next(2.0) == ("wait", 1.0)
    assert w.next(3.0) == ("ping", 0.0)
    assert w.answered(3.5, "a") == "alive"
    assert w.next(6.5) == ("ping", 0.0)
    assert w.answered(7.0, "b") == RESEND
    w.resent(7.0)
    assert w.next(10.0) == ("ping", 0.0)
    assert w.answered(10.0, "c") == "give_up"
    # nobody answers: given up answer_within after the first ping, pinging every second
    w = Watch(ResumePolicy(quiet=3, answer_within=10, ping_every=1), 0.0)
    steps = [w.next(float(t)) for t in range(3, 14)]
    assert [s for s, _ in steps].count("ping") == 10
    assert steps[-1] == ("not_answering", 10)
