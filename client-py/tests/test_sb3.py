"""paddock.sb3.VecEnv against Stable-Baselines3's documented VecEnv contract.

SB3 cannot be imported without torch, so the client's tests do not install it: the
adapter then subclasses paddock.sb3.VecEnvContract (SB3's interface in plain Python) and
these checks pin SB3's conventions on it: reset() without arguments and `reset_infos`,
seed() for the next reset, step_async/step_wait, rewards float32, dones = terminated or
truncated, the same-step autoreset with `terminal_observation` and `TimeLimit.truncated`
in the infos, get_attr/set_attr/env_method/env_is_wrapped by index, render() tiling.
With stable-baselines3 installed the same checks run against SB3's own base class.
"""

from __future__ import annotations

import numpy as np
import pytest

import paddock
from paddock import sb3

SMALL = {"num_beams": 108}


def make(endpoint: str, n: int = 3, **kwargs) -> sb3.VecEnv:
    return sb3.VecEnv(n, endpoint, keys=("scans", "linear_vels_x"), **{**SMALL, **kwargs})


def test_spaces_reset_seed_and_step(endpoint: str) -> None:
    env = make(endpoint, time_limit=20.0)
    try:
        base = "stable_baselines3" if sb3.SB3_BASE else "paddock.sb3"
        assert any(c.__module__.startswith(base) for c in type(env).__mro__[1:])
        assert env.num_envs == 3
        assert set(env.observation_space.spaces) == {"scans", "linear_vels_x"}
        assert env.observation_space["scans"].shape == (108,)
        assert env.action_space.shape == (2,)
        assert env.seed(10) == [10, 11, 12]
        obs = env.reset()
        assert obs["scans"].shape == (3, 108) and obs["scans"].dtype == np.float32
        assert obs["linear_vels_x"].shape == (3, 1)
        assert len(env.reset_infos) == 3 and env.reset_infos[0]["time"] == 0.0
        for i in range(3):
            assert env.observation_space.contains({k: v[i] for k, v in obs.items()})
        # the seeds applied once: the same seeds give the same starts, a plain reset not
        env.seed(10)
        again = env.reset()
        np.testing.assert_array_equal(again["scans"], obs["scans"])
        plain = env.reset()
        assert not np.array_equal(plain["scans"], obs["scans"])
        env.seed(10)
        env.reset()
        actions = np.tile(np.array([[0.0, 2.0]], dtype=np.float32), (3, 1))
        env.step_async(actions)
        o1, r1, d1, i1 = env.step_wait()
        assert r1.dtype == np.float32 and r1.shape == (3,)
        assert d1.dtype == np.bool_ and d1.shape == (3,) and not d1.any()
        assert isinstance(i1, list) and len(i1) == 3
        assert all(i["TimeLimit.truncated"] is False for i in i1)
        # plain Python numbers (loggers and Monitor files take them as they are), each env's
        # own: the same values as the frame's arrays read env by env
        for info in i1 + env.reset_infos:
            assert [type(info[key]) for key in ("progress", "laps", "time")] == [float, int, float]
        assert [i["time"] for i in i1] == [0.01] * 3
        assert len({i["progress"] for i in i1}) == 3, "three envs, three starts, three progresses"
        assert o1["linear_vels_x"][0, 0] > 0.0
        # step() is step_async + step_wait, and the env is deterministic per seed
        env.seed(10)
        env.reset()
        o2, r2, d2, _ = env.step(actions)
        np.testing.assert_array_equal(o1["scans"], o2["scans"])
        np.testing.assert_array_equal(r1, r2)
        with pytest.raises(ValueError, match=r"shape \(3, 2\)"):
            env.step(np.zeros((2, 2), dtype=np.float32))
    finally:
        env.close()


