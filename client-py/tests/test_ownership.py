"""Jobs belong to the client that submitted them: on a broker without CURVE keys a client
is its client token (a private file the client makes on first use), so another token
neither lists nor reaches them; the owner deletes its job."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from paddock import Client
from paddock import errors
from paddock.transport import client_token


def _client(endpoint: str, token_file: Path, monkeypatch: pytest.MonkeyPatch) -> Client:
    monkeypatch.setenv("PADDOCK_CLIENT_TOKEN_FILE", str(token_file))
    return Client(endpoint)


def test_the_token_file_is_private_and_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "cfg" / "client-token"
    monkeypatch.setenv("PADDOCK_CLIENT_TOKEN_FILE", str(path))
    first = client_token()
    assert len(first) == 32
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert client_token() == first
    path.write_text("not hex\n")
    with pytest.raises(errors.PaddockError, match="client token file"):
        client_token()


def test_jobs_are_their_owners(endpoint: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    alice = _client(endpoint, tmp_path / "alice", monkeypatch)
    bob = _client(endpoint, tmp_path / "bob", monkeypatch)
    try:
        job = alice.submit_tune("pure-pursuit", generations=1, popsize=2, seeds=1, holdout=1, seed=3)
        assert job.job_id.startswith("job-") and len(job.job_id) == 36
        assert any(j.job_id == job.job_id for j in alice.jobs())
        assert all(j.job_id != job.job_id for j in bob.jobs())
        with pytest.raises(errors.PaddockError, match="no such job"):
            bob.job(job.job_id).status()
        with pytest.raises(errors.PaddockError, match="no such job"):
            bob.job(job.job_id).delete()
        job.delete()
        assert all(j.job_id != job.job_id for j in alice.jobs())
        with pytest.raises(errors.PaddockError, match="no such job"):
            job.status()
    finally:
        alice.close()
        bob.close()
