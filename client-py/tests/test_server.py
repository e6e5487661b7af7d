"""The local server's endpoint: an abstract Unix domain socket on Linux, loopback TCP when
asked (or elsewhere), and a clear error for a transport that is not one."""

from __future__ import annotations

import gc
import sys

import pytest

from paddock import LocalServer, errors
from paddock import server as server_module
from paddock.server import local_endpoint
from paddock.transport import Connection

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="abstract sockets are Linux's")


def workers(endpoint: str) -> int:
    with Connection(endpoint, timeout=5.0) as c:
        return len(c.status(timeout=5.0).workers)


@linux
def test_the_default_is_an_abstract_socket_that_serves(server: LocalServer) -> None:
    # the session's server (every other test's) was started with the defaults
    assert server.endpoint.startswith("ipc://@paddock-"), server.endpoint
    assert workers(server.endpoint) > 0


def test_tcp_when_asked_serves_on_loopback() -> None:
    with LocalServer(threads=1, transport="tcp") as s:
        assert s.endpoint.startswith("tcp://127.0.0.1:"), s.endpoint
        assert workers(s.endpoint) > 0


@linux
def test_each_endpoint_is_new() -> None:
    a, b = local_endpoint(), local_endpoint("ipc")
    assert a != b and a.startswith("ipc://@") and b.startswith("ipc://@")
    assert local_endpoint("tcp").startswith("tcp://127.0.0.1:")


def test_an_unknown_transport_is_refused_by_name() -> None:
    for bad in ("udp", "", "IPC"):
        with pytest.raises(ValueError, match=f"transport = {bad!r} is not one of auto, ipc, tcp"):
            LocalServer(transport=bad)
        with pytest.raises(ValueError, match="is not one of"):
            local_endpoint(bad)


def test_a_server_refused_when_made_leaves_nothing_behind(monkeypatch: pytest.MonkeyPatch) -> None:
    # A refused transport, or no binary, ends `LocalServer(...)` before it has a process:
    # collecting what was made must not print an error of its own to the user's stderr.
    ignored: list[str] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: ignored.append(repr(u.exc_value)))
    with pytest.raises(ValueError, match="is not one of"):
        LocalServer(transport="udp")

    def no_binary() -> str:
        raise errors.ServerStartError("no `paddock` binary")

    monkeypatch.setattr(server_module, "find_paddock", no_binary)
    with pytest.raises(errors.ServerStartError, match="no `paddock` binary"):
        LocalServer()
    gc.collect()
    assert ignored == []


def test_envs_made_without_an_endpoint_share_one_local_serve() -> None:
    """Envs with ``endpoint=None`` (a gymnasium SyncVectorEnv's, say) share this process's
    local server per thread count, each with its own session; the last one closed stops
    it, and one that ended is started again for the next env."""
    import gymnasium as gym
    import numpy as np

    import paddock  # noqa: F401  (registers the env)

    def make(threads: int):
        return gym.make("paddock/F110-v0", endpoint=None, num_beams=16, threads=threads)

    envs = [make(1) for _ in range(3)]
    other = make(2)
    try:
        servers = [e.unwrapped._owned.server for e in envs]
        assert servers[0] is servers[1] is servers[2] and servers[0].running()
        assert other.unwrapped._owned.server is not servers[0]
        # each env its own session: the same seed, the same start; steps apart
        first = [e.reset(seed=4)[0]["scans"] for e in envs]
        assert all(np.array_equal(f, first[0]) for f in first)
        envs[0].step(np.array([0.0, 3.0], dtype=np.float32))
        assert np.array_equal(envs[1].step(np.array([0.0, 1.0], dtype=np.float32))[0]["scans"],
                              envs[2].step(np.array([0.0, 1.0], dtype=np.float32))[0]["scans"])
        process = servers[0].process
        envs[0].close()
        envs[1].close()
        assert process.poll() is None, "two envs closed, one still holds the server"
        assert envs[2].reset(seed=4)[0]["scans"].shape == (1, 16)
        envs[2].close()
        process.wait(timeout=30)  # the last holder stopped it
        # a server that ended is started again for the next env
        again = make(1)
        try:
            assert again.unwrapped._owned.server is not servers[0]
            again.unwrapped._owned.server.process.kill()
            again.unwrapped._owned.server.process.wait(timeout=30)
            fresh = make(1)
            try:
                assert fresh.unwrapped._owned.server.running()
                assert fresh.reset(seed=4)[0]["scans"].shape == (1, 16)
            finally:
                fresh.close()
        finally:
            again.close()
    finally:
        for e in envs + [other]:
            e.close()


def test_a_forked_childs_copy_of_a_server_leaves_it_running() -> None:
    """``stop()`` (or the garbage collector) on a forked child's copy of a LocalServer
    stopped the parent's server; only the process that started it stops it now."""
    import os

    with LocalServer(threads=1) as s:
        pid = os.fork()
        if pid == 0:  # the child: its copy of `s`, stopped, then collected
            try:
                s.stop()
            finally:
                os._exit(0)
        os.waitpid(pid, 0)
        assert s.running() and workers(s.endpoint) > 0
