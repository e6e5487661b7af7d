"""Fixtures: one real `paddock serve` (broker + workers) for the whole test run, started
as learners start it (on Linux on an abstract Unix domain socket, else on a free loopback
port), stopped at the end."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from paddock import Client, LocalServer


@pytest.fixture(scope="session")
def server() -> Iterator[LocalServer]:
    threads = int(os.environ.get("PADDOCK_TEST_THREADS", "2"))
    s = LocalServer(threads=threads).start()
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture(scope="session")
def endpoint(server: LocalServer) -> str:
    return server.endpoint


@pytest.fixture()
def client(endpoint: str) -> Iterator[Client]:
    c = Client(endpoint)
    try:
        yield c
    finally:
        c.close()
