"""Gymnasium environments whose steps run on a Paddock worker.

:class:`F110Env` is one environment (``gymnasium.make("paddock/F110-v0", ...)``);
:class:`F110VectorEnv` is ``num_envs`` of them in ONE env session on one worker, stepped
with one message round trip per step (``gymnasium.make_vec("paddock/F110-v0",
num_envs=N)`` or :func:`paddock.make_vec`). Observations are dicts with the f1tenth_gym
keys and units (metres, radians, seconds); bulk numbers are numpy views of the reply's
packed bytes (``numpy.frombuffer``), never per-element Python loops.

The learner drives car 0 with ``[steer (rad), speed (m/s)]``; further cars (opponents)
are driven on the worker by registry drivers or ONNX model files (``"policy.onnx"``,
stored in the broker once and fetched by each worker by its hash). ``terminated`` = car 0 crashed or finished
its laps; ``truncated`` = the time limit. With ``learners=N`` the learner drives cars
``0..N`` (f1tenth_gym's one action row per car: ``step(np.array([[steer, speed], ...]))``,
``scans`` one row per learner car); the episode ends when every learner car is out of the
race, and ``info`` holds each learner's reward and flag (``paddock.pettingzoo`` gives
each car to its own agent). The reward is computed on the worker from
weights (``reward={"progress": 1.0, "collision": -10.0, "lap": 0.0, "time": 0.0}``:
per metre of progress, per collision, per lap, per second); replace it in Python with a
wrapper (e.g. ``gymnasium.wrappers.TransformReward``) using ``info["progress"]``.

The cars' physics: ``params={"mu": 0.8, "m": 3.9, ...}`` with f1tenth_gym's keys (merged
over its defaults) and/or ``vehicle="vehicle.yaml"`` (the file ``paddock sysid`` writes,
fitted effects included); see :mod:`paddock.vehicle`. They apply to every car.

``endpoint=paddock.IN_PROCESS`` hosts the same sessions inside the learner's process
(:mod:`paddock.inprocess`): the same checks and observations, bit for bit, without the
broker hop and sockets.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import errors, wire
from .vehicle import vehicle_yaml as _vehicle_yaml
from ._proto import paddock_pb2 as pb
from .render import DEFAULT_WIDTH, RENDER_MODES, WIDTHS, Window, frames_of
from .inprocess import IN_PROCESS, InProcess
from .server import LocalServer, hold_shared, release_shared
from .transport import NOT_PICKLED, Connection

STATE_SIZE = 7  # x, y, theta, vx, vy, yaw_rate, steer per car
#: The observation keys of the ONNX observation contract (docs/onnx.md) that a learner
#: car's own view can give (``slip_angles`` is not sent by the env session): what
#: :mod:`paddock.sb3` and :mod:`paddock.pettingzoo` observe, so a policy trained on them
#: exports to a model with exactly these inputs.
CONTRACT_KEYS = ("scans", "poses_x", "poses_y", "poses_theta", "linear_vels_x",
                 "linear_vels_y", "ang_vels_z", "steering_angles", "progress", "lap_times",
                 "lap_counts", "collisions")
_STATE_COLUMN = {"poses_x": 0, "poses_y": 1, "poses_theta": 2, "linear_vels_x": 3,
                 "linear_vels_y": 4, "ang_vels_z": 5, "steering_angles": 6}
OBS_KEYS = ("scans", "poses_x", "poses_y", "poses_theta", "linear_vels_x", "linear_vels_y",
            "ang_vels_z", "collisions", "lap_times", "lap_counts")
_COLLISION = {"terminate": pb.COLLISION_TERMINATE, "stop": pb.COLLISION_STOP,
              "ignore": pb.COLLISION_IGNORE}
DEFAULT_REWARD = {"progress": 1.0, "collision": -10.0, "lap": 0.0, "time": 0.0}
# the wire's little-endian element types, made once
_F4, _F8, _U4, _U1 = np.dtype("<f4"), np.dtype("<f8"), np.dtype("<u4"), np.dtype("u1")


@dataclass
class Frame:
    """One reply's numbers, as arrays over envs (views of the reply's bytes). Per-learner
    arrays have a learner axis (length 1 with one learner)."""

    scans: np.ndarray               # (n, learners, beams) float32
    states: np.ndarray              # (n, agents, 7) float64
    learner_rewards: np.ndarray     # (n, learners) float64
    learner_terminated: np.ndarray  # (n, learners) bool: that car crashed or finished
    truncated: np.ndarray           # (n,) bool
    learner_progress: np.ndarray    # (n, learners) float64
    learner_laps: np.ndarray        # (n, learners) uint32
    time: np.ndarray                # (n,) float64
    collisions: np.ndarray          # (n, agents) float64
    lap_counts: np.ndarray          # (n, agents) int32
    lap_times: np.ndarray           # (n, agents) float64

    @property
    def num_learners(self) -> int:
        return self.learner_rewards.shape[1]

    @property
    def rewards(self) -> np.ndarray:
        """(n,): the learners' rewards summed (car 0's with one learner)."""
        r = self.learner_rewards
        return r[:, 0] if r.shape[1] == 1 else r.sum(axis=1)

    @property
    def terminated(self) -> np.ndarray:
        """(n,): every learner car is out of the race (crashed or finished)."""
        t = self.learner_terminated
        return t[:, 0] if t.shape[1] == 1 else t.all(axis=1)

    @property
    def progress(self) -> np.ndarray:
        """(n,) car 0's progress with one learner, else (n, learners)."""
        p = self.learner_progress
        return p[:, 0] if p.shape[1] == 1 else p

    @property
    def laps(self) -> np.ndarray:
        """(n,) car 0's completed laps with one learner, else (n, learners)."""
        laps = self.learner_laps
        return laps[:, 0] if laps.shape[1] == 1 else laps

    def obs(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The f1tenth_gym observation dict of every env (arrays over envs), or of env
        ``env`` alone (its rows, indexed once per key)."""
        if env is None:
            s, scans, collisions, lap_times, lap_counts = (
                self.states, self.scans, self.collisions, self.lap_times, self.lap_counts)
        else:
            s, scans, collisions, lap_times, lap_counts = (
                self.states[env], self.scans[env], self.collisions[env], self.lap_times[env],
                self.lap_counts[env])
        return {
            "scans": scans,
            "poses_x": s[..., 0],
            "poses_y": s[..., 1],
            "poses_theta": s[..., 2],
            "linear_vels_x": s[..., 3],
            "linear_vels_y": s[..., 4],
            "ang_vels_z": s[..., 5],
            "collisions": collisions,
            "lap_times": lap_times,
            "lap_counts": lap_counts,
        }

    def car_values(self, key: str, car: int) -> np.ndarray:
        """(n, width) float32: learner car ``car``'s own value of contract key ``key`` in
        every env, as an ONNX model's input takes it (``scans`` ``(n, beams)``, a scalar
        key ``(n, 1)``)."""
        if key == "scans":
            v = self.scans[:, car, :]
        elif key in _STATE_COLUMN:
            v = self.states[:, car, _STATE_COLUMN[key]][:, None]
        elif key == "progress":
            v = self.learner_progress[:, car][:, None]
        elif key in ("lap_times", "lap_counts", "collisions"):
            v = getattr(self, key)[:, car][:, None]
        else:
            raise KeyError(f"{key!r} is not one of {CONTRACT_KEYS}")
        return np.array(v, dtype=np.float32)

    def info(self) -> dict[str, np.ndarray]:
        info = {"progress": self.progress, "laps": self.laps, "time": self.time,
                "steering_angles": self.states[:, :, 6]}
        if self.num_learners > 1:
            info["rewards"] = self.learner_rewards
            info["terminated"] = self.learner_terminated
        return info


def check_contract_keys(keys: Sequence[str]) -> tuple[str, ...]:
    """``keys`` as a tuple when they are distinct contract keys, else ``ValueError``."""
    keys = tuple(keys)
    unknown = [k for k in keys if k not in CONTRACT_KEYS]
    if not keys or unknown or len(set(keys)) != len(keys):
        raise ValueError(f"keys = {keys!r}: give distinct observation keys from {CONTRACT_KEYS}")
    return keys


def contract_space(keys: Sequence[str], num_beams: int) -> spaces.Dict:
    """One car's observation space for contract ``keys``: ``scans`` ``(beams,)`` >= 0
    (metres: up to the LIDAR's range plus its noise), each scalar key ``(1,)``, all
    float32."""
    return spaces.Dict({
        k: spaces.Box(0.0, np.inf, (num_beams,), np.float32) if k == "scans"
        else spaces.Box(-np.inf, np.inf, (1,), np.float32)
        for k in keys})


# A reply array's element type, shape and size in bytes.
_Layout = tuple[np.dtype, tuple[int, ...], int]


def _layout(dtype: np.dtype, shape: tuple[int, ...]) -> _Layout:
    return dtype, shape, math.prod(shape) * dtype.itemsize


def _frombuffer(data: bytes | memoryview, layout: _Layout, field: str) -> np.ndarray:
    """A view of ``data`` as ``layout`` (exactly its size), else ``BadMessage``."""
    dtype, shape, want = layout
    if len(data) != want:
        raise errors.BadMessage(1, f"env_observation.{field}",
                                f"{field} has {len(data)} bytes, expected {want} for shape {shape}")
    return np.ndarray(shape, dtype, data)


class EnvSession:
    """An env session of ``num_envs`` copies on one worker, reached through a broker."""

    def __init__(self, conn: Connection, num_envs: int, *, map: str = "lakeside",
                 num_agents: int = 1, learners: int = 1,
                 opponents: Sequence[str | tuple[str, Sequence[float]]] | None = None,
                 seed: int = 0, num_beams: int = 1080, fov: float = 4.7, max_range: float = 30.0,
                 lidar_noise: float = 0.01, laps: int = 1, time_limit: float = 120.0,
                 collision_mode: str = "terminate", reward: Mapping[str, float] | None = None,
                 frame_skip: int = 1, vehicle_yaml: str = "", obstacles: int = 0,
                 params: Mapping[str, float] | None = None,
                 vehicle: str | os.PathLike[str] | None = None) -> None:
        num_envs = wire.whole("num_envs", num_envs, 1)
        num_agents = wire.whole("num_agents", num_agents, 1)
        num_beams, obstacles = wire.whole("num_beams", num_beams), wire.whole("obstacles", obstacles)
        laps, frame_skip = wire.whole("laps", laps), wire.whole("frame_skip", frame_skip)
        learners = wire.whole("learners", learners, 1)
        if learners > num_agents:
            raise ValueError(f"learners = {learners!r} must be in 1..num_agents ({num_agents}): "
                             f"the learner drives cars 0..learners, opponents the rest")
        if collision_mode not in _COLLISION:
            raise ValueError(f"collision_mode = {collision_mode!r} is not one of {sorted(_COLLISION)}")
        weights = dict(DEFAULT_REWARD)
        for k, v in (reward or {}).items():
            if k not in weights:
                raise ValueError(f"reward key {k!r} is not one of {sorted(weights)}")
            weights[k] = float(v)
        n_opp = num_agents - learners
        if opponents is None:
            opponents = ["pure-pursuit"] * n_opp
        elif len(opponents) != n_opp:
            raise ValueError(f"opponents: {len(opponents)} given for num_agents = {num_agents} "
                             f"and learners = {learners} (the learner drives cars 0..learners; "
                             f"give num_agents - learners = {n_opp} opponents)")
        if vehicle_yaml and (params or vehicle is not None):
            raise ValueError("give the vehicle as params= and/or vehicle=, or as vehicle_yaml=, not both")
        vehicle_yaml = vehicle_yaml or _vehicle_yaml(params, vehicle)
        agents = []
        for o in opponents:
            driver, driver_params = (o, ()) if isinstance(o, str) else (o[0], o[1])
            driver = conn.driver_name(driver)
            agents.append(pb.AgentSpec(driver=driver, params=[float(p) for p in driver_params],
                                       vehicle_yaml=vehicle_yaml))
        self.conn = conn
        msg = pb.EnvOpen(
            map=conn.map_ref(map), num_envs=num_envs, seed=wire.whole("seed", seed, 0, wire.U64_MAX),
            opponents=agents, vehicle_yaml=vehicle_yaml,
            lidar=pb.Lidar(num_beams=num_beams, fov=float(fov), max_range=float(max_range),
                           noise_std=float(lidar_noise), mount_offset=0.0),
            obstacles=pb.Obstacles(count=obstacles, length=0.4, width=0.4, passage=1.0,
                                   start_clearance=4.0),
            laps=laps, time_limit=float(time_limit), collision_mode=_COLLISION[collision_mode],
            reward=pb.RewardWeights(**weights), frame_skip=frame_skip, learners=learners)
        header, frames = conn.env(0, pb.ENV_OPEN, msg, timeout=max(conn.timeout, 60.0))
        opened = pb.EnvOpened.FromString(frames[0].bytes)
        self.session_id = header.session_id
        self.num_envs = opened.num_envs
        self.num_agents = opened.num_agents
        # a server from before learner cars answers 0: one learner
        self.num_learners = opened.num_learners or 1
        if self.num_learners != learners:
            raise errors.BadMessage(1, "env_opened.num_learners",
                                    f"the server opened {self.num_learners} learner cars, "
                                    f"{learners} were asked for (an older server?)")
        self.num_beams = opened.num_beams
        self.action_low = np.array(opened.action_low, dtype=np.float32)
        self.action_high = np.array(opened.action_high, dtype=np.float32)
        self.dt = opened.dt
        self.frame_skip = frame_skip
        self.max_range = float(max_range)
        # the reply's arrays, in the order of `_frame`
        n, a, b, lrn = self.num_envs, self.num_agents, self.num_beams, self.num_learners
        self._layouts = tuple(_layout(dt, shape) for dt, shape in (
            (_F4, (n, lrn, b)), (_F8, (n, a, STATE_SIZE)), (_F8, (n, lrn)), (_U1, (n, lrn)),
            (_U1, (n,)), (_F8, (n, lrn)), (_U4, (n, lrn)), (_F8, (n,)), (_U1, (n, a)),
            (_U4, (n, a)), (_F8, (n, a))))
        self.closed = False

    def _frame(self, frames: list[Any]) -> Frame:
        o = wire.observation(frames)
        m = o.message  # its fields read directly (not through the Observation's lookup)
        (scans, states, rewards, terminated, truncated, progress, laps, time, collisions,
         lap_counts, lap_times) = self._layouts
        return Frame(
            scans=_frombuffer(o.scans, scans, "scans"),
            states=_frombuffer(m.states, states, "states"),
            learner_rewards=_frombuffer(m.rewards, rewards, "rewards"),
            learner_terminated=_frombuffer(m.terminated, terminated, "terminated").astype(bool),
            truncated=_frombuffer(m.truncated, truncated, "truncated").astype(bool),
            learner_progress=_frombuffer(m.progress, progress, "progress"),
            learner_laps=_frombuffer(m.laps, laps, "laps"),
            time=_frombuffer(m.time, time, "time"),
            collisions=_frombuffer(m.agent_collisions, collisions, "agent_collisions").astype(np.float64),
            lap_counts=_frombuffer(m.agent_lap_counts, lap_counts, "agent_lap_counts").astype(np.int32),
            lap_times=_frombuffer(m.agent_lap_times, lap_times, "agent_lap_times"),
        )

    def reset(self, seeds: Sequence[int] | None = None, envs: Sequence[int] | None = None,
              poses: np.ndarray | None = None) -> Frame:
        msg = pb.EnvReset(seeds=[wire.whole(f"seeds[{k}]", s, 0, wire.U64_MAX)
                                 for k, s in enumerate(seeds if seeds is not None else [])],
                          envs=[wire.whole(f"envs[{k}]", i)
                                for k, i in enumerate(envs if envs is not None else [])])
        if poses is not None:
            p = np.ascontiguousarray(poses, dtype="<f8")
            count = len(envs) if envs is not None else self.num_envs
            if p.size != count * self.num_agents * 3:
                raise ValueError(f"poses: shape {p.shape} does not hold [x, y, theta] for "
                                 f"{count} envs x {self.num_agents} cars")
            msg.poses = p.tobytes()
        return self._frame(self.conn.env(self.session_id, pb.ENV_RESET, msg)[1])

    def step(self, actions: np.ndarray, reset_envs: Sequence[int] = ()) -> Frame:
        a = np.ascontiguousarray(actions, dtype="<f4")
        msg = pb.EnvStep(actions=a.tobytes(),
                         reset_envs=[wire.whole(f"reset_envs[{k}]", i) for k, i in enumerate(reset_envs)])
        return self._frame(self.conn.env(self.session_id, pb.ENV_STEP, msg)[1])

    def render(self, envs: Sequence[int] | None = None, width: int = DEFAULT_WIDTH) -> np.ndarray:
        """Top-down frames of ``envs`` (default: env 0) as they are now, shape
        (len(envs), height, width, 3) uint8; the session is not changed."""
        envs = [0] if envs is None else [wire.whole(f"envs[{k}]", i) for k, i in enumerate(envs)]
        msg = pb.EnvRender(envs=envs, width=wire.whole("width", width))
        image, rgb = wire.image(self.conn.env(self.session_id, pb.ENV_RENDER, msg)[1])
        return frames_of(image, rgb, len(envs))

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.conn.env(self.session_id, pb.ENV_CLOSE, timeout=min(self.conn.timeout, 5.0))
        except errors.PaddockError:
            pass  # the session is gone with its worker or broker: nothing left to close

    def spaces(self) -> tuple[spaces.Dict, spaces.Box]:
        """One env's observation and action spaces: ``[steer, speed]`` with one learner,
        one such row per learner car with several."""
        a, b, lrn = self.num_agents, self.num_beams, self.num_learners
        inf = np.inf

        def box(shape: tuple[int, ...], low: float = -inf, high: float = inf,
                dtype: Any = np.float64) -> spaces.Box:
            return spaces.Box(low=low, high=high, shape=shape, dtype=dtype)

        obs = spaces.Dict({
            "scans": box((lrn, b), 0.0, inf, np.float32),
            "poses_x": box((a,)), "poses_y": box((a,)), "poses_theta": box((a,)),
            "linear_vels_x": box((a,)), "linear_vels_y": box((a,)), "ang_vels_z": box((a,)),
            "collisions": box((a,), 0.0, 1.0),
            "lap_times": box((a,), 0.0, inf),
            "lap_counts": box((a,), 0, 2**31 - 1, np.int32),
        })
        if lrn == 1:
            act = spaces.Box(low=self.action_low, high=self.action_high, dtype=np.float32)
        else:
            act = spaces.Box(low=np.tile(self.action_low, (lrn, 1)),
                             high=np.tile(self.action_high, (lrn, 1)), dtype=np.float32)
        return obs, act


def reset_options(options: dict[str, Any] | None, known: tuple[str, ...]) -> dict[str, Any]:
    """``options`` of a ``reset`` (``{}`` for None); a key this env does not take is
    ignored with a warning naming it: gymnasium's envs ignore options they do not know,
    but a misspelt ``poses`` went unsaid, the cars starting where the seed puts them."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ValueError(f"options = {options!r} is not a dict (its keys: {', '.join(known)})")
    for k in options:
        if k not in known:
            warnings.warn(f"options: unknown key {k!r} ignored (this env takes {', '.join(known)})",
                          UserWarning, stacklevel=3)
    return options


class _Owned:
    """The connection an env opened for itself, and with ``endpoint=None`` its hold on
    this process's shared local server (:func:`paddock.server.hold_shared`: envs made
    with the same ``threads`` share one, stopped when the last of them closes). What every
    env holds its connection by, so pickling any env stops here, saying why."""

    def __getstate__(self) -> Any:
        raise TypeError(NOT_PICKLED)

    def __init__(self, endpoint: str | None, timeout: float, threads: int) -> None:
        self.server: LocalServer | None = None
        self.conn: Connection | InProcess
        if endpoint == IN_PROCESS:
            self.conn = InProcess(timeout=timeout)
            return
        threads = wire.whole("threads", threads)
        self.server = hold_shared(threads) if endpoint is None else None
        try:
            self.conn = Connection(self.server.endpoint if self.server else endpoint, timeout=timeout)
        except BaseException:
            if self.server is not None:
                release_shared(self.server)
            raise

    def close(self) -> None:
        self.conn.close()
        server, self.server = self.server, None
        if server is not None:
            release_shared(server)


def _check_render_mode(mode: str | None, allowed: list[str]) -> None:
    if mode is not None and mode not in allowed:
        raise ValueError(f"render_mode = {mode!r} is not one of {allowed} (or None)")


def _render_fps(frame_skip: int) -> int | float:
    """Env steps per simulated second (0.01 s physics steps, ``frame_skip`` per env step)."""
    return 100 // frame_skip if 100 % frame_skip == 0 else 100 / frame_skip


class F110Env(gym.Env):
    """One F1TENTH environment stepped on a Paddock worker.

    ``endpoint``: a broker's client endpoint (``tcp://HOST:PORT``), None to start a
    local ``paddock serve`` that :meth:`close` stops, or :data:`paddock.IN_PROCESS` to
    run the simulator inside this process (:mod:`paddock.inprocess`). Other arguments: see
    :class:`EnvSession`. ``reset(options={"poses": [[x, y, theta], ...]})`` places the cars.

    ``render_mode="rgb_array"``: :meth:`render` returns a top-down frame (height, width, 3)
    uint8 of the map, the driving line, every car with its heading, car 0's LIDAR scan and
    a lap and time overlay, ``render_width`` pixels wide. ``render_mode="human"`` shows it
    in a window after every reset and step (needs ``pip install "paddock[human]"``).
    ``metadata["render_fps"]`` is the env's steps per simulated second.
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": 100}

    def __init__(self, endpoint: str | None = None, *, timeout: float = 30.0, threads: int = 0,
                 render_mode: str | None = None, render_width: int = DEFAULT_WIDTH,
                 **kwargs: Any) -> None:
        _check_render_mode(render_mode, RENDER_MODES)
        self.render_mode = render_mode
        self.render_width = wire.whole("render_width", render_width, *WIDTHS)
        self._window: Window | None = None
        if render_mode == "human":
            self._window = Window(_render_fps(int(kwargs.get("frame_skip", 1))))
        self._owned = _Owned(endpoint, timeout, threads)
        try:
            self.session = EnvSession(self._owned.conn, 1, **kwargs)
        except BaseException:
            self._owned.close()
            raise
        self.observation_space, self.action_space = self.session.spaces()
        self.metadata = {**type(self).metadata, "render_fps": _render_fps(self.session.frame_skip)}
        self._needs_reset = True

    def _single(self, f: Frame) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        obs = f.obs(0)
        if f.num_learners == 1:
            info = {"progress": float(f.learner_progress[0, 0]), "laps": int(f.learner_laps[0, 0]),
                    "time": float(f.time[0]), "steering_angles": f.states[0, :, 6]}
        else:
            info = {k: v[0] for k, v in f.info().items()}
            info["time"] = float(f.time[0])
        return obs, info

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        options = reset_options(options, ("poses",))
        if seed is not None:  # checked before anything is seeded
            seed = wire.whole("seed", seed, 0, wire.U64_MAX)
        super().reset(seed=seed)
        poses = None if options.get("poses") is None else np.asarray(options["poses"])
        f = self.session.reset(seeds=[seed] if seed is not None else None, poses=poses)
        self._needs_reset = False
        if self.render_mode == "human":
            self.render()
        return self._single(f)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(action, dtype=np.float32)
        learners = self.session.num_learners
        if a.size != 2 * learners:
            want = "[steer, speed] (shape (2,))" if learners == 1 else \
                f"one [steer, speed] row per learner car (shape ({learners}, 2))"
            raise ValueError(f"action must be {want}, got shape {a.shape}")
        f = self.session.step(a.reshape(1, learners, 2))
        obs, info = self._single(f)
        if self.render_mode == "human":
            self.render()
        return obs, float(f.rewards[0]), bool(f.terminated[0]), bool(f.truncated[0]), info

    def render(self) -> np.ndarray | None:
        """The frame of the env as it is now (``rgb_array``), or show it (``human``)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode="
                            "\"rgb_array\" or \"human\" to gymnasium.make")
            return None
        frame = self.session.render([0], self.render_width)[0]
        if self.render_mode == "rgb_array":
            return frame
        assert self._window is not None
        self._window.show(frame)
        return None

    def close(self) -> None:
        if getattr(self, "_window", None) is not None:
            self._window.close()
            self._window = None
        if getattr(self, "session", None) is not None:
            self.session.close()
        if getattr(self, "_owned", None) is not None:
            self._owned.close()
        super().close()


