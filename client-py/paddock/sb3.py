"""Stable-Baselines3: the one-message vector env as an SB3 ``VecEnv``.

:class:`VecEnv` holds ``num_envs`` envs in ONE env session on one worker (one message
round trip per step, as :class:`paddock.F110VectorEnv`) and follows SB3's conventions:

- ``reset()`` takes no arguments and returns the observations; per-env reset infos are
  in ``reset_infos``; seeds given with ``seed(s)`` (env i gets ``s + i``) and options
  given with ``set_options`` apply to the next ``reset()`` only.
- ``step_async(actions)`` / ``step_wait()`` (and ``step``): rewards ``float32``, dones
  ``terminated or truncated``, one info dict per env. An env that ended is reset in the
  same call: its returned observation is the next episode's first, its info holds
  ``terminal_observation`` (the last one of the episode that ended) and
  ``TimeLimit.truncated`` (ended by the time limit, not by a crash or the finish), and
  ``reset_infos[i]`` the new episode's info.
- ``get_attr``, ``set_attr``, ``env_method`` and ``env_is_wrapped`` address each env by
  index (a small per-env object: ``render_mode``, the spaces, ``render()``, ``reset()``);
  ``render()`` tiles every env's top-down frame (``render_mode="rgb_array"``).

Observations are the ONNX observation contract (docs/onnx.md): a dict of the learner
car's own values keyed like the model inputs a policy exported from it takes, ``scans``
``(beams,)`` in metres and each scalar key ``(1,)``, all ``float32``, so a policy trained
on ``keys=("scans", "linear_vels_x")`` exports to an ONNX model with exactly those inputs
and drives in ``paddock benchmark --driver model.onnx`` and ``paddock bridge drive``.

With stable-baselines3 installed this class subclasses SB3's own ``VecEnv`` (so PPO, SAC,
``VecMonitor``, ``VecNormalize`` take it as it is); without it (SB3 needs torch) it
subclasses :class:`VecEnvContract`, the same documented interface in plain Python, which
is what the client's tests check.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from copy import deepcopy
from typing import Any

import numpy as np
from gymnasium import spaces

from . import wire
from .env import (CONTRACT_KEYS, EnvSession, Frame, _Owned, check_contract_keys, contract_space,
                  reset_options)
from .render import DEFAULT_WIDTH, WIDTHS

#: The observation keys a :class:`VecEnv` can give (see :data:`paddock.env.CONTRACT_KEYS`).
KEYS = CONTRACT_KEYS


def _tile(images: Sequence[np.ndarray]) -> np.ndarray:
    """Frames of one size in a near-square grid (SB3's ``tile_images`` layout)."""
    imgs = np.asarray(images)
    n, h, w, c = imgs.shape
    rows = int(math.ceil(math.sqrt(n)))
    cols = int(math.ceil(n / rows))
    imgs = np.concatenate([imgs, np.zeros((rows * cols - n, h, w, c), imgs.dtype)])
    return imgs.reshape(rows, cols, h, w, c).transpose(0, 2, 1, 3, 4).reshape(rows * h, cols * w, c)


class VecEnvContract:
    """SB3's documented ``VecEnv`` interface (``stable_baselines3.common.vec_env.VecEnv``)
    in plain Python: the base of :class:`VecEnv` when stable-baselines3 is not installed.
    Subclasses implement ``reset``, ``step_async``, ``step_wait``, ``close``, ``get_attr``,
    ``set_attr``, ``env_method``, ``env_is_wrapped`` and ``get_images``."""

    def __init__(self, num_envs: int, observation_space: spaces.Space,
                 action_space: spaces.Space) -> None:
        self.num_envs = num_envs
        self.observation_space = observation_space
        self.action_space = action_space
        self.reset_infos: list[dict[str, Any]] = [{} for _ in range(num_envs)]
        self._seeds: list[int | None] = [None for _ in range(num_envs)]
        self._options: list[dict[str, Any]] = [{} for _ in range(num_envs)]
        render_modes = self.get_attr("render_mode")
        if any(m != render_modes[0] for m in render_modes):
            raise ValueError("the envs must have one render mode")
        self.render_mode = render_modes[0]
        modes = [] if self.render_mode is None else (
            ["human", "rgb_array"] if self.render_mode == "rgb_array" else [self.render_mode])
        self.metadata = {"render_modes": modes}

    def _reset_seeds(self) -> None:
        self._seeds = [None for _ in range(self.num_envs)]

    def _reset_options(self) -> None:
        self._options = [{} for _ in range(self.num_envs)]

    def has_attr(self, attr_name: str) -> bool:
        try:
            self.get_attr(attr_name)
            return True
        except AttributeError:
            return False

    def step(self, actions: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray, list[dict]]:
        self.step_async(actions)
        return self.step_wait()

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seeds for the next ``reset()``: env i gets ``seed + i`` (a random base for
        None)."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + idx for idx in range(self.num_envs)]
        return self._seeds

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        """Options for the next ``reset()``: one dict for every env, or one per env."""
        if options is None:
            options = {}
        if isinstance(options, dict):
            self._options = deepcopy([options] * self.num_envs)
        else:
            self._options = deepcopy(list(options))

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """Every env's frame tiled into one image (``rgb_array``)."""
        mode = mode or self.render_mode
        if mode != "rgb_array" or self.render_mode != "rgb_array":
            warnings.warn(f"render(mode={mode!r}): this env renders rgb_array frames "
                          f"(render_mode={self.render_mode!r})", stacklevel=2)
            return None
        return _tile(self.get_images())

    @property
    def unwrapped(self) -> VecEnvContract:
        return self

    def getattr_depth_check(self, name: str, already_found: bool) -> str | None:
        if hasattr(self, name) and already_found:
            return f"{type(self).__module__}.{type(self).__name__}"
        return None

    def _get_indices(self, indices: None | int | Iterable[int]) -> Iterable[int]:
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int):
            return [indices]
        return indices


