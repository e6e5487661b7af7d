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