def test_same_step_autoreset_gives_the_terminal_observation(endpoint: str) -> None:
    """An env that ends is reset in the same step; its info has the episode's last
    observation, which is the one gymnasium's vector env (next-step autoreset) returns
    for that step."""
    kw = {"time_limit": 0.3, "frame_skip": 5}  # 6 steps to the time limit
    env = make(endpoint, 2, **kw)
    ref = paddock.make_vec(2, endpoint, **{**SMALL, **kw})
    try:
        env.seed(3)
        obs = env.reset()
        ref_obs, _ = ref.reset(seed=3)
        np.testing.assert_array_equal(obs["scans"], ref_obs["scans"][:, 0, :])
        actions = np.array([[0.05, 2.0], [-0.05, 1.0]], dtype=np.float32)
        for k in range(6):
            obs, rew, dones, infos = env.step(actions)
            ref_obs, ref_rew, term, trunc, _ = ref.step(actions)
            np.testing.assert_array_equal(rew, ref_rew.astype(np.float32))
            if k < 5:
                assert not dones.any()
                np.testing.assert_array_equal(obs["scans"], ref_obs["scans"][:, 0, :])
        assert dones.all() and trunc.all() and not term.any()
        for i in range(2):
            assert infos[i]["TimeLimit.truncated"] is True
            last = infos[i]["terminal_observation"]
            np.testing.assert_array_equal(last["scans"], ref_obs["scans"][i, 0, :])
            np.testing.assert_array_equal(last["linear_vels_x"],
                                          ref_obs["linear_vels_x"][i, :1].astype(np.float32))
            # the returned observation starts the next episode
            assert env.reset_infos[i]["time"] == 0.0
            assert not np.array_equal(obs["scans"][i], last["scans"])
        assert obs["linear_vels_x"][:, 0].tolist() == [0.0, 0.0]
    finally:
        env.close()
        ref.close()


def test_a_crash_is_not_a_truncation(endpoint: str) -> None:
    env = make(endpoint, 1, time_limit=30.0)
    try:
        env.seed(1)
        env.reset()
        for _ in range(3000):
            obs, rew, dones, infos = env.step(np.array([[0.4, 8.0]], dtype=np.float32))
            if dones[0]:
                break
        assert dones[0]
        assert infos[0]["TimeLimit.truncated"] is False
        assert rew[0] < -5.0  # the collision penalty
        assert "terminal_observation" in infos[0]
    finally:
        env.close()


def test_attributes_methods_and_render(endpoint: str) -> None:
    env = make(endpoint, 2, render_mode="rgb_array", render_width=160)
    try:
        assert env.render_mode == "rgb_array"
        assert env.get_attr("render_mode") == ["rgb_array", "rgb_array"]
        assert env.get_attr("action_space", indices=1)[0] == env.action_space
        env.set_attr("difficulty", 3, indices=[1])
        assert env.get_attr("difficulty", indices=[1]) == [3]
        with pytest.raises(AttributeError):
            env.get_attr("difficulty", indices=[0])
        assert env.env_is_wrapped(object) == [False, False]
        env.seed(5)
        env.reset()
        frames = env.env_method("render")
        assert len(frames) == 2 and frames[0].shape[1] == 160 and frames[0].dtype == np.uint8
        tiled = env.render()
        h, w = frames[0].shape[:2]
        assert tiled.shape == (2 * h, w, 3)  # SB3's tile_images: ceil(sqrt(n)) rows
        np.testing.assert_array_equal(tiled[:h], frames[0])
        np.testing.assert_array_equal(tiled[h:], frames[1])
        # env_method("reset") resets that env alone, from the given seed
        (o1, info1), = env.env_method("reset", seed=9, indices=[1])
        (o2, _), = env.env_method("reset", seed=9, indices=[1])
        np.testing.assert_array_equal(o1["scans"], o2["scans"])
        assert info1["time"] == 0.0
    finally:
        env.close()


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="keys"):
        sb3.VecEnv(1, "tcp://127.0.0.1:9", keys=("scans", "slip_angles"))
    with pytest.raises(ValueError, match="one learner car per env"):
        sb3.VecEnv(1, "tcp://127.0.0.1:9", learners=2)
