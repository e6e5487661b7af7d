"""Batch rollouts and jobs through a broker.

``Client(endpoint).rollouts(driver, params, seeds)`` runs one episode per (parameter
vector, seed) on the broker's workers and returns numpy arrays in that order: the inner
loop of evolution strategies and CMA-ES. ``submit_tune`` starts a tuning job that the
broker runs and stores; ``jobs()`` lists them; ``Job.wait()`` follows one to its result.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import errors, wire
from ._proto import paddock_pb2 as pb
from .server import LocalServer
from .transport import Connection
from .vehicle import vehicle_yaml as _vehicle_yaml

_COLLISION = {"terminate": pb.COLLISION_TERMINATE, "stop": pb.COLLISION_STOP,
              "ignore": pb.COLLISION_IGNORE}
_TERMINATION = {pb.FINISHED: "finished", pb.CRASHED: "crashed", pb.TIME_LIMIT: "time_limit"}
_DONE_STATES = {pb.SUCCEEDED, pb.FAILED, pb.CANCELLED_JOB}


@dataclass
class RolloutResults:
    """Car 0's results of ``P`` parameter vectors x ``S`` seeds, each array ``(P, S)``.

    ``lap_time`` is NaN exactly where the car completed no lap (it crashed or ran out of
    time before its first lap; then ``finished`` is False). Every other array is finite.
    Rank drivers with ``finished`` first: a fitness built on ``lap_time`` alone must
    replace the NaNs (e.g. ``np.where(r.finished, r.lap_time, penalty)``), since NaN
    compares false with everything and ``nanmean`` would drop exactly the failures.
    """

    lap_time: np.ndarray        # first lap's time, s (NaN: no lap completed)
    progress: np.ndarray        # metres along the track
    crashed: np.ndarray         # bool
    finished: np.ndarray        # bool: completed the scenario's laps (lap_time is finite)
    episode_return: np.ndarray  # progress minus the crash penalty if crashed
    time: np.ndarray            # simulated seconds of the episode
    episodes: list[pb.EpisodeResult]  # every result, task order (params-major)


@dataclass
class JobInfo:
    job_id: str
    name: str
    kind: str
    state: str
    rounds_done: int
    rounds_total: int
    episodes_done: int
    progress: dict[str, Any]
    error: str

    @classmethod
    def from_proto(cls, j: pb.JobInfo) -> "JobInfo":
        try:
            progress = json.loads(j.progress_json) if j.progress_json else {}
        except json.JSONDecodeError:
            progress = {"raw": j.progress_json}
        return cls(job_id=j.job_id, name=j.name, kind=j.kind, state=pb.JobState.Name(j.state),
                   rounds_done=j.rounds_done, rounds_total=j.rounds_total,
                   episodes_done=j.episodes_done, progress=progress, error=j.error)

    @property
    def done(self) -> bool:
        return pb.JobState.Value(self.state) in _DONE_STATES


class Job:
    """A job stored by the broker."""

    def __init__(self, client: "Client", job_id: str) -> None:
        self.client = client
        self.job_id = job_id

    def __repr__(self) -> str:
        return f"Job({self.job_id!r})"

    def status(self) -> JobInfo:
        return JobInfo.from_proto(self.client.conn.request(
            "job_status", pb.JobStatusRequest(job_id=self.job_id), "job_info"))

    def cancel(self) -> JobInfo:
        return JobInfo.from_proto(self.client.conn.request(
            "job_cancel", pb.JobCancel(job_id=self.job_id), "job_info"))

    def delete(self) -> None:
        """Delete the job and its result from the broker (cancelling it first if it is
        still queued or running)."""
        self.client.conn.request("job_delete", pb.JobDelete(job_id=self.job_id), "job_deleted")

    def result(self) -> dict[str, Any]:
        """The result document of a finished job (what ``paddock tune --json`` prints)."""
        r = self.client.conn.request("job_result_request", pb.JobResultRequest(job_id=self.job_id),
                                     "job_result")
        info = JobInfo.from_proto(r.info)
        if info.state != "SUCCEEDED":
            raise errors.JobFailed(self.job_id, info.state, info.error)
        return json.loads(r.result_json) if r.result_json else {}

    def wait(self, progress: bool | Callable[[JobInfo], None] = False,
             timeout: float | None = None, poll: float = 0.5) -> dict[str, Any]:
        """Wait for the job to end and return its result; ``progress=True`` prints a line
        per round on stderr, a callable gets every new :class:`JobInfo`."""
        deadline = None if timeout is None else time.monotonic() + timeout
        last = None
        while True:
            info = self.status()
            key = (info.state, info.rounds_done, info.episodes_done)
            if key != last:
                last = key
                if callable(progress):
                    progress(info)
                elif progress:
                    print(f"job {info.job_id} {info.state} round {info.rounds_done}/"
                          f"{info.rounds_total} {json.dumps(info.progress)}", file=sys.stderr)
            if info.done:
                return self.result()
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"job {self.job_id} still {info.state} after {timeout:g} s "
                                   f"(round {info.rounds_done}/{info.rounds_total})")
            time.sleep(poll)


class Client:
    """A client of a Paddock broker (``endpoint``), or of a local ``paddock serve`` that
    it starts itself when ``endpoint`` is None and stops on :meth:`close`."""

    def __init__(self, endpoint: str | None = None, timeout: float = 60.0, threads: int = 0) -> None:
        self.server = LocalServer(threads=threads).start() if endpoint is None else None
        self.endpoint = self.server.endpoint if self.server else str(endpoint)
        self.conn = Connection(self.endpoint, timeout=timeout)

    def close(self) -> None:
        self.conn.close()
        if self.server is not None:
            self.server.stop()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def status(self) -> pb.BrokerStatus:
        """Workers, queue depth and throughput of the broker."""
        return self.conn.status()

    def rollouts(self, driver: str, params: Sequence[float] | Sequence[Sequence[float]] | np.ndarray,
                 seeds: Sequence[int] | np.ndarray, *, map: str = "lakeside", laps: int = 1,
                 time_limit: float = 120.0, crash_penalty: float = 100.0,
                 collision_mode: str = "terminate", num_beams: int = 1080,
                 opponents: Sequence[tuple[str, Sequence[float]]] = (),
                 vehicle: str | os.PathLike[str] | None = None,
                 vehicle_params: Mapping[str, float] | None = None,
                 timeout: float | None = None) -> RolloutResults:
        """One episode per (parameter vector, seed) of driver ``driver`` on ``map``.

        ``driver`` (and each opponent's) is a driver name or an ONNX model file
        (``*.onnx``, which takes no parameters: ``params=[]``); a model is stored in the
        broker once per connection and fetched by its hash by each worker.

        ``params``: one vector or a ``(P, D)`` array (the driver's parameters in its
        declared order, ``paddock drivers``); ``seeds``: ``S`` seeds. Results are
        ``(P, S)`` arrays in that order. A task the server refuses raises its error.
        ``vehicle`` (a vehicle YAML path, as ``paddock sysid`` writes) and
        ``vehicle_params`` (f1tenth_gym's keys, see :mod:`paddock.vehicle`) set every
        car's physics.

        The batch outlives a restart of the broker (it is sent again, and gives the same
        results); a broker that does not answer raises
        :class:`paddock.errors.BrokerNotAnswering` (within about the client's
        ``timeout``). ``timeout``: a bound on the whole batch (None: none).
        """
        p = np.atleast_2d(np.asarray(params, dtype=np.float64))
        if p.ndim != 2:
            raise ValueError(f"params: shape {np.shape(params)}, expected (D,) or (P, D)")
        s = [wire.whole(f"seeds[{k}]", x, 0, wire.U64_MAX)
             for k, x in enumerate(np.asarray(seeds).reshape(-1).tolist())]
        if not s:
            raise ValueError("seeds: at least one seed is needed")
        if collision_mode not in _COLLISION:
            raise ValueError(f"collision_mode = {collision_mode!r} is not one of {sorted(_COLLISION)}")
        laps, num_beams = wire.whole("laps", laps), wire.whole("num_beams", num_beams)
        ref = self.conn.map_ref(map)
        car_yaml = _vehicle_yaml(vehicle_params, vehicle)
        name = self.conn.driver_name(driver)
        others = [pb.AgentSpec(driver=self.conn.driver_name(d), params=[float(v) for v in ps],
                               vehicle_yaml=car_yaml)
                  for d, ps in opponents]
        batch = pb.RolloutBatch()
        for row in p:
            batch.scenarios.append(pb.Scenario(
                map=ref, agents=[pb.AgentSpec(driver=name, params=row.tolist(), vehicle_yaml=car_yaml)] + others,
                start_kind=pb.START_RANDOM, laps=laps, time_limit=float(time_limit),
                collision_mode=_COLLISION[collision_mode],
                lidar=pb.Lidar(num_beams=num_beams, fov=4.7, max_range=30.0, noise_std=0.01),
                obstacles=pb.Obstacles(count=0, length=0.4, width=0.4, passage=1.0, start_clearance=4.0),
                crash_penalty=float(crash_penalty)).SerializeToString())
        for i in range(len(p)):
            for seed in s:
                batch.tasks.append(pb.RolloutTaskSpec(scenario=i, seed=seed))
        batch.progress = True
        # sent again if the broker restarts; a broker that does not answer raises
        # BrokerNotAnswering within about the connection's timeout
        reply, frames = self.conn.request_resumable("rollout_batch", batch, "rollout_result",
                                                    timeout=timeout)
        if reply.outcomes != len(batch.tasks) or len(frames) != len(batch.tasks):
            raise errors.BadMessage(1, "rollout_result.outcomes",
                                    f"{len(frames)} outcomes for {len(batch.tasks)} tasks")
        episodes = []
        for k, frame in enumerate(frames):
            o = pb.TaskOutcome.FromString(frame.bytes)
            if o.WhichOneof("outcome") != "episode":
                e = o.error
                err = errors.from_reply(e.code, f"tasks[{k}]" + (f".{e.field}" if e.field else ""), e.message)
                raise err
            episodes.append(o.episode)
        shape = (len(p), len(s))

        def arr(f: Callable[[pb.EpisodeResult], Any], dtype: Any) -> np.ndarray:
            return np.fromiter((f(e) for e in episodes), dtype=dtype, count=len(episodes)).reshape(shape)

        car = lambda e: e.agents[0]  # noqa: E731
        return RolloutResults(
            lap_time=arr(lambda e: car(e).lap_times[0] if car(e).lap_times else np.nan, np.float64),
            progress=arr(lambda e: car(e).progress, np.float64),
            crashed=arr(lambda e: car(e).termination == pb.CRASHED, bool),
            finished=arr(lambda e: car(e).termination == pb.FINISHED, bool),
            episode_return=arr(lambda e: car(e).episode_return, np.float64),
            time=arr(lambda e: e.time, np.float64),
            episodes=episodes,
        )

    def submit_tune(self, driver: str = "pure-pursuit", *, map: str = "lakeside",
                    generations: int = 60, popsize: int = 12, seeds: int = 8, holdout: int = 20,
                    seed: int = 0, crash_penalty: float = 100.0, name: str = "",
                    vehicle: str | os.PathLike[str] | None = None,
                    vehicle_params: Mapping[str, float] | None = None) -> Job:
        """Start a tuning job (CMA-ES over the driver's parameters) run by the broker;
        the defaults are those of ``paddock tune``. ``vehicle`` / ``vehicle_params``: the
        car to tune for (as in :meth:`rollouts`)."""
        # the ranges of `paddock tune`: on the wire a 0 means "the default", so a 0 given
        # here would run 60 generations (or a crash penalty of 100) unsaid
        penalty = float(crash_penalty)
        if not (math.isfinite(penalty) and penalty > 0):
            raise ValueError(f"crash_penalty = {crash_penalty!r} is out of range: must be a "
                             "positive finite number")
        spec = pb.TuneSpec(map=self.conn.map_ref(map), driver=driver,
                           generations=wire.whole("generations", generations, 1, 10_000),
                           popsize=wire.whole("popsize", popsize, 2, 1_000),
                           seeds=wire.whole("seeds", seeds, 1, 1_000),
                           holdout=wire.whole("holdout", holdout, 1, 10_000),
                           seed=wire.whole("seed", seed, 0, wire.U64_MAX), crash_penalty=penalty,
                           vehicle_yaml=_vehicle_yaml(vehicle_params, vehicle))
        info = self.conn.request("job_submit", pb.JobSubmit(name=name or f"tune {driver}", tune=spec),
                                 "job_info")
        return Job(self, info.job_id)

    def jobs(self) -> list[JobInfo]:
        """This client's jobs the broker stores (an admin key: everyone's), newest last."""
        listing = self.conn.request("job_list", pb.JobListRequest(), "job_listing")
        return [JobInfo.from_proto(j) for j in listing.jobs]

    def job(self, job_id: str) -> Job:
        return Job(self, job_id)


def drivers(binary: str | None = None) -> list[dict[str, Any]]:
    """The driver registry (names, parameters with defaults and bounds) as
    ``paddock drivers --json`` prints it."""
    import subprocess

    from .server import find_paddock

    out = subprocess.run([binary or find_paddock(), "drivers", "--json"], check=True,
                         capture_output=True, text=True, timeout=60)
    return json.loads(out.stdout)


def driver_defaults(name: str, binary: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(defaults, lower bounds, upper bounds) of driver ``name``'s parameters."""
    for d in drivers(binary):
        if d["name"] == name:
            ps = d["params"]
            return (np.array([p["default"] for p in ps]), np.array([p["lo"] for p in ps]),
                    np.array([p["hi"] for p in ps]))
    raise ValueError(f"unknown driver {name!r}")
