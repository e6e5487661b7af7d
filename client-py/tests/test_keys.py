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
from paddock.transport import Connection, _read_keys, fingerprint


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
            # a key the broker does not know: refused at once, with its fingerprint
            stranger = os.path.join(d, "stranger")
            subprocess.run([binary, "keys", "generate", "--role", "client", "--out", stranger],
                           check=True, stdout=subprocess.DEVNULL)
            stranger_key = os.path.join(stranger, "client.key")
            monkeypatch.setenv("PADDOCK_KEY_FILE", stranger_key)
            with Connection(front, timeout=30.0) as c:
                with pytest.raises(errors.KeyRefused) as refused:
                    c.status()
            assert fingerprint(_read_keys(stranger_key)["public"]) in str(refused.value)
            assert "refused this client's key" in str(refused.value)
            # refused before the first request (the handshake fails while the client is
            # idle, and the connection is gone when it sends): still said at once. Idle for
            # different times: ZeroMQ keeps reconnecting, each attempt refused, so the
            # request can meet a connection being set up or one just refused (a send that
            # polled writable then found no connection waited its whole timeout: 11 of 40
            # tries with both cores busy before the send watched the handshake too)
            for idle in [0.5, 0.13, 0.04, 0.005, 0.0] * 2:
                with Connection(front, timeout=30.0) as c:
                    time.sleep(idle)
                    started = time.monotonic()
                    with pytest.raises(errors.KeyRefused):
                        c.status()
                    assert time.monotonic() - started < 10, "the refusal waited for the timeout"
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


def _write(path: str, text: str) -> str:
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    return path


def test_bad_key_files_are_refused_naming_file_and_field() -> None:
    import zmq

    public, secret = (k.decode() for k in zmq.curve_keypair())
    other_public, other_secret = (k.decode() for k in zmq.curve_keypair())
    with tempfile.TemporaryDirectory() as d:
        bad_z85 = _write(os.path.join(d, "z85.key"),
                         f'public = "{public}"\nsecret = "~~~~{secret[4:]}"\n')
        with pytest.raises(errors.PaddockError, match=r"z85\.key.*`secret`.*Z85 alphabet") as e:
            _read_keys(bad_z85)
        assert secret[4:] not in str(e.value)
        short = _write(os.path.join(d, "short.key"), f'public = "{public[:39]}"\n')
        with pytest.raises(errors.PaddockError, match=r"short\.key.*`public`.*39 characters"):
            _read_keys(short)
        spliced = _write(os.path.join(d, "spliced.key"),
                         f'public = "{public}"\nsecret = "{other_secret}"\n')
        with pytest.raises(errors.PaddockError, match="different key pairs") as e:
            _read_keys(spliced)
        assert other_secret not in str(e.value)
        good = _write(os.path.join(d, "good.key"),
                      f'public = "{other_public}"\nsecret = "{other_secret}"\n')
        assert _read_keys(good)["public"] == other_public.encode()
