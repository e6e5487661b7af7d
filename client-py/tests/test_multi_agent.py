"""Several learner cars: f1tenth_gym's one action row per car in the gymnasium envs, and
the PettingZoo ParallelEnv (PettingZoo's own parallel_api_test, and self-play of two
learner cars in benchmark B3's head-to-head against `paddock benchmark b3`)."""

from __future__ import annotations

import json
import os
import subprocess
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import paddock
from paddock import errors

SMALL = {"num_beams": 108, "time_limit": 20.0}


def test_f1tenth_gym_style_every_car_a_learner(endpoint: str) -> None:
    env = gym.make("paddock/F110-v0", endpoint=endpoint, num_agents=2, learners=2, **SMALL)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        assert env.action_space.shape == (2, 2)
        obs, info = env.reset(seed=4)
        assert obs["scans"].shape == (2, 108)
        # each row is its own car's scan: the cars stand apart on the grid
        assert not np.array_equal(obs["scans"][0], obs["scans"][1])
        x0, y0 = obs["poses_x"].copy(), obs["poses_y"].copy()
        p0 = info["progress"].copy()
        total = 0.0
        for _ in range(100):
            obs, reward, terminated, truncated, info = env.step(np.array([[0.0, 2.0], [0.0, 0.0]]))
            total += reward
        assert (obs["poses_x"][1], obs["poses_y"][1]) == (x0[1], y0[1]), "car 1 stood still"
        assert np.hypot(obs["poses_x"][0] - x0[0], obs["poses_y"][0] - y0[0]) > 1.0
        # the reward is the learners' sum (progress per metre here); info has each one's
        assert info["rewards"].shape == (2,) and info["terminated"].shape == (2,)
        gained = info["progress"] - p0
        assert gained[1] == pytest.approx(0.0, abs=1e-9) and gained[0] > 1.0
        assert total == pytest.approx(gained.sum(), rel=1e-9)
        assert not terminated and not truncated
        with pytest.raises(ValueError, match=r"one \[steer, speed\] row per learner car"):
            env.step([0.0, 1.0])
    finally:
        env.close()


def test_vector_env_with_learner_rows(endpoint: str) -> None:
    vec = paddock.make_vec(3, endpoint, num_agents=3, learners=2, **SMALL)
    try:
        assert vec.single_action_space.shape == (2, 2)
        obs, info = vec.reset(seed=1)
        assert obs["scans"].shape == (3, 2, 108)
        assert obs["poses_x"].shape == (3, 3)
        a = np.zeros((3, 2, 2), dtype=np.float32)
        a[:, :, 1] = 1.5
        obs, rew, term, trunc, info = vec.step(a)
        assert rew.shape == (3,) and info["rewards"].shape == (3, 2)
        np.testing.assert_allclose(rew, info["rewards"].sum(axis=1))
        with pytest.raises(ValueError, match=r"\(3, 2, 2\)"):
            vec.step(np.zeros((3, 2), dtype=np.float32))
    finally:
        vec.close()
    with pytest.raises(ValueError, match="learners = 3 must be in 1..num_agents"):
        paddock.make_vec(1, endpoint, num_agents=2, learners=3)
    with pytest.raises(errors.InvalidArgument, match="learners"):
        paddock.make_vec(1, endpoint, num_agents=17, learners=17)
    with pytest.raises(ValueError, match="'missing.onnx': cannot read the model file"):
        paddock.make_vec(1, endpoint, num_agents=2, opponents=["missing.onnx"])


pettingzoo = pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test  # noqa: E402

from paddock import pettingzoo as ppz  # noqa: E402


def test_parallel_env_passes_pettingzoo_api_test(endpoint: str) -> None:
    env = ppz.parallel_env(3, endpoint, keys=("scans", "linear_vels_x"), num_beams=108,
                           time_limit=3.0)
    try:
        with warnings.catch_warnings():
            # the API test reports some contract breaks as warnings: make them failures
            warnings.simplefilter("error")
            parallel_api_test(env, num_cycles=400)
        obs, infos = env.reset(seed=2)
        assert set(obs) == {"car_0", "car_1", "car_2"}
        assert obs["car_1"]["scans"].shape == (108,)
        assert obs["car_1"]["linear_vels_x"].shape == (1,)
        assert env.observation_space("car_0").contains(obs["car_0"])
        assert env.state().shape == (3 * 7,)
    finally:
        env.close()


