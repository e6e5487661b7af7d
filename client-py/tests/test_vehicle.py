"""Vehicle parameters as f1tenth_gym users pass them (``params={...}``) and as ``paddock
sysid`` writes them (``vehicle=`` a YAML path), and results that cannot mislead."""

from __future__ import annotations

import importlib.util
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import paddock
from paddock import errors
from paddock.server import find_paddock
from paddock.vehicle import DEFAULT_PARAMS, VEHICLE_KEYS, params_yaml, vehicle_yaml

SMALL = {"num_beams": 108, "time_limit": 20.0}
SLIPPERY = "mu: 0.55\nm: 4.2\neffects:\n  steering_lag: { tau_s: 0.08 }\n"


def drive(endpoint: str, steps: int = 120, **kwargs: object) -> np.ndarray:
    """Poses of car 0 under a fixed action sequence from a fixed start."""
    env = gym.make("paddock/F110-v0", endpoint=endpoint, **SMALL, **kwargs)
    try:
        obs, _ = env.reset(seed=7)
        poses = []
        for k in range(steps):
            action = np.array([0.3 * np.sin(k / 15.0), 4.0], dtype=np.float32)
            obs, _, terminated, truncated, _ = env.step(action)
            poses.append([obs["poses_x"][0], obs["poses_y"][0], obs["poses_theta"][0]])
            if terminated or truncated:
                break
        return np.array(poses)
    finally:
        env.close()


def test_params_dict_has_f1tenth_gym_keys_and_defaults() -> None:
    assert set(DEFAULT_PARAMS) == set(VEHICLE_KEYS) and len(VEHICLE_KEYS) == 18
    # the full f1tenth_gym dict is the default car: it travels as exactly those values
    text = params_yaml(DEFAULT_PARAMS)
    assert text.splitlines()[0] == "mu: 1.0489"
    assert vehicle_yaml() == ""


def test_changed_params_change_the_trajectory(endpoint: str) -> None:
    stock = drive(endpoint)
    assert np.array_equal(stock, drive(endpoint, params=dict(DEFAULT_PARAMS))), \
        "the f1tenth_gym defaults are the default car"
    slippery = drive(endpoint, params={"mu": 0.5, "C_Sf": 3.0})
    assert slippery.shape[0] > 10
    n = min(len(stock), len(slippery))
    assert not np.array_equal(stock[:n], slippery[:n]), "mu and C_Sf change the car"
    assert np.array_equal(slippery, drive(endpoint, params={"mu": 0.5, "C_Sf": 3.0})), \
        "same params, same bits"


def test_unknown_keys_and_bad_values_are_refused_naming_key_and_value(endpoint: str) -> None:
    with pytest.raises(ValueError, match=r"'mass' = 3\.9"):
        gym.make("paddock/F110-v0", endpoint=endpoint, params={"mass": 3.9}, **SMALL)
    with pytest.raises(ValueError, match=r"params\['mu'\] = nan"):
        gym.make("paddock/F110-v0", endpoint=endpoint, params={"mu": float("nan")}, **SMALL)
    with pytest.raises(ValueError, match=r"params\['m'\] = 'heavy'"):
        gym.make("paddock/F110-v0", endpoint=endpoint, params={"m": "heavy"}, **SMALL)
    # out of range: the worker's check, naming the key and the value
    with pytest.raises(errors.InvalidArgument) as e:
        gym.make("paddock/F110-v0", endpoint=endpoint, params={"m": -2.5}, **SMALL)
    assert e.value.field.endswith("vehicle_yaml.m") and "-2.5" in e.value.message, e.value
    with pytest.raises(errors.InvalidArgument) as e:
        gym.make("paddock/F110-v0", endpoint=endpoint, params={"s_min": 0.6}, **SMALL)
    assert e.value.field.endswith("vehicle_yaml.s_min") and "0.6" in e.value.message, e.value


