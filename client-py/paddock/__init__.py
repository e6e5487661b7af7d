"""Paddock's Python client: gymnasium envs, vector envs and batch rollouts whose
simulation runs on a Paddock broker's workers (ZeroMQ + protobuf).

- ``gymnasium.make("paddock/F110-v0", endpoint="tcp://HOST:PORT", map="lakeside")``
  (``endpoint=None`` starts a local ``paddock serve``; ``endpoint=paddock.IN_PROCESS``
  runs the simulator inside this process, see :mod:`paddock.inprocess`)
- ``gymnasium.make_vec("paddock/F110-v0", num_envs=64, ...)`` or :func:`make_vec`
- ``Client(endpoint).rollouts(driver, params, seeds)``, ``submit_tune``, ``jobs``
- vehicle physics: ``params={...}`` (f1tenth_gym's keys) and ``vehicle="vehicle.yaml"``
  (what ``paddock sysid`` writes) in ``gymnasium.make``; see :mod:`paddock.vehicle`
- several learner cars: ``gymnasium.make(..., num_agents=2, learners=2)`` (f1tenth_gym's
  one action row per car), ``paddock.pettingzoo.parallel_env(num_agents=2)`` (PettingZoo)
- Stable-Baselines3: ``paddock.sb3.VecEnv(num_envs)``; exported policies:
  :mod:`paddock.onnx` (imported on demand: they need optional packages)
"""

from __future__ import annotations

import gymnasium as _gym

from . import errors
from .client import Client, Job, JobInfo, RolloutResults, driver_defaults, drivers
from .env import EnvSession, F110Env, F110VectorEnv, make_vec
from .inprocess import IN_PROCESS
from .server import LocalServer

ENV_ID = "paddock/F110-v0"

if ENV_ID not in _gym.registry:
    _gym.register(id=ENV_ID, entry_point="paddock.env:F110Env",
                  vector_entry_point="paddock.env:F110VectorEnv")

__all__ = ["Client", "EnvSession", "F110Env", "F110VectorEnv", "IN_PROCESS", "Job", "JobInfo", "LocalServer",
           "RolloutResults", "driver_defaults", "drivers", "errors", "make_vec", "ENV_ID"]
__version__ = "0.1.0"
