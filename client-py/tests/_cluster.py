"""A real `paddock broker` and `paddock worker` processes on loopback, for the tests that
need workers in processes of their own (a worker killed, models fetched by workers)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
import time
from collections.abc import Iterator

import pytest

from paddock import errors
from paddock.server import find_paddock, free_port, stop_process
from paddock.transport import Connection


@contextlib.contextmanager
def cluster(workers: int) -> Iterator[tuple[str, list[subprocess.Popen]]]:
    """A `paddock broker` and `workers` `paddock worker` processes on loopback."""
    binary = find_paddock()
    front, back = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as state:
        broker = subprocess.Popen([binary, "broker", "--bind", front, "--worker-bind", back,
                                   "--state", state], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        procs = [subprocess.Popen([binary, "worker", "--connect", back, "--threads", "1",
                                   "--maps", os.path.join(state, f"worker-maps-{i}")],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                 for i in range(workers)]
        try:
            with Connection(front, timeout=1.0) as c:
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline:
                    try:
                        if len(c.status().workers) == workers:
                            break
                    except errors.BrokerUnavailable:
                        pass
                    time.sleep(0.1)
                else:
                    pytest.fail(f"{workers} workers never registered")
            yield front, procs
        finally:
            for p in [*procs, broker]:
                stop_process(p)