def test_vehicle_file_and_params_on_top(endpoint: str, tmp_path: Path) -> None:
    base = tmp_path / "vehicle.yaml"
    base.write_text(SLIPPERY)
    merged = tmp_path / "merged.yaml"
    merged.write_text(SLIPPERY.replace("m: 4.2", "m: 3.3"))
    from_file = drive(endpoint, vehicle=base)
    n = min(len(from_file), len(drive(endpoint)))
    assert not np.array_equal(from_file[:n], drive(endpoint)[:n])
    # params apply on top of the file: the same car as the file with that key changed
    assert np.array_equal(drive(endpoint, vehicle=str(base), params={"m": 3.3}),
                          drive(endpoint, vehicle=merged))
    with pytest.raises(ValueError, match="cannot read the vehicle file"):
        gym.make("paddock/F110-v0", endpoint=endpoint, vehicle=tmp_path / "missing.yaml", **SMALL)


def test_vector_env_and_rollouts_take_the_vehicle(endpoint: str, client: paddock.Client) -> None:
    envs = gym.make_vec("paddock/F110-v0", num_envs=2, endpoint=endpoint, params={"mu": 0.5}, **SMALL)
    envs.close()
    defaults, _, _ = paddock.driver_defaults("pure-pursuit")
    kw = {"map": "lakeside", "time_limit": 15.0}
    stock = client.rollouts("pure-pursuit", defaults, [1, 2], **kw)
    slippery = client.rollouts("pure-pursuit", defaults, [1, 2], vehicle_params={"mu": 0.4}, **kw)
    assert not np.array_equal(stock.progress, slippery.progress)


def test_vehicle_yaml_written_by_sysid_loads(endpoint: str, tmp_path: Path) -> None:
    exe = find_paddock()
    rec = tmp_path / "rec.csv"
    subprocess.run([exe, "sysid", "synth", "--effect", "drag:c_lin=0.4,c_quad=0.05",
                    "--seconds", "20", "--seed", "3", "--out", str(rec)],
                   check=True, capture_output=True, timeout=300)
    out = tmp_path / "fit"
    subprocess.run([exe, "sysid", "--recording", str(rec), "--out", str(out), "--effects", "drag",
                    "--no-plots"], check=True, capture_output=True, timeout=600)
    fitted = out / "vehicle.yaml"
    assert "effects" in fitted.read_text(), fitted.read_text()
    assert len(drive(endpoint, vehicle=fitted)) > 10


def test_rollout_results_lap_time_is_nan_exactly_where_no_lap_was_completed(
        client: paddock.Client) -> None:
    defaults, _, hi = paddock.driver_defaults("pure-pursuit")
    # the defaults lap lakeside; every parameter at its upper bound crashes
    r = client.rollouts("pure-pursuit", np.stack([defaults, hi]), list(range(1, 5)),
                        map="lakeside", time_limit=40.0)
    assert r.finished.dtype == bool
    assert r.finished[0].all() and not r.finished[1].any(), r.finished
    assert np.array_equal(np.isnan(r.lap_time), ~r.finished)
    for a in (r.progress, r.episode_return, r.time):
        assert np.all(np.isfinite(a))


def _load_example(name: str):  # noqa: ANN202
    path = Path(__file__).resolve().parents[1] / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_example_fitness_handles_unfinished_episodes() -> None:
    cost = _load_example("cma_pure_pursuit").cost
    nan = float("nan")
    r = paddock.RolloutResults(
        lap_time=np.array([[10.0, 11.0], [9.0, nan], [nan, nan]]),
        progress=np.array([[80.0, 80.0], [80.0, 30.0], [5.0, 60.0]]),
        crashed=np.array([[False, False], [False, True], [True, False]]),
        finished=np.array([[True, True], [True, False], [False, False]]),
        episode_return=np.zeros((3, 2)), time=np.full((3, 2), 10.0), episodes=[])
    c = cost(r, 60.0)
    assert np.all(np.isfinite(c)), c
    # a driver that finishes every start beats one that is faster but fails one
    assert c[0] < c[1] < c[2], c


def test_tune_jobs_carry_the_vehicle(client: paddock.Client) -> None:
    with pytest.raises(errors.InvalidArgument) as e:
        client.submit_tune("pure-pursuit", generations=1, popsize=2, seeds=1, holdout=1,
                           vehicle_params={"m": -1.0})
    assert e.value.field == "job_submit.tune.vehicle_yaml.m", e.value
    job = client.submit_tune("pure-pursuit", generations=1, popsize=2, seeds=1, holdout=2,
                             vehicle_params={"mu": 0.6})
    result = job.wait(timeout=300)
    assert result["driver"] == "pure-pursuit"
    assert result["default"]["episodes"] == 2