try:  # SB3's own base class when stable-baselines3 (and so torch) is installed
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv as _Base  # type: ignore

    SB3_BASE = True
except ImportError:  # the same interface in plain Python
    _Base = VecEnvContract
    SB3_BASE = False


class _EnvView:
    """Env ``index`` of a :class:`VecEnv`, for ``get_attr``, ``set_attr`` and
    ``env_method``: its spaces and render mode, attributes set on it, ``render()`` (its
    frame) and ``reset(seed=None, options=None)`` (that env alone)."""

    def __init__(self, vec: VecEnv, index: int) -> None:
        self._vec = vec
        self.index = index

    @property
    def render_mode(self) -> str | None:
        return self._vec._render_mode

    @property
    def observation_space(self) -> spaces.Space:
        return self._vec._single_obs_space

    @property
    def action_space(self) -> spaces.Space:
        return self._vec._single_action_space

    @property
    def spec(self) -> None:
        return None

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self._vec.session.render([self.index], self._vec.render_width)[0]

    def reset(self, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict]:
        options = reset_options(options, ("poses",))
        seeds = None if seed is None else [wire.whole("seed", seed, 0, wire.U64_MAX)]
        f = self._vec._reset_envs([self.index], seeds, options.get("poses"))
        return self._vec._obs_at(f, self.index), self._vec._infos(f)[self.index]

    def get_wrapper_attr(self, name: str) -> Any:
        return getattr(self, name)

    def has_wrapper_attr(self, name: str) -> bool:
        return hasattr(self, name)


