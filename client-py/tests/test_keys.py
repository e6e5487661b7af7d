"""A broker that requires CURVE keys: the Python client gets in with the keys named by
PADDOCK_KEY_FILE / PADDOCK_BROKER_KEY_FILE (as the CLI does) and not without them."""

from __future__ import annotations

import os
import subprocess
import tempfile
import time

import pytest

import paddock
from paddock import errors
from paddock.server import find_paddock, free_port
from paddock.transport import Connection


def test_client_with_keys_gets_in_and_without_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    binary = find_paddock()
    front, back = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as d:
        keys = os.path.join(d, "keys")
        subprocess.run([binary, "keys", "generate", "--out", keys], check=True,
                       stdout=subprocess.DEVNULL)
        broker = subprocess.Popen(
            [binary, "broker", "--bind", front, "--worker-bind", back, "--state", os.path.join(d, "state"),
             "--secret-key", os.path.join(keys, "broker.key"),
             "--client-keys", os.path.join(keys, "clients"),
             "--worker-keys", os.path.join(keys, "workers")],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        worker = subprocess.Popen(
            [binary, "worker", "--connect", back, "--threads", "1",
             "--key", os.path.join(keys, "worker.key"),
             "--broker-key", os.path.join(keys, "broker.pub")],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            # no keys: the handshake never completes, so the request times out
            monkeypatch.delenv("PADDOCK_KEY_FILE", raising=False)
            monkeypatch.delenv("PADDOCK_BROKER_KEY_FILE", raising=False)
            with Connection(front, timeout=1.5) as c:
                with pytest.raises(errors.BrokerUnavailable):
                    c.status()
            monkeypatch.setenv("PADDOCK_KEY_FILE", os.path.join(keys, "client.key"))
            monkeypatch.setenv("PADDOCK_BROKER_KEY_FILE", os.path.join(keys, "broker.pub"))
            with Connection(front, timeout=1.0) as c:
                deadline = time.monotonic() + 30
                while True:
                    try:
                        if len(c.status().workers) == 1:
                            break
                    except errors.BrokerUnavailable:
                        pass
                    assert time.monotonic() < deadline, "the keyed worker never registered"
                    time.sleep(0.1)
            with paddock.Client(front, timeout=60) as client:
                r = client.rollouts("pure-pursuit", paddock.driver_defaults("pure-pursuit")[0],
                                    seeds=[1, 2], map="lakeside")
                assert r.progress.shape == (1, 2)
            # a key file that is not one
            bad = os.path.join(d, "bad.key")
            with open(bad, "w", encoding="utf-8") as f:
                f.write('public = "short"\n')
            monkeypatch.setenv("PADDOCK_KEY_FILE", bad)
            with pytest.raises(errors.PaddockError, match="bad.key"):
                Connection(front, timeout=1.0)
        finally:
            for p in (worker, broker):
                p.kill()
                p.wait()
