"""The gymnasium env and vector env against a real broker and worker."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import paddock
from paddock import errors
from paddock._proto import paddock_pb2 as pb
from paddock.server import free_port
from paddock.transport import Connection

SMALL = {"num_beams": 108, "time_limit": 20.0}


def test_check_env_passes(endpoint: str) -> None:
    env = gym.make("paddock/F110-v0", endpoint=endpoint, map="lakeside", num_agents=2, **SMALL)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, info = env.reset(seed=3)
        assert set(obs) == set(paddock.env.OBS_KEYS)
        assert obs["scans"].shape == (1, 108) and obs["scans"].dtype == np.float32
        assert obs["poses_x"].shape == (2,)
        assert env.observation_space.contains(obs)
        assert env.action_space.shape == (2,)
    finally:
        env.close()


def test_same_seed_same_observations(endpoint: str) -> None:
    def run() -> list[dict[str, np.ndarray]]:
        env = gym.make("paddock/F110-v0", endpoint=endpoint, **SMALL)
        try:
            out = [env.reset(seed=42)[0]]
            for k in range(30):
                out.append(env.step(np.array([0.1 * np.sin(k / 5), 2.0], dtype=np.float32))[0])
            return out
        finally:
            env.close()

    a, b = run(), run()
    for x, y in zip(a, b):
        for key in x:
            np.testing.assert_array_equal(x[key], y[key])
    # another seed starts elsewhere
    env = gym.make("paddock/F110-v0", endpoint=endpoint, **SMALL)
    try:
        other = env.reset(seed=43)[0]
    finally:
        env.close()
    assert other["poses_x"][0] != a[0]["poses_x"][0]
    # the car moved
    assert a[-1]["linear_vels_x"][0] > 0.5


def test_vector_env_shapes_and_next_step_autoreset(endpoint: str) -> None:
    n = 4
    env = gym.make_vec("paddock/F110-v0", num_envs=n, endpoint=endpoint, num_beams=64,
                       time_limit=0.2, frame_skip=5)
    try:
        assert env.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
        obs, info = env.reset(seed=7)
        assert obs["scans"].shape == (n, 1, 64)
        assert obs["poses_x"].shape == (n, 1)
        assert env.observation_space.contains(obs)
        assert env.action_space.shape == (n, 2)
        actions = np.tile(np.array([0.0, 1.0], dtype=np.float32), (n, 1))
        for k in range(4):
            obs, rew, term, trunc, info = env.step(actions)
            assert rew.shape == (n,) and term.shape == (n,) and trunc.shape == (n,)
        assert trunc.all() and not term.any()
        np.testing.assert_allclose(info["time"], 0.2)
        # the next step resets every env instead of stepping it
        obs, rew, term, trunc, info = env.step(actions)
        assert not trunc.any()
        np.testing.assert_array_equal(rew, 0.0)
        np.testing.assert_array_equal(info["time"], 0.0)
        obs, rew, term, trunc, info = env.step(actions)
        np.testing.assert_allclose(info["time"], 0.05)
        # envs of a vector env with seeds s + i equal single envs seeded s + i
        obs, _ = env.reset(seed=100)
        single = gym.make("paddock/F110-v0", endpoint=endpoint, num_beams=64, time_limit=0.2,
                          frame_skip=5)
        try:
            o2, _ = single.reset(seed=102)
        finally:
            single.close()
        np.testing.assert_array_equal(obs["scans"][2], o2["scans"])
        np.testing.assert_array_equal(obs["poses_theta"][2], o2["poses_theta"])
    finally:
        env.close()


def test_make_vec_partial_reset_and_poses(endpoint: str) -> None:
    env = paddock.make_vec(2, endpoint, num_beams=32)
    try:
        obs, _ = env.reset(seed=1)
        x, y, th = obs["poses_x"][1, 0], obs["poses_y"][1, 0], obs["poses_theta"][1, 0]
        env.step(np.array([[0.0, 2.0], [0.0, 2.0]]))
        obs, info = env.reset(options={"reset_mask": np.array([False, True]),
                                       "poses": [[[x, y, th + 0.05]]]})
        assert obs["poses_theta"][1, 0] == pytest.approx(th + 0.05)
        assert info["time"][1] == 0.0 and info["time"][0] > 0.0
    finally:
        env.close()


def test_bad_actions(endpoint: str) -> None:
    env = gym.make("paddock/F110-v0", endpoint=endpoint, **SMALL)
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="shape"):
            env.step(np.zeros(3, dtype=np.float32))
        with pytest.raises(errors.InvalidArgument) as e:
            env.step(np.array([0.0, np.nan], dtype=np.float32))
        assert e.value.field == "env_step.actions[1]"
        assert "NaN" in str(e.value)
        # the session goes on after a refused step
        env.step(np.array([0.0, 1.0], dtype=np.float32))
    finally:
        env.close()
    vec = paddock.make_vec(3, endpoint, num_beams=16)
    try:
        vec.reset(seed=0)
        with pytest.raises(ValueError, match=r"\(3, 2\)"):
            vec.step(np.zeros((2, 2)))
        # raw bytes of the wrong size: the worker names the field and the byte counts
        with pytest.raises(errors.InvalidArgument) as e:
            vec.unwrapped.session.step(np.zeros(5, dtype=np.float32))
        assert e.value.field == "env_step.actions"
        assert "24 bytes" in e.value.message and "20 bytes" in e.value.message
    finally:
        vec.close()


def test_unknown_map_and_driver(endpoint: str) -> None:
    with pytest.raises(FileNotFoundError, match="no-such-map"):
        gym.make("paddock/F110-v0", endpoint=endpoint, map="no-such-map")
    with pytest.raises(errors.InvalidArgument) as e:
        gym.make("paddock/F110-v0", endpoint=endpoint, num_agents=2, opponents=["nobody"])
    assert e.value.field == "env_open.opponents[0].driver"
    assert "nobody" in e.value.message
    # a map hash the broker never received
    with Connection(endpoint, timeout=10) as c:
        with pytest.raises(errors.NotFound) as e:
            c.env(0, pb.ENV_OPEN, pb.EnvOpen(map=pb.MapRef(name="x", hash="ab" * 32), num_envs=1,
                                             laps=1, time_limit=10, frame_skip=1))
        assert e.value.field == "env_open.map.hash"
        with pytest.raises(errors.NotFound) as e:
            c.env(987654, pb.ENV_STEP, pb.EnvStep())
        assert e.value.field == "env_request.session_id"


def test_broker_down_raises_naming_the_endpoint() -> None:
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    with pytest.raises(errors.BrokerUnavailable, match=endpoint.replace(".", r"\.")):
        gym.make("paddock/F110-v0", endpoint=endpoint, timeout=0.5)
    assert time.monotonic() - t0 < 5.0


def test_endpoint_none_starts_and_stops_a_local_serve() -> None:
    env = gym.make("paddock/F110-v0", endpoint=None, num_beams=16, threads=1)
    server = env.unwrapped._owned.server
    assert server is not None and server.process is not None
    process = server.process
    assert process.poll() is None
    obs, _ = env.reset(seed=0)
    assert obs["scans"].shape == (1, 16)
    env.close()
    assert process.poll() is not None, "close() stops the local serve"


def test_one_envs_observation_is_its_rows_of_every_envs() -> None:
    """`Frame.obs(i)` (what the single env returns) holds env i's rows of `Frame.obs()`
    (what the vector env returns), key by key, as views of the same arrays."""
    n, cars, learners, beams = 3, 2, 1, 5
    rng = np.random.default_rng(0)
    f = paddock.env.Frame(
        scans=rng.random((n, learners, beams), dtype=np.float32),
        states=rng.random((n, cars, 7)), learner_rewards=rng.random((n, learners)),
        learner_terminated=np.zeros((n, learners), bool), truncated=np.zeros(n, bool),
        learner_progress=rng.random((n, learners)), learner_laps=np.ones((n, learners), np.uint32),
        time=rng.random(n), collisions=rng.random((n, cars)),
        lap_counts=np.arange(n * cars, dtype=np.int32).reshape(n, cars),
        lap_times=rng.random((n, cars)))
    every = f.obs()
    assert list(every) == list(paddock.env.OBS_KEYS)
    for i in range(n):
        one = f.obs(i)
        assert list(one) == list(every)
        for k, v in one.items():
            assert v.shape == every[k].shape[1:], k
            np.testing.assert_array_equal(v, every[k][i], err_msg=k)
            assert np.shares_memory(v, every[k]), k
