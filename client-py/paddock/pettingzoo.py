"""PettingZoo: every car to its own agent, as a ``ParallelEnv``.

``paddock.pettingzoo.parallel_env(num_agents=2, ...)`` is one F1TENTH race whose first
``num_agents`` cars are learner agents (``car_0``, ``car_1``, ...), all stepped together
on a Paddock worker in one message round trip; further cars (``opponents=[...]``, registry
drivers) race too but are not agents. Self-play: give every agent the same policy.

- Each agent observes its own car as an ONNX model's inputs take it (docs/onnx.md):
  ``scans`` ``(beams,)`` in metres and each scalar key ``(1,)``, all ``float32``
  (``keys=("scans", "linear_vels_x")``; default the scan alone), so a policy trained here
  exports to a model that ``paddock benchmark b3 --driver model.onnx --opponent
  model.onnx`` races. ``state()`` is every car's ``[x, y, theta, vx, vy, yaw_rate,
  steer]`` (a centralised critic's input).
- Each agent acts with ``[steer (rad), speed (m/s)]``, and gets its own reward (the
  weights of ``reward=``, per metre of its progress, its collisions, laps, seconds).
- An agent is terminated when its car crashes or finishes its ``laps``, and leaves
  ``agents``; the others race on. All are truncated at ``time_limit``.
- ``reset(seed=s)`` is the race a rollout with seed ``s`` starts (the same grid, LIDAR
  noise); ``options={"poses": [[x, y, theta], ...]}`` places every car (e.g. the grid
  swapped, as benchmark B3's second race of a pair).
- ``render_mode="rgb_array"``: ``render()`` is the top-down frame of the race.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv as _ParallelEnv

from . import wire
from .env import EnvSession, Frame, _Owned, check_contract_keys, contract_space, STATE_SIZE
from .render import DEFAULT_WIDTH, WIDTHS


class ParallelEnv(_ParallelEnv):
    """``num_agents`` learner cars racing each other (and ``opponents``) on one worker.

    ``endpoint=None`` uses this process's local ``paddock serve`` (started for the
    first such env, stopped when the last one closes);
    ``endpoint=paddock.IN_PROCESS`` runs the simulator in this process. Other
    keyword arguments go to the env session as for ``gymnasium.make("paddock/F110-v0")``:
    ``map``, ``laps``, ``time_limit``, ``reward``, ``frame_skip``, ``num_beams``,
    ``collision_mode``, ``params``, ``vehicle`` (every car's physics), ``seed``, ...
    """

    metadata = {"name": "paddock_f110_v0", "render_modes": ["rgb_array"], "render_fps": 100,
                "is_parallelizable": True}

    def __init__(self, num_agents: int = 2, endpoint: str | None = None, *,
                 keys: Sequence[str] = ("scans",),
                 opponents: Sequence[str | tuple[str, Sequence[float]]] = (),
                 render_mode: str | None = None, render_width: int = DEFAULT_WIDTH,
                 timeout: float = 30.0, threads: int = 0, **kwargs: Any) -> None:
        learners = wire.whole("num_agents", num_agents, 1)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode = {render_mode!r} is not 'rgb_array' (or None)")
        for k in ("learners", "num_envs"):
            if k in kwargs:
                raise ValueError(f"{k}: a ParallelEnv is one race of num_agents learner cars")
        self.keys = check_contract_keys(keys)
        self.render_mode = render_mode
        self.render_width = wire.whole("render_width", render_width, *WIDTHS)
        self._owned = _Owned(endpoint, timeout, threads)
        try:
            self.session = EnvSession(self._owned.conn, 1,
                                      num_agents=learners + len(opponents), learners=learners,
                                      opponents=list(opponents), **kwargs)
        except BaseException:
            self._owned.close()
            raise
        s = self.session
        self.possible_agents = [f"car_{i}" for i in range(learners)]
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        # one space object per agent, the same on every call (PettingZoo seeds them)
        self.observation_spaces = {a: contract_space(self.keys, s.num_beams)
                                   for a in self.possible_agents}
        self.action_spaces = {a: spaces.Box(s.action_low, s.action_high, dtype=np.float32)
                              for a in self.possible_agents}
        self.state_space = spaces.Box(-np.inf, np.inf, (s.num_agents * STATE_SIZE,),
                                      np.float64)
        self.metadata = {**type(self).metadata, "render_fps":
                         100 // s.frame_skip if 100 % s.frame_skip == 0 else 100 / s.frame_skip}
        self._frame: Frame | None = None

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    def _obs(self, f: Frame, agent: str) -> dict[str, np.ndarray]:
        car = self._index[agent]
        return {k: f.car_values(k, car)[0] for k in self.keys}

    def _info(self, f: Frame, agent: str) -> dict[str, Any]:
        car = self._index[agent]
        return {"progress": float(f.learner_progress[0, car]),
                "laps": int(f.learner_laps[0, car]), "time": float(f.time[0]),
                "lap_times": float(f.lap_times[0, car])}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, Any]]]:
        # other keys are ignored unsaid: PettingZoo's API test resets with {"options": 1}
        # and takes a warning as a failure
        poses = None if not options or options.get("poses") is None else np.asarray(options["poses"])
        seeds = None if seed is None else [wire.whole("seed", seed, 0, wire.U64_MAX)]
        f = self.session.reset(seeds=seeds, poses=poses)
        self._frame = f
        self.agents = list(self.possible_agents)
        return ({a: self._obs(f, a) for a in self.agents},
                {a: self._info(f, a) for a in self.agents})

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self._frame is None:
            raise RuntimeError("call reset() before step()")
        if not self.agents:
            raise RuntimeError("every agent is done: call reset()")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"no action for the live agents {missing}")
        a = np.zeros((1, len(self.possible_agents), 2), dtype=np.float32)
        for agent in self.agents:
            act = np.asarray(actions[agent], dtype=np.float32)
            if act.shape != (2,):
                raise ValueError(f"action of {agent} must be [steer, speed] (shape (2,)), "
                                 f"got shape {act.shape}")
            a[0, self._index[agent]] = act
        f = self.session.step(a)
        self._frame = f
        live = self.agents
        obs = {ag: self._obs(f, ag) for ag in live}
        rewards = {ag: float(f.learner_rewards[0, self._index[ag]]) for ag in live}
        terminated = {ag: bool(f.learner_terminated[0, self._index[ag]]) for ag in live}
        truncated = {ag: bool(f.truncated[0]) for ag in live}
        infos = {ag: self._info(f, ag) for ag in live}
        self.agents = [ag for ag in live if not (terminated[ag] or truncated[ag])]
        return obs, rewards, terminated, truncated, infos

    def state(self) -> np.ndarray:
        """Every car's ``[x, y, theta, vx, vy, yaw_rate, steer]``, car-major."""
        if self._frame is None:
            raise RuntimeError("call reset() before state()")
        return np.array(self._frame.states[0].reshape(-1))

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.session.render([0], self.render_width)[0]

    def close(self) -> None:
        if getattr(self, "session", None) is not None:
            self.session.close()
        if getattr(self, "_owned", None) is not None:
            self._owned.close()


def parallel_env(num_agents: int = 2, endpoint: str | None = None, **kwargs: Any) -> ParallelEnv:
    """A race of ``num_agents`` learner cars (see :class:`ParallelEnv`)."""
    return ParallelEnv(num_agents, endpoint, **kwargs)
