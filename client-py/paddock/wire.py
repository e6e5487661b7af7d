"""Env replies read straight from the received frames.

An env observation is the one large reply a learner receives on every step (a 64-env
vector env with 1080-beam scans: about 280 KB). It travels as two payload frames after the
``EnvReply`` header: a small ``EnvObservation`` message (states, rewards, flags: a few KB)
and the scans, packed little-endian f32. The broker forwards both frames untouched; here
the small message is parsed by the protobuf runtime and the scans frame is handed out as a
``memoryview`` of the received ZeroMQ frame, which ``numpy.frombuffer`` turns into an array
without copying. An image reply (``EnvImage``) is the same: its size, then its pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from . import errors
from ._proto import paddock_pb2 as pb

_EMPTY = memoryview(b"")


def _view(frame: Any) -> memoryview:
    """A read-only view of a received frame (a ``zmq.Frame`` or bytes) without a copy."""
    buf = getattr(frame, "buffer", frame)
    view = memoryview(buf)
    return view if view.format == "B" else view.cast("B")


@dataclass
class Observation:
    """The fields of an ``EnvObservation`` and the scans frame (the same names as the
    protobuf message, bytes fields as buffers numpy reads in place)."""

    num_envs: int = 0
    scans: memoryview = _EMPTY
    states: bytes = b""
    rewards: bytes = b""
    terminated: bytes = b""
    truncated: bytes = b""
    progress: bytes = b""
    laps: bytes = b""
    time: bytes = b""
    agent_collisions: bytes = b""
    agent_lap_counts: bytes = b""
    agent_lap_times: bytes = b""


def observation(frames: list[Any]) -> Observation:
    """The observation of an env reply's two payload frames."""
    if len(frames) != 2:
        raise errors.BadMessage(1, "env_reply", f"an observation has 2 payload frames, got {len(frames)}")
    meta = pb.EnvObservation()
    meta.ParseFromString(_view(frames[0]))
    return Observation(
        num_envs=meta.num_envs, scans=_view(frames[1]), states=meta.states, rewards=meta.rewards,
        terminated=meta.terminated, truncated=meta.truncated, progress=meta.progress,
        laps=meta.laps, time=meta.time, agent_collisions=meta.agent_collisions,
        agent_lap_counts=meta.agent_lap_counts, agent_lap_times=meta.agent_lap_times)


def image(frames: list[Any]) -> tuple[pb.EnvImage, memoryview]:
    """The size and pixels of an image reply's two payload frames."""
    if len(frames) != 2:
        raise errors.BadMessage(1, "env_reply", f"an image has 2 payload frames, got {len(frames)}")
    meta = pb.EnvImage()
    meta.ParseFromString(_view(frames[0]))
    return meta, _view(frames[1])