class VecEnv(_Base):
    """``num_envs`` F1TENTH envs in one env session, as an SB3 ``VecEnv``.

    ``keys``: the observation keys (default the LIDAR scan alone), see :data:`KEYS`.
    ``endpoint=None`` uses this process's local ``paddock serve`` (started for the
    first such env, stopped when the last one closes);
    ``endpoint=paddock.IN_PROCESS`` runs the simulator in this process. Other
    keyword arguments go to the session as for ``gymnasium.make("paddock/F110-v0")``
    (``map``, ``num_agents``, ``opponents``, ``num_beams``, ``time_limit``, ``reward``,
    ``frame_skip``, ``params``, ``vehicle``, ...); the learner drives car 0.
    """

    def __init__(self, num_envs: int = 1, endpoint: str | None = None, *,
                 keys: Sequence[str] = ("scans",), render_mode: str | None = None,
                 render_width: int = DEFAULT_WIDTH, timeout: float = 30.0, threads: int = 0,
                 **kwargs: Any) -> None:
        keys = check_contract_keys(keys)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode = {render_mode!r} is not 'rgb_array' (or None)")
        if int(kwargs.get("learners", 1)) != 1:
            raise ValueError("an SB3 VecEnv has one learner car per env "
                             "(paddock.pettingzoo gives several cars to their own agents)")
        self.keys = keys
        self.render_width = wire.whole("render_width", render_width, *WIDTHS)
        self._render_mode = render_mode
        self._owned = _Owned(endpoint, timeout, threads)
        try:
            self.session = EnvSession(self._owned.conn, num_envs, **kwargs)
        except BaseException:
            self._owned.close()
            raise
        s = self.session
        self._single_obs_space = contract_space(keys, s.num_beams)
        self._single_action_space = spaces.Box(s.action_low, s.action_high, dtype=np.float32)
        self._views = [_EnvView(self, i) for i in range(s.num_envs)]
        self._actions: np.ndarray | None = None
        super().__init__(s.num_envs, self._single_obs_space, self._single_action_space)

    # -- observations -----------------------------------------------------------------

    def _obs(self, f: Frame) -> dict[str, np.ndarray]:
        """Every env's observation of the learner car (fresh arrays: SB3 keeps them)."""
        return {k: f.car_values(k, 0) for k in self.keys}

    def _obs_at(self, f: Frame, i: int) -> dict[str, np.ndarray]:
        return {k: f.car_values(k, 0)[i] for k in self.keys}

    @staticmethod
    def _infos(f: Frame, time_limit: list[bool] | None = None) -> list[dict[str, Any]]:
        """Every env's info: its learner car's progress, laps and the env's time, as
        Python numbers (the arrays turned into lists once, not read env by env), with
        ``TimeLimit.truncated`` from ``time_limit`` where given."""
        progress, laps, time = f.progress.tolist(), f.laps.tolist(), f.time.tolist()
        if time_limit is None:
            return [{"progress": p, "laps": n, "time": t}
                    for p, n, t in zip(progress, laps, time)]
        return [{"progress": p, "laps": n, "time": t, "TimeLimit.truncated": c}
                for p, n, t, c in zip(progress, laps, time, time_limit)]

    # -- the VecEnv interface ---------------------------------------------------------

    def _reset_envs(self, envs: list[int] | None, seeds: list[int] | None,
                    poses: Any = None) -> Frame:
        return self.session.reset(seeds=seeds, envs=envs,
                                  poses=None if poses is None else np.asarray(poses))

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """As SB3's: env i's next ``reset()`` gets ``seed + i`` (a random base for None).
        A seed that is not a whole number, or that would give an env one outside
        ``[0, 2**64 - 1]``, is refused here, naming it."""
        if seed is not None:
            seed = wire.whole("seed", seed, 0, wire.U64_MAX - (self.num_envs - 1))
        return super().seed(seed)

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        """As SB3's: options for the next ``reset()``, one dict for every env or one per
        env. A key the envs do not take (they take ``poses``) is named in a warning here."""
        if options is not None and not isinstance(options, dict):
            options = list(options)
        for o in options if isinstance(options, list) else [options]:
            reset_options(o, ("poses",))
        super().set_options(options)

    def reset(self) -> dict[str, np.ndarray]:
        """Reset every env (with the seeds of :meth:`seed` and the options of
        :meth:`set_options`, if given since the last reset) and return the observations;
        ``reset_infos`` holds each env's info."""
        n = self.num_envs
        seeded = [i for i in range(n) if self._seeds[i] is not None]
        posed = [i for i in range(n) if self._options[i].get("poses") is not None]
        f = None
        if not seeded and not posed:
            f = self._reset_envs(None, None)
        else:
            # one call per kind: seeded or not, and each env with its own poses alone
            plain = [i for i in range(n) if i not in posed]
            seeded_plain = [i for i in plain if i in seeded]
            if seeded_plain:
                f = self._reset_envs(seeded_plain, [self._seeds[i] for i in seeded_plain])
            unseeded_plain = [i for i in plain if i not in seeded]
            if unseeded_plain:
                f = self._reset_envs(unseeded_plain, None)
            for i in posed:
                seed = None if self._seeds[i] is None else [self._seeds[i]]
                f = self._reset_envs([i], seed, self._options[i]["poses"])
        assert f is not None
        self.reset_infos = self._infos(f)
        self._reset_seeds()
        self._reset_options()
        return self._obs(f)

    def step_async(self, actions: np.ndarray) -> None:
        a = np.asarray(actions, dtype=np.float32)
        if a.shape != (self.num_envs, 2):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2) "
                             f"(num_envs x [steer, speed]), got {a.shape}")
        self._actions = a

    def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, list[dict]]:
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async(actions)")
        actions, self._actions = self._actions, None
        f = self.session.step(actions.reshape(self.num_envs, 1, 2))
        obs = self._obs(f)
        rewards = np.array(f.rewards, dtype=np.float32)
        terminated = np.array(f.terminated, dtype=bool)
        truncated = np.array(f.truncated, dtype=bool)
        dones = terminated | truncated
        infos = self._infos(f, (truncated & ~terminated).tolist())
        ended = dones.nonzero()[0].tolist()
        if ended:
            for i in ended:
                infos[i]["terminal_observation"] = {k: v[i].copy() for k, v in obs.items()}
            # SB3 resets an ended env in the same step: from its own seed stream
            r = self._reset_envs(ended, None)
            fresh = self._obs(r)
            for k in obs:
                obs[k][ended] = fresh[k][ended]
            fresh_infos = self._infos(r)
            for i in ended:
                self.reset_infos[i] = fresh_infos[i]
        return obs, rewards, dones, infos

    def close(self) -> None:
        if getattr(self, "session", None) is not None:
            self.session.close()
        if getattr(self, "_owned", None) is not None:
            self._owned.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        if self._render_mode != "rgb_array":
            warnings.warn("get_images(): pass render_mode='rgb_array' to render frames",
                          stacklevel=2)
            return [None for _ in range(self.num_envs)]
        per_reply = None
        frames: list[np.ndarray] = []
        start = 0
        while start < self.num_envs:
            count = 1 if per_reply is None else per_reply
            envs = list(range(start, min(start + count, self.num_envs)))
            got = self.session.render(envs, self.render_width)
            frames.extend(got)
            if per_reply is None:  # as many frames per reply as the 32 MiB bound allows
                per_reply = max(1, (32 << 20) // got[0].nbytes)
            start += len(envs)
        return frames

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self._views[i], attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        for i in self._get_indices(indices):
            setattr(self._views[i], attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None,
                   **method_kwargs: Any) -> list[Any]:
        return [getattr(self._views[i], method_name)(*method_args, **method_kwargs)
                for i in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]