class F110VectorEnv(VectorEnv):
    """``num_envs`` F1TENTH environments in one env session, one round trip per step.

    Autoreset is NEXT_STEP (declared in ``metadata["autoreset_mode"]``): the step after
    an env terminated or truncated resets it (reward 0, flags false) instead of stepping
    it, in the same round trip. ``reset(seed=s)`` seeds env i with ``s + i``.

    ``render_mode="rgb_array"``: :meth:`render` returns one frame per env (a tuple of
    (height, width, 3) uint8 arrays), ``render_width`` pixels wide.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int, endpoint: str | None = None, *, timeout: float = 30.0,
                 threads: int = 0, render_mode: str | None = None,
                 render_width: int = DEFAULT_WIDTH, **kwargs: Any) -> None:
        _check_render_mode(render_mode, ["rgb_array"])
        self.render_mode = render_mode
        self.render_width = wire.whole("render_width", render_width, *WIDTHS)
        self._owned = _Owned(endpoint, timeout, threads)
        try:
            self.session = EnvSession(self._owned.conn, num_envs, **kwargs)
        except BaseException:
            self._owned.close()
            raise
        self.num_envs = self.session.num_envs
        self.single_observation_space, self.single_action_space = self.session.spaces()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._needs_reset = True
        self.metadata = {**type(self).metadata, "render_fps": _render_fps(self.session.frame_skip)}

    def reset(self, *, seed: int | Sequence[int] | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        options = reset_options(options, ("poses", "reset_mask"))
        if seed is None:
            seeds = None
        elif np.ndim(seed) == 0:  # env i gets seed + i
            base = wire.whole("seed", seed, 0, wire.U64_MAX - (self.num_envs - 1))
            seeds = [base + i for i in range(self.num_envs)]
        else:
            seeds = [wire.whole(f"seed[{k}]", s, 0, wire.U64_MAX) for k, s in enumerate(seed)]
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed: {len(seeds)} seeds for {self.num_envs} envs")
        if seed is not None:
            self._np_random, self._np_random_seed = gym.utils.seeding.np_random(
                seeds[0] if seeds else None)
        envs = None
        if options.get("reset_mask") is not None:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"reset_mask: shape {mask.shape}, expected ({self.num_envs},)")
            envs = [int(i) for i in np.flatnonzero(mask)]
            if seeds is not None:
                seeds = [seeds[i] for i in envs]
        poses = None if options.get("poses") is None else np.asarray(options["poses"])
        f = self.session.reset(seeds=seeds, envs=envs, poses=poses)
        if envs is None:
            self._autoreset[:] = False
        else:
            self._autoreset[envs] = False
        self._needs_reset = False
        return f.obs(), f.info()

    def step(self, actions: Any) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray,
                                          np.ndarray, dict[str, Any]]:
        if self._needs_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(actions, dtype=np.float32)
        learners = self.session.num_learners
        want = (self.num_envs, 2) if learners == 1 else (self.num_envs, learners, 2)
        if a.shape != want:
            what = "num_envs x [steer, speed]" if learners == 1 else \
                "num_envs x learners x [steer, speed]"
            raise ValueError(f"actions must have shape {want} ({what}), got {a.shape}")
        f = self.session.step(a, reset_envs=self._autoreset.nonzero()[0].tolist())
        self._autoreset = f.terminated | f.truncated
        return f.obs(), f.rewards, f.terminated, f.truncated, f.info()

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One frame per env (``rgb_array``), fetched in as few replies as the worker's
        reply size bound (32 MiB of frames) allows."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass "
                            "render_mode=\"rgb_array\" to gymnasium.make_vec")
            return None
        first = self.session.render([0], self.render_width)
        per_reply = max(1, (32 << 20) // first[0].nbytes)
        frames = [first[0]]
        for start in range(1, self.num_envs, per_reply):
            envs = list(range(start, min(start + per_reply, self.num_envs)))
            frames.extend(self.session.render(envs, self.render_width))
        return tuple(frames)

    def close_extras(self, **kwargs: Any) -> None:
        if getattr(self, "session", None) is not None:
            self.session.close()
        if getattr(self, "_owned", None) is not None:
            self._owned.close()


def make_vec(num_envs: int, endpoint: str | None = None, **kwargs: Any) -> F110VectorEnv:
    """``num_envs`` environments in one session (see :class:`F110VectorEnv`)."""
    return F110VectorEnv(num_envs, endpoint, **kwargs)
