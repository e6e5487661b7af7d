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

from typing import Any

from . import errors
from ._proto import paddock_pb2 as pb

U32_MAX = 2**32 - 1
U64_MAX = 2**64 - 1


def whole(name: str, value: Any, lo: int = 0, hi: int = U32_MAX) -> int:
    """``value`` as a whole number in ``[lo, hi]`` for the request field ``name``, or a
    ValueError naming the field and the value (as ``paddock``'s flags word it): without
    this, a value outside an unsigned 32-bit field was refused by the protobuf runtime
    as "Value out of range: -1", naming nothing, and a fraction was cut silently."""
    try:
        v = int(value)
    except (TypeError, ValueError, OverflowError):
        v = None
    # a number must equal its whole part; a string ("12") is whole once int() took it
    if v is None or (v != value and not isinstance(value, str)):
        raise ValueError(f"{name} = {value!r} is not a whole number in [{lo}, {hi}]")
    if not lo <= v <= hi:
        raise ValueError(f"{name} = {value!r} is out of range: must be a whole number in [{lo}, {hi}]")
    return v

def _view(frame: Any) -> memoryview:
    """A read-only view of a received frame (a ``zmq.Frame`` or bytes) without a copy."""
    buf = getattr(frame, "buffer", frame)
    view = memoryview(buf)
    return view if view.format == "B" else view.cast("B")


class Observation:
    """An ``EnvObservation`` as received: the parsed message (``message``; its fields are
    also read as this object's attributes, by the protobuf names) and the scans frame
    (``scans``), a buffer numpy reads in place."""

    __slots__ = ("message", "scans")

    def __init__(self, message: pb.EnvObservation, scans: memoryview) -> None:
        self.message = message
        self.scans = scans

    def __getattr__(self, name: str) -> Any:
        if name == "message":  # not set yet: no field to look for
            raise AttributeError(name)
        return getattr(self.message, name)


def observation(frames: list[Any]) -> Observation:
    """The observation of an env reply's two payload frames."""
    if len(frames) != 2:
        raise errors.BadMessage(1, "env_reply", f"an observation has 2 payload frames, got {len(frames)}")
    # the small message is parsed from its bytes (a zmq.Frame's are copied once: a few KB)
    raw = getattr(frames[0], "bytes", frames[0])
    meta = pb.EnvObservation.FromString(raw if isinstance(raw, bytes) else _view(frames[0]))
    return Observation(meta, _view(frames[1]))


def image(frames: list[Any]) -> tuple[pb.EnvImage, memoryview]:
    """The size and pixels of an image reply's two payload frames."""
    if len(frames) != 2:
        raise errors.BadMessage(1, "env_reply", f"an image has 2 payload frames, got {len(frames)}")
    meta = pb.EnvImage()
    meta.ParseFromString(_view(frames[0]))
    return meta, _view(frames[1])
