"""Batch rollouts and jobs through the broker."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import paddock
from paddock import Client, errors


def test_rollouts_in_task_order_and_deterministic(client: Client) -> None:
    defaults, lo, hi = paddock.driver_defaults("pure-pursuit")
    slow = defaults.copy()
    slow[2] = lo[2]  # lowest lateral acceleration: a slower lap
    params = np.stack([defaults, slow])
    r = client.rollouts("pure-pursuit", params, seeds=[1, 2, 3], time_limit=60.0)
    assert r.lap_time.shape == (2, 3)
    assert r.finished.all() and not r.crashed.any()
    assert (r.lap_time[1] > r.lap_time[0]).all(), r.lap_time
    assert [e.seed for e in r.episodes] == [1, 2, 3, 1, 2, 3]
    again = client.rollouts("pure-pursuit", params[::-1], seeds=[1, 2, 3], time_limit=60.0)
    np.testing.assert_array_equal(again.lap_time, r.lap_time[::-1])
    np.testing.assert_array_equal(again.progress, r.progress[::-1])


def test_rollout_errors_name_the_field(client: Client) -> None:
    defaults, _, hi = paddock.driver_defaults("pure-pursuit")
    bad = defaults.copy()
    bad[1] = hi[1] * 10
    with pytest.raises(errors.InvalidArgument) as e:
        client.rollouts("pure-pursuit", bad, seeds=[1])
    assert "params" in e.value.field
    with pytest.raises(errors.InvalidArgument) as e:
        client.rollouts("no-such-driver", [1.0], seeds=[1])
    assert "driver" in e.value.field or "no-such-driver" in e.value.message
    with pytest.raises(ValueError):
        client.rollouts("pure-pursuit", defaults, seeds=[])
    # whole-number fields the request cannot carry, named (not protobuf's bare "Value out
    # of range")
    with pytest.raises(ValueError, match=r"laps = -1 is out of range"):
        client.rollouts("pure-pursuit", defaults, seeds=[1], laps=-1)
    with pytest.raises(ValueError, match=r"num_beams = 1.5 is not a whole number"):
        client.rollouts("pure-pursuit", defaults, seeds=[1], num_beams=1.5)
    with pytest.raises(ValueError, match=r"popsize = -4 is out of range"):
        client.submit_tune("pure-pursuit", popsize=-4)
    # seeds, each named: they were wrapped modulo 2**64 (-1 ran as 2**64 - 1, 2**64 as 0)
    # and cut to whole numbers (1.5 ran as 1)
    for seeds, said in [([1, -1], r"seeds\[1\] = -1 is out of range: must be a whole number in "
                                  r"\[0, 18446744073709551615\]"),
                        ([2**64], r"seeds\[0\] = 18446744073709551616 is out of range"),
                        (np.array([1.5]), r"seeds\[0\] = 1.5 is not a whole number")]:
        with pytest.raises(ValueError, match=said):
            client.rollouts("pure-pursuit", defaults, seeds=seeds)
    with pytest.raises(ValueError, match=r"seed = -1 is out of range"):
        client.submit_tune("pure-pursuit", seed=-1)
    # a tune job's counts in `paddock tune`'s ranges: a 0 went on the wire as "the
    # default" and ran 60 generations (a crash penalty of 100) unsaid
    for kw, said in [(dict(generations=0), r"generations = 0 is out of range: must be a whole "
                                           r"number in \[1, 10000\]"),
                     (dict(popsize=1), r"popsize = 1 is out of range: must be a whole number in \[2, 1000\]"),
                     (dict(seeds=0), r"seeds = 0 is out of range"),
                     (dict(holdout=10_001), r"holdout = 10001 is out of range"),
                     (dict(crash_penalty=0), r"crash_penalty = 0 is out of range: must be a positive"),
                     (dict(crash_penalty=float("nan")), r"crash_penalty = nan is out of range")]:
        with pytest.raises(ValueError, match=said):
            client.submit_tune("pure-pursuit", **kw)
    # a client is a live connection: pickling one says so (it named a protobuf module)
    with pytest.raises(TypeError, match="cannot be pickled or copied"):
        pickle.dumps(client)


def test_tune_job_runs_to_a_result(client: Client) -> None:
    job = client.submit_tune("pure-pursuit", generations=2, popsize=4, seeds=2, holdout=2, seed=5)
    seen = []
    result = job.wait(progress=seen.append, timeout=120)
    assert isinstance(result, dict) and result
    assert seen and seen[-1].state == "SUCCEEDED"
    assert any(j.job_id == job.job_id for j in client.jobs())