def test_an_agent_out_of_the_race_leaves_and_the_others_race_on(endpoint: str) -> None:
    env = ppz.parallel_env(2, endpoint, num_beams=108, time_limit=30.0)
    try:
        env.reset(seed=6)
        crashed = None
        for _ in range(3000):
            obs, rew, term, trunc, info = env.step({"car_0": [0.4, 8.0], "car_1": [0.0, 1.0]})
            if term.get("car_0"):
                crashed = rew["car_0"]
                break
        assert crashed is not None and crashed < -5.0, "full lock at speed hits a wall"
        assert env.agents == ["car_1"]
        obs, rew, term, trunc, info = env.step({"car_1": [0.0, 1.0]})
        assert set(obs) == {"car_1"} and rew["car_1"] > 0
        with pytest.raises(ValueError, match="no action for the live agents"):
            env.step({})
    finally:
        env.close()


def task_seed(job_seed: int, index: int) -> int:
    """rollout's task_seed (SplitMix64 over the pair): benchmark episode seeds."""
    m = (1 << 64) - 1
    z = (job_seed * 0x9E3779B97F4A7C15 + index * 0xD1B54A32D192ED03 + 0x632BE59BD9B4E019) & m
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & m
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & m
    return z ^ (z >> 31)


def centering_model(beams: int = 1080, fov: float = 4.7, gain: float = 0.4,
                    speed: float = 2.5) -> bytes:
    """A linear wall-centering policy on the scan (the Rust tests' reference model)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    angle = -fov / 2 + fov * np.arange(beams) / (beams - 1)
    left = (angle >= 0.3) & (angle <= 1.6)
    right = (angle >= -1.6) & (angle <= -0.3)
    w = np.zeros((beams, 2), dtype=np.float32)
    w[left, 0] = gain / left.sum()
    w[right, 0] = -gain / right.sum()
    b = np.array([0.0, speed], dtype=np.float32)
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["scans", "w"], ["wx"]),
         helper.make_node("Add", ["wx", "b"], ["action"])],
        "policy",
        [helper.make_tensor_value_info("scans", TensorProto.FLOAT, ["batch", beams])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 2])],
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model.SerializeToString()


def test_self_play_b3_head_to_head_matches_the_benchmark(endpoint: str, tmp_path) -> None:
    """Two learner cars with one policy (an ONNX model run in onnxruntime) race B3's
    pairs of races (the same start, the grid swapped); the driver's laps and wins agree
    with `paddock benchmark b3 --driver model.onnx --opponent model.onnx` (Paddock's
    Rust runtime), up to the two runtimes' float32 rounding."""
    ort = pytest.importorskip("onnxruntime")
    path = tmp_path / "centering.onnx"
    path.write_bytes(centering_model())
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    seed, pairs, laps = 7, 1, 1
    env = ppz.parallel_env(2, endpoint, laps=laps, time_limit=90.0)
    laps_0, wins = [], 0
    try:
        for k in range(2 * pairs):
            start = task_seed(seed, k // 2)
            obs, _ = env.reset(seed=start)
            if k % 2 == 1:  # B3's second race of a pair: the grid swapped
                grid = env.state().reshape(2, 7)[:, :3]
                obs, _ = env.reset(seed=start, options={"poses": grid[::-1]})
            finish = {}
            while env.agents:
                acts = {a: session.run(["action"], {"scans": obs[a]["scans"][None]})[0][0]
                        for a in env.agents}
                obs, rew, term, trunc, info = env.step(acts)
                for a in term:
                    if term[a] and info[a]["laps"] >= laps:
                        finish[a] = info[a]["time"]
            assert set(finish) == {"car_0", "car_1"}, f"race {k}: both cars finish: {finish}"
            laps_0.append(finish["car_0"] / laps)
            wins += finish["car_0"] < finish["car_1"]
    finally:
        env.close()
    exe = os.environ.get("PADDOCK_BIN") or paddock.server.find_paddock()
    out = subprocess.run(
        [exe, "benchmark", "b3", "--driver", str(path), "--opponent", str(path),
         "--episodes", str(2 * pairs), "--seed", str(seed), "--laps", str(laps),
         "--time-limit", "90", "--json"],
        capture_output=True, text=True, check=True)
    report = json.loads(out.stdout)
    assert report["win_rate"] == wins / (2 * pairs), report
    assert report["lap_time_mean"] == pytest.approx(np.mean(laps_0), rel=5e-3), report
